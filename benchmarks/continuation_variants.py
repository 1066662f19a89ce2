"""The matched continuation of a finished run's stage-1 model under config variants: what the
training after stage 1 does to held-out views, without re-running the pipeline.

    python benchmarks/continuation_variants.py RUN [--set KEY=VALUE ...] [--keep-decay] [--out FILE.json]

The continuation is the pipeline's matched-iterations control (`pipeline.stages.matched_stage1`:
stage 1 continued for stage 2's length with stage 2's learning rates and densification window,
no pseudo-views), from RUN/model_stage1.ply and the camera response stage 1 trained. The
self-check's *continue* candidate is the same training on its fold. ``--keep-decay`` keeps the
run's learned opacity decay (``training.opacity_decay``) on in the continuation, where the
pipeline switches it off. ``--set scene.source=VAL`` scores it on validation cameras (same train
cameras). Reports the stage-1 model's and the continuation's PSNR there; RUN is only read.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import fixer4d  # noqa: F401  (sets the OpenMP wait policy before torch is imported)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from stage1_variants import variant_config  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished fixer4d run folder (its model_stage1.ply is used)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                        help="config override, e.g. scene.source=demo_val (repeatable)")
    parser.add_argument("--keep-decay", action="store_true",
                        help="keep the run's opacity decay on in the continuation")
    parser.add_argument("--out", type=Path, default=None, help="also write the result as JSON")
    args = parser.parse_args(argv)

    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.run_folder import RunFolder, load_scene_for
    from fixer4d.pipeline.stages import StageContext, evaluate_stage, stage1_response
    from fixer4d.render.views import model_render_fn
    from fixer4d.train.config import matched_config
    from fixer4d.train.trainer import Trainer

    stage1 = args.run / "model_stage1.ply"
    if not stage1.is_file():
        print(f"{stage1}: absent; run `fixer4d run` first", file=sys.stderr)
        return 2
    config = variant_config(args.run, args.sets)
    scene = load_scene_for(config)
    run_ctx = StageContext(run=RunFolder(args.run, config), scene=scene, progress=False)
    response = stage1_response(run_ctx)
    training = run_ctx.training_config()
    cfg = matched_config(training, config.stage2)
    if args.keep_decay:
        if not training.opacity_decay.enabled:
            print(f"{args.run}: its stage 1 has no opacity decay to keep", file=sys.stderr)
            return 2
        cfg = dataclasses.replace(cfg, opacity_decay=training.opacity_decay)
    model = load_ply(stage1)
    with tempfile.TemporaryDirectory(prefix="continuation_variant_") as tmp:
        ctx = StageContext(run=RunFolder(Path(tmp), config), scene=scene, progress=False)
        backend = config.training.backend
        before = evaluate_stage(ctx, "STGS w/ MVS", model_render_fn(model, backend, ctx.background), "stage1",
                                {})["mean"]
        trainer = Trainer(model, ctx.train_scene, cfg, run_dir=None, camera_response=response)
        cpu0 = time.process_time()
        trainer.train(progress=False)
        cpu = time.process_time() - cpu0
        after = evaluate_stage(ctx, "STGS w/ MVS (matched iterations)",
                               model_render_fn(trainer.host_model(), backend, ctx.background), "continued", {})["mean"]
    result = {"run": str(args.run), "sets": args.sets, "keep_decay": args.keep_decay,
              "stage1": {k: before.get(k) for k in ("psnr", "psnr_dynamic", "lpips")},
              "continued": {k: after.get(k) for k in ("psnr", "psnr_dynamic", "lpips")},
              "gain_db": after["psnr"] - before["psnr"], "iterations": cfg.iterations, "train_cpu_s": cpu}
    print(f"{' '.join(args.sets) or '(run config)'}{' keep-decay' if args.keep_decay else ''}: stage 1 "
          f"{before['psnr']:.2f} dB, continued {after['psnr']:.2f} dB ({result['gain_db']:+.2f}), {cpu:.0f} CPU s")
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
