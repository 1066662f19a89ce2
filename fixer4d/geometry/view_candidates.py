"""Candidate novel cameras around a rig, the pick of the best-scored ones, and the short paths
that reach them from the rig (the pseudo-views where the model is undetermined).

Only the train cameras' poses and intrinsics enter here: no image, no model, no held-out camera.

Pool (``orbit_candidates``): cameras on spheres around the rig's look-at centre (``rig_focus``),
each looking at that centre with the rig's mean image-up as up. Directions are an azimuth around
the up axis (measured from the train cameras' mean direction, every 360 / ``azimuths`` degrees),
and an elevation of the rig's mean elevation plus each of ``elevations_deg`` (above and below the
rig's plane); radii are ``radii`` x the train cameras' mean distance to the centre. A candidate
whose direction from the centre lies within ``MIN_TRAIN_ANGLE_DEG`` of a train camera's is left
out: that view is the train camera's own.

Pick (``pick_separated``): greedy top-k by score, each pick at least ``min_separation_deg`` (seen
from the centre) from every earlier one, so k picks look at k different sides of the scene.

Path (``approach_path``): Eq. 3 with A = 0 from the train camera nearest to the pick (alpha 0,
that camera bit for bit) to the pick (alpha 1); the restorer's references are the two train
cameras nearest to the pick, so every frame of the clip has its closest real frames as references.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.geometry.rig import rig_focus
from fixer4d.geometry.trajectory import Trajectory, alphas_for, interpolate_pair

# A candidate closer than this (degrees, seen from the centre) to a train camera's direction
# looks at what that camera films: 10 degrees is well inside the visibility rule's full-observation
# angle (25 degrees, restore.visibility), so such a view is observed by construction.
MIN_TRAIN_ANGLE_DEG = 10.0
# Elevations are kept this far (degrees) from the up axis: look_at needs a viewing direction that
# is not parallel to up, and a view from straight above has no defined image-up.
MAX_ELEVATION_DEG = 80.0
# A rig whose cameras' mean direction from the centre lies within this of up (sin of the angle)
# has no azimuth origin of its own: the first camera's direction is used.
MIN_HORIZONTAL = 1e-6


@dataclass(frozen=True)
class RigFrame:
    """Where a rig looks and how it stands: centre (3,) the look-at point (world units), up (3,)
    unit mean image-up, east (3,) unit azimuth origin (perpendicular to up), radius the train
    cameras' mean distance to the centre (world units), elevation_deg their mean elevation above
    the plane perpendicular to up through the centre (degrees)."""

    center: np.ndarray
    up: np.ndarray
    east: np.ndarray
    radius: float
    elevation_deg: float

    def direction(self, azimuth_deg: float, elevation_deg: float) -> np.ndarray:
        """(3,) unit direction from the centre at an azimuth (from ``east``, around ``up``) and elevation."""
        a, e = np.radians(azimuth_deg), np.radians(elevation_deg)
        north = np.cross(self.up, self.east)
        return np.cos(e) * (np.cos(a) * self.east + np.sin(a) * north) + np.sin(e) * self.up


def rig_frame(train_cameras: Sequence[Camera]) -> RigFrame:
    """The ``RigFrame`` of the train cameras (at least 2, at distinct centres from their focus)."""
    if len(train_cameras) < 2:
        raise InputError(f"view candidates need at least 2 train cameras, got {len(train_cameras)}")
    center = rig_focus(train_cameras)
    up = -np.sum([c.c2w[:3, 1] for c in train_cameras], axis=0)  # OpenCV image-up is camera -y
    if not np.linalg.norm(up) > 0:
        raise InputError("view candidates: the train cameras' image-up directions cancel out; the rig has no up")
    up = up / np.linalg.norm(up)
    offsets = np.stack([c.center for c in train_cameras]) - center
    dist = np.linalg.norm(offsets, axis=1)
    if not np.all(dist > 0):
        raise InputError("view candidates: a train camera sits at the rig's look-at centre")
    dirs = offsets / dist[:, None]
    for d in (dirs.mean(axis=0), dirs[0]):
        flat = d - np.dot(d, up) * up
        if np.linalg.norm(flat) > MIN_HORIZONTAL:
            east = flat / np.linalg.norm(flat)
            break
    else:  # every train camera straight above or below the centre: any horizontal axis will do
        axis = np.eye(3)[int(np.argmin(np.abs(up)))]
        east = axis - np.dot(axis, up) * up
        east /= np.linalg.norm(east)
    elevation = float(np.degrees(np.mean(np.arcsin(np.clip(dirs @ up, -1.0, 1.0)))))
    return RigFrame(center, up, east, float(dist.mean()), elevation)


def nearest_train(train_cameras: Sequence[Camera], camera: Camera, count: int = 2) -> list[int]:
    """Indices into ``train_cameras`` of the ``count`` centres nearest to ``camera``'s (ties by index)."""
    d = [float(np.linalg.norm(c.center - camera.center)) for c in train_cameras]
    return sorted(range(len(d)), key=lambda i: (d[i], i))[:count]


