"""Does a stage-1 field's training depend on the compute thread count? Field 0 of RUN's stage 1,
built as the pipeline builds it (`pipeline.stages.stage1_trainer`), stepped on THREADS threads;
a hash of every model tensor at the listed steps (docs/decisions/field-workers.md).

    python benchmarks/thread_count_probe.py RUN THREADS [--steps 50,100,150,200] [--set KEY=VALUE ...] [--out FILE.json]

Run it once per thread count and compare the hashes: the first step where they part is where a
sum's order follows the thread count. ``--set`` changes RUN's config as `fixer4d run --set` does
(e.g. ``training.opacity_decay.enabled=false``). RUN (a finished run with its init) is only read.
"""
from __future__ import annotations

import argparse
import hashlib
import shutil
import sys
import tempfile
from pathlib import Path

import fixer4d  # noqa: F401  (sets the OpenMP wait policy before torch is imported)

sys.path.insert(0, str(Path(__file__).resolve().parent))


def state_hash(model) -> str:
    """sha256 (first 16 hex digits) of the model's tensors, by name."""
    h = hashlib.sha256()
    for _, t in sorted(model.tensors().items()):
        h.update(t.detach().cpu().numpy().tobytes())
    return h.hexdigest()[:16]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("threads", type=int)
    parser.add_argument("--steps", default="50,100,150,200")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)

    from fixer4d.jit import set_compute_threads

    set_compute_threads(args.threads)
    from fixer4d.atomic import write_json
    from fixer4d.pipeline import stages as S
    from fixer4d.pipeline.run import open_context
    from fixer4d.pipeline.run_folder import source_commit
    from fixer4d.threads import digit_threads
    from stage1_variants import variant_config

    marks = sorted(int(s) for s in args.steps.split(","))
    rows = []
    with tempfile.TemporaryDirectory(prefix="thread_probe_") as tmp, digit_threads():
        work = Path(tmp)
        config = variant_config(args.run, args.sets)
        ctx = open_context(config, work, progress=False)
        shutil.copytree(args.run / "init_mvs", work / "init_mvs")
        trainer, _ = S.stage1_trainer(ctx, S.init_stage(ctx, config.init_method), None, field=0)
        for step in range(1, marks[-1] + 1):
            trainer.step()
            if step in marks:
                rows.append({"step": step, "gaussians": trainer.model.num_gaussians, "hash": state_hash(trainer.model)})
                print(f"threads {args.threads} step {step}: {rows[-1]['gaussians']} Gaussians, {rows[-1]['hash']}", flush=True)
    if args.out is not None:
        write_json(args.out, {"run": str(args.run), "threads": args.threads, "sets": args.sets, "commit": source_commit(),
                              "command": "python benchmarks/thread_count_probe.py " + " ".join(sys.argv[1:] if argv is None else argv),
                              "steps": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
