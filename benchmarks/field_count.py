"""How many stage-1 fields (``training.fields``) does a steady stage 1 need? Measured without
training: the quality bench's runs already hold two fields each (seed s and s + 1 000 003,
``RUNS/SET/seed<S>/fields/field<k>/model.ply``), every one an independent draw of one field (its own
subsample of the same dense init, its own training draws). Any n of the pooled fields merged
(``train.fields.merge_fields``, what a run with ``training.fields=n`` makes of its n fields) is a
draw of an n-field stage 1, so the spread over many n-subsets of the pool estimates the seed
spread of STGS w/ MVS at n fields far more sharply than a handful of runs (docs/decisions/field-count.md).

    python benchmarks/field_count.py SET [--runs DIR] [--seeds 0,1,2,3,4] [--sizes 1,2,3,4]
                                     [--draws 40] [--split val|test] --out FILE.json

Each merged model is scored like the "STGS w/ MVS" row (``pipeline.stages.evaluate_stage`` on the
set's validation or test cameras). Size n uses every n-subset of the pool when there are at most
``--draws`` of them, else ``--draws`` subsets drawn without repetition (numpy seed 0). The file is
rewritten after every score and a rerun skips the subsets it holds, so a killed study resumes.
Per size: the mean, the seed spread (the standard deviation across the subsets corrected for
their overlap, ``seed_sd``), the jackknife's standard errors of both (each pooled field left out in
turn: the subsets share fields, so their own spread cannot give the error), and the gain over one field less with its jackknife error (both sizes drawn from the
one pool, so the difference is far sharper than either mean). Subsets that are one run's own two fields (``runs``) are the bench's STGS w/ MVS models:
their scores check this path against the result files.
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import fixer4d  # noqa: E402,F401  (sets the OpenMP wait policy before torch is imported)
from fixer4d.atomic import write_json  # noqa: E402
from fixer4d.bench.quality import ROW_MVS, camera_sets  # noqa: E402


def pool_fields(runs: Path, set_name: str, seeds: list[int]) -> dict[str, Path]:
    """{"s<S>f<k>": model path} for every finished field of the set's runs."""
    from fixer4d.train.fields import FIELD_MODEL, field_dir

    pool = {}
    for s in seeds:
        run = runs / set_name / f"seed{s}"
        k = 0
        while (field_dir(run, k) / FIELD_MODEL).is_file():
            pool[f"s{s}f{k}"] = field_dir(run, k) / FIELD_MODEL
            k += 1
        if k == 0:
            raise SystemExit(f"{run} holds no finished field ({field_dir(run, 0) / FIELD_MODEL}); run the quality "
                             f"bench with training.fields >= 2 first")
    return pool


def subsets(names: list[str], size: int, draws: int) -> list[tuple[str, ...]]:
    """Every ``size``-subset of ``names`` when there are at most ``draws``, else ``draws`` distinct
    ones drawn with numpy seed 0 (sorted names in each)."""
    every = list(itertools.combinations(sorted(names), size))
    if len(every) <= draws:
        return every
    pick = np.random.default_rng(0).choice(len(every), size=draws, replace=False)
    return [every[i] for i in sorted(pick)]


def seed_sd(values: np.ndarray, pool_size: int, size: int) -> float | None:
    """The seed spread (dB) of an n-field stage 1 from the scores of n-subsets of one pool of
    ``pool_size`` fields. Subsets of one finite pool overlap, so the spread across them is
    (N − n)/N of the spread of independent n-field draws (exact when a merged model's score is the
    mean of its fields' effects plus a constant, to first order otherwise): the variance across
    the subsets (all of them: ddof 0; a sample: ddof 1) times N/(N − n)."""
    if values.size < 2 or pool_size <= size:
        return None
    every = values.size == math.comb(pool_size, size)
    return float(np.sqrt(values.var(ddof=0 if every else 1) * pool_size / (pool_size - size)))


def jackknife(scores: dict[tuple[str, ...], float], pool: list[str]) -> dict[str, float | None]:
    """Mean and seed sd (``seed_sd``) of the n-subsets' ``scores`` with jackknife standard errors:
    each pooled field left out in turn (the statistic over the subsets without it, from a pool of
    N − 1), se² = (m − 1)/m · Σ (θ₋ⱼ − θ̄)²."""
    size = len(next(iter(scores)))
    values = np.array(list(scores.values()), float)
    out: dict[str, float | None] = {"n": int(values.size), "mean": float(values.mean()),
                                    "sd": seed_sd(values, len(pool), size), "mean_se": None, "sd_se": None}
    leave = []
    for name in pool:
        kept = np.array([v for members, v in scores.items() if name not in members], float)
        sd = seed_sd(kept, len(pool) - 1, size)
        if sd is not None:
            leave.append((kept.mean(), sd))
    if len(leave) > 1:
        arr = np.array(leave)
        m = len(leave)
        se = np.sqrt((m - 1) / m * ((arr - arr.mean(0)) ** 2).sum(0))
        out["mean_se"], out["sd_se"] = float(se[0]), float(se[1])
    return out


