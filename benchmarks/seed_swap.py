"""Where a stage-1 seed's luck enters: the init subsample drawn with one seed, the training (frame
and view order, densification draws, the decay network) with another.

    python benchmarks/seed_swap.py RUN INIT_SEED TRAIN_SEED VAL [--out FILE.json]

From RUN's dense init and configuration, stage 1 is built as the pipeline builds it
(`pipeline.stages.stage1_trainer`) with ``training.seed=INIT_SEED`` (the seeded subsample of the
init points), then trained by a Trainer whose seed is TRAIN_SEED, and scored like the "STGS w/
MVS" row on RUN's test cameras and on the validation cameras of VAL (a scene source with the same
train cameras). INIT_SEED = TRAIN_SEED is the pipeline's stage 1 of that seed. RUN is only read.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import fixer4d  # noqa: F401  (sets the OpenMP wait policy before torch is imported)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from stage1_variants import variant_config  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished fixer4d run folder (its init_mvs/ is used)")
    parser.add_argument("init_seed", type=int)
    parser.add_argument("train_seed", type=int)
    parser.add_argument("val", help="scene source of the validation cameras")
    parser.add_argument("--out", type=Path, default=None, help="also write the result as JSON")
    args = parser.parse_args(argv)

    from fixer4d.init.decompose import DecomposedInit
    from fixer4d.pipeline.run_folder import RunFolder, load_scene_for
    from fixer4d.pipeline.stages import StageContext, evaluate_stage, stage1_trainer
    from fixer4d.render.views import model_render_fn
    from fixer4d.train.trainer import Trainer

    config = variant_config(args.run, [f"training.seed={args.init_seed}"])
    backend = config.training.backend
    result = {"run": str(args.run), "init_seed": args.init_seed, "train_seed": args.train_seed}
    with tempfile.TemporaryDirectory(prefix="seed_swap_") as tmp:
        ctx = StageContext(run=RunFolder(Path(tmp), config), scene=load_scene_for(config), progress=False)
        built, _ = stage1_trainer(ctx, DecomposedInit.load(args.run / "init_mvs"), None)
        trainer = Trainer(built.model, ctx.train_scene, ctx.training_config(seed=args.train_seed), run_dir=None,
                          terms=config.model_terms, camera_response=built.response)
        trainer.train(progress=False)
        model = trainer.host_model()
        result["test_psnr"] = evaluate_stage(ctx, "STGS w/ MVS", model_render_fn(model, backend, ctx.background),
                                             "test", {})["mean"]["psnr"]
    val_config = variant_config(args.run, [f"training.seed={args.init_seed}", f"scene.source={args.val}"])
    with tempfile.TemporaryDirectory(prefix="seed_swap_") as tmp:
        ctx = StageContext(run=RunFolder(Path(tmp), val_config), scene=load_scene_for(val_config), progress=False)
        result["val_psnr"] = evaluate_stage(ctx, "STGS w/ MVS", model_render_fn(model, backend, ctx.background), "val",
                                            {})["mean"]["psnr"]
    print(json.dumps(result))
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
