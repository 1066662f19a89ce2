"""A paper estimate of a long capture's wall time on N machines, from a measured run's stage seconds.

    python benchmarks/segment_estimate.py RUN --frames 300 --segment-frames 50 \
        --width 676 --height 507 --machines 1 2 4 8 [--main-only] [--out FILE.json]

RUN is a finished run folder (its `stages.json` holds the measured seconds of every stage, its
`report.json` the scene's frames and resolution). The model, stated so it can be checked:

* A segment is a complete run on its frame range (fixer4d.pipeline.segments), so every stage of
  RUN runs once per segment.
* Stages with a fixed iteration count (stage 1 / 2, the matched control, the learned restorer's
  training) cost the same per segment whatever its frame count; init and evaluation stages
  scale linearly with the segment's frames (conservative for the decomposed init, whose static
  sweep runs once per segment).
* Every stage scales linearly with the pixel count (rasterization, plane sweep and the restorer
  are per-pixel work at a fixed Gaussian budget).
* Segments are independent (the Ray executor runs one per machine at a time, each machine like
  the one RUN was measured on) and cost the same: the wall time is ceil(segments / N) segment
  times. With ``--shared`` (``segments.share_static=true``) the first segment runs alone and the
  others train on top of its static Gaussians: 1 + ceil((segments - 1) / N). The whole-clip
  evaluation on the head is ignored (seconds against hours).

`--main-only` drops the baseline rows (sparse init and its stage 1, the matched control, the
restoration rows), which a production run of a long capture would switch off.
"""
from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fixer4d.pipeline.segments import split_segments  # noqa: E402

FIXED_ITERATION_STAGES = ("stage1", "stage1_sparse", "matched", "stage2", "restorer")
BASELINE_STAGES = ("init_sparse", "stage1_sparse", "eval:stgs-w-colmap", "matched",
                   "eval:stgs-w-mvs-matched-iterations", "eval:restoration-init", "eval:restoration-refined")


def measured(run: Path) -> tuple[dict[str, float], int, int, int]:
    """(seconds per stage, frames, width, height) of a finished run folder."""
    stages = json.loads((run / "stages.json").read_text())
    report = json.loads((run / "report.json").read_text())
    m = re.search(r"(\d+) frames at (\d+)x(\d+)", report["scene"])
    if m is None:
        raise SystemExit(f"{run}/report.json: cannot read frames and resolution from {report['scene']!r}")
    seconds = {k: float(v["seconds"]) for k, v in stages.items() if v.get("done")}
    return seconds, int(m.group(1)), int(m.group(2)), int(m.group(3))


def segment_seconds(seconds: dict[str, float], run_frames: int, segment_frames: int, pixel_ratio: float,
                    main_only: bool) -> dict[str, float]:
    """Estimated seconds of each stage for one segment of ``segment_frames`` frames."""
    out = {}
    for stage, s in seconds.items():
        if main_only and stage in BASELINE_STAGES:
            continue
        frame_ratio = 1.0 if stage in FIXED_ITERATION_STAGES else segment_frames / run_frames
        out[stage] = s * frame_ratio * pixel_ratio
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="a finished run folder (stages.json, report.json)")
    ap.add_argument("--frames", type=int, default=300, help="frames of the long capture")
    ap.add_argument("--segment-frames", type=int, default=50)
    ap.add_argument("--overlap", type=int, default=2)
    ap.add_argument("--width", type=int, help="capture width (default: the run's)")
    ap.add_argument("--height", type=int, help="capture height (default: the run's)")
    ap.add_argument("--machines", type=int, nargs="+", default=[1, 2, 4, 8])
    ap.add_argument("--main-only", action="store_true", help="without the baseline and control rows")
    ap.add_argument("--shared", action="store_true",
                    help="segments that share the first one's static Gaussians (segments.share_static=true): "
                         "the first segment is a wave of its own")
    ap.add_argument("--out", type=Path, help="write the estimate as JSON here")
    args = ap.parse_args(argv)

    seconds, frames, width, height = measured(args.run)
    w, h = args.width or width, args.height or height
    pixel_ratio = (w * h) / float(width * height)
    segments = split_segments(args.frames, args.segment_frames, args.overlap)
    per_stage = segment_seconds(seconds, frames, args.segment_frames, pixel_ratio, args.main_only)
    per_segment = sum(per_stage.values())
    rows = []
    for n in args.machines:
        waves = 1 + math.ceil((len(segments) - 1) / n) if args.shared else math.ceil(len(segments) / n)
        rows.append({"machines": n, "waves": waves, "hours": waves * per_segment / 3600.0})

    print(f"measured: {args.run} ({frames} frames at {width}x{height}, {sum(seconds.values()) / 60:.1f} min of stages)")
    print(f"capture: {args.frames} frames at {w}x{h} -> {len(segments)} segments of {args.segment_frames} frames "
          f"(overlap {args.overlap}); pixels x{pixel_ratio:.2f}{'; main method only' if args.main_only else ''}")
    for stage, s in sorted(per_stage.items(), key=lambda kv: -kv[1]):
        print(f"  {stage:<40s} {s / 60:8.1f} min per segment")
    print(f"  {'one segment':<40s} {per_segment / 60:8.1f} min")
    print("| machines | segment waves | wall time (h) |\n|---|---|---|")
    for r in rows:
        print(f"| {r['machines']} | {r['waves']} | {r['hours']:.1f} |")
    if args.out:
        args.out.write_text(json.dumps({"run": str(args.run), "measured_frames": frames, "measured_size": [width, height],
                                        "frames": args.frames, "size": [w, h], "segments": segments,
                                        "segment_seconds": per_stage, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