def orbit_candidates(train_cameras: Sequence[Camera], *, azimuths: int, elevations_deg: Sequence[float],
                     radii: Sequence[float]) -> list[Camera]:
    """The candidate pool (module docstring): len(radii) x len(elevations_deg) x azimuths cameras,
    minus those within ``MIN_TRAIN_ANGLE_DEG`` of a train camera. Each candidate has the
    intrinsics and image size of the train camera nearest to it; names ``cand_r<r>_e<e>_a<a>``
    (indices into the three lists)."""
    if azimuths < 1 or not elevations_deg or not radii:
        raise InputError("view candidates: need at least 1 azimuth, 1 elevation and 1 radius")
    if not all(np.isfinite(r) and r > 0 for r in radii):
        raise InputError(f"view candidates: radii must be finite and > 0, got {list(radii)}")
    frame = rig_frame(train_cameras)
    train_dirs = np.stack([(c.center - frame.center) / np.linalg.norm(c.center - frame.center)
                           for c in train_cameras])
    cos_min = np.cos(np.radians(MIN_TRAIN_ANGLE_DEG))
    out = []
    for (ri, r), (ei, de), ai in itertools.product(enumerate(radii), enumerate(elevations_deg), range(azimuths)):
        elevation = float(np.clip(frame.elevation_deg + de, -MAX_ELEVATION_DEG, MAX_ELEVATION_DEG))
        d = frame.direction(360.0 * ai / azimuths, elevation)
        if np.max(train_dirs @ d) > cos_min:
            continue
        eye = frame.center + r * frame.radius * d
        like = train_cameras[int(np.argmin([np.linalg.norm(c.center - eye) for c in train_cameras]))]
        out.append(Camera.look_at(eye, frame.center, frame.up, K=like.K, width=like.width, height=like.height,
                                  name=f"cand_r{ri}_e{ei}_a{ai}"))
    return out


def pick_separated(directions: np.ndarray, scores: np.ndarray, k: int, min_separation_deg: float) -> list[int]:
    """Indices of up to ``k`` candidates by decreasing score (ties by index), each at least
    ``min_separation_deg`` from every earlier pick. directions: (N, 3) unit directions of the
    candidates from the centre; scores: (N,) finite."""
    directions = np.asarray(directions, np.float64).reshape(-1, 3)
    scores = np.asarray(scores, np.float64).reshape(-1)
    if len(scores) != len(directions) or not np.all(np.isfinite(scores)):
        raise InputError(f"pick: need one finite score per candidate, got {len(scores)} for {len(directions)}")
    cos_max = np.cos(np.radians(min_separation_deg))
    picked: list[int] = []
    for i in sorted(range(len(scores)), key=lambda i: (-scores[i], i)):
        if len(picked) >= k:
            break
        if all(float(directions[i] @ directions[j]) < cos_max for j in picked):
            picked.append(i)
    return picked


def approach_path(train_cameras: Sequence[Camera], target: Camera, frames: int, view_index: int) -> Trajectory:
    """The clip of pick ``view_index``: ``frames`` cameras from the nearest train camera to
    ``target`` (module docstring). Its ``pair`` is (nearest, second nearest) train-list indices,
    the restorer's references; named ``view<k>``."""
    near = nearest_train(train_cameras, target, 2)
    alphas = alphas_for(frames)
    name = f"view{int(view_index)}"
    cameras = interpolate_pair(train_cameras[near[0]], target, alphas, 0.0, name=name)
    return Trajectory(name, cameras, alphas, pair=(near[0], near[1]), amplitude=0.0, view_index=int(view_index))
