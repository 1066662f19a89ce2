"""The scene's own prior, measured: how much do other seeds' stage-1 fields know about the views
four cameras leave undetermined, and does stage 2 carry it into one model?
(docs/decisions/seed-ensemble.md)

    python benchmarks/seed_ensemble.py renders SET --seeds 0,1,2,3,4 [--runs runs/quality_bg] --out FILE
    python benchmarks/seed_ensemble.py distil SET --seed S --twins T[,T...] --work DIR --out FILE [--set KEY=VALUE ...]
    python benchmarks/seed_ensemble.py coreg SET --seed S --out FILE [--weight 0.5]
    python benchmarks/seed_ensemble.py merge SET --seeds 0,1,2,3,4 --out FILE
    python benchmarks/seed_ensemble.py summary FILE ... --out FILE

SET is a quality-bench camera set (demo, panoptic, panoptic_c); the runs are the bench's finished
runs ``RUNS/SET/seed<S>`` (``fixer4d bench quality``), which differ in the seed only (the init's
subsample draw and the training's draws).

``renders`` scores, on the set's validation and test cameras, each seed's stage-1 model (the
"STGS w/ MVS" row) and the per-pixel mean of the renders of several seeds' models: each pair of
neighbouring seeds (s, s+1 mod n), each triple and all of them. ``gain`` is a pair's (triple's) PSNR
minus the mean PSNR of its members; the neighbouring pairs share members, so their interval is
descriptive, not a test.

``distil`` runs stage 2 forced (the pipeline's own ``stages.stage2``, from RUN's stage-1 model, into
DIR) with the mean of the current model's render and the twins' stage-1 renders as the pseudo-target
of every pixel (``stage2.pseudo_target=restored``, confidence 1); it scores Full on the validation
and test cameras and pairs it with the bench's rows of that seed. The "restorer" here renders the
twins itself: a diagnostic, never a restorer choice of the method (restorers never render).

``coreg`` trains stage 1 again from RUN's dense init as two fields side by side
(``train.co_fields``' twin: the same init, the seed moved), co-regularized in CoR-GS's way: from
step ``COREG_START``, before every ``COREG_CHUNK`` steps of a field, ``COREG_CLIPS`` clips (a pair
trajectory or arc at a random frame) are rendered by both fields, and their per-pixel mean is that
field's pseudo-target for the chunk (L1 at ``--weight``, the pseudo-views outside the
densification statistics; the stage-1 trainers are given stage 2's ``PseudoTargets`` and a schedule
that draws pseudo-views, which no pipeline stage does). Field A is scored like "STGS w/ MVS" and
paired with the bench's row.

``merge`` scores, for each neighbouring pair of seeds, one model made of both stage-1 models'
Gaussians under three opacity rules: ``halved`` (``train.fields.merge_fields``: each opacity / 2,
what ``training.fields=2`` does), ``transmittance`` (1 − sqrt(1 − opacity): a Gaussian seen
through its twin lets through what it alone would) and ``kept`` (the opacities as they were), on
the validation and test cameras, beside the pair's mean render and its members.

``summary`` pairs ``distil`` files by set and twin count over seeds (``fixer4d.stats.interval``).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import fixer4d  # noqa: E402,F401  (sets the OpenMP wait policy before torch is imported)
from fixer4d.atomic import write_json  # noqa: E402
from fixer4d.bench.quality import ROW_FULL, ROW_MATCHED, ROW_MVS, camera_sets  # noqa: E402
from fixer4d.stats import interval  # noqa: E402

DEFAULT_RUNS = ROOT / "runs" / "quality_bg"
# the quality bench's result files of those runs (one stage-1 field each, as before two fields
# became the default)
BASE_OUT = ROOT / "benchmarks" / "results" / "quality_one_field"
# Co-regularization from the second densification round of the default 1500-step schedule (the
# fields first grow apart from their shared init), targets renewed every 50 steps of a field from
# 8 clips: about 60 renders per field and chunk, a quarter of the chunk's own rendering.
COREG_START, COREG_CHUNK, COREG_CLIPS = 300, 50, 8
RenderFn = Callable[[Any, float], np.ndarray]


def mean_render(fns: Sequence[RenderFn]) -> RenderFn:
    """``fn(camera, t)``: the per-pixel mean of the renders of ``fns`` (float32, (H, W, 3))."""
    if not fns:
        raise ValueError("mean_render: no render functions")

    def fn(camera, t: float) -> np.ndarray:
        return np.mean([np.asarray(f(camera, t), np.float32) for f in fns], axis=0).astype(np.float32)

    return fn


def memoized(fn: RenderFn) -> RenderFn:
    """``fn`` with its images kept per (camera, t): every combination of seeds reads each render once."""
    memo: dict[tuple[int, float], np.ndarray] = {}

    def cached(camera, t: float) -> np.ndarray:
        key = (id(camera), round(float(t), 9))
        if key not in memo:
            memo[key] = np.asarray(fn(camera, t), np.float32)
        return memo[key]

    return cached


def combinations(seeds: Sequence[int]) -> dict[str, list[int]]:
    """Named seed groups: every seed alone, each neighbouring pair and triple (cyclic), all."""
    n = len(seeds)
    groups = {f"s{s}": [s] for s in seeds}
    for size in (2, 3):
        if n > size:
            for i in range(n):
                members = [seeds[(i + k) % n] for k in range(size)]
                groups["+".join(f"s{s}" for s in members)] = members
    if n > 1:
        groups["all"] = list(seeds)
    return groups


def group_gains(scores: dict[str, dict[str, Any]], groups: dict[str, list[int]]) -> dict[str, Any]:
    """Per group size k > 1: the interval of (group's PSNR − mean PSNR of its members)."""
    out: dict[str, Any] = {}
    for size in sorted({len(m) for m in groups.values()} - {1}):
        gains = [scores[name]["psnr"] - float(np.mean([scores[f"s{s}"]["psnr"] for s in members]))
                 for name, members in groups.items() if len(members) == size]
        out[str(size)] = interval(gains)
    return out


MERGE_RULES = ("halved", "transmittance", "kept")


def union(models: Sequence[Any], rule: str):
    """One model of ``models``' Gaussians with their opacities under ``rule`` (``MERGE_RULES``)."""
    import torch

    from fixer4d.model.spacetime import SpacetimeGaussians
    from fixer4d.train.fields import merge_fields

    if rule == "halved":
        return merge_fields(models)
    tensors = {k: torch.cat([m.tensors()[k].detach() for m in models]) for k in models[0].tensors()}
    if rule == "transmittance":
        alpha = torch.sigmoid(tensors["opacity_logits"].double())
        alpha = (1.0 - (1.0 - alpha).clamp_min(1e-12) ** (1.0 / len(models))).clamp(1e-12, 1 - 1e-12)
        tensors["opacity_logits"] = (torch.log(alpha) - torch.log1p(-alpha)).float()
    elif rule != "kept":
        raise ValueError(f"union: rule {rule!r} is not one of {MERGE_RULES}")
    return SpacetimeGaussians.from_tensors(models[0].config, tensors, source="union")


def merge(args: argparse.Namespace) -> int:
    from benchmarks.stage1_variants import variant_config
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.run_folder import RunFolder, load_scene_for
    from fixer4d.pipeline.stages import StageContext, evaluate_stage
    from fixer4d.render.views import model_render_fn
    from fixer4d.train.background import resolve_background

    seeds = [int(s) for s in args.seeds.split(",")]
    runs = {s: args.runs / args.set / f"seed{s}" for s in seeds}
    models = {s: load_ply(runs[s] / "model_stage1.ply") for s in seeds}
    pairs = [(seeds[i], seeds[(i + 1) % len(seeds)]) for i in range(len(seeds))]
    result: dict[str, Any] = {"set": args.set, "seeds": seeds, "runs": str(args.runs), "rules": list(MERGE_RULES),
                              "command": " ".join(sys.argv)}
    for split, source in _set_paths(args.set).items():
        config = variant_config(runs[seeds[0]], [f"scene.source={source}", "eval.examples=0"])
        scene = load_scene_for(config)
        background = resolve_background(config.training.background, scene)
        fns = {s: memoized(model_render_fn(models[s], config.training.backend, background)) for s in seeds}
        rows: dict[str, Any] = {}
        with tempfile.TemporaryDirectory(prefix="seed_ensemble_merge_") as tmp:
            ctx = StageContext(run=RunFolder(Path(tmp), config), scene=scene, progress=False)

            def psnr(fn, name: str) -> float:
                return float(evaluate_stage(ctx, ROW_MVS, fn, name, {})["mean"]["psnr"])

            alone = {s: psnr(fns[s], f"s{s}") for s in seeds}
            for a, b in pairs:
                row = {"members": float(np.mean([alone[a], alone[b]])),
                       "mean_render": psnr(mean_render([fns[a], fns[b]]), f"s{a}+s{b}")}
                for rule in MERGE_RULES:
                    fn = model_render_fn(union([models[a], models[b]], rule), config.training.backend, background)
                    row[rule] = psnr(fn, f"s{a}+s{b}_{rule}")
                rows[f"s{a}+s{b}"] = row
                print(f"{args.set} {split} s{a}+s{b}: " + ", ".join(f"{k} {v:.3f}" for k, v in row.items()), flush=True)
        gains = {k: interval([r[k] - r["members"] for r in rows.values()]) for k in ("mean_render", *MERGE_RULES)}
        result[split] = {"alone": alone, "pairs": rows, "gain_over_members": gains}
    write_json(args.out, result)
    return 0


def _set_paths(name: str) -> dict[str, str]:
    cs = camera_sets()[name]
    return {"val": cs.validation, "test": cs.scene}


def renders(args: argparse.Namespace) -> int:
    from benchmarks.stage1_variants import variant_config
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.run_folder import RunFolder, load_scene_for
    from fixer4d.pipeline.stages import StageContext, evaluate_stage
    from fixer4d.render.views import model_render_fn
    from fixer4d.train.background import resolve_background

    seeds = [int(s) for s in args.seeds.split(",")]
    runs = {s: args.runs / args.set / f"seed{s}" for s in seeds}
    groups = combinations(seeds)
    result: dict[str, Any] = {"set": args.set, "seeds": seeds, "runs": str(args.runs), "command": " ".join(sys.argv)}
    for split, source in _set_paths(args.set).items():
        config = variant_config(runs[seeds[0]], [f"scene.source={source}", "eval.examples=0"])
        scene = load_scene_for(config)
        background = resolve_background(config.training.background, scene)
        fns = {s: memoized(model_render_fn(load_ply(runs[s] / "model_stage1.ply"), config.training.backend, background))
               for s in seeds}
        scores: dict[str, dict[str, Any]] = {}
        with tempfile.TemporaryDirectory(prefix="seed_ensemble_") as tmp:
            ctx = StageContext(run=RunFolder(Path(tmp), config), scene=scene, progress=False)
            for name, members in groups.items():
                m = evaluate_stage(ctx, ROW_MVS, mean_render([fns[s] for s in members]), name, {})["mean"]
                scores[name] = {"members": members, "psnr": m["psnr"], "lpips": m.get("lpips")}
                print(f"{args.set} {split} {name}: {m['psnr']:.3f} dB", flush=True)
        result[split] = {"scores": scores, "gain": group_gains(scores, groups)}
    write_json(args.out, result)
    return 0


class TwinMean:
    """A diagnostic "restorer": the mean of the request's render and the twins' renders of the
    clip's cameras at its time, with confidence 1 (it renders the twins itself)."""

    name = "twin-mean"

    def __init__(self, twins: Sequence[Any], backend: str, background) -> None:
        self.twins, self.backend, self.background = list(twins), backend, background

    def settings(self) -> dict[str, Any]:
        return {"twins": len(self.twins)}

    def restore(self, request, progress=None):
        from fixer4d.render.views import render_views
        from fixer4d.restore.base import RestoreResult

        images = [np.asarray(request.rgb, np.float32)]
        images += [np.asarray(render_views(t, list(request.cameras), request.time, self.backend, self.background)[0],
                              np.float32) for t in self.twins]
        rgb = np.clip(np.mean(images, axis=0), 0.0, 1.0).astype(np.float32)
        conf = np.ones(rgb.shape[:3], np.float32)
        return RestoreResult(rgb=rgb, confidence=conf, frame_confidence=conf.mean(axis=(1, 2)))


def distil(args: argparse.Namespace) -> int:
    import shutil

    from benchmarks.stage1_variants import variant_config
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline import config_tree
    from fixer4d.pipeline import stages as S
    from fixer4d.pipeline.config import RunConfig
    from fixer4d.pipeline.restoration import make_refresh_callback
    from fixer4d.pipeline.run import open_context
    from fixer4d.pipeline.run_folder import RunFolder, load_scene_for, read_run_config
    from fixer4d.render.views import model_render_fn

    twins = [int(t) for t in args.twins.split(",")]
    if args.seed in twins:
        raise SystemExit("distil: a twin must be another seed's run")
    run = args.runs / args.set / f"seed{args.seed}"
    paths = _set_paths(args.set)
    tree = config_tree.to_dict(read_run_config(run))
    for key, value in {"scene.source": paths["val"], "stage2.pseudo_target": "restored", "eval.examples": 0,
                       **config_tree.parse_set_overrides(args.sets)}.items():
        config_tree.set_dotted(tree, key, value)
    config = config_tree.build(RunConfig, tree)
    ctx = open_context(config, args.work, progress=False)
    shutil.copy(run / "model_terms.json", args.work / "model_terms.json")  # stage 1's camera response
    restorer = TwinMean([load_ply(args.runs / args.set / f"seed{t}" / "model_stage1.ply") for t in twins],
                        ctx.backend, ctx.background)
    refresh = make_refresh_callback(ctx.path, ctx.train_scene, config, backend=ctx.backend, restorer=restorer,
                                    progress=False)
    tic = time.perf_counter()
    model = S.stage2(ctx, load_ply(run / "model_stage1.ply"), refresh=refresh)
    seconds = time.perf_counter() - tic
    result: dict[str, Any] = {"set": args.set, "seed": args.seed, "twins": twins, "settings": args.sets,
                              "stage2_s": seconds, "command": " ".join(sys.argv)}
    for split, source in paths.items():
        cfg = variant_config(args.work, [f"scene.source={source}"])
        scene = load_scene_for(cfg)
        with tempfile.TemporaryDirectory(prefix="seed_ensemble_") as tmp:
            eval_ctx = S.StageContext(run=RunFolder(Path(tmp), cfg), scene=scene, progress=False)
            m = S.evaluate_stage(eval_ctx, ROW_FULL, model_render_fn(model, ctx.backend, ctx.background), "distil", {})
        suffix = "_val" if split == "val" else ""
        base = {r["method"]: r for r in
                json.loads((args.base_out / f"{args.set}{suffix}_seed{args.seed}.json").read_text())["rows"]}
        full = {"psnr": m["mean"]["psnr"], "lpips": m["mean"].get("lpips")}
        result[split] = {"distilled": full, "mvs": base[ROW_MVS]["psnr"], "matched": base[ROW_MATCHED]["psnr"],
                         "bench_full": base[ROW_FULL]["psnr"], "gain_over_mvs": full["psnr"] - base[ROW_MVS]["psnr"]}
        print(f"{args.set} seed {args.seed} twins {twins} {split}: Full {full['psnr']:.3f} dB, "
              f"STGS w/ MVS {base[ROW_MVS]['psnr']:.3f} ({result[split]['gain_over_mvs']:+.3f})", flush=True)
    write_json(args.out, result)
    return 0


@dataclass
class _ClipTarget:
    """One pseudo-target clip held in memory (what ``PseudoTargets`` reads from a cache entry)."""

    key: str
    cameras: list
    time: float
    image: np.ndarray

    def rgb(self) -> np.ndarray:
        return self.image

    def confidence(self) -> np.ndarray:
        return np.ones(self.image.shape[:3], np.float32)

    def unobserved(self) -> None:
        return None


class _Rounds:
    """An in-memory pseudo-target cache: round -> clips."""

    def __init__(self) -> None:
        self.rounds: dict[int, list[_ClipTarget]] = {}

    def entries(self, round: int | None = None) -> list[_ClipTarget]:
        return self.rounds[round]

    def latest_round(self) -> int | None:
        return max(self.rounds) if self.rounds else None


def coreg(args: argparse.Namespace) -> int:
    import dataclasses

    from benchmarks.stage1_variants import variant_config
    from fixer4d.init.decompose import DecomposedInit
    from fixer4d.pipeline.restoration import scene_trajectories_for
    from fixer4d.pipeline.run_folder import RunFolder, load_scene_for
    from fixer4d.pipeline.stages import StageContext, evaluate_stage, stage1_trainer
    from fixer4d.render.views import model_render_fn, render_views
    from fixer4d.train.co_fields import twin_trainer
    from fixer4d.train.config import Stage2Config
    from fixer4d.train.pseudo_targets import PseudoTargets

    run = args.runs / args.set / f"seed{args.seed}"
    config = variant_config(run, [f"scene.source={_set_paths(args.set)['val']}", "eval.examples=0"])
    scene = load_scene_for(config)
    rng = np.random.default_rng(args.seed + 777)
    with tempfile.TemporaryDirectory(prefix="seed_ensemble_coreg_") as tmp:
        ctx = StageContext(run=RunFolder(Path(tmp), config), scene=scene, progress=False)
        a, decision = stage1_trainer(ctx, DecomposedInit.load(run / "init_mvs"), None)
        b = twin_trainer(a, config.model_terms if decision is not None else None, None)
        train_scene = ctx.train_scene
        clips = scene_trajectories_for(train_scene, config.trajectories)
        pseudo = Stage2Config(lambda_gen=args.weight, batch_pseudo=1, pseudo_target="restored",
                              densify_stats="observed")
        caches = {id(a): _Rounds(), id(b): _Rounds()}
        render_s = 0.0

        def renew(trainer) -> None:
            nonlocal render_s
            tic = time.perf_counter()
            cache = caches[id(trainer)]
            r = len(cache.rounds)
            targets = []
            for k in range(COREG_CLIPS):
                trajectory, _ = clips[int(rng.integers(len(clips)))]
                t = train_scene.time(int(rng.integers(train_scene.num_frames)))
                images = [np.asarray(render_views(f.host_model(), trajectory.cameras, t, ctx.backend, ctx.background)[0])
                          for f in (a, b)]
                targets.append(_ClipTarget(f"r{r}_{k}", list(trajectory.cameras), t,
                                           (0.5 * (images[0] + images[1])).astype(np.float32)))
            cache.rounds[r] = targets
            trainer.pseudo.load_round(r)
            render_s += time.perf_counter() - tic

        wall0 = time.perf_counter()
        a.train(COREG_START)
        b.train(COREG_START)
        for trainer in (a, b):
            trainer.pseudo = PseudoTargets(pseudo, caches[id(trainer)], None, train_scene.train_cameras,
                                           device=trainer.device)
            trainer.schedule = dataclasses.replace(trainer.schedule, lambda_gen=args.weight, pseudo_batch=1, rounds=0,
                                                   densify_stats="observed")
        while a.step_count < a.total_iterations:
            n = min(COREG_CHUNK, a.total_iterations - a.step_count)
            for trainer in (a, b):
                renew(trainer)
                trainer.train(n)
        wall = time.perf_counter() - wall0
        scores = {name: evaluate_stage(ctx, ROW_MVS, model_render_fn(t.host_model(), config.training.backend, ctx.background),
                                       f"field-{name}", {})["mean"]["psnr"] for name, t in (("a", a), ("b", b))}
    base = {r["method"]: r for r in
            json.loads((args.base_out / f"{args.set}_val_seed{args.seed}.json").read_text())["rows"]}[ROW_MVS]["psnr"]
    result = {"set": args.set, "seed": args.seed, "weight": args.weight, "start": COREG_START, "chunk": COREG_CHUNK,
              "clips": COREG_CLIPS, "field_a": scores["a"], "field_b": scores["b"], "baseline": base,
              "gain_db": scores["a"] - base, "wall_s": wall, "target_render_s": render_s,
              "gaussians": [a.model.num_gaussians, b.model.num_gaussians], "command": " ".join(sys.argv)}
    print(f"{args.set} seed {args.seed}: field A {scores['a']:.3f} dB (STGS w/ MVS {base:.3f}, {result['gain_db']:+.3f}), "
          f"field B {scores['b']:.3f}; {wall:.0f} s", flush=True)
    write_json(args.out, result)
    return 0


def summary(args: argparse.Namespace) -> int:
    records = [json.loads(p.read_text()) for p in args.files]
    out: dict[str, Any] = {}
    for rec in records:
        key = f"{rec['set']}/twins{len(rec['twins'])}" + "".join(f"/{s}" for s in rec.get("settings", []))
        out.setdefault(key, []).append(rec)
    result = {}
    for key, recs in sorted(out.items()):
        recs.sort(key=lambda r: r["seed"])
        result[key] = {"seeds": [r["seed"] for r in recs]}
        for split in ("val", "test"):
            result[key][split] = {
                "Full - STGS w/ MVS": interval([r[split]["distilled"]["psnr"] - r[split]["mvs"] for r in recs]),
                "Full - matched": interval([r[split]["distilled"]["psnr"] - r[split]["matched"] for r in recs]),
                "Full - bench Full": interval([r[split]["distilled"]["psnr"] - r[split]["bench_full"] for r in recs])}
            iv = result[key][split]["Full - STGS w/ MVS"]
            print(f"{key} {split}: Full - STGS w/ MVS {iv['mean']:+.2f} ± {iv['ci95'] or float('nan'):.2f} "
                  f"{[round(v, 2) for v in iv['values']]}")
    write_json(args.out, result)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sets = ["demo", "panoptic", "panoptic_c"]
    for name, fn, what in (("renders", renders, "score seed groups' mean renders"),
                           ("merge", merge, "score one model of two seeds' Gaussians under each opacity rule")):
        p = sub.add_parser(name, help=what)
        p.add_argument("set", choices=sets)
        p.add_argument("--seeds", default="0,1,2,3,4")
        p.add_argument("--runs", type=Path, default=DEFAULT_RUNS)
        p.add_argument("--out", type=Path, required=True)
        p.set_defaults(fn=fn)
    p = sub.add_parser("distil", help="stage 2 forced with the twins' mean as pseudo-target")
    p.add_argument("set", choices=sets)
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--twins", required=True, help="the twin seeds, comma-separated")
    p.add_argument("--runs", type=Path, default=DEFAULT_RUNS)
    p.add_argument("--base-out", type=Path, default=BASE_OUT, help="the bench's result files of those runs")
    p.add_argument("--work", type=Path, required=True, help="new run folder for the forced stage 2 (outside git)")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--out", type=Path, required=True)
    p.set_defaults(fn=distil)
    p = sub.add_parser("coreg", help="stage 1 as two co-regularized fields, field A scored")
    p.add_argument("set", choices=sets)
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--weight", type=float, default=0.5, help="weight of the co-regularization L1")
    p.add_argument("--runs", type=Path, default=DEFAULT_RUNS)
    p.add_argument("--base-out", type=Path, default=BASE_OUT, help="the bench's result files of those runs")
    p.add_argument("--out", type=Path, required=True)
    p.set_defaults(fn=coreg)
    p = sub.add_parser("summary", help="pair distil files over seeds")
    p.add_argument("files", type=Path, nargs="+")
    p.add_argument("--out", type=Path, required=True)
    p.set_defaults(fn=summary)
    args = parser.parse_args(argv)
    return args.fn(args)


if __name__ == "__main__":
    sys.exit(main())
