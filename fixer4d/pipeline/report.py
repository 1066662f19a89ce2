"""The run's report: the paper's Table-2 rows with per-stage seconds (RUN/report.json, report.md).

A row is {"method", "status", "psnr", "dssim1", "dssim2", "lpips", "psnr_dynamic", "psnr_static",
"seconds"} plus "error" when the row's stage failed (its metrics are then null and the reason is
shown in the table), so one failing baseline never hides the others.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from fixer4d import atomic

ROW_COLMAP = "STGS w/ COLMAP"
ROW_MVS = "STGS w/ MVS"
ROW_MATCHED = "STGS w/ MVS (matched iterations)"
ROW_RESTORED_INIT = "Restoration (init)"
ROW_FULL = "Full"
ROW_RESTORED_REFINED = "Restoration (refined)"
# Baselines beside the restoration rows: the stage-1 render itself, and a plain blur of it.
ROW_IDENTITY = "Identity (init)"
ROW_BLUR = "Blur (init)"
ROW_NAMES = (ROW_COLMAP, ROW_MVS, ROW_MATCHED, ROW_IDENTITY, ROW_BLUR, ROW_RESTORED_INIT, ROW_FULL,
             ROW_RESTORED_REFINED)
METRIC_KEYS = ("psnr", "dssim1", "dssim2", "lpips", "psnr_dynamic", "psnr_static", "psnr_unobserved", "psnr_aligned",
               "unobserved_fraction")


def metrics_row(method: str, metrics: dict[str, Any], seconds: float | None) -> dict[str, Any]:
    """A finished row from an ``evaluate()`` result."""
    mean = metrics["mean"]
    row = {"method": method, "status": "ok", **{k: mean.get(k) for k in METRIC_KEYS}, "seconds": seconds}
    if metrics.get("held_out") is False:  # scored on the train views: the scene has no held-out camera
        row["held_out"] = False
    return row


def copied_row(method: str, metrics: dict[str, Any], seconds: float | None = None) -> dict[str, Any]:
    """A row whose images are another row's (the identity baseline is the stage-1 render; the final
    model where the self-check kept stage 1): its metrics, under ``method``, with ``seconds``
    (None: no time of its own)."""
    row = metrics_row(method, metrics, seconds)
    row["same_as"] = metrics.get("method")
    return row


def failed_row(method: str, reason: str) -> dict[str, Any]:
    return {"method": method, "status": "failed", **dict.fromkeys(METRIC_KEYS), "seconds": None, "error": reason}


def _fmt(value: float | None, digits: int) -> str:
    """Table cell: n/a for a missing value (LPIPS without weights; an empty moving mask)."""
    return "n/a" if value is None else f"{value:.{digits}f}"


def restorer_line(summary: dict[str, Any]) -> str:
    """'Restorer: learned (validation ...)' for the report."""
    v = summary.get("validation")
    if not v:
        return f"Restorer: {summary.get('kind', 'warp')}"
    cpu = (v.get("cpu_seconds") or {}).get("total")
    return (f"Restorer: learned (leave-one-camera-out validation on train camera {v['held_out_fold_camera']}: "
            f"render {v['psnr_render']:.2f} dB -> restored {v['psnr_learned']:.2f} dB, {v['gain_db']:+.2f} dB; "
            f"warp restorer {v['psnr_warp']:.2f} dB" + (f"; {cpu:.0f} CPU s to train)" if cpu is not None else ")"))


def camera_response_line(model: dict[str, Any]) -> str:
    """The report's sentence on the per-camera colour response (``model`` = terms_report)."""
    reason = (model.get("reasons") or {}).get("camera_response")
    trained = model.get("camera_response")
    if trained is None:
        return f"Camera response: off ({reason or 'no decomposed init to measure it on'})."
    gains = ", ".join("/".join(f"{g:.3f}" for g in v["gain"]) for v in trained["views"])
    return (f"Camera response: on ({reason}); trained RGB gains per train camera: {gains} "
            "(renders at other cameras use the rig's mean response).")


