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
ROW_NAMES = (ROW_COLMAP, ROW_MVS, ROW_MATCHED, ROW_RESTORED_INIT, ROW_FULL, ROW_RESTORED_REFINED)
METRIC_KEYS = ("psnr", "dssim1", "dssim2", "lpips", "psnr_dynamic", "psnr_static")


def metrics_row(method: str, metrics: dict[str, Any], seconds: float | None) -> dict[str, Any]:
    """A finished row from an ``evaluate()`` result."""
    mean = metrics["mean"]
    return {"method": method, "status": "ok", **{k: mean.get(k) for k in METRIC_KEYS}, "seconds": seconds}


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


def write_report(run_dir: Path, scene_text: str, rows: list[dict[str, Any]], stage_seconds: dict[str, float],
                 extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """Write RUN/report.json and RUN/report.md; returns the report dict."""
    report = {"rows": rows, "stage_seconds": stage_seconds, "scene": scene_text, **(extra or {})}
    atomic.write_json(run_dir / "report.json", report)
    lines = [f"# fixer4d report: {run_dir.name}", "", f"Scene: {scene_text}", ""]
    if report.get("restorer"):
        lines += [restorer_line(report["restorer"]), ""]
    lines += ["| Method | PSNR | PSNR dynamic | PSNR static | DSSIM1 | DSSIM2 | LPIPS | Time (s) |",
              "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r.get("status") == "failed":
            lines.append(f"| {r['method']} | failed: {r.get('error', '')} | | | | | | |")
            continue
        lines.append(f"| {r['method']} | {_fmt(r['psnr'], 2)} | {_fmt(r.get('psnr_dynamic'), 2)} | "
                     f"{_fmt(r.get('psnr_static'), 2)} | {_fmt(r['dssim1'], 4)} | {_fmt(r['dssim2'], 4)} | "
                     f"{_fmt(r['lpips'], 4)} | {_fmt(r['seconds'], 1)} |")
    lines += ["", "Seconds per stage:", "", "| Stage | Seconds |", "|---|---|"]
    lines += [f"| {k} | {v:.1f} |" for k, v in stage_seconds.items()]
    atomic.write_text(run_dir / "report.md", "\n".join(lines) + "\n")
    return report
