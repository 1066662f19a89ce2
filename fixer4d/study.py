"""Accuracy vs time: sweep the pipeline's knobs, time every stage, draw the Pareto front.

A study is a list of variants, each a set of overrides of the pipeline configuration
(dotted keys such as ``"training.iterations"``). Every variant runs the real pipeline in its own
run folder (so an interrupted study resumes: finished variants are read back, half-finished
ones resume stage by stage), is evaluated on the held-out cameras, and lands in
``study.json``, a markdown table sorted by time, and five plots:

- ``psnr_vs_time.png``, ``psnr_dynamic_vs_time.png``, ``psnr_static_vs_time.png``,
  ``lpips_vs_time.png``: quality against wall-clock seconds (all pixels, the held-out
  moving-content mask, the rest), the Pareto front highlighted and labelled;
- ``stage_seconds.png``: seconds per stage as stacked bars.

Fronts are drawn for every metric in ``METRICS``; "the fastest variant within 0.5 dB of the
best" ranks by ``StudyConfig.rank`` (PSNR, or the moving / static pixels' PSNR).

A budget (minutes) bounds the sweep: variants run in the order given (the default sweep puts
the base configuration first) and the study starts no new variant once the budget is spent.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from fixer4d import atomic

# Variants of the default sweep: one knob at a time away from the base configuration, so each
# knob's price and gain can be read off directly.
DEFAULT_SWEEP: list[dict[str, Any]] = [
    {"name": "base"},
    # stage-2 knobs first: they reuse the base's init and stage-1 model (the stage cache)
    {"name": "no-restoration", "stage2.rounds": 0},
    {"name": "rounds-1", "stage2.rounds": 1},
    {"name": "rounds-3", "stage2.rounds": 3},
    {"name": "K-0.5x", "stage2.refresh_every": 0.5},
    {"name": "restorer-refs-only", "restorer.warp.use_extra_views": False},
    {"name": "undetermined-views-4", "trajectories.undetermined_views": 4},
    # the restorer axis: geometric warp vs the learned per-scene prior at two training budgets
    {"name": "restorer-warp", "restorer.kind": "warp"},
    {"name": "restorer-learned", "restorer.kind": "learned"},
    {"name": "restorer-learned-2x", "restorer.kind": "learned", "restorer.learned.steps": 2.0,
     "restorer.learned.loo_iterations": 2.0},
    {"name": "sparse-init", "init.method": "sparse"},
    # the model-terms axis: decided by evidence (the base), every term on every Gaussian, static only
    {"name": "model-terms-all", "model_terms.mode": "all"},
    {"name": "model-terms-static", "model_terms.mode": "static"},
    # stage 1's opacity reset in place of the learned opacity decay (train.opacity_decay), one
    # stage-1 field in place of two merged (train.fields), and two with co-pruning (train.co_fields)
    {"name": "opacity-reset", "training.opacity_decay.enabled": False},
    {"name": "one-field", "training.fields": 1},
    {"name": "co-fields", "co_fields.enabled": True, "training.fields": 1},
    {"name": "res-0.5", "scene.scale": 0.5},
    {"name": "iters-0.5x", "training.iterations": 0.5},
    {"name": "iters-2x", "training.iterations": 2.0},
    {"name": "cap-0.25x", "training.max_gaussians": 0.25},
    {"name": "planes-0.5x", "init.mvs.planes": 0.5},
    {"name": "mvs-res-0.5x", "init.mvs.scale": 0.5},
]

# Knobs whose override is a multiplier of the base value rather than an absolute value, so one
# sweep file serves every scene size.
RELATIVE_KNOBS = {"scene.scale", "training.iterations", "training.max_gaussians", "init.mvs.planes", "init.mvs.scale",
                  "stage2.refresh_every", "stage2.iterations", "restorer.learned.steps",
                  "restorer.learned.loo_iterations"}


# The metrics a study draws fronts for and can rank by: name -> (higher is better, label). The
# dynamic / static PSNRs are over the held-out moving-content mask and the rest of the image
# (None where a run has no moving pixels).
METRICS: dict[str, tuple[bool, str]] = {"psnr": (True, "PSNR"), "psnr_dynamic": (True, "PSNR dyn."),
                                        "psnr_static": (True, "PSNR static"), "lpips": (False, "LPIPS")}
# the dB metrics "fastest within X dB of the best" can rank by
RANK_METRICS = ("psnr", "psnr_dynamic", "psnr_static")


@dataclass
class StudyResult:
    """One finished variant: its overrides, its metrics, its per-stage seconds and the metrics on
    whose Pareto front it lies (``pareto``, keys of METRICS)."""

    name: str
    overrides: dict[str, Any]
    psnr: float
    dssim1: float
    dssim2: float
    lpips: float | None
    seconds: dict[str, float]
    run_dir: str
    psnr_dynamic: float | None = None
    psnr_static: float | None = None
    pareto: list[str] = field(default_factory=list)

    @property
    def total_seconds(self) -> float:
        return float(self.seconds.get("total", sum(v for k, v in self.seconds.items() if k != "total")))


# ---------------------------------------------------------------------------------------------
# Pareto front
# ---------------------------------------------------------------------------------------------
def pareto_front(costs: list[float], scores: list[float | None], higher_is_better: bool = True) -> list[int]:
    """Indices of the non-dominated points, sorted by cost.

    A point is dominated when another costs no more and scores at least as well, and is
    strictly better in one of the two. Points with a missing or non-finite score are never on
    the front.
    """
    idx = [i for i, s in enumerate(scores) if s is not None and math.isfinite(s) and math.isfinite(costs[i])]
    sign = 1.0 if higher_is_better else -1.0
    front = []
    for i in idx:
        dominated = False
        for j in idx:
            if j == i:
                continue
            no_worse = costs[j] <= costs[i] and sign * scores[j] >= sign * scores[i]
            better = costs[j] < costs[i] or sign * scores[j] > sign * scores[i]
            if no_worse and better:
                dominated = True
                break
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: (costs[i], -sign * scores[i]))


def mark_fronts(results: list[StudyResult]) -> None:
    """Set each result's ``pareto``: the METRICS on whose time/quality front it lies."""
    costs = [r.total_seconds for r in results]
    for r in results:
        r.pareto = []
    for metric, (higher, _) in METRICS.items():
        for i in pareto_front(costs, [getattr(r, metric) for r in results], higher_is_better=higher):
            results[i].pareto.append(metric)


