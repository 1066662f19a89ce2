"""The plane sweep's numba matching cost (fixer4d.init.mvs_kernel) against the torch reference."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from fixer4d.init import mvs_kernel
from fixer4d.init.matching_cost import RefView, SourceView, homography_terms, pixel_grid
from fixer4d.init.plane_sweep import PlaneSweepConfig, PlaneSweepMVS
from fixer4d.init.sweep_regions import crop_camera

pytestmark = pytest.mark.skipif(mvs_kernel.unavailable_reason() is not None, reason="numba unavailable")


@pytest.fixture(scope="module")
def toy_views():
    from toyscene import render, rig

    cams = rig(96, 72)[:4]
    images, depths = zip(*[render(c, 0.0) for c in cams])
    return list(images), list(depths), cams


def _gray(img):
    return torch.from_numpy(np.ascontiguousarray(img.mean(-1), dtype=np.float32))


@pytest.mark.parametrize("topk", [1, 2, 3])
@pytest.mark.parametrize("aggregation", [1, 3])
def test_kernel_scores_match_torch_on_whole_images(toy_views, topk, aggregation):
    images, _, cams = toy_views
    cfg = PlaneSweepConfig(topk=topk, aggregation=aggregation, window=7)
    ref = RefView(_gray(images[0])[None, None], cfg.window, cfg.min_patch_std)
    sources = [SourceView(_gray(im)[None, None], c) for im, c in zip(images[1:], cams[1:])]
    geo = [homography_terms(cams[0], s.cam, pixel_grid(0, 0, ref.height, ref.width)) for s in sources]
    # inverse depths from behind the cameras' far range to very near: warps leave the image
    ws = torch.linspace(0.05, 1.2, 9, dtype=torch.float32)[:, None]
    est_t, est_k = PlaneSweepMVS(cfg, kernel=False), PlaneSweepMVS(cfg, kernel=True)
    a = est_t._scores(ref, sources, geo, ws)
    b = est_k._scores(ref, sources, geo, ws)
    assert a.shape == b.shape == (9, 1, ref.height, ref.width)
    assert bool((a == -1).any())  # some windows are mostly outside a source: the -1 rule is exercised
    np.testing.assert_allclose(b.numpy(), a.numpy(), atol=2e-4)


def test_kernel_scores_match_torch_on_tiles_with_their_own_planes(toy_views):
    images, _, cams = toy_views
    cfg = PlaneSweepConfig()
    full = _gray(images[1])
    boxes = [(0, 0), (30, 20), (72, 48)]  # (x, y) of 24 x 24 tiles, one at the image corner
    tiles = torch.stack([full[y:y + 24, x:x + 24][None] for x, y in boxes])
    ref = RefView(tiles, cfg.window, cfg.min_patch_std)
    others = [0, 2, 3]
    sources = [SourceView(_gray(images[i])[None, None], cams[i]) for i in others]
    grid = torch.cat([pixel_grid(x, y, 24, 24) for x, y in boxes], 1)
    geo = [homography_terms(cams[1], s.cam, grid) for s in sources]
    ws = torch.stack([torch.linspace(0.15, 0.6, 6) + 0.01 * b for b in range(3)], 1).to(torch.float32)
    a = PlaneSweepMVS(cfg, kernel=False)._scores(ref, sources, geo, ws)
    b = PlaneSweepMVS(cfg, kernel=True)._scores(ref, sources, geo, ws)
    assert a.shape == b.shape == (6, 3, 24, 24)
    np.testing.assert_allclose(b.numpy(), a.numpy(), atol=2e-4)


def test_kernel_and_torch_sweeps_give_the_same_depths(toy_views):
    images, _, cams = toy_views
    ranges = [(1.5, 8.0)] * 4
    a = PlaneSweepMVS(PlaneSweepConfig(planes=64), kernel=False).estimate(images, cams, ranges)
    b = PlaneSweepMVS(PlaneSweepConfig(planes=64), kernel=True).estimate(images, cams, ranges)
    for ra, rb in zip(a, b):
        assert ra.valid.sum() > 0.2 * ra.valid.size
        # round-off may flip a near-tie between planes at a handful of pixels, no more
        assert np.mean(ra.valid != rb.valid) < 2e-3
        both = ra.valid & rb.valid
        assert np.mean(np.abs(ra.depth[both] - rb.depth[both]) <= 1e-4 * ra.depth[both]) > 0.998


def test_kernel_scores_of_a_crop_camera_match(toy_views):
    """Region sweeps use crop cameras (shifted principal point) for the reference."""
    images, _, cams = toy_views
    cfg = PlaneSweepConfig()
    box = (20, 10, 70, 50)
    cam_r = crop_camera(cams[0], box)
    ref = RefView(_gray(images[0])[box[1]:box[3], box[0]:box[2]][None, None], cfg.window, cfg.min_patch_std)
    sources = [SourceView(_gray(im)[None, None], c) for im, c in zip(images[1:], cams[1:])]
    geo = [homography_terms(cam_r, s.cam, pixel_grid(0, 0, ref.height, ref.width)) for s in sources]
    ws = torch.linspace(0.2, 0.5, 5, dtype=torch.float32)[:, None]
    a = PlaneSweepMVS(cfg, kernel=False)._scores(ref, sources, geo, ws)
    b = PlaneSweepMVS(cfg, kernel=True)._scores(ref, sources, geo, ws)
    np.testing.assert_allclose(b.numpy(), a.numpy(), atol=2e-4)
