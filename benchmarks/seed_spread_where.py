"""Where a stage-1 seed's luck lands in the image: the seeds' spread of the validation error, split by
how much each run's own fields disagree at a pixel (docs/decisions/stage1-seed-spread.md).

    python benchmarks/seed_spread_where.py SET --seeds 0,1,2,3,4 --runs DIR --out DIR

SET is a quality-bench camera set (demo, panoptic, panoptic_c); the runs are the bench's finished
several-field runs ``DIR/SET/seed<S>`` (``fixer4d bench quality --set training.fields=4``), which
keep every field's model in ``fields/field<k>/model.ply``. On the set's validation cameras, at the
frames the evaluation scores, each seed's stage-1 model (the "STGS w/ MVS" row) is rendered for
its per-pixel squared error e_s(p) (mean over RGB), and its fields for their disagreement d_s(p):
the variance over the fields of the colour, mean over RGB. It reads the validation cameras after
the runs, as the bench's rows do, and chooses nothing.

The pooled error of seed s is E_s = mean_p e_s(p). The pixels are cut into bins by quantiles of
the disagreement, box-smoothed over the undetermined map's window (``restore.undetermined``), and
E_s = sum_b E_s,b with E_s,b = (1/P) sum_{p in bin b} e_s(p). A bin's share of the seeds' variance
of E is cov_s(E_s,b, E_s) / var_s(E_s): the shares sum to 1, and a bin whose error moved with no
seed has share 0. Two cuts: ``by_disagreement`` bins every seed's pixels alike by the seeds' mean
disagreement (where the spread lives), ``by_own_disagreement`` bins each run's pixels by its own map
(what a run could locate by itself). The same split by validation view says whether a few views or
all of them carry it. Beside it, per seed, the PSNR row of every field alone and of the per-pixel
mean of the fields' renders, against the merged model's (``metric_db``).
Result: DIR/SET.json and DIR/SET.png (per row, one view: the seeds' mean error, their sd of the
error and the mean disagreement, each scaled to its own 99.5th percentile).
"""
from __future__ import annotations

import argparse
import datetime
import sys
from pathlib import Path
from typing import Any, Sequence

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import fixer4d  # noqa: E402,F401  (sets the OpenMP wait policy before torch is imported)
from fixer4d.atomic import write_json  # noqa: E402
from fixer4d.psnr import psnr_from_mse  # noqa: E402
from fixer4d.stats import interval  # noqa: E402

# Upper ends of the disagreement bins, as quantiles of the map binned: the top is cut finer than
# the bottom, since the spread sits in the most disagreeing fifth (docs/decisions/stage1-seed-spread.md).
BIN_QUANTILES = (0.5, 0.8, 0.9, 0.95, 0.99)
BIN_NAMES = ("0-50 %", "50-80 %", "80-90 %", "90-95 %", "95-99 %", "99-100 %")
# Views drawn in the PNG (evenly spaced over the scored views).
FIGURE_VIEWS = 5


def quantile_bins(disagreement: np.ndarray, quantiles: Sequence[float] = BIN_QUANTILES) -> np.ndarray:
    """(S, P) int: each pixel's bin among ``len(quantiles) + 1``, cut at each row's own quantiles of
    ``disagreement`` (S, P); ties at an edge go to the lower bin."""
    d = np.asarray(disagreement, np.float64)
    edges = np.quantile(d, quantiles, axis=1).T  # (S, Q)
    return np.stack([np.searchsorted(e, row, side="left") for e, row in zip(edges, d)])


def variance_shares(error: np.ndarray, groups: np.ndarray, count: int) -> list[dict[str, float]]:
    """Per group g < count: its share of the pixels, of the seeds' mean pooled error and of their
    variance of it (cov_s(E_s,g, E_s) / var_s(E_s); the shares sum to 1).

    error: (S, P) per-pixel squared error of S seeds' renders; groups: (S, P) int in [0, count),
    each seed's own grouping of its pixels. Raises ValueError below two seeds or when the pooled
    error did not move."""
    e = np.asarray(error, np.float64)
    g = np.asarray(groups)
    if e.shape != g.shape or e.ndim != 2:
        raise ValueError(f"variance_shares: error {e.shape} and groups {g.shape} must be the same (S, P)")
    if e.shape[0] < 2:
        raise ValueError("variance_shares: a variance over seeds needs two seeds at least")
    pooled = e.mean(1)
    var = pooled.var(ddof=1)
    if not var > 0:
        raise ValueError("variance_shares: the pooled error is the same for every seed")
    rows = []
    for k in range(count):
        inside = g == k
        part = np.where(inside, e, 0.0).sum(1) / e.shape[1]
        rows.append({"pixels": float(inside.mean()), "error": float(part.mean() / pooled.mean()),
                     "variance": float(np.cov(part, pooled, ddof=1)[0, 1] / var)})
    return rows


def _render_all(model_path: Path, views, scene, backend: str, background) -> np.ndarray:
    from fixer4d.model.io import load_ply
    from fixer4d.render.views import model_render_fn

    fn = model_render_fn(load_ply(model_path), backend, background)
    return np.stack([np.asarray(fn(scene.cameras[c], scene.time(f)), np.float32) for c, f in views])