def check_rank(metric: str) -> str:
    """``metric`` when the study can rank by it (RANK_METRICS), else InputError listing them."""
    if metric not in RANK_METRICS:
        from fixer4d.errors import InputError

        raise InputError(f"study rank metric {metric!r}: choose one of {list(RANK_METRICS)}")
    return metric


def fastest_within(results: list[StudyResult], db: float = 0.5, metric: str = "psnr") -> StudyResult | None:
    """The fastest variant whose ``metric`` (a dB metric of RANK_METRICS) is within ``db`` of the
    best one; variants without that metric are not ranked. None when none has it."""
    check_rank(metric)
    scored = [r for r in results if getattr(r, metric) is not None and math.isfinite(getattr(r, metric))]
    if not scored:
        return None
    best = max(getattr(r, metric) for r in scored)
    ok = [r for r in scored if getattr(r, metric) >= best - db]
    return min(ok, key=lambda r: r.total_seconds)


# ---------------------------------------------------------------------------------------------
# Reports
# ---------------------------------------------------------------------------------------------
def markdown_table(results: list[StudyResult]) -> str:
    rows = sorted(results, key=lambda r: r.total_seconds)
    stages = sorted({k for r in rows for k in r.seconds if k != "total"})
    head = ("| Variant | PSNR | PSNR dyn. | PSNR static | DSSIM1 | DSSIM2 | LPIPS | Total s | "
            + " | ".join(f"{s} s" for s in stages) + " | Pareto |")
    sep = "|" + "---|" * (8 + len(stages) + 1)
    lines = [head, sep]

    def fmt(v: float | None, digits: int) -> str:
        return "n/a" if v is None else f"{v:.{digits}f}"

    for r in rows:
        per = " | ".join(f"{r.seconds.get(s, 0.0):.1f}" for s in stages)
        mark = ", ".join(METRICS[m][1] for m in METRICS if m in r.pareto)
        lines.append(f"| {r.name} | {r.psnr:.2f} | {fmt(r.psnr_dynamic, 2)} | {fmt(r.psnr_static, 2)} | {r.dssim1:.4f} | "
                     f"{r.dssim2:.4f} | {fmt(r.lpips, 4)} | {r.total_seconds:.1f} | {per} | {mark} |")
    return "\n".join(lines) + "\n"


# Where a point's label may go, in points from the point (dx, dy, horizontal alignment), tried in
# this order until the label's box overlaps no label placed before it.
_LABEL_OFFSETS = ((4, 4, "left"), (4, -11, "left"), (-4, 4, "right"), (-4, -11, "right"), (4, 14, "left"),
                  (4, -21, "left"), (-4, 14, "right"), (-4, -21, "right"))


