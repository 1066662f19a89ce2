"""Shared fixtures and helpers for the viewer tests (imported by the test modules): an EGL
none), synthetic Gaussian sets, and helpers that drive the UI through imgui's io."""
from __future__ import annotations

import numpy as np
import pytest

from app.gaussians import GaussianArrays

WINDOW = (1152, 720)
# The viewer's default window size (app.main.DEFAULT_SIZE): the layout is designed for it.
DEFAULT_WINDOW = (1440, 900)


@pytest.fixture(scope="session")
def gl_ctx():
    moderngl = pytest.importorskip("moderngl")
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as exc:  # no libEGL, no device: the GL tests cannot run here
        pytest.skip(f"no EGL OpenGL 3.3 context: {exc}")
    yield ctx
    ctx.release()


def make_gaussians(n_static: int = 400, n_moving: int = 60, seed: int = 0) -> GaussianArrays:
    """A static textured wall (z = 0, x,y in [-1.5, 1.5]) and a blob of dynamic Gaussians at
    z = -0.8 that moves from x = -0.8 at t = 0 to x = +0.8 at t = 1 (m1 = 1.6 / clip)."""
    rng = np.random.default_rng(seed)
    side = int(np.sqrt(n_static))
    gx, gy = np.meshgrid(np.linspace(-1.5, 1.5, side), np.linspace(-1.5, 1.5, side))
    wall = np.stack([gx.ravel(), gy.ravel(), np.zeros(side * side)], 1)
    blob = rng.normal(0.0, 0.08, (n_moving, 3)) + np.array([-0.8, 0.0, -0.8])
    n_s, n_m = wall.shape[0], blob.shape[0]
    n = n_s + n_m
    motion = np.zeros((n, 9))
    motion[n_s:, 0] = 1.6
    return GaussianArrays(
        means=np.concatenate([wall, blob]),
        log_scales=np.log(np.concatenate([np.full((n_s, 3), 3.0 / side), np.full((n_m, 3), 0.06)])),
        quats=rng.normal(size=(n, 4)), opacity_logits=np.full(n, 3.0),
        colors=np.concatenate([rng.normal(0, 1.0, (n_s, 3)), np.tile([[1.5, -1.5, -1.5]], (n_m, 1))]),
        t_center=np.concatenate([np.zeros(n_s), np.full(n_m, 0.5)]), t_log_scale=np.full(n, 2.0),
        motion=motion, omega=np.zeros((n, 4)), dynamic=np.concatenate([np.zeros(n_s, bool), np.ones(n_m, bool)]))


class Driver:
    """Feeds mouse input through imgui's io and runs viewer frames into an offscreen target."""

    def __init__(self, viewer, ctx, size=WINDOW):
        self.viewer = viewer
        self.fbo = ctx.simple_framebuffer(size)

    def frame(self, n: int = 1, dt: float = 1.0 / 30.0) -> None:
        for _ in range(n):
            self.viewer.frame(dt, self.fbo)

    def settle(self, max_frames: int = 8) -> None:
        """Run frames until the 3D view rests at full size (adaptive resolution refined)."""
        for _ in range(max_frames):
            self.frame()
            if self.viewer.state.gaussians is None or self.viewer.adaptive.final:
                return

    def _io(self):
        from imgui_bundle import imgui

        return imgui.get_io()

    def move(self, x: float, y: float) -> None:
        self._io().add_mouse_pos_event(float(x), float(y))
        self.frame()

    def button(self, down: bool) -> None:
        self._io().add_mouse_button_event(0, down)
        self.frame()

    def click(self, x: float, y: float) -> None:
        self.move(x, y)
        self.button(True)
        self.button(False)

    def click_item(self, name: str, fx: float = 0.5) -> None:
        x0, y0, x1, y1 = self.viewer.item_rects[name]
        self.click(x0 + fx * (x1 - x0), (y0 + y1) / 2.0)

    def press(self, key: str, ctrl: bool = False, frames_held: int = 0, dt: float = 1.0 / 30.0) -> None:
        """A key press as the window delivers it (app.main's key callback calls
        ``viewer.key_event``; imgui's backend queues io events): down, ``frames_held`` frames,
        up, one frame. ``frames_held=0``: down and up arrive in one poll, as a 1 ms press does."""
        from imgui_bundle import imgui

        io = self._io()
        code = imgui.Key.space if key == "space" else getattr(imgui.Key, key)
        if ctrl:
            io.add_key_event(imgui.Key.mod_ctrl, True)
        io.add_key_event(code, True)
        self.viewer.key_event(key, True, ctrl=ctrl)
        self.frame(frames_held, dt)
        io.add_key_event(code, False)
        self.viewer.key_event(key, False, ctrl=ctrl)
        if ctrl:
            io.add_key_event(imgui.Key.mod_ctrl, False)
        self.frame(1, dt)

    def drag(self, x0: float, y0: float, x1: float, y1: float, steps: int = 4) -> None:
        self.move(x0, y0)
        self.button(True)
        for k in range(1, steps + 1):
            self.move(x0 + (x1 - x0) * k / steps, y0 + (y1 - y0) * k / steps)
        self.button(False)


@pytest.fixture
def make_viewer(gl_ctx, tmp_path):
    """make_viewer(state, source) -> Driver; closes every viewer at teardown."""
    from app.viewer import Viewer

    made = []

    def make(state, source, size=WINDOW, **kw):
        from app.sources import app_services

        kw.setdefault("services", app_services(config_dir=tmp_path / "config"))
        viewer = Viewer(gl_ctx, state, source, **kw)
        made.append(viewer)
        driver = Driver(viewer, gl_ctx, size)
        driver.frame(2)
        return driver

    yield make
    for v in made:
        v.close()


def scene_gaussians(scene, frame: int = 0, stride: int = 2) -> GaussianArrays:
    """Static Gaussians on the scene's ground-truth surfaces: every ``stride``-th pixel of each
    train view at ``frame`` back-projected with its depth and coloured by its pixel."""
    from fixer4d.model.sh import SH_C0

    pts, cols, sizes = [], [], []
    for i in scene.train_ids:
        cam = scene.cameras[i]
        depth = scene.depth(frame, i)
        rgb = scene.frame(frame, i)
        xyz = cam.backproject_depth(np.where(np.isfinite(depth), depth, 0.0))
        sel = np.zeros(depth.shape, bool)
        sel[::stride, ::stride] = True
        sel &= np.isfinite(depth)
        pts.append(xyz[sel])
        cols.append(rgb[sel])
        sizes.append(depth[sel] * stride / cam.fx)  # one sample spacing on the surface
    p, c, s = np.concatenate(pts), np.concatenate(cols), np.concatenate(sizes)
    n = p.shape[0]
    return GaussianArrays(means=p, log_scales=np.log(np.repeat(s[:, None], 3, 1)), quats=np.tile([1.0, 0, 0, 0], (n, 1)),
                          opacity_logits=np.full(n, 4.0), colors=(c - 0.5) / SH_C0, t_center=np.zeros(n),
                          t_log_scale=np.zeros(n), motion=np.zeros((n, 9)), omega=np.zeros((n, 4)),
                          dynamic=np.zeros(n, bool),
                          model_config={"motion_degree": 3, "rotation_velocity": True, "temporal_opacity": True,
                                        "sh_degree": 0})
