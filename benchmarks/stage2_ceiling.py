"""How much can stage 2 gain at best? Stage 2 with *perfect* pseudo-targets, on a synthetic scene.

    python benchmarks/stage2_ceiling.py RUN --out DIR [--set stage2.lambda_gen=1.0 ...]

RUN is a finished `fixer4d run` folder of a synthetic scene (its config, scene and stage-1 model
are used as they are). Stage 2 is run again into DIR with the pipeline's own stage function and
refresh callback, but the restorer is replaced by an oracle that returns the scene's ground-truth
render of every trajectory camera at the clip's time, with confidence 1. Whatever this run gains
over RUN's matched-iterations control is the most any restorer could give with these
trajectories, iterations and loss weights: the ceiling of the report's "Full - matched" figure.
The oracle's frames are the pseudo-targets on every pixel (``stage2.pseudo_target=restored``:
a perfect frame needs no gate); ``--set stage2.pseudo_target=gated`` measures the gated loss
with perfect restorations instead.

This is a diagnostic that reads ground truth, so it lives here and never in the method: the
oracle is not a restorer choice, and nothing it produces feeds another run.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

import fixer4d  # noqa: F401  (sets the OpenMP wait policy before torch is imported)


class GroundTruthOracle:
    """A "restorer" that knows the answer: the synthetic scene's ray-cast RGB at each camera."""

    name = "ground-truth-oracle"

    def __init__(self, scene) -> None:
        if not hasattr(scene, "render_gt"):
            raise SystemExit("stage2_ceiling: the run's scene has no ground truth (synthetic scenes only)")
        self.scene = scene

    def settings(self) -> dict[str, Any]:
        return {"oracle": "ground truth"}

    def restore(self, request, progress=None):
        from fixer4d.restore.base import RestoreResult

        rgb = np.stack([self.scene.render_gt(cam, request.time)[0] for cam in request.cameras]).astype(np.float32)
        conf = np.ones(rgb.shape[:3], np.float32)
        return RestoreResult(rgb=np.clip(rgb, 0, 1), confidence=conf, frame_confidence=conf.mean(axis=(1, 2)))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished fixer4d run folder of a synthetic scene")
    parser.add_argument("--out", type=Path, required=True, help="new folder for the oracle stage 2")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="stage2.* / trajectories.* overrides for the oracle run")
    args = parser.parse_args(argv)

    from fixer4d.model.io import load_ply
    from fixer4d.pipeline import config_tree
    from fixer4d.pipeline import report as R
    from fixer4d.pipeline import stages as S
    from fixer4d.pipeline.config import RunConfig
    from fixer4d.pipeline.restoration import make_refresh_callback
    from fixer4d.render.views import model_render_fn
    from fixer4d.pipeline.run import open_context
    from fixer4d.pipeline.run_folder import read_run_config

    base = read_run_config(args.run)
    tree = config_tree.to_dict(base)
    config_tree.set_dotted(tree, "stage2.pseudo_target", "restored")
    for key, value in config_tree.parse_set_overrides(args.set).items():
        if not key.startswith(("stage2.", "trajectories.")):
            raise SystemExit(f"stage2_ceiling: only stage2.* and trajectories.* may change, not {key}")
        config_tree.set_dotted(tree, key, value)
    config = config_tree.build(RunConfig, tree)
    ctx = open_context(config, args.out)
    model = load_ply(args.run / "model_stage1.ply")
    refresh = make_refresh_callback(ctx.path, ctx.scene, config, backend=ctx.backend,
                                    restorer=GroundTruthOracle(ctx.scene))
    model = S.stage2(ctx, model, refresh=refresh)
    m = S.evaluate_stage(ctx, "Full (oracle pseudo-targets)",
                         model_render_fn(model, ctx.backend, ctx.background),
                         S.stage2_key(config) + ":oracle", {"prep": None, "train": ctx.run.records.seconds("stage2")})

    report = json.loads((args.run / "report.json").read_text())
    rows = {r["method"]: r for r in report["rows"]}
    oracle = R.metrics_row("Full (oracle pseudo-targets)", m, ctx.run.records.seconds("stage2"))
    out_rows = [rows.get(n) for n in (R.ROW_MVS, R.ROW_MATCHED, R.ROW_FULL)] + [oracle]
    lines = ["| row | PSNR | PSNR dynamic | PSNR static |", "|---|---|---|---|"]
    for r in out_rows:
        if r is not None and r.get("psnr") is not None:
            lines.append(f"| {r['method']} | {r['psnr']:.2f} | {r.get('psnr_dynamic') or float('nan'):.2f} | "
                         f"{r.get('psnr_static') or float('nan'):.2f} |")
    text = "\n".join(lines)
    print(text)
    (args.out / "ceiling.md").write_text(f"stage 2 ceiling of {args.run} (overrides: {args.set or 'none'})\n\n{text}\n")
    (args.out / "ceiling.json").write_text(json.dumps({"run": str(args.run), "overrides": args.set,
                                                       "rows": [r for r in out_rows if r is not None]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