def _boxes_overlap(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    """Whether two (x0, y0, x1, y1) boxes intersect."""
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _label_points(ax, fig, points: list[tuple[float, float, str, bool]]) -> None:
    """Annotate (x, y, name, on_front) points so that their labels do not overlap (greedy, in
    display pixels; front labels first); a label with no free slot takes the first one."""
    fig.canvas.draw()  # fixes the axis limits, so data -> pixel is final
    px_per_pt = fig.dpi / 72.0
    placed: list[tuple[float, float, float, float]] = []
    for x, y, name, on in sorted(points, key=lambda p: (not p[3], p[0])):
        size = 8 if on else 7
        w, h = 0.6 * size * len(name) * px_per_pt, size * px_per_pt
        px, py = ax.transData.transform((x, y))

        def box(dx: float, dy: float, ha: str) -> tuple[float, float, float, float]:
            x0, y0 = px + dx * px_per_pt - (w if ha == "right" else 0.0), py + dy * px_per_pt
            return x0, y0, x0 + w, y0 + h

        free = [o for o in _LABEL_OFFSETS if not any(_boxes_overlap(box(*o), b) for b in placed)]
        dx, dy, ha = (free or _LABEL_OFFSETS)[0]
        placed.append(box(dx, dy, ha))
        ax.annotate(name, (x, y), textcoords="offset points", xytext=(dx, dy), ha=ha, fontsize=size,
                    color="#d1495b" if on else "#52606d")


def plot_study(results: list[StudyResult], out_dir: Path) -> list[Path]:
    """Write the PNG plots (one per METRICS entry, and the stage seconds); returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    written = []
    axis_labels = {"psnr": "PSNR (dB, higher is better)", "lpips": "LPIPS-alex (lower is better)",
                   "psnr_dynamic": "PSNR on the moving pixels (dB, higher is better)",
                   "psnr_static": "PSNR on the static pixels (dB, higher is better)"}
    for metric, (better, _) in METRICS.items():
        fname, label = f"{metric}_vs_time.png", axis_labels[metric]
        pts = [r for r in results if getattr(r, metric) is not None]
        fig, ax = plt.subplots(figsize=(7.5, 4.8), dpi=110)
        if pts:
            xs = [r.total_seconds for r in pts]
            ys = [getattr(r, metric) for r in pts]
            ax.scatter(xs, ys, c="#9aa5b1", s=28, label="variant", zorder=2)
            front = [pts[i] for i in pareto_front(xs, ys, higher_is_better=better)]
            ax.plot([r.total_seconds for r in front], [getattr(r, metric) for r in front], "-o", c="#d1495b",
                    lw=1.8, ms=6, label="Pareto front", zorder=3)
            _label_points(ax, fig, [(r.total_seconds, getattr(r, metric), r.name, r in front) for r in pts])
        else:
            ax.text(0.5, 0.5, f"{metric.upper()} unavailable", ha="center", va="center", transform=ax.transAxes)
        ax.set_xlabel("wall-clock seconds (all stages)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        if pts:
            ax.legend(loc="best", fontsize=8)
        fig.tight_layout()
        with atomic.atomic_path(out_dir / fname) as tmp:
            fig.savefig(tmp)
        plt.close(fig)
        written.append(out_dir / fname)

    rows = sorted(results, key=lambda r: r.total_seconds)
    stages = sorted({k for r in rows for k in r.seconds if k != "total"})
    fig, ax = plt.subplots(figsize=(max(6.0, 0.6 * len(rows) + 2), 4.8), dpi=110)
    bottom = [0.0] * len(rows)
    cmap = plt.get_cmap("tab10")
    for k, s in enumerate(stages):
        vals = [r.seconds.get(s, 0.0) for r in rows]
        ax.bar(range(len(rows)), vals, bottom=bottom, label=s, color=cmap(k % 10))
        bottom = [b + v for b, v in zip(bottom, vals)]
    ax.set_xticks(range(len(rows)))
    ax.set_xticklabels([r.name for r in rows], rotation=40, ha="right", fontsize=8)
    ax.set_ylabel("seconds")
    ax.set_title("seconds per stage")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    with atomic.atomic_path(out_dir / "stage_seconds.png") as tmp:
        fig.savefig(tmp)
    plt.close(fig)
    written.append(out_dir / "stage_seconds.png")
    return written


# ---------------------------------------------------------------------------------------------
# The sweep
# ---------------------------------------------------------------------------------------------
RunVariant = Callable[[dict[str, Any], Path], dict[str, Any]]
"""(variant overrides, run_dir) -> {"psnr", "dssim1", "dssim2", "lpips", optional "psnr_dynamic" / "psnr_static",
"seconds": {stage: s, "total": s}};
the study's base overrides are the runner's business (the default runner passes them as absolute values)."""


@dataclass
class StudyConfig:
    """What to sweep and how long it may take."""

    source: str = "demo"
    budget_minutes: float | None = None
    rank: str = "psnr"  # RANK_METRICS: what "fastest within 0.5 dB of the best" ranks by
    variants: list[dict[str, Any]] = field(default_factory=lambda: [dict(v) for v in DEFAULT_SWEEP])
    base: dict[str, Any] = field(default_factory=dict)  # absolute overrides applied to every variant


# A variant is scored on the final model alone: the extra report rows would only cost time.
VARIANT_BASE = {"baseline_sparse": False, "eval.restoration_rows": False, "eval.matched_row": False}


def variant_config(source: str, overrides: dict[str, Any], base: dict[str, Any] | None = None):
    """The RunConfig of a variant: the defaults <- VARIANT_BASE <- the study's absolute ``base``
    <- the variant's ``overrides`` (keys in RELATIVE_KNOBS multiply the value they replace)."""
    from fixer4d.pipeline.config import resolve

    absolute = resolve(source, overrides={**VARIANT_BASE, **(base or {})})
    return resolve(config_file=absolute.to_dict(), overrides=overrides, relative=RELATIVE_KNOBS, defaults={}) \
        if overrides else absolute


def run_pipeline_variant(source: str, overrides: dict[str, Any], run_dir: str | Path, *, progress: bool = True,
                         base: dict[str, Any] | None = None, stage_cache: str | Path | None = None) -> dict[str, Any]:
    """Run one variant through the pipeline; its final model's held-out metrics and per-stage seconds.

    Variants sharing a ``stage_cache`` reuse each other's inits and stage-1 models (their recorded
    seconds still count)."""
    from fixer4d.pipeline.run import run_pipeline

    report = run_pipeline(variant_config(source, overrides, base), run_dir, progress=progress, stage_cache=stage_cache)
    final = report["rows"][-1]
    st = report["stage_seconds"]
    seconds = {"init": sum(v for k, v in st.items() if k.startswith("init_")), "stage1": st.get("stage1", 0.0),
               "stage2": st.get("stage2", 0.0)}
    seconds["total"] = sum(seconds.values())
    return {**{k: final.get(k) for k in ("psnr", "dssim1", "dssim2", "lpips", "psnr_dynamic", "psnr_static")},
            "seconds": seconds, "method": final["method"]}


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in name)