def measure(run_dirs: dict[int, Path], source: str) -> dict[str, Any]:
    """Per seed: (V, H, W) squared error of the stage-1 model and disagreement of its fields on the
    validation cameras of ``source``, plus the scored views and the per-image PSNR metric."""
    import cv2

    from benchmarks.stage1_variants import variant_config
    from fixer4d.eval.evaluate import select_frames
    from fixer4d.restore.undetermined import WINDOW_PX
    from fixer4d.pipeline.run_folder import load_scene_for
    from fixer4d.train.background import resolve_background

    first = next(iter(run_dirs.values()))
    config = variant_config(first, [f"scene.source={source}", "eval.examples=0"])
    scene = load_scene_for(config)
    background = resolve_background(config.training.background, scene)
    views = [(int(c), int(f)) for c in scene.test_ids for f in select_frames(scene.num_frames, config.eval.stride, None)]
    truth = np.stack([np.asarray(scene.frame(f, c), np.float32) for c, f in views])
    error, disagreement, metric, fields_db, mean_render_db = [], [], [], [], []
    for seed, run in run_dirs.items():
        fields = sorted((run / "fields").glob("field*/model.ply"))
        if len(fields) < 2:
            raise SystemExit(f"{run}: {len(fields)} field models in fields/; run the bench with "
                             "--set training.fields=4 (or 2) so that each run keeps its fields")
        render = _render_all(run / "model_stage1.ply", views, scene, config.training.backend, background)
        error.append(((render - truth) ** 2).mean(-1))
        metric.append(image_psnr(render, truth))
        per_field = np.stack([_render_all(p, views, scene, config.training.backend, background) for p in fields])
        disagreement.append(np.stack([cv2.blur(d, (WINDOW_PX, WINDOW_PX)) for d in per_field.var(0).mean(-1)]))
        fields_db.append([image_psnr(r, truth) for r in per_field])
        mean_render_db.append(image_psnr(per_field.mean(0), truth))
        print(f"seed {seed}: {len(fields)} fields rendered at {len(views)} views", flush=True)
    return {"views": views, "error": np.stack(error), "disagreement": np.stack(disagreement), "metric": np.array(metric),
            "fields_db": fields_db, "mean_render_db": mean_render_db}


def image_psnr(render: np.ndarray, truth: np.ndarray) -> float:
    """The evaluation's PSNR row of (V, H, W, 3) renders: the mean over views of each view's PSNR, dB."""
    from fixer4d.eval.metrics import psnr

    return float(np.mean([psnr(r, t) for r, t in zip(render, truth)]))


def figure(error: np.ndarray, disagreement: np.ndarray, path: Path) -> None:
    """PNG, one row per drawn view: seeds' mean error | their sd of it | mean disagreement."""
    import cv2

    picks = np.unique(np.linspace(0, error.shape[1] - 1, FIGURE_VIEWS).round().astype(int))
    rows = []
    for v in picks:
        maps = [np.sqrt(error[:, v].mean(0)), np.sqrt(error[:, v].std(0)), np.sqrt(disagreement[:, v].mean(0))]
        rows.append(np.concatenate([np.clip(m / max(float(np.quantile(m, 0.995)), 1e-12), 0, 1) for m in maps], 1))
    cv2.imwrite(str(path), (np.concatenate(rows, 0) * 255).round().astype(np.uint8))


def main(argv: list[str] | None = None) -> int:
    from fixer4d.bench.quality import camera_sets
    from fixer4d.pipeline.run_folder import source_commit

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("set", choices=sorted(camera_sets()))
    parser.add_argument("--seeds", default="0,1,2,3,4")
    parser.add_argument("--runs", type=Path, required=True, help="the bench's runs folder (DIR/SET/seed<S>)")
    parser.add_argument("--out", type=Path, required=True, help="folder for SET.json and SET.png")
    args = parser.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    run_dirs = {s: args.runs / args.set / f"seed{s}" for s in seeds}
    source = camera_sets()[args.set].validation
    m = measure(run_dirs, source)
    S, V = m["error"].shape[:2]
    error = m["error"].reshape(S, -1)
    disagreement = m["disagreement"].reshape(S, -1)
    common = np.broadcast_to(disagreement.mean(0), disagreement.shape)
    bins = variance_shares(error, quantile_bins(common), len(BIN_NAMES))
    own = variance_shares(error, quantile_bins(disagreement), len(BIN_NAMES))
    view_groups = np.broadcast_to(np.arange(V)[None, :, None], (S, V, m["error"][0, 0].size)).reshape(S, -1)
    views = variance_shares(error, view_groups, V)
    pooled_db = np.array([psnr_from_mse(e) for e in error.mean(1)])
    args.out.mkdir(parents=True, exist_ok=True)
    write_json(args.out / f"{args.set}.json", {
        "set": args.set, "validation": source, "seeds": seeds, "runs": str(args.runs),
        "commit": source_commit(), "date": datetime.date.today().isoformat(),
        "command": "python benchmarks/seed_spread_where.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "views": [{"camera": c, "frame": f} for c, f in m["views"]],
        "metric_db": interval(m["metric"].tolist()),
        "pooled_db": interval(pooled_db.tolist()),
        "metric_vs_pooled_correlation": float(np.corrcoef(m["metric"], pooled_db)[0, 1]),
        "fields_db": {"per_seed": m["fields_db"], "every_field": interval(np.ravel(m["fields_db"]).tolist()),
                      "mean_of_the_fields": interval(np.mean(m["fields_db"], 1).tolist())},
        "mean_render_db": interval(m["mean_render_db"]),
        "by_disagreement": {name: row for name, row in zip(BIN_NAMES, bins)},
        "by_own_disagreement": {name: row for name, row in zip(BIN_NAMES, own)},
        "by_view": {f"cam{c}_f{f}": row for (c, f), row in zip(m["views"], views)},
        "largest_view_share": max(r["variance"] for r in views),
    })
    figure(m["error"], m["disagreement"], args.out / f"{args.set}.png")
    for name, row, mine in zip(BIN_NAMES, bins, own):
        print(f"{args.set} {name}: pixels {row['pixels']:.3f}, error {row['error']:.3f}, seed variance "
              f"{row['variance']:.3f} (binned by each run's own map: {mine['variance']:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
