"""Every calibration import format, read back against the cameras it was written from."""
from __future__ import annotations

import json

import numpy as np
import pytest

from fixer4d.calib.formats import camera_of, find_calibration, read_calibration
from fixer4d.calib.rig import Rig, RigCamera
from fixer4d.errors import InputError
from fixer4d.geometry.camera import CV_TO_GL
from fixer4d.geometry.llff import cameras_to_llff

DIST = {"k1": -0.12, "k2": 0.03, "p1": 0.001, "p2": -0.002}


def _rig_cameras(tiny4, distorted: bool) -> list[RigCamera]:
    scene, ids = tiny4
    out = []
    for k, i in enumerate(ids):
        c = scene.cameras[i]
        K = c.K.copy()
        K[0, 0] *= 1.0 + 0.01 * k  # distinct intrinsics per camera
        K[1, 1] *= 1.0 + 0.012 * k
        K[0, 2] += 0.7 * k
        out.append(RigCamera(c.name, c.width, c.height, K, c.w2c, dict(DIST) if distorted else {}))
    return out


def _assert_same(rig: Rig, cams: list[RigCamera], dist: bool = True):
    assert rig.names() == [c.name for c in cams]
    for got, want in zip(rig.cameras, cams):
        np.testing.assert_allclose(got.K, want.K, atol=1e-6)
        np.testing.assert_allclose(got.w2c, want.w2c, atol=1e-6)
        if dist:
            np.testing.assert_allclose(got.coefficients, want.coefficients, atol=1e-9)
        assert (got.width, got.height) == (want.width, want.height)


def test_rig_json_round_trip(tmp_path, tiny4):
    cams = _rig_cameras(tiny4, True)
    Rig(cams, pairs=[{"cameras": ["a", "b"], "raw_matches": 1, "verified_matches": 1, "shared_points": 1}],
        frames_used=[0, 2], scale="test").write(tmp_path / "rig.json")
    assert find_calibration(tmp_path) == tmp_path / "rig.json"
    rig = read_calibration(tmp_path / "rig.json", [c.name for c in cams])
    _assert_same(rig, cams)
    assert rig.frames_used == [0, 2] and rig.scale == "test"


@pytest.mark.parametrize("binary", [True, False])
def test_colmap_model(tmp_path, tiny4, binary):
    import pycolmap

    cams = _rig_cameras(tiny4, True)
    rec = pycolmap.Reconstruction()
    for k, c in enumerate(cams):
        cam = pycolmap.Camera(model="OPENCV", width=c.width, height=c.height, camera_id=k + 1,
                              params=[c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2], *(DIST[n] for n in ("k1", "k2", "p1", "p2"))])
        rec.add_camera_with_trivial_rig(cam)
        for f in range(2):  # two images of one static camera: one pose
            image = pycolmap.Image(name=f"{c.name}/{f:06d}.jpg", camera_id=k + 1, image_id=2 * k + f + 1)
            rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(c.w2c[:3]))
    model = tmp_path / "sparse" / "0"
    model.mkdir(parents=True)
    rec.write_binary(str(model)) if binary else rec.write_text(str(model))
    assert find_calibration(tmp_path) == model
    _assert_same(read_calibration(model, [c.name for c in cams]), cams)


def test_transforms_json(tmp_path, tiny4):
    cams = _rig_cameras(tiny4, True)
    frames = [{"file_path": f"images/{c.name}_000000.png", "fl_x": c.K[0, 0], "fl_y": c.K[1, 1], "cx": c.K[0, 2],
               "cy": c.K[1, 2], "transform_matrix": (np.linalg.inv(c.w2c) @ CV_TO_GL).tolist()} for c in cams]
    data = {"camera_model": "OPENCV", "w": cams[0].width, "h": cams[0].height, **DIST, "frames": frames}
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    assert find_calibration(tmp_path) == tmp_path / "transforms.json"
    _assert_same(read_calibration(tmp_path / "transforms.json", [c.name for c in cams]), cams)


def test_poses_bounds(tmp_path, tiny4):
    scene, ids = tiny4
    cams = [RigCamera(scene.cameras[i].name, scene.cameras[i].width, scene.cameras[i].height, scene.cameras[i].K,
                      scene.cameras[i].w2c) for i in ids]
    np.save(tmp_path / "poses_bounds.npy", cameras_to_llff([c.camera() for c in cams], np.array([0.5, 9.0])))
    _assert_same(read_calibration(tmp_path / "poses_bounds.npy", [c.name for c in cams]), cams, dist=False)


def test_missing_camera_and_unknown_format_are_refused(tmp_path, tiny4):
    cams = _rig_cameras(tiny4, False)
    Rig(cams[:3]).write(tmp_path / "rig.json")
    with pytest.raises(InputError, match=cams[3].name):
        read_calibration(tmp_path / "rig.json", [c.name for c in cams])
    (tmp_path / "calib.yaml").write_text("x: 1")
    with pytest.raises(InputError, match="unknown calibration format"):
        read_calibration(tmp_path / "calib.yaml", ["cam00"])


def test_camera_of_image_paths():
    names = ["cam01", "cam09"]
    assert camera_of("cam01/000000.jpg", names) == "cam01"
    assert camera_of("images/cam09_000012.png", names) == "cam09"
    assert camera_of("cam09.png", names) == "cam09"
    assert camera_of("other/frame.png", names) is None
