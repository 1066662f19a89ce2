"""PLYs in the reference implementation's layout (SpacetimeGaussians lite) load through fixer4d's
one model loader and render as the model they were written from."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from fixer4d.errors import InputError
from fixer4d.model.io import load_model, load_ply
from fixer4d.model.spacetime import ModelConfig
from fixer4d.render.api import render
from output_scene import front_camera, small_model

# STGS lite's save_ply field order (its construct_list_of_attributes), written down here.
REFERENCE_FIELDS = (["x", "y", "z", "trbf_center", "trbf_scale", "nx", "ny", "nz"] + [f"motion_{i}" for i in range(9)]
                    + ["f_dc_0", "f_dc_1", "f_dc_2", "opacity"] + [f"scale_{i}" for i in range(3)]
                    + [f"rot_{i}" for i in range(4)] + [f"omega_{i}" for i in range(4)])
C0 = 0.28209479177387814
LITE = ModelConfig(motion_degree=3, rotation_velocity=True, temporal_opacity=True, sh_degree=0)


def write_reference_ply(model, path, drop: tuple[str, ...] = ()) -> None:
    """The model as STGS lite saves one: f_dc is the RGB the rasterizer gets (no SH), every
    Gaussian dynamic, activations applied by the reader (sigmoid, exp, normalize)."""
    m = {k: v.detach().numpy().astype(np.float64) for k, v in model.tensors().items()}
    n = model.num_gaussians
    cols = {"x": m["means"][:, 0], "y": m["means"][:, 1], "z": m["means"][:, 2], "trbf_center": m["t_center"],
            "trbf_scale": m["t_log_scale"], "nx": np.zeros(n), "ny": np.zeros(n), "nz": np.zeros(n),
            "opacity": m["opacity_logits"]}
    rgb = 0.5 + C0 * m["colors"]
    for i in range(9):
        cols[f"motion_{i}"] = m["motion"][:, i]
    for i in range(3):
        cols[f"f_dc_{i}"] = rgb[:, i]
        cols[f"scale_{i}"] = m["log_scales"][:, i]
    for i in range(4):
        cols[f"rot_{i}"] = m["quats"][:, i]
        cols[f"omega_{i}"] = m["omega"][:, i]
    fields = [f for f in REFERENCE_FIELDS if f not in drop]
    data = np.empty(n, dtype=[(f, "f4") for f in fields])
    for f in fields:
        data[f] = cols[f]
    PlyData([PlyElement.describe(data, "vertex")]).write(str(path))


def renders(model, times=(0.0, 0.3, 0.75)):
    cam = front_camera()
    return np.stack([render(model.snapshot(t, camera_center=cam.center), cam, backend="reference").rgb.numpy()
                     for t in times])


def test_reference_ply_renders_as_its_model(tmp_path):
    model = small_model(300, config=LITE, static_fraction=0.0)  # STGS has no static rows
    write_reference_ply(model, tmp_path / "point_cloud.ply")
    loaded = load_model(tmp_path / "point_cloud.ply")  # the loader view, eval and refine use
    assert loaded.config == LITE and bool(loaded.dynamic.all())
    torch.testing.assert_close(loaded.colors, model.colors, atol=1e-5, rtol=0)  # RGB -> SH DC
    for name in ("means", "quats", "log_scales", "opacity_logits", "t_center", "t_log_scale", "motion", "omega"):
        assert torch.equal(getattr(loaded, name), getattr(model, name)), name
    expected = renders(model)
    assert expected.mean() > 0.02
    np.testing.assert_allclose(renders(loaded), expected, atol=1e-5, rtol=0)


def test_missing_reference_fields_take_the_no_effect_defaults(tmp_path):
    model = small_model(200, config=LITE, static_fraction=0.0)
    write_reference_ply(model, tmp_path / "no_spin.ply", drop=tuple(f"omega_{i}" for i in range(4)) + ("trbf_scale",))
    loaded = load_ply(tmp_path / "no_spin.ply")
    assert loaded.config == ModelConfig(motion_degree=3, rotation_velocity=False, temporal_opacity=False, sh_degree=0)
    with torch.no_grad():
        model.omega.zero_()
        model.t_log_scale.fill_(20.0)  # a temporal std of e^20: constant opacity over the clip
    np.testing.assert_allclose(renders(loaded), renders(model), atol=1e-5, rtol=0)


def test_unknown_layouts_are_refused_with_the_fields_found(tmp_path):
    data = np.zeros(3, dtype=[(f, "f4") for f in ("x", "y", "z", "red", "green", "blue")])
    PlyData([PlyElement.describe(data, "vertex")]).write(str(tmp_path / "points.ply"))
    with pytest.raises(InputError, match=r"points\.ply: unknown Gaussian PLY layout \(fields: blue, green, red, x, y, z\)"):
        load_ply(tmp_path / "points.ply")
    full = [f for f in REFERENCE_FIELDS if not f.startswith("f_dc")] + [f"f_dc_{i}" for i in range(9)]
    data = np.zeros(2, dtype=[(f, "f4") for f in full])
    PlyData([PlyElement.describe(data, "vertex")]).write(str(tmp_path / "full.ply"))
    with pytest.raises(InputError, match="9 f_dc feature channels: an STGS full-model PLY"):
        load_ply(tmp_path / "full.ply")
    partial = [f for f in REFERENCE_FIELDS if f != "opacity"]
    data = np.zeros(2, dtype=[(f, "f4") for f in partial])
    PlyData([PlyElement.describe(data, "vertex")]).write(str(tmp_path / "partial.ply"))
    with pytest.raises(InputError, match=r"without \['opacity'\] \(found fields: \["):
        load_ply(tmp_path / "partial.ply")
