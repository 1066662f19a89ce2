"""The gate between a self-calibration and its use: a rig that is not trustworthy is refused in
one InputError naming the camera, the matches of every pair and what to do; never used silently.

A rig passes when
* every camera registered, and each one's mean reprojection error is at most
  ``MAX_REPROJECTION_PX``;
* the pairs with at least ``MIN_PAIR_MATCHES`` verified matches connect every camera, and each
  camera shares at least ``MIN_CAMERA_POINTS`` 3D points with the others;
* the frames determine the focal length: forcing every focal ``sfm.FOCAL_PROBE`` times larger or
  smaller raises the mean reprojection error by at least ``MIN_FOCAL_SENSITIVITY_PX`` after the
  rest is refitted (``sfm.focal_sensitivity``; skipped when the focal was given);
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
# Rise of the mean reprojection error (pixels) when the focal is off by 10 %. Measured
# (docs/calibration.md): the demo's parallel 2x2 rig 0.0000 px (focal off by 97 %: any focal
# fits it), the same grid converging on the scene 0.001 px (focal off 7 %), four cameras on a 60
# degree arc 0.003 px (off 4-5 %), Panoptic's four basketball cameras 0.015-0.05 px (off 3-16 %).
# A 10 % focal error that costs under a quarter pixel is not pinned down by the frames.
MIN_FOCAL_SENSITIVITY_PX = 0.25
# Fields of view outside this range are not lenses anyone films a scene with; a focal there is a
# degenerate solution.
MIN_FOV_DEG = 5.0
MAX_FOV_DEG = 150.0

ADVICE = ("give the focal length if you know it (`fixer4d calibrate CAPTURE --focal PX --out rig.json`), or film a "
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


def problems(rig: Rig, expected: list[str], focal_given: bool = False) -> list[str]:
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
    sens = rig.checks.get("focal_sensitivity_px")
    if not focal_given and sens is not None and sens < MIN_FOCAL_SENSITIVITY_PX:
        found.append(f"the frames do not determine the focal length (a 10 % focal change moves the reprojection "
                     f"error by {sens:.3f} px, need >= {MIN_FOCAL_SENSITIVITY_PX}; cameras that all face the same way "
                     f"or see little depth cause this)")
    return found + field_of_view_problems(rig.cameras)


def check_rig(rig: Rig, expected: list[str], label: str, focal_given: bool = False) -> Rig:
    """``rig`` if it passes; else InputError in one line: what is wrong, the per-pair figures, what to do."""
    found = problems(rig, expected, focal_given)
    rig.checks["gate"] = {"passed": not found, "problems": found}
    if found:
        raise InputError(f"{label}: self-calibration refused: {'; '.join(found)}. Matches per pair: "
                         f"{pair_table(rig)}. To fix: {ADVICE}")
    return rig
