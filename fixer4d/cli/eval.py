"""`fixer4d eval RUN [--model PATH] [--stride S] [--backend B] [--cameras-from DIR]`: evaluate a run on its
held-out cameras (or, with ``--cameras-from``, on another folder's: ``pipeline.other_cameras``).

Opens the run folder (``fixer4d.pipeline.RunFolder``: versioned config, its scene), loads the latest model
(``model_final.ply``, else ``model_stage1.ply``, or ``--model``), renders every held-out camera at
every S-th frame (default: the run's ``eval.stride``, the report's protocol) and writes
``RUN/eval/<method-slug>/`` (metrics.json, metrics.md, PNGs) and a copy of metrics.json at
``RUN/metrics.json``. Another stride writes ``RUN/eval/<method-slug>-stride<S>/`` only: the
report's rows are never replaced by figures over other frames.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from fixer4d.errors import InputError
from fixer4d.cli.export import RUN_MODELS, missing_model_message


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="run folder (holds config.json and model_*.ply)")
    parser.add_argument("--model", default=None,
                        help="model to evaluate (.ply); default: RUN/model_final.ply, else RUN/model_stage1.ply")
    parser.add_argument("--stride", type=int, default=None,
                        help="evaluate every S-th frame (default: the run's eval.stride, as the report; another "
                             "stride writes RUN/eval/<method>-stride<S>/ and leaves the report's files alone)")
    parser.add_argument("--backend", default="auto", help="render backend: auto, reference, cpu, gsplat")
    parser.add_argument("--method", default=None, help="method name in the table (default: from the model file)")
    parser.add_argument("--examples", type=int, default=3, help="frames saved as render|gt|error PNGs per view")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--cameras-from", default=None, metavar="DIR",
                        help="score the run's models on the held-out cameras of DIR instead (a validation folder "
                             "with the same train cameras) -> RUN/heldout/<DIR name>/report.md")


def find_model(run: Path, model: str | None = None) -> Path:
    """The model to evaluate: ``model`` if given, else the run's latest (final, then stage 1)."""
    if model is not None:
        path = Path(model)
        if not path.is_file():
            raise InputError(f"--model {path}: no such file")
        return path
    for name in RUN_MODELS:
        if (run / name).is_file():
            return run / name
    raise InputError(missing_model_message(run) + "; or pass --model")


def known_seconds(folder, model_path: Path) -> dict[str, float]:
    """Preparation and training seconds the run recorded for ``model_path`` (absent when unknown)."""
    rec = folder.records
    method = folder.config.init_method
    found: dict[str, float] = {}
    if f"init_{method}" in rec.as_seconds():
        found["prep"] = rec.seconds(f"init_{method}")
    stages = {"model_stage1.ply": ("stage1",), "model_final.ply": ("stage1", "stage2")}.get(model_path.name)
    if stages and all(s in rec.as_seconds() for s in stages):
        found["train"] = rec.seconds(*stages)
    return found


def method_name_for(model_path: Path, init_method: str) -> str:
    """A table label: the report's row name for the run's own models, the file stem otherwise."""
    from fixer4d.pipeline import report as R

    if model_path.name == "model_final.ply":
        return R.ROW_FULL
    if model_path.name == "model_stage1.ply":
        return R.ROW_MVS if init_method != "sparse" else R.ROW_COLMAP
    return model_path.stem


def run(args: argparse.Namespace) -> int:
    from fixer4d.atomic import write_json
    from fixer4d.eval.evaluate import evaluate, markdown_table
    from fixer4d.model.io import load_ply
    from fixer4d.render.views import model_render_fn
    from fixer4d.pipeline.run_folder import RunFolder
    from fixer4d.train.background import resolve_background
    from fixer4d.pipeline.stages import eval_slug

    if args.cameras_from is not None:
        from fixer4d.pipeline.other_cameras import evaluate_on_other_cameras

        report = evaluate_on_other_cameras(args.run, args.cameras_from, progress=not args.quiet)
        print(f"wrote {Path(args.run) / 'heldout' / Path(args.cameras_from).resolve().name}/report.md "
              f"({len(report['rows'])} rows on {report['scene']})")
        return 0
    folder = RunFolder.open(args.run)
    model_path = find_model(folder.path, args.model)
    model = load_ply(model_path).eval()
    render_fn = model_render_fn(model, args.backend, resolve_background(folder.config.training.background,
                                                                        folder.scene))
    method = args.method or method_name_for(model_path, folder.config.init_method)
    stride = folder.config.eval.stride if args.stride is None else args.stride
    if stride < 1:
        raise InputError(f"--stride {stride}: must be >= 1")
    protocol = stride == folder.config.eval.stride
    out = folder.path / "eval" / (eval_slug(method) if protocol else f"{eval_slug(method)}-stride{stride}")
    result = evaluate(render_fn, folder.scene, out, frame_stride=stride, method_name=method,
                      seconds=known_seconds(folder, model_path), save_examples=args.examples, progress=not args.quiet)
    result["model"] = str(model_path)
    write_json(out / "metrics.json", result)
    if protocol:
        write_json(folder.path / "metrics.json", result)
    print(markdown_table([result]), end="")
    if result["lpips_unavailable_reason"]:
        print(f"LPIPS unavailable: {result['lpips_unavailable_reason']}")
    print(f"wrote {folder.path / 'metrics.json'} and {out}/" if protocol else
          f"wrote {out}/ (stride {stride}, not the run's {folder.config.eval.stride}: RUN/metrics.json and the "
          "report's rows are left as they are)")
    return 0
