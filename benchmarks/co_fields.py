"""Stage 1 with a twin field and co-pruning (``co_fields``), from a finished run's dense init: what
the option is worth on held-out (validation) cameras, paired with the quality bench's baseline.

    python benchmarks/co_fields.py run RUN [--set KEY=VALUE ...] --baseline FILE.json --out OUT.json
    python benchmarks/co_fields.py weights RUN --fields DIR [--set KEY=VALUE ...] --out OUT.json
    python benchmarks/co_fields.py summary OUT.json ... --out SUMMARY.json

``run`` builds stage 1 exactly as the pipeline does (``pipeline.stages.stage1_trainer``, RUN's
config.json with the ``--set`` overrides, ``co_fields.enabled=true`` and one field added), trains
field A and its twin side by side (``train.co_fields.CoFields``) and scores field A like the "STGS
w/ MVS" row (``pipeline.stages.evaluate_stage``), field B too. ``--baseline`` is the quality bench's result file
of the same set and seed (its "STGS w/ MVS" row is field A's paired baseline). The cost is each
field's own training seconds in the same process, and the co-pruning's. ``summary`` pairs the
runs by set over seeds (``fixer4d.stats``: mean of the paired differences and its 95 % interval).
``run --save-fields DIR`` keeps both fields (DIR/field_a.ply, DIR/field_b.ply) for ``weights``: the
gated "Restoration (init)" row of field A with RUN's restorer, once per ``co_fields.weight``
(visibility, undetermined, max; field B the twin), on the same cameras: the weight's effect on
the restored images, paired on one model.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import fixer4d  # noqa: E402,F401  (sets the OpenMP wait policy before torch is imported)
from benchmarks.stage1_variants import train_view_psnr, variant_config  # noqa: E402

ROW = "STGS w/ MVS"


def run(args: argparse.Namespace) -> int:
    from fixer4d.init.decompose import DecomposedInit, has_decomposed
    from fixer4d.pipeline.run_folder import RunFolder, load_scene_for
    from fixer4d.pipeline.stages import StageContext, evaluate_stage, stage1_trainer
    from fixer4d.render.views import model_render_fn
    from fixer4d.train.co_fields import CoFields, twin_trainer

    init_dir = args.run / "init_mvs"
    if not has_decomposed(init_dir):
        print(f"{init_dir}: no decomposed dense init; run `fixer4d run` first", file=sys.stderr)
        return 2
    sets = args.sets + ["co_fields.enabled=true", "training.fields=1"]
    config = variant_config(args.run, sets)
    baseline = next(r for r in json.loads(args.baseline.read_text())["rows"] if r["method"] == ROW)
    scene = load_scene_for(config)
    with tempfile.TemporaryDirectory(prefix="co_fields_") as tmp:
        ctx = StageContext(run=RunFolder(Path(tmp), config), scene=scene, progress=False)
        a, decision = stage1_trainer(ctx, DecomposedInit.load(init_dir), None)
        co = CoFields(a, twin_trainer(a, config.model_terms if decision is not None else None, None),
                      config.co_fields)
        wall0 = time.perf_counter()
        co.train()
        wall = time.perf_counter() - wall0
        if args.save_fields is not None:
            from fixer4d.model.io import save_ply

            args.save_fields.mkdir(parents=True, exist_ok=True)
            save_ply(co.a.model.cpu(), args.save_fields / "field_a.ply")
            save_ply(co.b.model.cpu(), args.save_fields / "field_b.ply")
        scores = {}
        for name, trainer in (("a", co.a), ("b", co.b)):
            render = model_render_fn(trainer.model, config.training.backend, ctx.background)
            m = evaluate_stage(ctx, ROW, render, f"field-{name}", {})["mean"]
            scores[name] = {"psnr": m["psnr"], "psnr_dynamic": m.get("psnr_dynamic"),
                            "psnr_static": m.get("psnr_static"), "lpips": m.get("lpips"),
                            "train_view_psnr": train_view_psnr(render, scene, config.eval.stride),
                            "gaussians": trainer.model.num_gaussians, "train_s": trainer.train_seconds}
    result = {"run": str(args.run), "scene": Path(config.scene.source).name, "sets": sets,
              "co_fields": config.co_fields.to_dict(),
              "seed": config.training.seed, "baseline_file": str(args.baseline), "baseline_psnr": baseline["psnr"],
              "baseline_lpips": baseline.get("lpips"), "field_a": scores["a"], "field_b": scores["b"],
              "gain_db": scores["a"]["psnr"] - baseline["psnr"], "co_prune": co.history,
              "co_prune_s": co.seconds, "wall_s": wall,
              "cost_ratio": (scores["a"]["train_s"] + scores["b"]["train_s"] + co.seconds) / scores["a"]["train_s"]}
    print(f"{' '.join(args.sets)}: field A {scores['a']['psnr']:.2f} dB (baseline {baseline['psnr']:.2f}, "
          f"{result['gain_db']:+.2f}), field B {scores['b']['psnr']:.2f}; {scores['a']['gaussians']} / "
          f"{scores['b']['gaussians']} Gaussians; stage 1 {wall:.0f} s wall, field A alone {scores['a']['train_s']:.0f} s "
          f"(x{result['cost_ratio']:.2f}); pruned {[(h['pruned_a'], h['pruned_b']) for h in co.history]}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    return 0


def weights(args: argparse.Namespace) -> int:
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.restoration import TwinWeight, UnobservedMasks, restoration_render_fn, run_restorer
    from fixer4d.train.background import resolve_background
    from fixer4d.pipeline.run_folder import RunFolder, load_scene_for
    from fixer4d.pipeline.stages import StageContext, evaluate_stage
    from fixer4d.train.co_fields_config import WEIGHTS

    config = variant_config(args.run, args.sets)
    scene = load_scene_for(config)
    a, b = load_ply(args.fields / "field_a.ply"), load_ply(args.fields / "field_b.ply")
    restorer = run_restorer(config, args.run)
    gate, backend = config.stage2.visibility, config.training.backend
    unobserved = UnobservedMasks(a, scene, gate, backend)
    result = {"run": str(args.run), "scene": Path(config.scene.source).name, "seed": config.training.seed,
              "sets": args.sets, "fields": str(args.fields), "rows": {}}
    with tempfile.TemporaryDirectory(prefix="co_fields_weights_") as tmp:
        ctx = StageContext(run=RunFolder(Path(tmp), config), scene=scene, progress=False)
        for mode in WEIGHTS:
            twin = None if mode == "visibility" else TwinWeight(b, mode)
            render = restoration_render_fn(a, scene, restorer, backend, gate, config.eval.fill_unobserved, twin,
                                           resolve_background(config.training.background, scene))
            tic = time.perf_counter()
            m = evaluate_stage(ctx, "Restoration (init)", render, f"weight-{mode}", {}, unobserved)["mean"]
            result["rows"][mode] = {"psnr": m["psnr"], "psnr_unobserved": m.get("psnr_unobserved"),
                                    "lpips": m.get("lpips"), "seconds": time.perf_counter() - tic}
            print(f"{mode}: Restoration (init) {m['psnr']:.3f} dB (unobserved {m.get('psnr_unobserved')})", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    return 0


def summary(args: argparse.Namespace) -> int:
    from fixer4d.stats import interval, paired_gain, student_t_quantile

    by_set: dict[str, list[dict]] = {}
    by_weights: dict[str, list[dict]] = {}
    for path in args.files:
        r = json.loads(path.read_text())
        (by_weights if "fields" in r else by_set).setdefault(r["scene"], []).append(r)
    out = {}
    for name, runs in sorted(by_weights.items()):
        runs.sort(key=lambda r: r["seed"])
        base = [r["rows"]["visibility"]["psnr"] for r in runs]
        entry = {"seeds": [r["seed"] for r in runs], "visibility": interval(base)}
        for mode in ("undetermined", "max"):
            mean, se = paired_gain([r["rows"][mode]["psnr"] for r in runs], base)
            entry[f"{mode}_minus_visibility_db"] = {
                "mean": mean, "ci95": None if se is None else student_t_quantile(0.975, len(runs) - 1) * se}
            print(f"{name} Restoration (init) {mode} - visibility: {mean:+.3f} dB")
        out[f"weights:{name}"] = entry
    for name, runs in sorted(by_set.items()):
        runs.sort(key=lambda r: r["seed"])
        a = [r["field_a"]["psnr"] for r in runs]
        base = [r["baseline_psnr"] for r in runs]
        mean, se = paired_gain(a, base)
        half = None if se is None else student_t_quantile(0.975, len(runs) - 1) * se
        out[name] = {"seeds": [r["seed"] for r in runs], "co_fields": runs[0]["co_fields"],
                     "field_a": interval(a), "baseline": interval(base), "field_b": interval([r["field_b"]["psnr"] for r in runs]),
                     "gain_db": {"mean": mean, "ci95": half, "values": [x - y for x, y in zip(a, base)]},
                     "cost_ratio": interval([r["cost_ratio"] for r in runs]),
                     "wall_s": interval([r["wall_s"] for r in runs]),
                     "field_a_train_s": interval([r["field_a"]["train_s"] for r in runs])}
        g = out[name]["gain_db"]
        print(f"{name} seeds {out[name]['seeds']}: field A {out[name]['field_a']['mean']:.2f}, baseline "
              f"{out[name]['baseline']['mean']:.2f}, paired {g['mean']:+.2f} ± {g['ci95'] if half is None else f'{half:.2f}'} dB, "
              f"cost x{out[name]['cost_ratio']['mean']:.2f}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("run", help="train both fields of one set and seed, score field A")
    p.add_argument("run", type=Path, help="a finished fixer4d run folder (its init_mvs/ is used)")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--baseline", type=Path, required=True, help="the quality bench's file of this set and seed")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--save-fields", dest="save_fields", type=Path, default=None, help="keep both fields here")
    p.set_defaults(fn=run)
    w = sub.add_parser("weights", help="the gated Restoration (init) row of field A under each co_fields.weight")
    w.add_argument("run", type=Path, help="the finished run whose restorer is used")
    w.add_argument("--fields", type=Path, required=True, help="a `run --save-fields` folder")
    w.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    w.add_argument("--out", type=Path, required=True)
    w.set_defaults(fn=weights)
    s = sub.add_parser("summary", help="pair the runs by set over seeds")
    s.add_argument("files", type=Path, nargs="+")
    s.add_argument("--out", type=Path, required=True)
    s.set_defaults(fn=summary)
    args = parser.parse_args(argv)
    return args.fn(args)


if __name__ == "__main__":
    raise SystemExit(main())