def gain_over(larger: dict[tuple[str, ...], float], smaller: dict[tuple[str, ...], float],
              pool: list[str]) -> dict[str, float | None]:
    """Mean score of the larger subsets minus that of the smaller ones, with its jackknife standard
    error (each pooled field left out of both sizes at once: the two means share the pool)."""
    def diff(without: str | None) -> float:
        return (float(np.mean([v for m, v in larger.items() if without not in m]))
                - float(np.mean([v for m, v in smaller.items() if without not in m])))

    leave = np.array([diff(name) for name in pool])
    m = len(leave)
    return {"gain_db": diff(None), "se_db": float(np.sqrt((m - 1) / m * ((leave - leave.mean()) ** 2).sum())) if m > 1 else None}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("set", choices=sorted(camera_sets()))
    parser.add_argument("--runs", type=Path, default=ROOT / "runs" / "quality")
    parser.add_argument("--seeds", default="0,1,2,3,4")
    parser.add_argument("--sizes", default="1,2,3,4")
    parser.add_argument("--draws", type=int, default=40, help="at most this many subsets per size")
    parser.add_argument("--split", choices=("val", "test"), default="val")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)

    from benchmarks.stage1_variants import variant_config
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.run_folder import RunFolder, load_scene_for
    from fixer4d.pipeline.stages import StageContext, evaluate_stage
    from fixer4d.render.views import model_render_fn
    from fixer4d.train.background import resolve_background
    from fixer4d.train.fields import merge_fields

    seeds = [int(s) for s in args.seeds.split(",")]
    pool = pool_fields(args.runs, args.set, seeds)
    cs = camera_sets()[args.set]
    source = cs.validation if args.split == "val" else cs.scene
    config = variant_config(args.runs / args.set / f"seed{seeds[0]}", [f"scene.source={source}", "eval.examples=0"])
    scene = load_scene_for(config)
    background = resolve_background(config.training.background, scene)
    sizes = [int(n) for n in args.sizes.split(",")]

    result: dict[str, Any] = json.loads(args.out.read_text()) if args.out.exists() else {}
    import datetime

    from fixer4d import numerics
    from fixer4d.bench.machine import cpu_topology
    from fixer4d.pipeline.run_folder import source_commit

    command = " ".join(["python benchmarks/field_count.py", *(argv or sys.argv[1:])])
    result.update({"name": "field_count", "set": args.set, "split": args.split, "source": source,
                   "runs": str(args.runs), "pool": sorted(pool), "command": command,
                   "date": datetime.date.today().isoformat(), "commit": source_commit(), "machine": cpu_topology(),
                   "numerics": numerics.status()})
    scores: dict[str, dict[str, Any]] = result.setdefault("scores", {})
    models: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="field_count_") as tmp:
        ctx = StageContext(run=RunFolder(Path(tmp), config), scene=scene, progress=False)
        for n in sizes:
            todo = [m for m in subsets(list(pool), n, args.draws) if "+".join(m) not in scores]
            for i, members in enumerate(todo):
                t0 = time.perf_counter()
                for name in members:
                    if name not in models:
                        models[name] = load_ply(pool[name])
                fn = model_render_fn(merge_fields([models[m] for m in members]), config.training.backend, background)
                metrics = evaluate_stage(ctx, ROW_MVS, fn, "+".join(members), {})["mean"]
                key = "+".join(members)
                scores[key] = {"size": n, "psnr": metrics["psnr"], "lpips": metrics.get("lpips")}
                write_json(args.out, result)
                print(f"{args.set} {args.split} n={n} [{i + 1}/{len(todo)}] {key}: {metrics['psnr']:.3f} dB "
                      f"({time.perf_counter() - t0:.0f} s)", flush=True)
    by_size, previous = {}, None
    for n in sorted({v["size"] for v in scores.values()}):
        of_n = {tuple(k.split("+")): v["psnr"] for k, v in scores.items() if v["size"] == n}
        by_size[str(n)] = jackknife(of_n, sorted(pool))
        if previous is not None:
            by_size[str(n)]["gain_over_one_field_less"] = gain_over(of_n, previous, sorted(pool))
        previous = of_n
        own = [v for k, v in of_n.items() if n == 2 and k[0][:k[0].index("f")] == k[1][:k[1].index("f")]]
        if own:
            by_size[str(n)]["runs_own_fields"] = own
    result["by_size"] = by_size
    write_json(args.out, result)
    for n, row in by_size.items():
        gain = row.get("gain_over_one_field_less")
        print(f"n={n}: {row['n']} subsets, mean {row['mean']:.3f} ± {row['mean_se'] or 0:.3f} (se), "
              f"sd {row['sd'] or 0:.3f} ± {row['sd_se'] or 0:.3f} (se)"
              + (f", {gain['gain_db']:+.3f} ± {gain['se_db']:.3f} dB over n={int(n) - 1}" if gain else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
