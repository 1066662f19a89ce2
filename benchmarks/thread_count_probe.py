"""Does a stage-1 field's training depend on the compute thread count? Field 0 of RUN's stage 1,
built as the pipeline builds it (`pipeline.stages.stage1_trainer`), stepped on THREADS threads;
a hash of every model tensor at the listed steps (docs/decisions/field-workers.md).

    python benchmarks/thread_count_probe.py RUN THREADS [--steps 50,100,150,200] [--set KEY=VALUE ...]
                                           [--time-blocks N] [--out FILE.json]

Run it once per thread count and compare the hashes: the first step where they part is where an
op's result follows the thread count (none does under the one-thread rule, fixer4d/threads.py). ``--set`` changes RUN's config as `fixer4d run --set` does
(e.g. ``training.opacity_decay.enabled=false``). RUN (a finished run with its init) is only read.
THREADS is numba's count; torch steps on ``fixer4d.threads.DIGIT_TORCH_THREADS`` as in a run.
``--time-blocks N``: after the last step, N pairs of blocks of ``BLOCK_STEPS`` steps, one with torch
on ``DIGIT_TORCH_THREADS`` and one with torch on THREADS, taking turns in this one process (a
change of load hits both alike): what the one-thread rule costs or saves a step.
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

# Steps per timed block: long enough to hold a densification step at most now and then, short
# enough that the two settings take turns often.
BLOCK_STEPS = 8


def state_hash(model) -> str:
    """sha256 (first 16 hex digits) of the model's tensors, by name."""
    h = hashlib.sha256()
    for _, t in sorted(model.tensors().items()):
        h.update(t.detach().cpu().numpy().tobytes())
    return h.hexdigest()[:16]


def time_torch_threads(trainer, threads: int, blocks: int) -> dict:
    """Seconds per step of ``trainer`` with torch on DIGIT_TORCH_THREADS and on ``threads`` threads
    (numba on ``threads`` both): ``blocks`` pairs of BLOCK_STEPS-step blocks taking turns; each
    setting's mean, and every block's seconds with /proc/loadavg's first figure after it."""
    import os
    import time

    from fixer4d import threads as digit

    chosen = digit.DIGIT_TORCH_THREADS
    per = {chosen: [], threads: []}
    try:
        for _ in range(blocks):
            for torch_count in (chosen, threads):
                digit.DIGIT_TORCH_THREADS = torch_count
                tic = time.perf_counter()
                for _ in range(BLOCK_STEPS):
                    trainer.step()
                per[torch_count].append({"seconds_per_step": (time.perf_counter() - tic) / BLOCK_STEPS,
                                         "load": os.getloadavg()[0], "gaussians": trainer.model.num_gaussians})
    finally:
        digit.DIGIT_TORCH_THREADS = chosen
    out = {"block_steps": BLOCK_STEPS, "numba_threads": threads, "blocks": {str(k): v for k, v in per.items()},
           "mean_seconds_per_step": {str(k): sum(b["seconds_per_step"] for b in v) / len(v) for k, v in per.items()}}
    print(f"seconds per step, torch on {chosen} / {threads} threads: "
          + " / ".join(f"{out['mean_seconds_per_step'][str(k)]:.4f}" for k in (chosen, threads)), flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("threads", type=int)
    parser.add_argument("--steps", default="50,100,150,200")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--time-blocks", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.time_blocks > 0 and args.threads == 1:
        parser.error("--time-blocks compares torch on one thread with torch on THREADS: give THREADS > 1")

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
        timing = time_torch_threads(trainer, args.threads, args.time_blocks) if args.time_blocks > 0 else None
    if args.out is not None:
        write_json(args.out, {"run": str(args.run), "threads": args.threads, "sets": args.sets, "commit": source_commit(),
                              "command": "python benchmarks/thread_count_probe.py " + " ".join(sys.argv[1:] if argv is None else argv),
                              "steps": rows, **({} if timing is None else {"timing": timing})})
    return 0


if __name__ == "__main__":
    sys.exit(main())
