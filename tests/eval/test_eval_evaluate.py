"""evaluate() on a fake scene with a fake render function writes the metrics.json contract."""
import json
import math

import numpy as np
import pytest
from PIL import Image

from fixer4d.errors import InputError, NumericalError
from fixer4d.eval import metrics as M
from fixer4d.eval.evaluate import (REGION_MASK_ESTIMATED, REGION_MASK_EXACT, evaluate, markdown_table,
                                   select_frames)
from fixer4d.eval.lpips import ENV_WEIGHTS
from fixer4d.geometry.camera import Camera
from fixer4d.scene.base import MultiViewVideo

H, W = 40, 56  # >= 31: LPIPS-alex's smallest side


class FakeScene(MultiViewVideo):
    """5 cameras on a circle, 6 frames of smooth colour patterns in [0.2, 0.8]; cameras 1 and 3 held out."""

    def __init__(self, num_frames=6, test_ids=(1, 3)):
        super().__init__()
        self.name = "fake"
        self.cameras = [Camera.look_at((np.cos(a) * 3, 0.0, np.sin(a) * 3), (0, 0, 0), width=W, height=H,
                                       name=f"cam{i:02d}")
                        for i, a in enumerate(np.linspace(0, 2, 5))]
        self.test_ids = list(test_ids)
        self.train_ids = [i for i in range(5) if i not in test_ids]
        self.num_frames = num_frames

    def _load_frame(self, frame, cam):
        y, x = np.mgrid[0:H, 0:W].astype(np.float32)
        img = np.stack([np.sin(x / 5 + frame), np.cos(y / 4 + cam), np.sin((x + y) / 9)], -1)
        return (0.5 + 0.3 * img).astype(np.float32)


def test_evaluate_writes_the_contract(tmp_path):
    scene = FakeScene()
    calls = []

    def render_fn(camera, t):
        idx = [c.name for c in scene.cameras].index(camera.name)
        frame = int(round(t * scene.num_frames))
        calls.append((idx, frame))
        return scene.frame(frame, idx) + np.float32(0.05)  # MSE = 0.0025 -> PSNR 26.0206 dB

    out = tmp_path / "eval"
    res = evaluate(render_fn, scene, out, frame_stride=2, method_name="STGS (mvs init)",
                   seconds={"prep": 12.5, "train": 300.0}, save_examples=2, progress=False)
    assert sorted(calls) == [(c, f) for c in (1, 3) for f in (0, 2, 4)]
    on_disk = json.loads((out / "metrics.json").read_text())
    assert on_disk == json.loads(json.dumps(res))
    assert set(on_disk["mean"]) == {"psnr", "dssim1", "dssim2", "lpips", "psnr_dynamic", "psnr_static",
                                    "ssim_dynamic", "ssim_static", "psnr_aligned"}
    # The fake scene is no synthetic scene: its held-out masks come from its own video.
    assert on_disk["protocol"]["regions"]["mask"] == REGION_MASK_ESTIMATED
    for key in ("psnr_dynamic", "psnr_static"):
        if on_disk["mean"][key] is not None:
            assert on_disk["mean"][key] == pytest.approx(-10 * math.log10(0.0025), abs=1e-3)
    assert on_disk["mean"]["psnr"] == pytest.approx(-10 * math.log10(0.0025), abs=1e-3)
    assert 0 < on_disk["mean"]["dssim2"] < on_disk["mean"]["dssim1"] < 0.05
    assert set(on_disk["seconds"]) == {"prep", "train", "eval"}
    assert on_disk["seconds"]["prep"] == 12.5 and on_disk["seconds"]["train"] == 300.0
    assert on_disk["seconds"]["eval"] > 0
    assert set(on_disk["per_view"]) == {"cam01", "cam03"}
    assert on_disk["per_view"]["cam03"]["frames"] == 3
    assert len(on_disk["per_frame"]) == 6
    assert on_disk["protocol"]["frames"] == [0, 2, 4]
    if on_disk["lpips_unavailable_reason"] is None:
        assert on_disk["mean"]["lpips"] > 0
    else:
        assert on_disk["mean"]["lpips"] is None
    # 2 example frames (first and last evaluated) per held-out view, render | gt | error
    assert sorted(on_disk["examples"]) == sorted(f"example_cam0{c}_f000{f}.png" for c in (1, 3) for f in (0, 4))
    png = np.asarray(Image.open(out / on_disk["examples"][0]))
    assert png.shape == (H, 3 * W, 3)
    gt = scene.frame(0, 1)
    assert np.abs(png[:, W:2 * W] / 255.0 - gt).max() < 1 / 255 + 1e-6
    assert np.abs(png[:, :W] / 255.0 - (gt + 0.05)).max() < 1 / 255 + 1e-6
    table = (out / "metrics.md").read_text().splitlines()
    assert table[0].startswith("| Method | PSNR") and "Prep. time" in table[0]
    assert table[2].startswith("| STGS (mvs init) | 26.02 |") and table[2].endswith("| 12.5 s |")
    assert not list(out.glob(".*"))  # no temporaries left behind


