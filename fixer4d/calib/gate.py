"""The gate between a self-calibration and its use: a rig that is not trustworthy is refused in
one InputError naming the camera, the matches of every pair and what to do; never used silently.

A rig passes when
* every camera registered, and each one's mean reprojection error is at most
  ``MAX_REPROJECTION_PX``;
* the pairs with at least ``MIN_PAIR_MATCHES`` verified matches connect every camera, and each
  camera shares at least ``MIN_CAMERA_POINTS`` 3D points with the others;
* every camera is determined: the standard errors of its focal, rotation and centre from the
  last bundle adjustment's covariance (``fixer4d.calib.adjust``; with the focal priors the frames
  allow) are at most ``MAX_FOCAL_SD_REL``, ``MAX_ROTATION_SD_DEG`` and ``MAX_CENTRE_SD_REL``, and
  no focal prior contradicts the frames of a camera they do not determine (``priors.weigh_priors``);
* the recovered field of view is in [``MIN_FOV_DEG``, ``MAX_FOV_DEG``].
"""
from __future__ import annotations

import numpy as np

from fixer4d.calib.rig import Rig, RigCamera
from fixer4d.errors import InputError

# SIFT keypoints of a correct rig reproject within about half a pixel to one pixel; past 1.5 px
# the lens/pose model does not explain the matches.
MAX_REPROJECTION_PX = 1.5
# A pair with fewer verified matches (pooled over the timestamps) is not counted as a link of the
# match graph: a few dozen can be consistent by chance or all lie on one small patch.
MIN_PAIR_MATCHES = 100
# 3D points a camera must share with the others for its pose to rest on more than a patch.
MIN_CAMERA_POINTS = 100
# Standard errors a camera may have: half of what a usable rig may be off by (2 % focal, 1 degree,
# 2 % of the rig radius), so that an error of two standard errors stays within it.
MAX_FOCAL_SD_REL = 0.01
MAX_ROTATION_SD_DEG = 0.5
MAX_CENTRE_SD_REL = 0.01
# Fields of view outside this range are not lenses anyone films a scene with; a focal there is a
# degenerate solution.
MIN_FOV_DEG = 5.0
MAX_FOV_DEG = 150.0

ADVICE = ("give the focal lengths you know as priors (`fixer4d calibrate CAPTURE --focal PX --out rig.json`, per camera "
          "`--focal CAM=PX`, with an uncertainty `--focal CAM=PX:SD`), or film a "
          "ChArUco board through the volume with every camera (print it with `fixer4d calibrate --write-board "
          "board.png`) and put the board videos, named like the capture's, with its board.json in CAPTURE/board/, or "
          "put a calibration from another method (COLMAP, ...) beside the videos (rig.json, a COLMAP sparse model, "
          "transforms.json, poses_bounds.npy) or pass it with --calibration")


def pair_table(rig: Rig) -> str:
    """'cam01-cam09 95 verified/205 raw, 92 shared points; ...'."""
    return "; ".join(f"{p['cameras'][0]}-{p['cameras'][1]} {p['verified_matches']} verified/{p['raw_matches']} raw, "
                     f"{p['shared_points']} shared points" for p in rig.pairs)


def field_of_view_problems(cameras: list[RigCamera]) -> list[str]:
    """One phrase per camera whose horizontal field of view (degrees, from its width and focal)
    lies outside [``MIN_FOV_DEG``, ``MAX_FOV_DEG``]."""
    found = []
    for c in cameras:
        fov = float(np.degrees(2 * np.arctan(c.width / (2 * c.K[0, 0]))))
        if not MIN_FOV_DEG <= fov <= MAX_FOV_DEG:
            found.append(f"camera {c.name} came out with a {fov:.1f} degree field of view (focal {c.K[0, 0]:.1f} px)")
    return found


def problems(rig: Rig, expected: list[str]) -> list[str]:
    """What makes ``rig`` untrustworthy, one phrase each (empty: it passes)."""
    found = []
    names = [c.name for c in rig.cameras]
    missing = [n for n in expected if n not in names]
    if missing:
        found.append(f"cameras {missing} could not be registered")
    for c in rig.cameras:
        if c.reprojection_error_px is None or c.reprojection_error_px > MAX_REPROJECTION_PX:
            err = "no" if c.reprojection_error_px is None else f"{c.reprojection_error_px:.2f} px"
            found.append(f"camera {c.name} has {err} mean reprojection error (at most {MAX_REPROJECTION_PX} px)")
    # match graph over the links strong enough to count
    parent = {n: n for n in expected}

    def root(n: str) -> str:
        while parent[n] != n:
            n = parent[n]
        return n

    points = dict.fromkeys(expected, 0)
    for p in rig.pairs:
        a, b = p["cameras"]
        if a in parent and b in parent:
            points[a] += p["shared_points"]
            points[b] += p["shared_points"]
            if p["verified_matches"] >= MIN_PAIR_MATCHES:
                parent[root(a)] = root(b)
    groups: dict[str, list[str]] = {}
    for n in expected:
        groups.setdefault(root(n), []).append(n)
    if len(groups) > 1:
        found.append(f"the pairs with >= {MIN_PAIR_MATCHES} verified matches split the cameras into "
                     f"{sorted(groups.values())}")
    weak = [f"{n} ({points[n]})" for n in expected if points[n] < MIN_CAMERA_POINTS and n not in missing]
    if weak:
        found.append(f"cameras {', '.join(weak)} share fewer than {MIN_CAMERA_POINTS} 3D points with the others")
    return found + undetermined(rig.checks.get("cameras", {})) + field_of_view_problems(rig.cameras)


def undetermined(figures: dict[str, dict]) -> list[str]:
    """One phrase per camera whose focal, rotation or centre the frames (and the priors they
    allow) do not determine, or whose focal prior they contradict; ``figures``: rig.checks["cameras"]."""
    found = []
    for name, c in figures.items():
        f, sd = c["focal_px"], c["focal_sd_px"]
        prior = c.get("prior") or {}
        if prior.get("verdict") == "contradicts the frames":
            found.append(f"camera {name}: the focal prior {prior['focal_px']:.1f} +- {prior['sd_px']:.1f} px "
                         f"contradicts its frames ({c['frames_focal_px']:.1f} +- {c['frames_focal_sd_px']:.1f} px), "
                         f"which do not determine it either")
        elif sd > MAX_FOCAL_SD_REL * f or c["rotation_sd_deg"] > MAX_ROTATION_SD_DEG \
                or c["centre_sd_rel"] > MAX_CENTRE_SD_REL:
            found.append(f"camera {name} is not determined by the frames: standard errors focal {sd:.1f} px "
                         f"({100 * sd / f:.1f} % of {f:.1f}, at most {100 * MAX_FOCAL_SD_REL:.0f} %), rotation "
                         f"{c['rotation_sd_deg']:.2f} deg (at most {MAX_ROTATION_SD_DEG}), centre "
                         f"{100 * c['centre_sd_rel']:.1f} % of the rig radius (at most {100 * MAX_CENTRE_SD_REL:.0f} %)")
    return found


def check_rig(rig: Rig, expected: list[str], label: str) -> Rig:
    """``rig`` if it passes; else InputError in one line: what is wrong, the per-pair figures, what to do."""
    found = problems(rig, expected)
    rig.checks["gate"] = {"passed": not found, "problems": found}
    if found:
        raise InputError(f"{label}: self-calibration refused: {'; '.join(found)}. Matches per pair: "
                         f"{pair_table(rig)}. To fix: {ADVICE}")
    return rig