def self_check_line(check: dict[str, Any]) -> str:
    """'Stage-2 self-check: ...' for the report (the decision and its fold figures)."""
    psnr = check.get("psnr")
    if not psnr:
        return f"Stage-2 self-check: {check.get('decision')} ({check.get('reason', '')})"
    secs = sum((check.get("seconds") or {}).values())
    settings = check.get("settings") or {}
    tie = settings.get("tie_db")
    if tie is None:
        margin = ""
    elif settings.get("margin") == "measured":
        margin = f" (a candidate must beat the simplest by more than {tie:g} dB and its gain's 95 % half-width)"
    else:
        margin = f" (a candidate must beat the simplest by more than {tie:g} dB)"
    g = check.get("gains") or {}

    def fig(name: str, label: str) -> str:
        se = (g.get(name) or {}).get("se_db")
        return f"{label} {psnr[name]:.2f} dB" + ("" if se is None else f" ({g[name]['gain_db']:+.2f} ± {se:.2f})")

    unit = "fold" if check.get("gain_unit") == "fold" else "scored frame"
    if check.get("folds"):
        names = ", ".join(str(f["held_back_name"]) for f in check["folds"])
        where = (f"on held-back train cameras {names}, one fold each (each trained on the other cameras at scale "
                 f"{check['scale']:g}, {secs:.0f} s in all); mean over the folds")
    else:
        # a fold recorded before the cameras' names were kept names them by index
        held = check.get("held_back_name", check["held_back_camera"])
        fold = ", ".join(str(c) for c in check.get("fold_names", check["fold_cameras"]))
        where = f"on held-back train camera {held} (fold of cameras {fold} at scale {check['scale']:g}, {secs:.0f} s)"
    more = f"{fig('continue', 'more training')}, " if "continue" in psnr else ""
    return (f"Stage-2 self-check {where}: before {psnr['skip']:.2f} dB, "
            f"{more}{fig('refine', 'stage 2')}{margin} -> "
            f"**{check['decision']}**: the final model is {_FINAL[check['decision']]}. Gains are over before, per "
            f"{unit}: mean ± standard error.")


_FINAL = {"skip": "the stage-1 model", "continue": "the matched-iterations control (no pseudo-views)",
          "refine": "stage 2's"}


def write_report(run_dir: Path, scene_text: str, rows: list[dict[str, Any]], stage_seconds: dict[str, float],
                 extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """Write RUN/report.json and RUN/report.md; returns the report dict."""
    report = {"rows": rows, "stage_seconds": stage_seconds, "scene": scene_text, **(extra or {})}
    atomic.write_json(run_dir / "report.json", report)
    lines = [f"# fixer4d report: {run_dir.name}", "", f"Scene: {scene_text}", ""]
    held_out = not any(r.get("held_out") is False for r in rows)
    if not held_out:
        response = ((report.get("model") or {}).get("camera_response")
                    and " Each train view is rendered through the colour response its camera trained (the sparse "
                        "baseline trains none).")
        lines += ["No held-out camera: every camera trained, so the table shows the fit to the train views, not "
                  f"novel-view quality (`fixer4d run CAPTURE --holdout CAM` holds one camera out).{response or ''}", ""]
    if report.get("model"):
        lines += [camera_response_line(report["model"]), ""]
    if report.get("restorer"):
        lines += [restorer_line(report["restorer"]), ""]
    if report.get("self_check"):
        lines += [self_check_line(report["self_check"]), ""]
    for r, summary in (report.get("pseudo_views") or {}).items():
        frac = summary.get("unobserved_fraction")
        if frac:
            lines += [f"Pseudo-views, round {r}: {summary['clips']} clips; the pseudo-loss acts on "
                      f"{100 * frac['mean']:.1f} % of their pixels on average ({100 * frac['min']:.1f}-"
                      f"{100 * frac['max']:.1f} % per clip): the rest is observed by the train cameras.", ""]
    lines += ["| Method | PSNR | PSNR dynamic | PSNR static | PSNR unobserved | PSNR exposure-aligned | DSSIM1 | DSSIM2 "
              "| LPIPS | Time (s) |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r.get("status") == "failed":
            lines.append(f"| {r['method']} | failed: {r.get('error', '')} | | | | | | | | |")
            continue
        lines.append(f"| {r['method']} | {_fmt(r['psnr'], 2)} | {_fmt(r.get('psnr_dynamic'), 2)} | "
                     f"{_fmt(r.get('psnr_static'), 2)} | {_fmt(r.get('psnr_unobserved'), 2)} | "
                     f"{_fmt(r.get('psnr_aligned'), 2)} | {_fmt(r['dssim1'], 4)} | {_fmt(r['dssim2'], 4)} | "
                     f"{_fmt(r['lpips'], 4)} | {_fmt(r['seconds'], 1)} |")
    fractions = [r.get("unobserved_fraction") for r in rows if r.get("unobserved_fraction") is not None]
    if fractions:
        lines += ["", f"PSNR unobserved: over the {'held-out' if held_out else 'train-view'} pixels that no train "
                      f"camera explains in the stage-1 model "
                      f"({100 * fractions[0]:.1f} % of them; restore.visibility, from renders only). PSNR "
                      "exposure-aligned: after a per-image per-channel affine colour fit to the ground truth. "
                      f"{ROW_IDENTITY} is the {ROW_MVS} render itself; {ROW_BLUR} a Gaussian blur of it."]
    lines += ["", "Seconds per stage:", "", "| Stage | Seconds |", "|---|---|"]
    lines += [f"| {k} | {v:.1f} |" for k, v in stage_seconds.items()]
    atomic.write_text(run_dir / "report.md", "\n".join(lines) + "\n")
    return report
