"""Per-frame 3DGS PLYs: an independent reader of the 3DGS convention renders each frame as
fixer4d renders the model at that frame's time."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from plyfile import PlyData

from fixer4d.errors import InputError
from fixer4d.eval.metrics import psnr
from fixer4d.model.formats.ply_sequence import export_ply_sequence
from fixer4d.model.io import save_ply
from fixer4d.model.snapshot import Snapshot
from fixer4d.render.api import render
from fixer4d.render.constants import ALPHA_MIN
from output_scene import front_camera, small_model

# The 3DGS convention, written down here independently of fixer4d/model/formats/ply3dgs.py.
C0 = 0.28209479177387814
C1 = 0.4886025119029199


def read_3dgs_degree1(path, camera_center: np.ndarray) -> Snapshot:
    """Plain Gaussians from an INRIA 3DGS PLY with SH degree <= 1: activations sigmoid(opacity),
    exp(scale), normalized wxyz rotation, colour max(0.5 + C0 dc + C1 (-y, z, -x) . rest, 0)."""
    v = PlyData.read(str(path))["vertex"].data
    names = v.dtype.names
    assert names[:9] == ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2")
    assert names[-8:] == ("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")

    def cols(fields):
        return np.stack([np.asarray(v[f], np.float64) for f in fields], 1)

    means = cols(["x", "y", "z"])
    rgb = 0.5 + C0 * cols(["f_dc_0", "f_dc_1", "f_dc_2"])
    n_rest = len([f for f in names if f.startswith("f_rest_")])
    if n_rest:
        assert n_rest == 9
        rest = cols([f"f_rest_{i}" for i in range(9)]).reshape(-1, 3, 3)  # [gaussian, channel, coefficient]
        d = means - camera_center
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        basis = np.stack([-C1 * d[:, 1], C1 * d[:, 2], -C1 * d[:, 0]], 1)
        rgb += np.einsum("nk,nck->nc", basis, rest)
    quats = cols([f"rot_{i}" for i in range(4)])
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    f32 = lambda a: torch.tensor(a, dtype=torch.float32)  # noqa: E731
    return Snapshot(means=f32(means), quats=f32(quats), scales=f32(np.exp(cols(["scale_0", "scale_1", "scale_2"]))),
                    opacities=f32(1.0 / (1.0 + np.exp(-np.asarray(v["opacity"], np.float64)))),
                    colors=f32(np.maximum(rgb, 0.0)))


def test_each_frame_renders_like_the_model_at_its_time(tmp_path):
    model = small_model()
    cameras = [front_camera(), front_camera(name="side", azimuth_deg=70.0)]
    times = [0.0, 0.35, 0.8]
    manifest_path = export_ply_sequence(model, tmp_path / "seq", times, fps=12.0, min_opacity=ALPHA_MIN)
    manifest = json.loads(manifest_path.read_text())
    assert manifest["fps"] == 12.0 and manifest["frame_count"] == 3
    assert manifest["frames"] == ["frame_00000.ply", "frame_00001.ply", "frame_00002.ply"]
    assert sorted(p.name for p in (tmp_path / "seq").iterdir()) == sorted(manifest["frames"] + ["manifest.json"])
    dropped = []
    for name, t in zip(manifest["frames"], times):
        for cam in cameras:
            ours = render(model.snapshot(t, camera_center=cam.center), cam, backend="reference").rgb.numpy()
            theirs = render(read_3dgs_degree1(tmp_path / "seq" / name, cam.center), cam, backend="reference").rgb.numpy()
            assert ours.mean() > 0.05  # the scene is in view
            value = psnr(theirs, ours)
            assert value >= 40.0, (name, cam.name, value)
        dropped.append(model.num_gaussians - len(PlyData.read(str(tmp_path / "seq" / name))["vertex"].data))
    assert max(dropped) > 0  # the visibility threshold left faded Gaussians out
    assert manifest["gaussians"] == [model.num_gaussians - d for d in dropped]


def test_static_rows_are_written_unchanged(tmp_path):
    model = small_model(static_fraction=1.0)
    export_ply_sequence(model, tmp_path / "s", [0.1, 0.9], fps=30.0, min_opacity=0.0)
    a = PlyData.read(str(tmp_path / "s" / "frame_00000.ply"))["vertex"].data
    b = PlyData.read(str(tmp_path / "s" / "frame_00001.ply"))["vertex"].data
    assert len(a) == model.num_gaussians and np.array_equal(a, b)
    np.testing.assert_array_equal(a["opacity"], model.opacity_logits.detach().numpy())  # logits pass through
    np.testing.assert_array_equal(a["scale_1"], model.log_scales[:, 1].detach().numpy())


def test_export_verb_writes_a_sequence_and_keeps_foreign_folders(tmp_path, capsys):
    from fixer4d.cli import main

    model_path = save_ply(small_model(60), tmp_path / "m.ply")
    out = tmp_path / "frames"
    assert main(["export", str(model_path), "--format", "ply-sequence", "--out", str(out), "--quiet"]) == 2
    assert "--frames" in capsys.readouterr().err  # a bare model file has no frame count
    assert main(["export", str(model_path), "--format", "ply-sequence", "--out", str(out), "--frames", "4",
                 "--fps", "8", "--quiet"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["frame_count"] == 4 and manifest["fps"] == 8.0
    assert manifest["times"] == [k / 4 for k in range(4)]
    # a rerun replaces its own sequence; a folder holding anything else is refused, untouched
    assert main(["export", str(model_path), "--format", "ply-sequence", "--out", str(out), "--frames", "2",
                 "--quiet"]) == 0
    assert len(list(out.glob("frame_*.ply"))) == 2
    (out / "notes.txt").write_text("mine")
    assert main(["export", str(model_path), "--format", "ply-sequence", "--out", str(out), "--frames", "2",
                 "--quiet"]) == 2
    assert (out / "notes.txt").read_text() == "mine"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporaries left
    with pytest.raises(InputError, match="at least one frame"):
        export_ply_sequence(small_model(5), tmp_path / "none", [], fps=30.0, min_opacity=ALPHA_MIN)
    assert math.isclose(ALPHA_MIN, 1 / 255)
