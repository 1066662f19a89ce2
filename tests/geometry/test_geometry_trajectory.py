"""Trajectories (Eq. 3): endpoints, the arc, degenerate rigs, presets and nerfstudio camera paths."""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fixer4d.errors import InputError
from fixer4d.geometry import quaternion as quat
from fixer4d.geometry.camera import Camera
from fixer4d.geometry.trajectory import (ARC_AMPLITUDE_RANGE, Trajectory, arc_normal, diagonal_pairs,
                                         interpolate_pair, load_nerfstudio, load_presets, save_nerfstudio,
                                         save_presets, scene_trajectories)

coord = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
points = st.tuples(coord, coord, coord).map(np.array)
comp = st.floats(-1.0, 1.0, allow_nan=False)
orientations = st.tuples(comp, comp, comp, comp).map(np.array).filter(lambda q: np.linalg.norm(q) > 1e-2)


def make_camera(center, q, f=100.0, cx=32.0, cy=24.0, name="c") -> Camera:
    c2w = np.eye(4)
    c2w[:3, :3] = quat.to_matrix(q)
    c2w[:3, 3] = center
    return Camera(np.array([[f, 0, cx], [0, f * 1.1, cy], [0, 0, 1]]), c2w, 64, 48, name)


def rig(centers, target=(0.0, 0.0, 0.0)) -> list[Camera]:
    """Cameras at the given centres, all looking at ``target`` with world +y as image-up."""
    cams = []
    for k, c in enumerate(np.asarray(centers, float)):
        z = np.asarray(target) - c
        z /= np.linalg.norm(z)
        x = np.cross(z, [0.0, 1.0, 0.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([x, y, z], 1)
        c2w[:3, 3] = c
        cams.append(Camera(Camera.intrinsics_from_fov(np.radians(50), 64, 48), c2w, 64, 48, f"cam{k}"))
    return cams


def assert_valid_path(cams: list[Camera]) -> None:
    for c in cams:
        assert np.all(np.isfinite(c.c2w)) and np.all(np.isfinite(c.K))
        np.testing.assert_allclose(c.R.T @ c.R, np.eye(3), atol=1e-9)
        assert np.linalg.det(c.R) == pytest.approx(1.0, abs=1e-9)
        assert np.linalg.norm(quat.from_matrix(c.R)) == pytest.approx(1.0, abs=1e-12)


@settings(max_examples=80, deadline=None)
@given(ci=points, cj=points, qi=orientations, qj=orientations, frames=st.integers(2, 40),
       amp=st.floats(-3.0, 3.0, allow_nan=False))
def test_pair_path_endpoints_exact_and_everything_finite(ci, cj, qi, qj, frames, amp):
    a = make_camera(ci, qi, name="a")
    b = make_camera(cj, qj, f=140.0, cx=30.0, name="b")
    if np.linalg.norm(ci - cj) <= 1e-9 * max(1.0, np.linalg.norm(ci), np.linalg.norm(cj)):
        if amp != 0.0 or np.max(np.abs(a.R - b.R)) <= 1e-12:
            with pytest.raises(InputError, match="no trajectory exists between identical centres"):
                interpolate_pair(a, b, np.linspace(0, 1, frames), amp)
            return
    cams = interpolate_pair(a, b, np.linspace(0, 1, frames), amp)
    assert len(cams) == frames
    for got, want in ((cams[0], a), (cams[-1], b)):
        np.testing.assert_array_equal(got.c2w, want.c2w)
        np.testing.assert_array_equal(got.K, want.K)
    assert_valid_path(cams)


def test_arc_follows_equation_3():
    a, b = rig([[-1.0, 0.0, -4.0], [1.0, 0.0, -4.0]])
    alphas = np.linspace(0, 1, 9)
    amp = 0.5
    cams = interpolate_pair(a, b, alphas, amp)
    n = arc_normal(a.center, b.center, [0.0, 1.0, 0.0])
    np.testing.assert_allclose(n, [0.0, 1.0, 0.0], atol=1e-12)  # the rig's up, orthogonal to the baseline
    for alpha, cam in zip(alphas, cams):
        expected = (1 - alpha) * a.center + alpha * b.center + amp * np.sin(np.pi * alpha) * n
        np.testing.assert_allclose(cam.center, expected, atol=1e-12)
        np.testing.assert_allclose(cam.K, (1 - alpha) * a.K + alpha * b.K, atol=1e-12)
        q = quat.slerp(quat.from_matrix(a.R), quat.from_matrix(b.R), alpha)
        np.testing.assert_allclose(cam.R, quat.to_matrix(q), atol=1e-12)
    assert cams[4].center[1] == pytest.approx(amp)  # peak height A at alpha = 1/2
    straight = interpolate_pair(a, b, alphas, 0.0)
    np.testing.assert_allclose([c.center[1] for c in straight], 0.0, atol=1e-15)


@settings(max_examples=100, deadline=None)
@given(ci=points, cj=points, up=points, fwd=points)
def test_arc_normal_is_unit_and_perpendicular(ci, cj, up, fwd):
    if np.linalg.norm(cj - ci) <= 1e-9 * max(1.0, np.linalg.norm(ci), np.linalg.norm(cj)):
        with pytest.raises(InputError, match="identical centres"):
            arc_normal(ci, cj, up, fwd)
        return
    n = arc_normal(ci, cj, up, fwd)
    b = (cj - ci) / np.linalg.norm(cj - ci)
    assert np.linalg.norm(n) == pytest.approx(1.0, abs=1e-12)
    assert abs(np.dot(n, b)) < 1e-9


def test_coincident_centres():
    q0 = np.array([1.0, 0, 0, 0])
    q1 = quat.normalize(np.array([0.9, 0.0, 0.3, 0.0]))
    a = make_camera([1.0, 2.0, 3.0], q0, name="a")
    turned = make_camera([1.0, 2.0, 3.0], q1, name="b")
    with pytest.raises(InputError, match="no trajectory exists between identical centres"):
        interpolate_pair(a, turned, np.linspace(0, 1, 5), amplitude=0.3)
    with pytest.raises(InputError, match="no trajectory exists between identical centres"):
        interpolate_pair(a, make_camera([1.0, 2.0, 3.0], q0, name="a2"), np.linspace(0, 1, 5))
    spin = interpolate_pair(a, turned, np.linspace(0, 1, 7))  # rotation in place
    for cam in spin:
        np.testing.assert_array_equal(cam.center, a.center)
    angles = [float(quat.angle_between(quat.from_matrix(c.R), q0)) for c in spin]
    assert np.all(np.diff(angles) > 0)
    assert_valid_path(spin)
    # the longest baseline is 2-3, so the second diagonal is the coincident pair 0-1: its straight
    # path turns in place, its arc cannot exist and is left out (the other diagonal keeps its arc)
    four = [a, turned, make_camera([-4.0, 2.0, 3.0], q0), make_camera([6.0, 2.0, 3.0], q0)]
    assert len(scene_trajectories(four, 4, arcs=False)) == 6
    arcs = [t.pair for t in scene_trajectories(four, 4) if t.arc_index is not None]
    assert arcs == [(2, 3)]


def test_collinear_and_vertical_rigs():
    line = rig([[x, 0.0, -5.0] for x in (-3.0, -1.0, 1.0, 3.0)])
    trajs = scene_trajectories(line, 5, amplitude=0.4)
    assert [t.name for t in trajs] == ["0-1", "0-2", "0-3", "1-2", "1-3", "2-3", "0-3_arc0", "1-2_arc1"]
    for t in trajs:
        assert_valid_path(t.cameras)
    mid = trajs[6].cameras[2].center
    np.testing.assert_allclose(mid, [0.0, 0.4, -5.0], atol=1e-9)  # the arc rises along the rig's up

    # cameras stacked along the up axis: up is parallel to every baseline, so arcs bulge along
    # the mean viewing direction (+z here) instead
    tower = []
    for y in (-3.0, -1.0, 1.0, 3.0):
        c2w = np.eye(4)
        c2w[:3, 3] = [0.0, y, -5.0]
        tower.append(Camera(Camera.intrinsics_from_fov(1.0, 64, 48), c2w, 64, 48))
    arcs = [t for t in scene_trajectories(tower, 5, amplitude=0.4) if t.arc_index is not None]
    np.testing.assert_allclose(arcs[0].cameras[2].center, [0.0, 0.0, -4.6], atol=1e-9)


def test_diagonal_pairs_of_a_rectangle():
    centers = np.array([[0.0, 0, 0], [4.0, 0, 0], [0.0, 3, 0], [4.0, 3, 0]])
    assert diagonal_pairs(centers) == [(0, 3), (1, 2)]
    assert diagonal_pairs(centers[:3]) == [(1, 2)]
    assert diagonal_pairs(centers[:1]) == []


@settings(max_examples=25, deadline=None)
@given(frames=st.integers(2, 30), seed=st.integers(0, 2**31 - 1),
       jitter=st.lists(st.floats(-0.5, 0.5), min_size=12, max_size=12))
def test_scene_trajectories_any_frame_count(frames, seed, jitter):
    centers = np.array([[-2.0, 0.5, -5], [2.0, 0.5, -5], [-2.0, -0.5, -5], [2.0, -0.5, -5]]) + np.reshape(jitter, (4, 3))
    cams = rig(centers)
    trajs = scene_trajectories(cams, frames, seed=seed)
    assert len(trajs) == 8
    for t in trajs:
        assert t.frames == frames
        np.testing.assert_array_equal(t.alphas, np.linspace(0, 1, frames))
        i, j = t.pair
        np.testing.assert_array_equal(t.cameras[0].c2w, cams[i].c2w)
        np.testing.assert_array_equal(t.cameras[-1].c2w, cams[j].c2w)
        assert_valid_path(t.cameras)
    for t in trajs[6:]:
        baseline = np.linalg.norm(cams[t.pair[1]].center - cams[t.pair[0]].center)
        assert ARC_AMPLITUDE_RANGE[0] * baseline <= t.amplitude <= ARC_AMPLITUDE_RANGE[1] * baseline
        assert t.seed == seed
    again = scene_trajectories(cams, frames, seed=seed)
    assert [t.amplitude for t in again] == [t.amplitude for t in trajs]


def test_frame_count_and_input_checks():
    cams = rig([[-1.0, 0, -4], [1.0, 0, -4]])
    with pytest.raises(InputError, match="at least 2 frames"):
        scene_trajectories(cams, 1)
    with pytest.raises(InputError, match="at least 2 train cameras"):
        scene_trajectories(cams[:1], 4)
    with pytest.raises(InputError, match=r"\[0, 1\]"):
        interpolate_pair(cams[0], cams[1], [0.0, 1.5])
    with pytest.raises(InputError, match="differ in size"):
        interpolate_pair(cams[0], cams[1].resized(32, 24), [0.0, 1.0])
    assert len(scene_trajectories(cams, 3, arcs=False)) == 1
    assert [t.name for t in scene_trajectories(cams, 3)] == ["0-1", "0-1_arc0"]


def test_preset_round_trip(tmp_path):
    cams = rig([[-2.0, 0.5, -5], [2.0, 0.5, -5], [-2.0, -0.5, -5], [2.1, -0.5, -5]])
    trajs = scene_trajectories(cams, 7, seed=3)
    trajs.append(Trajectory("custom", trajs[0].cameras[:3], [0.0, 0.2, 1.0], times=[0.1, 0.2, 0.3]))
    path = save_presets(trajs, tmp_path / "p.json", meta={"scene": "test"})
    doc = json.loads(path.read_text())
    assert doc["format"] == "fixer4d-trajectories" and doc["version"] == 1
    assert set(doc["trajectories"][6]) >= {"name", "pair", "amplitude", "arc_index", "frames", "seed", "cameras"}
    back = load_presets(path)
    assert [t.to_dict() for t in back] == [t.to_dict() for t in trajs]
    for t, u in zip(trajs, back):
        for c, d in zip(t.cameras, u.cameras):
            np.testing.assert_array_equal(c.c2w, d.c2w)
            np.testing.assert_array_equal(c.K, d.K)


def test_preset_bad_files(tmp_path):
    with pytest.raises(InputError, match="no such"):
        load_presets(tmp_path / "missing.json")
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(InputError, match="junk.json"):
        load_presets(tmp_path / "junk.json")
    (tmp_path / "ns.json").write_text(json.dumps({"camera_path": []}))
    with pytest.raises(InputError, match="not a fixer4d trajectory preset"):
        load_presets(tmp_path / "ns.json")
    (tmp_path / "new.json").write_text(json.dumps({"format": "fixer4d-trajectories", "version": 99}))
    with pytest.raises(InputError, match="newer"):
        load_presets(tmp_path / "new.json")
    (tmp_path / "short.json").write_text(json.dumps({"format": "fixer4d-trajectories", "version": 1,
                                                     "trajectories": [{"name": "x", "frames": 3, "cameras": []}]}))
    with pytest.raises(InputError, match="3 frames but has 0 cameras"):
        load_presets(tmp_path / "short.json")


def test_nerfstudio_round_trip(tmp_path):
    cams = rig([[-2.0, 0.5, -5], [2.0, 0.5, -5], [-2.0, -0.5, -5], [2.0, -0.5, -5]])
    traj = scene_trajectories(cams, 6, seed=1)[6]
    path = save_nerfstudio(traj, tmp_path / "ns.json", render_time=0.25)
    doc = json.loads(path.read_text())
    assert doc["camera_type"] == "perspective" and (doc["render_width"], doc["render_height"]) == (64, 48)
    assert doc["seconds"] == pytest.approx(6 / doc["fps"])
    first = doc["camera_path"][0]
    np.testing.assert_array_equal(np.reshape(first["camera_to_world"], (4, 4)), cams[0].c2w_opengl())
    assert first["fov"] == pytest.approx(50.0) and first["aspect"] == pytest.approx(64 / 48)
    assert all(e["render_time"] == 0.25 for e in doc["camera_path"])
    back = load_nerfstudio(path)
    assert back.frames == 6 and back.name == "ns" and back.pair is None
    np.testing.assert_array_equal(back.times, 0.25)
    for c, d in zip(traj.cameras, back.cameras):
        np.testing.assert_array_equal(d.c2w, c.c2w)  # the GL axis flip is exact both ways
        np.testing.assert_allclose(d.K, c.K, rtol=1e-12)  # square pixels + centred principal point here

    sweep = json.loads(save_nerfstudio([traj, traj], tmp_path / "two.json").read_text())
    times = [e["render_time"] for e in sweep["camera_path"]]
    assert len(times) == 12 and times[0] == 0.0 and max(times) < 1.0 and np.all(np.diff(times) > 0)


def test_nerfstudio_bad_files(tmp_path):
    (tmp_path / "bad.json").write_text(json.dumps({"render_width": 4, "render_height": 4, "camera_path": [
        {"camera_to_world": [1, 0, 0], "fov": 50}, {"camera_to_world": [1, 0, 0], "fov": 50}]}))
    with pytest.raises(InputError, match=r"bad\.json.*camera_path\[0\]"):
        load_nerfstudio(tmp_path / "bad.json")
    (tmp_path / "fields.json").write_text(json.dumps({"camera_path": []}))
    with pytest.raises(InputError, match="malformed nerfstudio camera path \\(no key 'render_width'\\)"):
        load_nerfstudio(tmp_path / "fields.json")
    with pytest.raises(InputError, match=r"\[0, 1\)"):
        save_nerfstudio(Trajectory("t", rig([[0, 0, -3.0]]), [0.0]), tmp_path / "x.json", render_time=1.0)


def test_trajectories_verb_on_the_demo_scene(tmp_path):
    pytest.importorskip("fixer4d.scene.synthetic")
    from fixer4d.cli import main
    from fixer4d.scene import load_scene

    out, ns = tmp_path / "presets.json", tmp_path / "path.json"
    assert main(["trajectories", "demo", "--out", str(out), "--nerfstudio", str(ns), "--frames", "5",
                 "--seed", "2", "--time", "0.5"]) == 0
    trajs = load_presets(out)
    scene = load_scene("demo")
    train = [scene.cameras[i] for i in scene.train_ids]
    assert len(trajs) == len(train) * (len(train) - 1) // 2 + 2
    for t in trajs:
        np.testing.assert_array_equal(t.cameras[0].c2w, train[t.pair[0]].c2w)
        np.testing.assert_array_equal(t.cameras[-1].c2w, train[t.pair[1]].c2w)
    assert load_nerfstudio(ns).frames == 5 * len(trajs)
    assert main(["trajectories", "demo", "--out", str(out), "--only", "nope"]) == 2


def test_trajectories_verb_on_a_run_folder_gives_the_runs_stage2_trajectories(tmp_path):
    pytest.importorskip("fixer4d.scene.synthetic")
    from fixer4d.cli import main
    from fixer4d.pipeline.config import RunConfig, SceneConfig, TrajectoryConfig
    from fixer4d.pipeline.run_folder import RunFolder
    from fixer4d.scene import load_scene

    config = RunConfig(scene=SceneConfig("tiny", scale=0.5), trajectories=TrajectoryConfig(frames=4, seed=3, arcs=False))
    RunFolder.create(tmp_path / "run", config)
    out = tmp_path / "presets.json"
    assert main(["trajectories", str(tmp_path / "run"), "--out", str(out)]) == 0
    scene = load_scene("tiny", scale=0.5)
    want = scene_trajectories([scene.cameras[i] for i in scene.train_ids], 4, arcs=False, seed=3)
    assert [t.to_dict() for t in load_presets(out)] == [t.to_dict() for t in want]
    assert main(["trajectories", str(tmp_path / "run"), "--out", str(out), "--frames", "6"]) == 0
    assert {t.frames for t in load_presets(out)} == {6}


def test_bundled_demo_preset_matches_the_demo_rig():
    pytest.importorskip("fixer4d.scene.synthetic")
    from fixer4d import ASSETS_DIR
    from fixer4d.scene import load_scene

    scene = load_scene("demo")
    train = [scene.cameras[i] for i in scene.train_ids]
    trajs = load_presets(ASSETS_DIR / "presets" / "demo.json")
    fresh = scene_trajectories(train)  # the preset is `fixer4d trajectories demo` with its defaults
    assert [t.to_dict() for t in trajs] == [t.to_dict() for t in fresh], \
        "assets/presets/demo.json is stale: rerun `fixer4d trajectories demo --out assets/presets/demo.json`"


def test_novel_frame_mask_flags_exactly_the_train_cameras():
    from fixer4d.geometry.camera import Camera
    from fixer4d.geometry.trajectory import novel_frame_mask, scene_trajectories

    rig = [Camera.look_at(np.array([x, 0.0, -4.0]), np.zeros(3), width=32, height=24) for x in (-1.0, -0.3, 0.4, 1.1)]
    for tr in scene_trajectories(rig, 5, arcs=True, seed=0):
        # endpoints are train cameras, interior frames are not, also after a JSON round trip of the poses
        expect = [False, True, True, True, False]
        assert list(novel_frame_mask(tr.cameras, rig)) == expect
        reread = [Camera.from_dict(json.loads(json.dumps(c.to_dict()))) for c in tr.cameras]
        assert list(novel_frame_mask(reread, rig)) == expect
    # a camera at a train camera's centre but turned is a novel view; so is the same pose at another size
    turned = rig[0].with_pose(rig[1].c2w.copy())
    turned_c2w = rig[0].c2w.copy()
    turned_c2w[:3, :3] = rig[1].c2w[:3, :3]
    assert list(novel_frame_mask([rig[0].with_pose(turned_c2w), rig[0].scaled(0.5), turned], rig)) == [True, True, False]


def test_scene_trajectories_leave_out_a_duplicated_camera_pair():
    """A capture whose two train cameras share one pose (a duplicated camera) still gets its other
    pairs and arcs; only a rig with a single pose is an error."""
    rig = [Camera.look_at(np.array([x, 0.0, -4.0]), np.zeros(3), width=32, height=24, name=f"c{k}")
           for k, x in enumerate((-1.0, 1.1, 0.4, -1.0))]  # c3 duplicates c0
    trajs = scene_trajectories(rig, 4, amplitude=0.3)
    pairs = [t.pair for t in trajs if t.arc_index is None]
    assert (0, 3) not in pairs and len(pairs) == 5
    assert all(t.pair != (0, 3) for t in trajs) and any(t.arc_index is not None for t in trajs)
    for t in trajs:
        assert all(np.isfinite(c.c2w).all() for c in t.cameras)
    with pytest.raises(InputError, match="different poses"):
        scene_trajectories([rig[0], rig[3]], 4)
