"""Model files: exact PLY/npz round trips, STGS field names, validation, the export verb."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from fixer4d.errors import InputError, NumericalError
from fixer4d.model.io import load_model, load_npz, load_ply, save_model, save_npz, save_ply
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians

CONFIGS = [
    ModelConfig(),
    ModelConfig(0, False, False, 0),
    ModelConfig(motion_degree=1, rotation_velocity=False, temporal_opacity=True, sh_degree=3),
    ModelConfig(motion_degree=2, rotation_velocity=True, temporal_opacity=False, sh_degree=1),
]


def random_model(n: int, config: ModelConfig, seed: int = 0) -> SpacetimeGaussians:
    g = torch.Generator().manual_seed(seed)
    m = SpacetimeGaussians(config, n)
    with torch.no_grad():
        for name in m.param_names():
            getattr(m, name).copy_(torch.randn(getattr(m, name).shape, generator=g))
    m.set_dynamic(torch.rand(n, generator=g) < 0.5)
    return m


def assert_same(a: SpacetimeGaussians, b: SpacetimeGaussians) -> None:
    assert a.config == b.config
    assert a.param_names() == b.param_names()
    for k, v in a.tensors().items():
        assert torch.equal(v, b.tensors()[k]), k


@pytest.mark.parametrize("config", CONFIGS, ids=lambda c: json.dumps(c.to_dict()))
@pytest.mark.parametrize("ext", [".ply", ".npz"])
def test_round_trip_is_exact(tmp_path, config, ext):
    m = random_model(57, config)
    path = save_model(m, tmp_path / f"m{ext}")
    assert_same(m, load_model(path))
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporaries left behind


def test_empty_model_round_trip(tmp_path):
    m = SpacetimeGaussians(ModelConfig(), 0)
    assert_same(m, load_ply(save_ply(m, tmp_path / "e.ply")))
    assert_same(m, load_npz(save_npz(m, tmp_path / "e.npz")))


def test_ply_has_stgs_fields_and_neutral_values(tmp_path):
    m = random_model(5, ModelConfig(motion_degree=1, rotation_velocity=False, temporal_opacity=False, sh_degree=1))
    ply = PlyData.read(str(save_ply(m, tmp_path / "m.ply")))
    assert ply.header.splitlines()[1] == "format binary_little_endian 1.0"
    names = list(ply["vertex"].data.dtype.names)
    expected = (["x", "y", "z", "trbf_center", "trbf_scale"] + [f"motion_{i}" for i in range(9)]
                + [f"omega_{i}" for i in range(4)] + ["f_dc_0", "f_dc_1", "f_dc_2"]
                + [f"f_rest_{i}" for i in range(9)] + ["opacity"] + [f"scale_{i}" for i in range(3)]
                + [f"rot_{i}" for i in range(4)] + ["dynamic"])
    assert names == expected
    v = ply["vertex"].data
    np.testing.assert_array_equal(v["motion_0"], m.motion[:, 0].detach().numpy())
    assert not np.any(v["motion_3"]) and not np.any(v["omega_2"])  # absent effects are neutral zeros
    assert np.all(v["trbf_scale"] >= 20.0)  # no temporal opacity -> RBF == 1 for other STGS readers
    # f_rest is channel-major as 3DGS writes it: f_rest_{c*K + k} = sh_rest[:, k, c]
    np.testing.assert_array_equal(v["f_rest_4"], m.sh_rest[:, 1, 1].detach().numpy())


def test_foreign_stgs_ply_without_header_infers_effects(tmp_path):
    n = 4
    fields = (["x", "y", "z", "trbf_center", "trbf_scale"] + [f"motion_{i}" for i in range(9)]
              + ["f_dc_0", "f_dc_1", "f_dc_2", "opacity"] + [f"scale_{i}" for i in range(3)]
              + [f"rot_{i}" for i in range(4)] + [f"omega_{i}" for i in range(4)])
    data = np.zeros(n, dtype=[(f, "<f4") for f in fields])
    data["rot_0"] = 1.0
    data["x"] = np.arange(n)
    PlyData([PlyElement.describe(data, "vertex")]).write(str(tmp_path / "stgs.ply"))
    m = load_ply(tmp_path / "stgs.ply")
    assert m.config == ModelConfig(motion_degree=3, rotation_velocity=True, temporal_opacity=True, sh_degree=0)
    assert m.num_gaussians == n and bool(m.dynamic.all())
    np.testing.assert_array_equal(m.means[:, 0].detach().numpy(), np.arange(n))


def test_nan_is_rejected_naming_the_file(tmp_path):
    m = random_model(6, ModelConfig())
    save_ply(m, tmp_path / "ok.ply")
    ply = PlyData.read(str(tmp_path / "ok.ply"))
    ply["vertex"].data["motion_4"][2] = np.nan
    ply.write(str(tmp_path / "bad.ply"))
    with pytest.raises(NumericalError, match=r"bad\.ply.*motion"):
        load_ply(tmp_path / "bad.ply")
    arrays = {k: v.numpy().copy() for k, v in m.tensors().items()}
    with np.load(save_npz(m, tmp_path / "ok.npz")) as z:
        arrays["format"] = z["format"]
    arrays["means"][0, 0] = np.inf
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(NumericalError, match=r"bad\.npz.*means"):
        load_npz(tmp_path / "bad.npz")
    with torch.no_grad():
        m.colors[0, 0] = float("nan")
    with pytest.raises(NumericalError, match="colors"):
        save_ply(m, tmp_path / "never.ply")
    assert not (tmp_path / "never.ply").exists()


def test_bad_files_raise_input_errors(tmp_path):
    with pytest.raises(InputError, match="no such model file"):
        load_ply(tmp_path / "missing.ply")
    good = save_ply(random_model(50, ModelConfig()), tmp_path / "m.ply")
    (tmp_path / "cut.ply").write_bytes(good.read_bytes()[:1500])
    with pytest.raises(InputError, match="cut.ply"):
        load_ply(tmp_path / "cut.ply")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="junk.npz"):
        load_npz(tmp_path / "junk.npz")
    np.savez(tmp_path / "foreign.npz", means=np.zeros((1, 3)))
    with pytest.raises(InputError, match="format"):
        load_npz(tmp_path / "foreign.npz")
    header = PlyData.read(str(good))
    fields = [f for f in header["vertex"].data.dtype.names if f != "omega_3"]
    stripped = np.empty(len(header["vertex"].data), dtype=[(f, header["vertex"].data.dtype[f]) for f in fields])
    for f in fields:
        stripped[f] = header["vertex"].data[f]
    PlyData([PlyElement.describe(stripped, "vertex")], comments=header.comments).write(str(tmp_path / "lacking.ply"))
    with pytest.raises(InputError, match=r"lacking\.ply: missing PLY fields \['omega_3'\]"):
        load_ply(tmp_path / "lacking.ply")
    with pytest.raises(InputError, match="unknown model format"):
        save_model(random_model(2, ModelConfig()), tmp_path / "m.obj")


def test_export_verb_converts_files_and_runs(tmp_path):
    from fixer4d.cli import main

    m = random_model(20, ModelConfig(sh_degree=2))
    save_ply(m, tmp_path / "m.ply")
    assert main(["export", str(tmp_path / "m.ply"), "--out", str(tmp_path / "m.npz")]) == 0
    assert_same(m, load_npz(tmp_path / "m.npz"))
    assert main(["export", str(tmp_path / "m.npz"), "--out", str(tmp_path / "back.ply")]) == 0
    assert_same(m, load_ply(tmp_path / "back.ply"))

    run = tmp_path / "runs" / "demo"
    run.mkdir(parents=True)
    assert main(["export", str(run), "--out", str(tmp_path / "x.npz")]) == 2  # no model yet: clear error
    stage1 = random_model(5, ModelConfig(), seed=1)
    save_ply(stage1, run / "model_stage1.ply")
    assert main(["export", str(run), "--out", str(tmp_path / "s1.npz")]) == 0
    assert_same(stage1, load_npz(tmp_path / "s1.npz"))
    save_ply(m, run / "model_final.ply")  # the latest model wins
    assert main(["export", str(run), "--out", str(tmp_path / "final.npz")]) == 0
    assert_same(m, load_npz(tmp_path / "final.npz"))


@pytest.mark.parametrize("header, message", [
    ('"just a string"', "header format 'str' is not 'fixer4d-stgs'"),
    ('{"format": "other-tool", "version": 1, "config": {}}', "header format 'other-tool'"),
    ('{"format": "fixer4d-stgs", "version": 99, "config": {}}', "version 99, but this fixer4d reads versions <= 1"),
    ('{"format": "fixer4d-stgs", "version": 1}', "malformed model config"),
    ('{"format": "fixer4d-stgs", "version": 1, "config": {"sh_degree": "x"}}', None),
    ("{not json", "unreadable 'format' entry"),
])
def test_foreign_or_newer_npz_header_is_one_clear_error(tmp_path, header, message):
    m = random_model(4, ModelConfig())
    arrays = {k: v.numpy().copy() for k, v in m.tensors().items()}
    arrays["format"] = np.array(header)
    np.savez(tmp_path / "h.npz", **arrays)
    with pytest.raises(InputError) as info:
        load_npz(tmp_path / "h.npz")
    assert "h.npz" in str(info.value)
    if message is not None:
        assert message in str(info.value)


def test_npz_with_pickled_objects_is_refused_without_unpickling(tmp_path):
    class Payload:
        def __reduce__(self):
            return (open, (str(tmp_path / "pwned"), "w"))

    np.savez(tmp_path / "evil.npz", format=np.array([Payload()], dtype=object))
    with pytest.raises(InputError, match="evil.npz"):
        load_npz(tmp_path / "evil.npz")
    assert not (tmp_path / "pwned").exists()


@pytest.mark.parametrize("ext", [".ply", ".npz"])
def test_frozen_flags_round_trip_and_plain_models_write_no_field(tmp_path, ext):
    model = SpacetimeGaussians.from_points(np.random.default_rng(0).normal(size=(5, 3)), np.full((5, 3), 0.5),
                                           np.zeros(5))
    save_model(model, tmp_path / f"plain{ext}")
    if ext == ".ply":
        assert "frozen" not in PlyData.read(str(tmp_path / "plain.ply"))["vertex"].data.dtype.names
    assert load_model(tmp_path / f"plain{ext}").num_frozen == 0
    model.set_frozen(torch.tensor([True, False, True, False, False]))
    save_model(model, tmp_path / f"frozen{ext}")
    assert load_model(tmp_path / f"frozen{ext}").frozen.tolist() == [True, False, True, False, False]