def test_dynamic_and_static_regions_use_the_exact_mask_on_synthetic_scenes(tiny_scene, tmp_path):
    """Errors of 0.1 on moving pixels and 0.01 elsewhere: 20 dB dynamic, 40 dB static."""
    scene = tiny_scene
    T = scene.num_frames

    def render_fn(camera, t):
        f = int(round(t * T))
        cam = next(i for i, c in enumerate(scene.cameras) if c is camera)
        moving = scene.moving_mask(f, cam)
        gt = scene.frame(f, cam)
        error = np.where(moving[..., None], 0.1, 0.01) * np.where(gt < 0.5, 1.0, -1.0)  # away from clipping
        return (gt + error).astype(np.float32)

    res = evaluate(render_fn, scene, tmp_path / "e", save_examples=0, progress=False)
    assert res["protocol"]["regions"]["mask"] == REGION_MASK_EXACT
    rows = [r for r in res["per_frame"] if r["psnr_dynamic"] is not None]
    assert rows, "the tiny scene's ball is seen by a held-out camera"
    for r in rows:
        assert r["psnr_dynamic"] == pytest.approx(20.0, abs=0.05)
        assert r["psnr_static"] == pytest.approx(40.0, abs=0.05)
        assert 0 < r["moving_fraction"] < 0.5
        assert r["ssim_dynamic"] < r["ssim_static"] <= 1.0
    assert res["mean"]["psnr_dynamic"] == pytest.approx(20.0, abs=0.05)
    # The overall PSNR mixes both: between them, near the static one (few pixels move).
    assert 20.0 < res["mean"]["psnr"] < 40.0
    table = (tmp_path / "e" / "metrics.md").read_text().splitlines()
    assert "PSNR dyn." in table[0] and "| 20.0" in table[2]


def test_lpips_null_with_reason_when_weights_absent(tmp_path, monkeypatch):
    monkeypatch.setenv(ENV_WEIGHTS, str(tmp_path / "absent.ckpt"))
    M.reset_lpips_cache()
    try:
        scene = FakeScene(num_frames=2, test_ids=(2,))
        res = evaluate(lambda cam, t: scene.frame(int(round(t * 2)), 2), scene, tmp_path / "e", save_examples=0,
                       progress=False)
    finally:
        M.reset_lpips_cache()
    on_disk = json.loads((tmp_path / "e" / "metrics.json").read_text())
    assert on_disk["mean"]["lpips"] is None and "absent.ckpt" in on_disk["lpips_unavailable_reason"]
    # an exact render has infinite PSNR, written as null (JSON has no inf); DSSIM is 0
    assert on_disk["mean"]["psnr"] is None and on_disk["mean"]["dssim1"] == pytest.approx(0.0, abs=1e-12)
    assert on_disk["seconds"]["prep"] is None and res["examples"] == []
    assert "| n/a | n/a |" in (tmp_path / "e" / "metrics.md").read_text()


def test_bad_renders_and_scenes_raise(tmp_path):
    scene = FakeScene(num_frames=2)
    with pytest.raises(InputError, match="shape"):
        evaluate(lambda cam, t: np.zeros((H, W - 1, 3), np.float32), scene, tmp_path, progress=False)
    with pytest.raises(NumericalError, match="NaN"):
        evaluate(lambda cam, t: np.full((H, W, 3), np.nan, np.float32), scene, tmp_path, progress=False)
    # no held-out camera (a capture trained on all of them): the train views' fit is scored
    every = FakeScene(num_frames=2, test_ids=())
    res = evaluate(lambda cam, t: every.frame(0, 0) * 0.9, every, tmp_path / "fit", progress=False)
    assert res["held_out"] is False and res["protocol"]["test_cameras"] == [c.name for c in every.cameras]
    assert np.isfinite(res["mean"]["psnr"])


def test_select_frames():
    assert select_frames(10, 3) == [0, 3, 6, 9]
    assert select_frames(10, 2, frames=[1, 2, 5, 7]) == [1, 5]
    with pytest.raises(InputError, match="outside"):
        select_frames(4, 1, frames=[4])
    with pytest.raises(InputError, match=">= 1"):
        select_frames(4, 0)


def test_markdown_table_rows():
    rows = [{"method": "STGS (sparse init)", "mean": {"psnr": 20.123, "dssim1": 0.1, "dssim2": 0.05, "lpips": 0.3},
             "seconds": {"prep": 4000.0}},
            {"method": "STGS (mvs init)", "mean": {"psnr": 24.0, "dssim1": 0.08, "dssim2": 0.04, "lpips": None},
             "seconds": {"prep": 90.0}}]
    lines = markdown_table(rows).splitlines()
    assert lines[2] == "| STGS (sparse init) | 20.12 | 0.1000 | 0.0500 | 0.3000 | 1.11 h |"
    assert lines[3] == "| STGS (mvs init) | 24.00 | 0.0800 | 0.0400 | n/a | 1.5 min |"


def test_exposure_aligned_psnr_undoes_a_gain_and_offset_and_never_lowers_psnr():
    from fixer4d.eval.metrics import exposure_aligned
    from fixer4d.eval.metrics import psnr

    rng = np.random.default_rng(0)
    gt = rng.uniform(0.1, 0.8, (24, 32, 3)).astype(np.float32)
    brighter = np.clip(gt * np.array([1.08, 1.05, 0.95]) + 0.02, 0, 1).astype(np.float32)  # exposure + white balance
    assert psnr(exposure_aligned(brighter, gt), gt) > 60.0 > psnr(brighter, gt)
    noisy = np.clip(gt + rng.normal(0, 0.05, gt.shape), 0, 1).astype(np.float32)
    assert psnr(exposure_aligned(noisy, gt), gt) >= psnr(noisy, gt)
    flat = np.full_like(gt, 0.5)  # no variation: only the offset
    assert np.isfinite(exposure_aligned(flat, gt)).all()
