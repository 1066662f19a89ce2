"""Stage 1 alone under config variants, from a finished run's dense init: what a stage-1 setting
is worth on held-out views, without re-running the rest of the pipeline.

    python benchmarks/stage1_variants.py RUN [--set training.KEY=VALUE ...] [--average-from STEP ...] [--out FILE.json]

The base is RUN's own configuration (config.json), with the ``--set`` overrides applied as
`fixer4d run --set` would. Stage 1 is one field (``training.fields``: the variants are of one
field's training), built exactly as the pipeline builds each (`pipeline.stages.stage1_trainer`)
from RUN/init_mvs, trained in a temporary run folder and
evaluated there like the "STGS w/ MVS" row (`pipeline.stages.evaluate_stage`: held-out cameras
every `eval.stride` frames, all / moving / static pixels). It also reports the PSNR on the train
views (same frames), which tells over- from under-fitting. RUN itself is only read.
``--average-from STEP`` also scores the model whose parameters are the mean of the iterates
after STEP (one every ``AVERAGE_EVERY`` steps; restarted if the Gaussian count changes): tail
averaging, a candidate for a steadier stage 1 over seeds. ``--set scene.source=demo_val`` scores
the variants on the demo's validation cameras (same train cameras, same init).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import fixer4d  # noqa: F401  (sets the OpenMP wait policy before torch is imported)


def train_view_psnr(render_fn, scene, stride: int) -> float:
    """Mean PSNR (dB) of ``render_fn`` over the train cameras at every ``stride``-th frame."""
    values = []
    for cid in scene.train_ids:
        for f in range(0, scene.num_frames, stride):
            err = float(np.mean((render_fn(scene.cameras[cid], scene.time(f)) - scene.frame(f, cid)) ** 2))
            values.append(-10.0 * np.log10(max(err, 1e-12)))
    return float(np.mean(values))


def variant_config(run: Path, sets: list[str]):
    """RUN's RunConfig with the ``--set`` overrides applied as `fixer4d run --config` applies them
    (a new ``training.iterations`` rescales the schedule the run derived from its own count)."""
    from fixer4d.pipeline import config_tree
    from fixer4d.pipeline.config import resolve
    from fixer4d.pipeline.run_folder import read_run_config

    return resolve(config_file=read_run_config(run).to_dict(), overrides=config_tree.parse_set_overrides(sets),
                   defaults={})


# Steps between two iterates taken into a tail average: 10 of the last few hundred steps keep the
# average's noise close to the every-step average at a tenth of the copies.
AVERAGE_EVERY = 10


def train_with_tail_averages(trainer, starts: list[int]) -> dict[int, dict]:
    """Train ``trainer`` to the end; returns {start: (mean of its floating state after ``start``,
    count)} over iterates every ``AVERAGE_EVERY`` steps (an average restarts when a tensor's
    shape changes: densification or pruning inside the window)."""
    sums: dict[int, dict] = {s: {"state": None, "n": 0} for s in starts}
    while trainer.step_count < trainer.total_iterations:
        trainer.train(AVERAGE_EVERY if starts else None, progress=False)
        state = {k: v.detach().clone() for k, v in trainer.model.state_dict().items() if v.is_floating_point()}
        for s in starts:
            acc = sums[s]
            if trainer.step_count <= s:
                continue
            if acc["state"] is None or any(acc["state"][k].shape != v.shape for k, v in state.items()):
                acc["state"], acc["n"] = state, 1
            else:
                for k, v in state.items():
                    acc["state"][k] += v
                acc["n"] += 1
    return {s: {"state": {k: v / acc["n"] for k, v in acc["state"].items()}, "n": acc["n"]}
            for s, acc in sums.items() if acc["state"] is not None}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished fixer4d run folder (its init_mvs/ is used)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help="config override, e.g. training.seed=1 (repeatable)")
    parser.add_argument("--average-from", dest="average_from", type=int, action="append", default=[], metavar="STEP",
                        help="also score the mean of the iterates after STEP (repeatable)")
    parser.add_argument("--out", type=Path, default=None, help="also write the result as JSON")
    args = parser.parse_args(argv)

    from fixer4d.init.decompose import DecomposedInit, has_decomposed
    from fixer4d.render.views import model_render_fn
    from fixer4d.pipeline.run_folder import RunFolder, load_scene_for
    from fixer4d.pipeline.stages import StageContext, evaluate_stage, stage1_trainer

    init_dir = args.run / "init_mvs"
    if not has_decomposed(init_dir):
        print(f"{init_dir}: no decomposed dense init; run `fixer4d run` first", file=sys.stderr)
        return 2
    config = variant_config(args.run, ["training.fields=1", *args.sets])
    scene = load_scene_for(config)
    init = DecomposedInit.load(init_dir)
    with tempfile.TemporaryDirectory(prefix="stage1_variant_") as tmp:
        ctx = StageContext(run=RunFolder(Path(tmp), config), scene=scene, progress=False)
        trainer, _ = stage1_trainer(ctx, init, None)
        cpu0, wall0 = time.process_time(), time.perf_counter()
        averages = train_with_tail_averages(trainer, args.average_from)
        cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
        render = model_render_fn(trainer.model, config.training.backend, ctx.background)
        mean = evaluate_stage(ctx, "STGS w/ MVS", render, "variant", {})["mean"]
        result = {"run": str(args.run), "sets": args.sets, "psnr": mean["psnr"],
                  "psnr_dynamic": mean.get("psnr_dynamic"), "psnr_static": mean.get("psnr_static"),
                  "lpips": mean.get("lpips"), "train_view_psnr": train_view_psnr(render, scene, config.eval.stride),
                  "gaussians": trainer.model.num_gaussians, "train_cpu_s": cpu, "train_wall_s": wall, "averaged": {}}
        last = {k: v.clone() for k, v in trainer.model.state_dict().items()}
        for start, avg in averages.items():
            trainer.model.load_state_dict({**last, **avg["state"]})
            render = model_render_fn(trainer.model, config.training.backend, ctx.background)
            m = evaluate_stage(ctx, "STGS w/ MVS", render, f"average-from-{start}", {})["mean"]
            result["averaged"][str(start)] = {"iterates": avg["n"], "psnr": m["psnr"],
                                              "psnr_dynamic": m.get("psnr_dynamic"), "lpips": m.get("lpips")}
        trainer.model.load_state_dict(last)
    fmt = lambda v: "n/a" if v is None else f"{v:.2f}"  # noqa: E731
    print(f"{' '.join(args.sets) or '(run config)'}: PSNR {fmt(result['psnr'])} (moving {fmt(result['psnr_dynamic'])}, "
          f"static {fmt(result['psnr_static'])}), train views {fmt(result['train_view_psnr'])}, "
          f"{result['gaussians']} Gaussians, stage 1 {cpu:.0f} CPU s / {wall:.0f} s wall")
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
