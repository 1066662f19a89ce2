"""`fixer4d eval RUN [--model PATH] [--stride S] [--backend B]`: evaluate a run on its held-out cameras.

Opens the run's scene from ``RUN/config.json`` ("scene" section), loads the latest model
(``model_final.ply``, else ``model_stage1.ply``, or ``--model``), renders every held-out camera at
every S-th frame and writes ``RUN/eval/<method-slug>/`` (metrics.json, metrics.md, PNGs) and a
copy of metrics.json at ``RUN/metrics.json``.
"""
from __future__ import annotations

import argparse
import json
import re
from pathlib import Path
from typing import Any

from fixer4d.errors import InputError

MODEL_NAMES = ("model_final.ply", "model_stage1.ply")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="run folder (holds config.json and model_*.ply)")
    parser.add_argument("--model", default=None,
                        help="model to evaluate (.ply); default: RUN/model_final.ply, else RUN/model_stage1.ply")
    parser.add_argument("--stride", type=int, default=1, help="evaluate every S-th frame (default 1: every frame)")
    parser.add_argument("--backend", default="auto", help="render backend: auto, reference, cpu, gsplat")
    parser.add_argument("--method", default=None, help="method name in the table (default: from the model file)")
    parser.add_argument("--examples", type=int, default=3, help="frames saved as render|gt|error PNGs per view")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def _read_json(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc}); the run folder is corrupt") from exc


def find_model(run: Path, model: str | None = None) -> Path:
    """The model to evaluate: ``model`` if given, else the run's latest (final, then stage 1)."""
    if model is not None:
        path = Path(model)
        if not path.is_file():
            raise InputError(f"--model {path}: no such file")
        return path
    for name in MODEL_NAMES:
        if (run / name).is_file():
            return run / name
    raise InputError(f"{run}: no {' or '.join(MODEL_NAMES)}; run `fixer4d reconstruct` first or pass --model")


def config_section(config: dict[str, Any], name: str) -> dict[str, Any]:
    """A stage's section of config.json: top level (``fixer4d reconstruct`` runs) or under
    "pipeline" (``fixer4d run`` runs)."""
    section = config.get(name)
    if section is None:
        section = (config.get("pipeline") or {}).get(name)
    return dict(section or {})


def known_seconds(run: Path, model_path: Path | None = None, init_method: str | None = None) -> dict[str, float]:
    """Preparation and training seconds recorded in the run; unknown ones stay absent (null).

    Per-stage timings (report.json's "stage_seconds", else stages.json) give prep = init_<method>
    and train = stage1 (+ stage2 for model_final.ply); otherwise report.json's or a previous
    metrics.json's "seconds" {"prep", "train"} are taken as they are.
    """
    stages: dict[str, Any] = {}
    if (run / "report.json").is_file():
        stages = _read_json(run / "report.json").get("stage_seconds") or {}
    if not stages and (run / "stages.json").is_file():
        stages = _read_json(run / "stages.json")
    if stages and init_method:
        found: dict[str, float] = {}
        if isinstance(stages.get(f"init_{init_method}"), (int, float)):
            found["prep"] = float(stages[f"init_{init_method}"])
        train_stages = ["stage1"] + (["stage2"] if model_path is not None and model_path.name == "model_final.ply" else [])
        if all(isinstance(stages.get(k), (int, float)) for k in train_stages):
            found["train"] = float(sum(stages[k] for k in train_stages))
        if found:
            return found
    for name in ("report.json", "metrics.json"):
        path = run / name
        if path.is_file():
            secs = _read_json(path).get("seconds") or {}
            found = {k: float(secs[k]) for k in ("prep", "train") if isinstance(secs.get(k), (int, float))}
            if found:
                return found
    return {}


def method_name_for(model_path: Path, config: dict[str, Any]) -> str:
    """A table label: "4DGS-Fixer" for a final model, "STGS (<init> init)" for a stage-1 model."""
    init = config_section(config, "init").get("method")
    if model_path.name == "model_final.ply":
        return "4DGS-Fixer"
    if model_path.name == "model_stage1.ply":
        return f"STGS ({init} init)" if init else "STGS"
    return model_path.stem


def run(args: argparse.Namespace) -> int:
    import torch

    from fixer4d.atomic import write_json
    from fixer4d.eval.evaluate import evaluate, markdown_table
    from fixer4d.model.io import load_ply
    from fixer4d.render.api import render
    from fixer4d.scene import load_scene

    run_dir = Path(args.run)
    config_path = run_dir / "config.json"
    if not config_path.is_file():
        raise InputError(f"{config_path}: no such file; is {run_dir} a fixer4d run folder?")
    config = _read_json(config_path)
    scene_kwargs = dict(config.get("scene") or {})
    if "source" not in scene_kwargs:
        raise InputError(f"{config_path}: the \"scene\" section has no \"source\"")
    if scene_kwargs.get("frame_range") is not None:
        scene_kwargs["frame_range"] = tuple(scene_kwargs["frame_range"])
    scene = load_scene(**scene_kwargs)
    model_path = find_model(run_dir, args.model)
    model = load_ply(model_path).eval()
    background = config_section(config, "stage1").get("background")

    def render_fn(camera, t: float):
        with torch.no_grad():
            snap = model.at(t, camera_center=camera.center)
            return render(snap, camera, background=background, backend=args.backend).rgb.cpu().numpy()

    method = args.method or method_name_for(model_path, config)
    slug = re.sub(r"[^A-Za-z0-9._-]+", "-", method).strip("-").lower() or "model"
    seconds = known_seconds(run_dir, model_path, config_section(config, "init").get("method"))
    result = evaluate(render_fn, scene, run_dir / "eval" / slug, frame_stride=args.stride, method_name=method,
                      seconds=seconds, save_examples=args.examples, progress=not args.quiet)
    result["model"] = str(model_path)
    write_json(run_dir / "eval" / slug / "metrics.json", result)
    write_json(run_dir / "metrics.json", result)
    print(markdown_table([result]), end="")
    if result["lpips_unavailable_reason"]:
        print(f"LPIPS unavailable: {result['lpips_unavailable_reason']}")
    print(f"wrote {run_dir / 'metrics.json'} and {run_dir / 'eval' / slug}/")
    return 0