def check_variants(variants: Any) -> None:
    """A study's variants: a list of objects, each with a distinct non-empty "name" (its run folder
    is named after it) and dotted config keys; InputError naming what is wrong otherwise."""
    from fixer4d.errors import InputError

    if not isinstance(variants, list) or not variants:
        raise InputError('study variants: expected a non-empty JSON list of objects like [{"name": "base"}, '
                         f'{{"name": "iters-2x", "training.iterations": 2.0}}], got {type(variants).__name__}')
    seen: dict[str, str] = {}
    for k, v in enumerate(variants):
        if not isinstance(v, dict):
            raise InputError(f"study variant #{k}: expected an object with a \"name\", got {v!r}")
        name = v.get("name")
        if not isinstance(name, str) or not _slug(name).strip("-."):
            raise InputError(f"study variant #{k}: needs a non-empty \"name\" (its run folder is named after it), "
                             f"got {name!r}")
        if _slug(name) in seen:
            raise InputError(f"study variants: {seen[_slug(name)]!r} and {name!r} would share the run folder "
                             f"runs/{_slug(name)}; give every variant its own name")
        seen[_slug(name)] = name


def _variant_settings(config: StudyConfig, overrides: dict[str, Any]) -> dict[str, Any]:
    """What a variant's result depends on (kept in its study_result.json): scene, base, overrides."""
    return json.loads(json.dumps({"source": config.source, "base": config.base, "overrides": overrides}))


