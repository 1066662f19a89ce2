"""MVSAnywhereEstimator against a fake ``mvsanywhere`` package (fixer4d.init.mvsanywhere).

The fake stands in for the package's options handler, model loader and DepthModel: it records
what the adapter hands it and answers with a depth map of the documented shape, so that the
adapter's half of the contract is checked without the package, its weights or a GPU.
"""
from __future__ import annotations

import sys
import types

import numpy as np
import pytest
import torch

from fixer4d.errors import BackendUnavailable
from fixer4d.init.depth_range import scene_depth_ranges
from fixer4d.init.mvsanywhere import (IMAGENET_MEAN, IMAGENET_STD, MVSANYWHERE_CONFIG_ENV, MVSANYWHERE_WEIGHTS_ENV,
                                      MVSAnywhereConfig, MVSAnywhereEstimator)

# The fake model's options, written to the temp config YAML that the fake options handler reads.
MATCHING_SCALE = 0.25
PREDICTION_SCALE = 0.5
NET_W, NET_H = 512, 384  # MVSAnywhereConfig's network input size
# Pixels of every predicted map the fake marks invalid the ways a model output can be: NaN,
# zero, negative and infinite depth.
INVALID = {(0, 0): np.nan, (0, 1): 0.0, (0, 2): -1.0, (0, 3): np.inf}


