"""The candidate pool around a rig, the separated pick and the approach paths
(geometry.view_candidates): valid cameras that look at the rig's centre and are no train camera."""
from __future__ import annotations

import numpy as np

from fixer4d.geometry.camera import Camera
from fixer4d.geometry.trajectory import Trajectory, novel_frame_mask
from fixer4d.geometry.view_candidates import (MIN_TRAIN_ANGLE_DEG, approach_path, orbit_candidates,
                                              pick_separated, rig_frame)

CENTER = np.array([0.5, -0.2, 1.0])


def ring(n: int = 4, radius: float = 3.0, height: float = 0.8, spread_deg: float = 120.0) -> list[Camera]:
    """n cameras on an arc of ``spread_deg`` around CENTER, a little above it, looking at it (+y up)."""
    cams = []
    for k, a in enumerate(np.radians(np.linspace(-spread_deg / 2, spread_deg / 2, n))):
        eye = CENTER + np.array([radius * np.sin(a), height, radius * np.cos(a)])
        cams.append(Camera.look_at(eye, CENTER, (0.0, 1.0, 0.0), width=64, height=48, name=f"cam{k}"))
    return cams


def test_the_rig_frame_finds_the_centre_up_and_distance():
    train = ring()
    frame = rig_frame(train)
    assert np.allclose(frame.center, CENTER, atol=1e-9)
    assert frame.up @ np.array([0.0, 1.0, 0.0]) > 0.95  # the mean image-up tilts with the cameras' pitch
    assert abs(frame.radius - np.hypot(3.0, 0.8)) < 1e-9


def test_candidates_are_finite_look_at_the_centre_and_are_no_train_camera():
    train = ring()
    pool = orbit_candidates(train, azimuths=12, elevations_deg=[-20.0, 0.0, 20.0], radii=[1.0, 1.3])
    assert 0 < len(pool) < 72  # the ones beside a train camera are left out
    frame = rig_frame(train)
    train_dirs = np.stack([(c.center - CENTER) / np.linalg.norm(c.center - CENTER) for c in train])
    heights = set()
    for cam in pool:
        assert np.all(np.isfinite(cam.K)) and np.all(np.isfinite(cam.c2w))
        to_center = (CENTER - cam.center) / np.linalg.norm(CENTER - cam.center)
        assert to_center @ cam.forward > 1.0 - 1e-9  # the optical axis runs through the centre
        d = -to_center
        assert np.degrees(np.arccos(np.max(train_dirs @ d))) >= MIN_TRAIN_ANGLE_DEG - 1e-9
        assert novel_frame_mask([cam], train)[0]
        r = np.linalg.norm(cam.center - CENTER) / frame.radius
        assert min(abs(r - 1.0), abs(r - 1.3)) < 1e-9
        heights.add(round(float(np.degrees(np.arcsin(d @ frame.up)) - frame.elevation_deg)))
    assert heights == {-20, 0, 20}  # above and below the rig's plane, and in it


def test_the_pick_takes_the_best_scores_apart_from_each_other():
    dirs = np.array([[1.0, 0, 0], [np.cos(0.1), np.sin(0.1), 0], [0, 1.0, 0], [0, 0, 1.0]])
    scores = np.array([0.9, 0.95, 0.5, 0.7])
    # the second-best lies 5.7 degrees from the best: left out; then by score
    assert pick_separated(dirs, scores, 3, 25.0) == [1, 3, 2]
    assert pick_separated(dirs, scores, 2, 0.0) == [1, 0]
    assert pick_separated(dirs, scores, 10, 25.0) == [1, 3, 2]  # fewer than asked when the pool runs out


def test_the_approach_path_starts_at_the_nearest_train_camera_and_ends_at_the_pick():
    train = ring()
    target = orbit_candidates(train, azimuths=12, elevations_deg=[20.0], radii=[1.3])[0]
    d = [np.linalg.norm(c.center - target.center) for c in train]
    path = approach_path(train, target, 5, 2)
    assert isinstance(path, Trajectory) and path.frames == 5 and path.view_index == 2 and path.name == "view2"
    assert path.pair == tuple(int(i) for i in np.argsort(d)[:2])
    first, last = path.cameras[0], path.cameras[-1]
    assert np.array_equal(first.c2w, train[path.pair[0]].c2w) and np.array_equal(first.K, train[path.pair[0]].K)
    assert np.array_equal(last.c2w, target.c2w)
    assert novel_frame_mask(path.cameras, train).tolist() == [False, True, True, True, True]
    assert Trajectory.from_dict(path.to_dict()).view_index == 2