def _check_finished(done_file: Path, name: str, settings: dict[str, Any]) -> None:
    """Refuse to reuse a finished variant run under other settings (a result without recorded
    settings, from before they were recorded, is reused as it is)."""
    from fixer4d.errors import InputError

    old = json.loads(done_file.read_text()).get("settings")
    if old is None or old == settings:
        return
    changed = []
    for part in ("source", "base", "overrides"):
        a, b = old.get(part), settings[part]
        if a == b:
            continue
        if isinstance(a, dict) and isinstance(b, dict):
            changed += [f"{part} {k}: {a.get(k)!r} -> {b.get(k)!r}" for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
        else:
            changed.append(f"{part}: {a!r} -> {b!r}")
    raise InputError(f"{done_file.parent}: variant {name!r} finished under other settings ({'; '.join(changed)}); "
                     f"study into a new --out, or delete {done_file.parent} to run it again")


def run_study(config: StudyConfig, out_dir: str | Path, run_variant: RunVariant | None = None,
              progress: bool = True) -> list[StudyResult]:
    """Run (or resume) every variant within the budget; write study.json, study.md and the plots.
    A variant already finished in ``out_dir`` is read back, and refused when it ran under other
    settings (scene, base or its own overrides)."""
    check_rank(config.rank)
    check_variants(config.variants)
    out_dir = Path(out_dir)
    for variant in config.variants:
        done_file = out_dir / "runs" / _slug(variant["name"]) / "study_result.json"
        if done_file.exists():
            _check_finished(done_file, variant["name"],
                            _variant_settings(config, {k: v for k, v in variant.items() if k != "name"}))
    out_dir.mkdir(parents=True, exist_ok=True)
    if run_variant is None:
        def run_variant(overrides: dict[str, Any], run_dir: Path) -> dict[str, Any]:
            return run_pipeline_variant(config.source, overrides, run_dir, progress=progress, base=config.base,
                                        stage_cache=out_dir / "stage_cache")

    atomic.write_json(out_dir / "study_config.json", {"source": config.source, "budget_minutes": config.budget_minutes,
                                                      "variants": config.variants, "base": config.base})
    budget_s = None if config.budget_minutes is None else 60.0 * config.budget_minutes
    started = time.perf_counter()
    results: list[StudyResult] = []
    skipped: list[str] = []
    ran_any = False
    for variant in config.variants:
        name = variant["name"]
        overrides = {k: v for k, v in variant.items() if k != "name"}
        run_dir = out_dir / "runs" / _slug(name)
        done_file = run_dir / "study_result.json"
        if done_file.exists():
            res = json.loads(done_file.read_text())
        else:
            # the budget is checked before starting a variant; the first one always runs
            if budget_s is not None and ran_any and time.perf_counter() - started > budget_s:
                skipped.append(name)
                continue
            if progress:
                print(f"[study] variant {name}: {overrides}", flush=True)
            res = {**run_variant(overrides, run_dir), "settings": _variant_settings(config, overrides)}
            ran_any = True
            atomic.write_json(done_file, res)
        results.append(StudyResult(name=name, overrides=overrides, psnr=float(res["psnr"]), dssim1=float(res["dssim1"]),
                                   dssim2=float(res["dssim2"]), lpips=res.get("lpips"),
                                   seconds={k: float(v) for k, v in res["seconds"].items()}, run_dir=str(run_dir),
                                   psnr_dynamic=res.get("psnr_dynamic"), psnr_static=res.get("psnr_static")))
        _write_outputs(results, skipped, out_dir, config.rank)
    _write_outputs(results, skipped, out_dir, config.rank)
    return results


def _write_outputs(results: list[StudyResult], skipped: list[str], out_dir: Path, rank: str = "psnr") -> None:
    mark_fronts(results)
    best = fastest_within(results, 0.5, rank)
    by_time = sorted(results, key=lambda r: r.total_seconds)
    payload = {
        "results": [{**r.__dict__, "total_seconds": r.total_seconds} for r in results],
        **{f"pareto_{m}": [r.name for r in by_time if m in r.pareto] for m in METRICS},
        "rank": rank,
        "fastest_within_0.5db": None if best is None else best.name,
        "skipped_over_budget": skipped,
    }
    atomic.write_json(out_dir / "study.json", payload)
    text = "# Study: accuracy vs time\n\n" + markdown_table(results)
    if best is not None:
        text += (f"\nFastest variant within 0.5 dB of the best {METRICS[rank][1]}: **{best.name}** "
                 f"({best.total_seconds:.1f} s, {getattr(best, rank):.2f} dB).\n")
    if skipped:
        text += f"\nNot run (budget spent): {', '.join(skipped)}.\n"
    atomic.write_text(out_dir / "study.md", text)
    if results:
        plot_study(results, out_dir)