class FakeDepthModel:
    """Records every call; predicts, for each key view, the z-depth of ``target`` (a world point)
    in the key camera's frame per ``cam_T_world_b44``, at the prediction resolution."""

    target = None  # (3,) world point, set by the test

    def __init__(self, opts) -> None:
        self.opts = opts
        self.devices: list[str] = []
        self.eval_called = False
        self.calls: list[dict] = []

    def to(self, device):
        self.devices.append(str(device))
        return self

    def eval(self):
        self.eval_called = True
        return self

    def __call__(self, phase, cur_data, src_data, unbatched_matching_encoder_forward=False, return_mask=False,
                 num_refinement_steps=0):
        self.calls.append({"phase": phase, "cur": dict(cur_data), "src": dict(src_data),
                           "unbatched": unbatched_matching_encoder_forward, "return_mask": return_mask,
                           "refinement_steps": num_refinement_steps})
        h, w = cur_data["image_b3hw"].shape[-2:]
        h_out, w_out = int(h * self.opts.prediction_scale), int(w * self.opts.prediction_scale)
        X = torch.tensor([*self.target, 1.0], dtype=torch.float32)
        z = (cur_data["cam_T_world_b44"][0] @ X)[2]
        depth = torch.full((1, 1, h_out, w_out), float(z))
        for (i, j), value in INVALID.items():
            depth[0, 0, i, j] = value
        return {"depth_pred_s0_b1hw": depth, "log_depth_pred_s0_b1hw": torch.log(depth.clamp_min(1e-6)),
                "overall_mask_bhw": torch.ones((1, h // 4, w // 4), dtype=torch.bool)}


@pytest.fixture
def fake_mvsanywhere(monkeypatch, tmp_path):
    """Installs the fake package and points the weights/config environment variables at small
    temp files. Returns a namespace with the paths and what the fake loader saw."""
    seen = types.SimpleNamespace(config_paths=[], weights=[], models=[])
    weights = tmp_path / "mvsanywhere_hero.ckpt"
    weights.write_bytes(b"fake checkpoint")
    config = tmp_path / "mvsanywhere_model.yaml"
    config.write_text(f"matching_scale: {MATCHING_SCALE}\nprediction_scale: {PREDICTION_SCALE}\n")

    class OptionsHandler:
        def __init__(self) -> None:
            self.options = types.SimpleNamespace(load_weights_from_checkpoint=None)

        def parse_and_merge_options(self, config_filepaths=None, ignore_cl_args=False):
            assert ignore_cl_args, "the adapter must not let mvsanywhere parse fixer4d's command line"
            seen.config_paths.append(config_filepaths)
            for line in open(config_filepaths).read().splitlines():
                key, value = line.split(":")
                setattr(self.options, key.strip(), float(value))

    def get_model_class(opts):
        return FakeDepthModel

    def load_model_inference(opts, model_class):
        seen.weights.append(opts.load_weights_from_checkpoint)
        model = model_class(opts)
        seen.models.append(model)
        return model

    package = types.ModuleType("mvsanywhere")
    package.__path__ = []
    options = types.ModuleType("mvsanywhere.options")
    options.OptionsHandler = OptionsHandler
    utils = types.ModuleType("mvsanywhere.utils")
    utils.__path__ = []
    model_utils = types.ModuleType("mvsanywhere.utils.model_utils")
    model_utils.get_model_class = get_model_class
    model_utils.load_model_inference = load_model_inference
    package.options, package.utils, utils.model_utils = options, utils, model_utils
    for name, module in [("mvsanywhere", package), ("mvsanywhere.options", options),
                         ("mvsanywhere.utils", utils), ("mvsanywhere.utils.model_utils", model_utils)]:
        monkeypatch.setitem(sys.modules, name, module)
    monkeypatch.setenv(MVSANYWHERE_WEIGHTS_ENV, str(weights))
    monkeypatch.setenv(MVSANYWHERE_CONFIG_ENV, str(config))
    seen.weights_path, seen.config_path = str(weights), str(config)
    return seen


@pytest.fixture(scope="module")
def tiny_views():
    """The tiny scene's train views at frame 0, their cameras, depth ranges and a world point
    seen in front of every camera (a true surface point at view 0's image centre)."""
    from fixer4d.scene import load_scene

    scene = load_scene("tiny")
    cams = scene.train_cameras
    images = [np.asarray(scene.frame(0, i), np.float32) for i in scene.train_ids]
    ranges, _ = scene_depth_ranges(cams)
    cam0 = cams[0]
    v, u = cam0.height // 2, cam0.width // 2
    target = cam0.backproject(np.array([[u + 0.5, v + 0.5]]), np.array([scene.depth(0, scene.train_ids[0])[v, u]]))[0]
    assert all(c.world_to_camera(target[None])[0, 2] > 0 for c in cams)
    return images, cams, ranges, target


@pytest.fixture
def run_adapter(fake_mvsanywhere, tiny_views, monkeypatch):
    images, cams, ranges, target = tiny_views
    monkeypatch.setattr(FakeDepthModel, "target", target)
    est = MVSAnywhereEstimator(MVSAnywhereConfig(device="cpu"))
    results = est.estimate(images, cams, ranges)
    return results, fake_mvsanywhere.models[0]


def test_loads_the_configured_model_once(fake_mvsanywhere, run_adapter):
    _, model = run_adapter
    assert fake_mvsanywhere.config_paths == [fake_mvsanywhere.config_path]
    assert fake_mvsanywhere.weights == [fake_mvsanywhere.weights_path]
    assert model.devices == ["cpu"] and model.eval_called


def test_one_call_per_key_view_with_the_others_as_sources(run_adapter, tiny_views):
    _, model = run_adapter
    _, cams, ranges, _ = tiny_views
    V = len(cams)
    assert len(model.calls) == V
    for r, call in enumerate(model.calls):
        assert call["phase"] == "test" and call["unbatched"] and call["return_mask"] and call["refinement_steps"] == 1
        cur, src = call["cur"], call["src"]
        assert cur["image_b3hw"].shape == (1, 3, NET_H, NET_W)
        assert src["image_b3hw"].shape == (1, V - 1, 3, NET_H, NET_W)
        for key in ("world_T_cam_b44", "cam_T_world_b44", "K_matching_b44", "invK_matching_b44"):
            assert cur[key].shape == (1, 4, 4) and src[key].shape == (1, V - 1, 4, 4)
        for t in list(cur.values()) + list(src.values()):
            assert t.dtype == torch.float32 and t.device.type == "cpu"
        others = [s for s in range(V) if s != r]
        for k, s in enumerate(others):
            assert np.allclose(src["world_T_cam_b44"][0, k].numpy(), cams[s].c2w, atol=1e-6)
        # the range hints, per key view
        assert cur["min_depth"].shape == (1,) and cur["max_depth"].shape == (1,)
        assert np.allclose([cur["min_depth"].item(), cur["max_depth"].item()], ranges[r], rtol=1e-6)


def test_images_are_imagenet_normalized_rgb_in_channels_first(run_adapter, tiny_views):
    _, model = run_adapter
    images = tiny_views[0]
    mean = torch.tensor(IMAGENET_MEAN)[:, None, None]
    std = torch.tensor(IMAGENET_STD)[:, None, None]
    for r, call in enumerate(model.calls):
        rgb = call["cur"]["image_b3hw"][0] * std + mean  # back to the estimator's [0, 1] input
        assert float(rgb.min()) >= -1e-5 and float(rgb.max()) <= 1 + 1e-5
        # area resampling keeps each channel's mean; a swapped channel order or axis would not
        assert np.allclose(rgb.mean((1, 2)).numpy(), images[r].mean((0, 1)), atol=0.02)
    V = len(model.calls)
    for r in range(V):  # a view enters as a source exactly as it enters as the key view
        q = (r + 1) % V
        k = [s for s in range(V) if s != q].index(r)
        assert torch.equal(model.calls[q]["src"]["image_b3hw"][0, k], model.calls[r]["cur"]["image_b3hw"][0])


def test_intrinsics_and_poses_project_like_the_scene_cameras(run_adapter, tiny_views):
    """K_matching with cam_T_world maps a world point to the scene camera's pixel, scaled to the
    network input and then to the matching resolution (pixel-centre convention kept), and the
    pose is world-to-camera in scene units (no metre conversion)."""
    _, model = run_adapter
    _, cams, _, target = tiny_views
    rng = np.random.default_rng(0)
    points = target + rng.normal(scale=0.05, size=(20, 3))
    for r, call in enumerate(model.calls):
        cam = cams[r]
        K = call["cur"]["K_matching_b44"][0].double().numpy()
        w2c = call["cur"]["cam_T_world_b44"][0].double().numpy()
        c2w = call["cur"]["world_T_cam_b44"][0].double().numpy()
        assert np.allclose(w2c @ c2w, np.eye(4), atol=1e-5)
        assert np.allclose(call["cur"]["invK_matching_b44"][0].double().numpy() @ K, np.eye(4), atol=1e-5)
        assert np.allclose(c2w[:3, 3], cam.center, atol=1e-5)
        pc = points @ w2c[:3, :3].T + w2c[:3, 3]
        assert np.allclose(pc[:, 2], cam.world_to_camera(points)[:, 2], rtol=1e-5)  # scene units
        p = pc @ K[:3, :3].T
        uv_matching = p[:, :2] / p[:, 2:]
        uv, _ = cam.project(points)
        expect = uv * [NET_W / cam.width, NET_H / cam.height] * MATCHING_SCALE
        assert np.allclose(uv_matching, expect, atol=1e-3)


def test_results_are_depth_results_in_scene_units(run_adapter, tiny_views):
    results, _ = run_adapter
    _, cams, _, target = tiny_views
    h, w = int(NET_H * PREDICTION_SCALE), int(NET_W * PREDICTION_SCALE)
    assert len(results) == len(cams)
    for cam, res in zip(cams, results):
        assert res.depth.shape == res.valid.shape == res.confidence.shape == (h, w)
        assert res.depth.dtype == np.float32 and res.confidence.dtype == np.float32 and res.valid.dtype == bool
        assert (res.camera.width, res.camera.height) == (w, h)
        assert np.allclose(res.camera.K, cam.resized(w, h).K) and np.allclose(res.camera.c2w, cam.c2w)
        z = cam.world_to_camera(target[None])[0, 2]
        bad = np.zeros((h, w), bool)
        bad[tuple(np.array(list(INVALID)).T)] = True
        assert np.array_equal(res.valid, ~bad)
        assert np.all(res.depth[bad] == 0) and np.all(res.confidence[bad] == 0)
        assert np.allclose(res.depth[~bad], z, rtol=1e-5)  # the model's scene-unit depth, unchanged
        assert np.all(res.confidence[~bad] == 1)


def test_config_fields_win_over_the_environment(fake_mvsanywhere, tmp_path):
    other = tmp_path / "other.ckpt"
    other.write_bytes(b"x")
    est = MVSAnywhereEstimator(MVSAnywhereConfig(weights_path=str(other), device="cpu"))
    assert est.weights == str(other) and est.config_file == fake_mvsanywhere.config_path


def test_a_cuda_device_needs_cuda(fake_mvsanywhere, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(BackendUnavailable, match="CUDA") as exc:
        MVSAnywhereEstimator(MVSAnywhereConfig(device="cuda"))
    assert "weights" not in str(exc.value) and "package" not in str(exc.value)
    # with a CUDA device reported, the model goes to it (the fake allocates nothing)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    est = MVSAnywhereEstimator(MVSAnywhereConfig(device="cuda"))
    est._load()
    assert fake_mvsanywhere.models[0].devices == ["cuda"]
