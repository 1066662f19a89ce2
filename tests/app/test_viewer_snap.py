"""Camera-true views: snapped to a train camera the viewport shows that camera's image,
letterboxed to its aspect and intrinsics (not stretched to the panel), and the GL view agrees
with the torch render of the same camera and with the ground-truth frame's geometry."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from PIL import Image

from app.sources import initial_state
from app.viewer import ViewerSource
from fixer4d.render.api import render
from fixer4d.scene import load_scene
from viewer_helpers import gl_ctx, make_viewer, scene_gaussians  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl

# GL view vs the torch rasterizer on the same Gaussians and camera (the renderers' parity bar).
MIN_PSNR_TORCH_DB = 35.0
# The displayed viewport vs the real frame upsampled to the displayed size must beat, by this
# margin, what the old display showed there (the camera stretched to the panel's aspect,
# centre part): the Gaussians are the frames' pixels back-projected, so splat blur keeps the
# absolute agreement modest, but a 1.3x stretch misplaces every edge.
MIN_GAIN_OVER_STRETCHED_DB = 2.0
# Splat std relative to one pixel's footprint: small splats keep the frame's detail.
SPLAT_SIZE_FACTOR = 0.5


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(-10.0 * np.log10(max(np.mean((np.asarray(a, float) - np.asarray(b, float)) ** 2), 1e-20)))


def _resize(img: np.ndarray, w: int, h: int) -> np.ndarray:
    im = Image.fromarray((np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8))
    return np.asarray(im.resize((w, h), Image.BILINEAR), np.float32) / 255.0


@pytest.mark.parametrize("cam_index", [0, 2])
def test_snapped_view_is_letterboxed_and_matches_torch_and_truth(make_viewer, cam_index):
    scene = load_scene("tiny")
    src = ViewerSource(scene=scene, label="tiny")
    g = scene_gaussians(scene, frame=0, stride=1)
    g = replace(g, log_scales=g.log_scales + np.float32(np.log(SPLAT_SIZE_FACTOR)))
    st = initial_state(src, g)
    st.show_frusta = st.show_trajectories = False
    cam = scene.train_cameras[cam_index]
    st.view.snap_to(cam)
    d = make_viewer(st, src)
    d.settle()
    v = d.viewer
    rc = v.render_camera
    x0, y0, w, h = v.viewport_rect
    # letterboxed: the camera's own aspect and pose, K scaled uniformly with the image
    assert (rc.width, rc.height) == (int(w), int(h)) and rc is not None
    assert abs(rc.width / rc.height - cam.width / cam.height) < 2.0 / rc.height
    assert abs((rc.fx / rc.fy) / (cam.fx / cam.fy) - 1.0) < 2.0 / rc.height
    np.testing.assert_allclose(rc.c2w, cam.c2w)
    assert rc.width > cam.width  # the panel is larger than the 64x48 camera: upscaled, not cropped
    # the panel's area is wider than the camera's 4:3: bars left and right, image centred
    ax0, ay0, ax1, ay1 = v.item_rects["viewport_area"]
    assert (ax1 - ax0) > 1.2 * w and abs((x0 - ax0) - (ax1 - (x0 + w))) <= 1.0
    # GL vs torch on the same camera
    model = g.to_model()
    gl_rgb = v.splats.read_rgb(st.background)
    out = render(model.snapshot(st.time, rc.center), rc, background=st.background)
    assert _psnr(gl_rgb, out.rgb.numpy()) >= MIN_PSNR_TORCH_DB
    # what the window shows in the viewport vs the real frame at that size
    shot = v.screenshot(d.fbo)[int(y0):int(y0) + int(h), int(x0):int(x0) + int(w)].astype(np.float32) / 255.0
    truth = scene.frame(0, scene.train_ids[cam_index])
    truth_box = _resize(truth, int(w), int(h))
    good = _psnr(shot, truth_box)
    # the old display: the camera's K stretched to the whole area, its middle part where ours is
    stretched = rc.resized(int(ax1 - ax0), int(h))
    v.splats.render(stretched, st.time, wait_sort=True)
    off = int(x0 - ax0)
    old = np.clip(v.splats.read_rgb(st.background), 0, 1)[:, off:off + int(w)]
    assert good >= _psnr(old, truth_box) + MIN_GAIN_OVER_STRETCHED_DB, (good, _psnr(old, truth_box))
