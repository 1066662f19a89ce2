"""The moderngl spacetime-Gaussian splat renderer (docs/design.md §16).

Instanced screen-space quads, one per Gaussian, drawn front to back; a transform-feedback pass
first evaluates and projects each Gaussian once (splat_prep.vert), the quads only place corners. Raw parameters sit in an
RGBA32F texture read with texelFetch (GL 3.3 data path, runs on macOS too); the vertex shader
evaluates the spacetime terms at the current time and projects with the same EWA Jacobian and
low-pass as the torch rasterizer. The depth order at the current time is computed on a worker
thread and re-computed whenever the camera, the time or the Gaussians change; until it arrives
the last order of the same Gaussians is drawn, so the UI never waits on a sort.

Two float targets accumulate, with the blend src*(1 - dst_alpha) + dst:
  colour (premultiplied rgb, accumulated alpha) and depth (alpha-weighted z, alpha).
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import moderngl
import numpy as np

from app.gaussians import GaussianArrays
from app.gl.lod import area_factor, lod_count, lod_subset, screen_importance
from app.gl.programs import load_program, shader_source
from app.gl.sync import finish
from fixer4d.geometry.camera import Camera
from fixer4d.model.spacetime import T_LOG_SCALE_MIN
# One constant set with the torch rasterizer, so the two agree (a test measures it).
from fixer4d.render.constants import (ALPHA_MAX, ALPHA_MIN, DET_MIN, LOWPASS_2D, NEAR_PLANE, POWER_MAX,
                                      SIGMA_EXTENT, TAN_FOV_MARGIN)


# Texels per Gaussian in the parameter texture without view-dependent colour, and the texture's
# width in texels. 4096 is within every GL 3.3 implementation's minimum max-texture-size
# guarantee for float textures in practice and gives 512 Gaussians per row at 8 texels (16M
# Gaussians before the 4096-row limit). Higher SH bands add ceil(3 K / 4) texels (K = (d+1)^2-1
# coefficients per channel, 12 texels at degree 3); the shader's SH array holds that maximum.
TEXELS_PER_GAUSSIAN = 8
MAX_SH_TEXELS = 12
TEXTURE_WIDTH = 4096
# Bytes per Gaussian in the transform-feedback buffer: centre/size/z, conic/opacity, colour.
FEEDBACK_BYTES = 3 * 4 * 4


def sh_texels(num_rest: int) -> int:
    """Texels holding ``num_rest`` higher-band SH coefficients per channel (3 floats each)."""
    return -(-3 * int(num_rest) // 4)


def sh_degree_of(num_rest: int) -> int:
    """The SH degree d with (d+1)^2 - 1 == num_rest (0, 3, 8, 15 -> 0..3)."""
    d = int(round((num_rest + 1) ** 0.5)) - 1
    if (d + 1) ** 2 - 1 != num_rest or not 0 <= d <= 3:
        raise ValueError(f"{num_rest} SH coefficients per channel is not a full band set of degree 0..3")
    return d

# Debug modes of the resolve pass (heatmap.frag) and of the splat colours (splat.vert); the blur
# and undetermined maps are both an uploaded scalar map in turbo over grey.
RESOLVE_MODES = {"color": 0, "holes": 1, "depth": 2, "blur": 3, "alpha": 4, "moving": 5, "undetermined": 3}
SPLAT_MODES = {"color": 0, "speed": 1, "temporal_opacity": 2}


def texels_per_gaussian(g: GaussianArrays) -> int:
    return TEXELS_PER_GAUSSIAN + sh_texels(g.sh_rest.shape[1])


def pack_params(g: GaussianArrays) -> np.ndarray:
    """(rows, TEXTURE_WIDTH, 4) float32 texture image holding ``texels_per_gaussian(g)`` texels
    per Gaussian: mean+opacity logit, log-scale+t_center, quat, colour+t_log_scale, m1+dynamic,
    m2, m3, omega, then the higher SH bands as a flat (K, 3) row-major float run."""
    n = g.n
    k = g.sh_rest.shape[1]
    texels = np.zeros((max(n, 1), texels_per_gaussian(g), 4), np.float32)
    if n:
        texels[:, 0, :3], texels[:, 0, 3] = g.means, g.opacity_logits
        texels[:, 1, :3], texels[:, 1, 3] = g.log_scales, g.t_center
        texels[:, 2] = g.quats
        texels[:, 3, :3], texels[:, 3, 3] = g.colors, g.t_log_scale
        texels[:, 4, :3], texels[:, 4, 3] = g.motion[:, 0:3], g.dynamic.astype(np.float32)
        texels[:, 5, :3] = g.motion[:, 3:6]
        texels[:, 6, :3] = g.motion[:, 6:9]
        texels[:, 7] = g.omega
        if k:
            flat = np.zeros((n, 4 * sh_texels(k)), np.float32)
            flat[:, : 3 * k] = g.sh_rest.reshape(n, 3 * k)
            texels[:, TEXELS_PER_GAUSSIAN:] = flat.reshape(n, -1, 4)
    flat = texels.reshape(-1, 4)
    rows = -(-flat.shape[0] // TEXTURE_WIDTH)
    out = np.zeros((rows * TEXTURE_WIDTH, 4), np.float32)
    out[: flat.shape[0]] = flat
    return out.reshape(rows, TEXTURE_WIDTH, 4)


def depth_order(g: GaussianArrays, w2c: np.ndarray, t: float, focal: float | None = None):
    """Indices (uint32) of the Gaussians visible at time t, sorted front to back by camera z.

    Gaussians whose opacity at t is below ALPHA_MIN or whose centre is behind the near plane are
    left out (the shader would cull them anyway; leaving them out saves instances). With
    ``focal`` (px) also returns (area, importance) per Gaussian for level of detail
    (``app.gl.lod.screen_importance``; zero for the ones left out).
    """
    if g.n == 0:
        empty = np.zeros(0, np.uint32)
        return empty if focal is None else (empty, np.zeros(0, np.float32), np.zeros(0, np.float32))
    mu = g.means_at(t)
    r = np.asarray(w2c, np.float32)
    z = mu @ r[2, :3] + r[2, 3]
    opacity = g.opacity_at(t)
    live = (z > NEAR_PLANE) & (opacity >= ALPHA_MIN)
    idx = np.flatnonzero(live)
    order = idx[np.argsort(z[idx], kind="stable")].astype(np.uint32)
    if focal is None:
        return order
    area, importance = screen_importance(z, g.log_scales, opacity, focal)
    return order, area, importance


class DepthSorter:
    """Sorts on a worker thread. ``request`` replaces any pending job (only the newest view
    matters); ``result`` returns the newest finished (key, order)."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._job: tuple | None = None
        self._result: tuple | None = None
        self._closed = False
        self.last_sort_ms = 0.0
        self._thread = threading.Thread(target=self._loop, name="splat-sort", daemon=True)
        self._thread.start()

    def request(self, key: tuple, g: GaussianArrays, w2c: np.ndarray, t: float, focal: float = 1.0) -> None:
        with self._cond:
            self._job = (key, g, w2c, t, focal)
            self._cond.notify_all()

    def result(self) -> tuple | None:
        with self._cond:
            return self._result

    def wait(self, key: tuple, timeout: float = 30.0) -> tuple | None:
        """Block until the order for ``key`` is ready (tests, screenshots, benchmarks)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._result is None or self._result[0] != key:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(left)
            return self._result

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join(timeout=5)

    def _loop(self) -> None:
        while True:
            with self._cond:
                while self._job is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                key, g, w2c, t, focal = self._job
                self._job = None
            t0 = time.perf_counter()
            order, area, importance = depth_order(g, w2c, t, focal)
            ms = 1e3 * (time.perf_counter() - t0)
            with self._cond:
                self._result = (key, order, area, importance)
                self.last_sort_ms = ms
                self._cond.notify_all()


@dataclass
class FrameStats:
    """Milliseconds spent in the last frame's parts (draw includes waiting for the GPU)."""

    sort_ms: float = 0.0
    upload_ms: float = 0.0
    draw_ms: float = 0.0
    instances: int = 0
    fraction: float = 1.0  # level of detail: the fraction of the Gaussians drawn (app.gl.lod)


class SplatRenderer:
    """Draws a ``GaussianArrays`` set for a ``Camera`` at a time into float targets.

    Usage: ``set_gaussians(g)``; ``render(camera, t)``; then ``resolve()`` for a displayable RGBA8
    texture, or ``read_rgb()/read_alpha()/read_depth()`` for numpy images (H, W, ...) with row 0
    at the top.
    """

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self.prog = load_program(ctx, "splat.vert", "splat.frag")
        self.prep_prog = ctx.program(vertex_shader=shader_source("splat_prep.vert"),
                                     varyings=["f_center", "f_conic", "f_color"])
        self._feedback_buf: moderngl.Buffer | None = None
        self._prep_vao: moderngl.VertexArray | None = None
        self.resolve_prog = load_program(ctx, "screen.vert", "heatmap.frag")
        self.sorter = DepthSorter()
        self.gaussians: GaussianArrays | None = None
        self.version = 0
        self._param_tex: moderngl.Texture | None = None
        self._flag_tex: moderngl.Texture | None = None
        self._scalar_tex = ctx.texture((1, 1), 1, np.zeros(1, np.float32).tobytes(), dtype="f4")
        self._order_buf: moderngl.Buffer | None = None
        self._order_key: tuple | None = None
        self._full_order: np.ndarray | None = None  # the installed depth order (all live Gaussians)
        self._drawn: tuple | None = None  # (order key, count) of the index buffer's contents
        self._area: np.ndarray | None = None  # per Gaussian, for the installed order (app.gl.lod)
        self._importance: np.ndarray | None = None
        self._instances = 0
        self._vao: moderngl.VertexArray | None = None
        self._targets: tuple | None = None
        self._display: tuple | None = None
        self._empty_vao = ctx.vertex_array(self.resolve_prog, [])
        self.stats = FrameStats()
        self.last_camera: Camera | None = None

    # ---- data ---------------------------------------------------------------------------------
    def set_gaussians(self, g: GaussianArrays, selection: np.ndarray | None = None) -> None:
        """Upload a new Gaussian set (and optionally a bool (N,) selection to highlight)."""
        t0 = time.perf_counter()
        tex = pack_params(g)
        if self._param_tex is not None:
            self._param_tex.release()
        self._param_tex = self.ctx.texture((TEXTURE_WIDTH, tex.shape[0]), 4, tex.tobytes(), dtype="f4")
        self._param_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.gaussians = g
        self.version += 1
        self._order_key = None
        self._full_order = None
        self._drawn = None
        self._area = self._importance = None
        self._instances = 0
        self.set_selection(selection)
        self.stats.upload_ms = 1e3 * (time.perf_counter() - t0)

    def set_selection(self, selection: np.ndarray | None) -> None:
        n = 0 if self.gaussians is None else self.gaussians.n
        flags = np.zeros(max(n, 1), np.float32)
        if selection is not None and n:
            flags[: n] = np.asarray(selection, bool)[:n]
        rows = -(-flags.size // TEXTURE_WIDTH)
        img = np.zeros(rows * TEXTURE_WIDTH, np.float32)
        img[: flags.size] = flags
        if self._flag_tex is not None:
            self._flag_tex.release()
        self._flag_tex = self.ctx.texture((TEXTURE_WIDTH, rows), 1, img.tobytes(), dtype="f4")
        self._flag_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)

    def set_scalar_map(self, values: np.ndarray) -> None:
        """Upload an (H, W) float map (row 0 at the top) for the 'blur', 'undetermined' and 'moving'
        resolve modes."""
        v = np.ascontiguousarray(np.asarray(values, np.float32)[::-1])
        self._scalar_tex.release()
        self._scalar_tex = self.ctx.texture((v.shape[1], v.shape[0]), 1, v.tobytes(), dtype="f4")

    # ---- targets ------------------------------------------------------------------------------
    def _ensure_targets(self, width: int, height: int) -> None:
        if self._targets is not None and self._targets[0].size == (width, height):
            return
        if self._targets is not None:
            for obj in self._targets:
                obj.release()
        color = self.ctx.texture((width, height), 4, dtype="f4")
        depth = self.ctx.texture((width, height), 4, dtype="f4")
        fbo = self.ctx.framebuffer(color_attachments=[color, depth])
        self._targets = (color, depth, fbo)

    @property
    def size(self) -> tuple[int, int]:
        return (0, 0) if self._targets is None else self._targets[0].size

    # ---- drawing ------------------------------------------------------------------------------
    def _sort_key(self, camera: Camera, t: float) -> tuple:
        # the focal length sizes the splats for level of detail (a zoom changes the importance)
        return (self.version, np.round(camera.w2c[:3], 9).tobytes(), round(float(t), 9), round(float(camera.fx), 6))

    def render(self, camera: Camera, t: float, *, mode: str = "color", heat_scale: float = 1.0,
               show_selection: bool = True, wait_sort: bool = False, fraction: float = 1.0) -> FrameStats:
        """Draw at ``camera`` (its own width x height) and time ``t`` into the float targets.

        ``wait_sort``: block until the order for exactly this camera and time is ready (tests,
        screenshots); otherwise the newest finished order of the same Gaussians is drawn.
        ``fraction`` < 1: level of detail, draw that fraction of the Gaussians (``app.gl.lod``:
        a fixed, importance-weighted subset, each kept splat's footprint scaled by 1/fraction).
        """
        self._ensure_targets(camera.width, camera.height)
        color, depth, fbo = self._targets
        self.last_camera = camera
        fbo.use()
        fbo.clear(0.0, 0.0, 0.0, 0.0)
        g = self.gaussians
        stats = FrameStats()
        if g is None or g.n == 0:
            self.stats = stats
            return stats
        key = self._sort_key(camera, t)
        if key != self._order_key:
            self.sorter.request(key, g, camera.w2c, t, camera.fx)
            res = self.sorter.wait(key) if (wait_sort or self._instances == 0) else self.sorter.result()
            if res is not None and res[0][0] == self.version and res[0] != self._order_key:
                self._full_order, self._area, self._importance = res[1], res[2], res[3]
                self._order_key = res[0]
                stats.sort_ms = self.sorter.last_sort_ms
        t0 = time.perf_counter()
        count, lod_area = self._install(fraction)
        stats.upload_ms = 1e3 * (time.perf_counter() - t0)
        stats.fraction = count / g.n if self._full_order is not None and self._full_order.size else 1.0
        t0 = time.perf_counter()
        p = self.prep_prog
        self._param_tex.use(0)
        self._flag_tex.use(1)
        uniforms = {
            "u_params": 0, "u_flags": 1, "u_tex_width": TEXTURE_WIDTH, "u_texels": texels_per_gaussian(g),
            "u_sh_degree": sh_degree_of(g.sh_rest.shape[1]), "u_cam_center": tuple(float(x) for x in camera.center),
            "u_intr": (camera.fx, camera.fy, camera.cx, camera.cy), "u_size": (float(camera.width), float(camera.height)),
            "u_time": float(t), "u_t_log_scale_min": T_LOG_SCALE_MIN, "u_near": NEAR_PLANE, "u_lowpass": LOWPASS_2D,
            "u_det_min": DET_MIN, "u_min_alpha": ALPHA_MIN, "u_sigma_extent": SIGMA_EXTENT,
            "u_fov_clamp": TAN_FOV_MARGIN, "u_mode": SPLAT_MODES[mode], "u_heat_scale": float(heat_scale),
            "u_show_selection": int(show_selection), "u_max_alpha": ALPHA_MAX, "u_power_max": POWER_MAX,
            "u_lod_area": lod_area}
        for prog in (self.prep_prog, self.prog):
            for name, value in uniforms.items():
                member = prog.get(name, None)  # each stage declares only what it uses
                if member is not None:
                    member.value = value
        p["u_w2c"].write(np.ascontiguousarray(camera.w2c.T, dtype=np.float32).tobytes())
        if self._instances:  # once per Gaussian: evaluate and project into the feedback buffer
            self._prep_vao.transform(self._feedback_buf, moderngl.POINTS, vertices=self._instances)
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        self.ctx.enable(moderngl.BLEND)
        self.ctx.blend_func = (moderngl.ONE_MINUS_DST_ALPHA, moderngl.ONE)
        self.ctx.blend_equation = moderngl.FUNC_ADD
        if self._instances:
            self._vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=self._instances)
        finish(self.ctx)  # the wait without the GIL: training threads keep running
        self.ctx.disable(moderngl.BLEND)
        stats.draw_ms = 1e3 * (time.perf_counter() - t0)
        stats.instances = self._instances
        self.stats = stats
        return stats

    def order_matches(self, camera: Camera, t: float) -> bool:
        """Whether the installed depth order is the exact one for ``camera`` at ``t``."""
        return self._order_key is not None and self._order_key == self._sort_key(camera, t)

    def upload_order(self, order: np.ndarray, camera: Camera, t: float) -> None:
        """Install a depth order computed elsewhere (``depth_order``) for ``camera`` at ``t``, so
        the next ``render`` of that view draws it without sorting (benchmarks, scripts)."""
        self._full_order = np.asarray(order, np.uint32)
        self._area = self._importance = None
        self._order_key = self._sort_key(camera, t)
        self._install(1.0)

    def _install(self, fraction: float) -> tuple[int, float]:
        """Put the installed order (or its level-of-detail subset at ``fraction``: the most
        important splats for this view, ``app.gl.lod``) into the index buffer unless it is there
        already. Returns (Gaussians drawn or N when drawing everything, the kept splats' area
        factor)."""
        g = self.gaussians
        if self._full_order is None or g is None:
            return (0 if g is None else g.n), 1.0
        count = g.n if fraction >= 1.0 or self._importance is None else lod_count(g.n, fraction)
        if self._drawn is None or self._drawn[:2] != (self._order_key, count):
            order, factor = self._full_order, 1.0
            if count < order.size:
                order = lod_subset(order, self._importance, count)
                factor = area_factor(float(self._area[self._full_order].sum()), float(self._area[order].sum()),
                                     self._full_order.size, order.size)
            self._upload_order(order)
            self._drawn = (self._order_key, count, factor)
        return count, self._drawn[2]

    def _upload_order(self, order: np.ndarray) -> None:
        data = np.ascontiguousarray(order, np.uint32)
        if self._order_buf is None or self._order_buf.size < max(data.nbytes, 4):
            for obj in (self._vao, self._prep_vao, self._order_buf, self._feedback_buf):
                if obj is not None:
                    obj.release()
            self._order_buf = self.ctx.buffer(reserve=max(data.nbytes, 4))
            # 3 vec4 per Gaussian out of the preparation pass, read per instance by the quads
            self._feedback_buf = self.ctx.buffer(reserve=max(data.size, 1) * FEEDBACK_BYTES)
            self._prep_vao = self.ctx.vertex_array(self.prep_prog, [(self._order_buf, "u4", "a_index")])
            self._vao = self.ctx.vertex_array(self.prog, [(self._feedback_buf, "4f 4f 4f/i", "i_center", "i_conic",
                                                           "i_color")])
        if data.nbytes:
            self._order_buf.write(data.tobytes())
        self._instances = int(data.size)

    def resolve(self, background=(0.0, 0.0, 0.0), mode: str = "color", *, hole_alpha: float = 0.5,
                depth_range: tuple[float, float] = (0.1, 10.0), scalar_max: float = 1.0) -> moderngl.Texture:
        """Composite the targets over ``background`` (or a debug map) into an RGBA8 texture of the
        render size, bottom row first (GL convention) and return it."""
        color, depth, _ = self._targets
        if self._display is None or self._display[0].size != color.size:
            if self._display is not None:
                for obj in self._display:
                    obj.release()
            tex = self.ctx.texture(color.size, 4)
            self._display = (tex, self.ctx.framebuffer(color_attachments=[tex]))
        tex, fbo = self._display
        fbo.use()
        p = self.resolve_prog
        color.use(0)
        depth.use(1)
        self._scalar_tex.use(2)
        p["u_color"].value, p["u_depth"].value, p["u_scalar"].value = 0, 1, 2
        p["u_background"].value = tuple(float(x) for x in background)
        p["u_mode"].value = RESOLVE_MODES[mode]
        p["u_hole_alpha"].value = float(hole_alpha)
        p["u_depth_range"].value = tuple(float(x) for x in depth_range)
        p["u_scalar_max"].value = float(scalar_max)
        self._empty_vao.render(moderngl.TRIANGLES, vertices=3)
        return tex

    @property
    def display_texture(self) -> moderngl.Texture | None:
        return None if self._display is None else self._display[0]

    @property
    def display_framebuffer(self) -> moderngl.Framebuffer | None:
        return None if self._display is None else self._display[1]

    # ---- read back (row 0 = image top) ----------------------------------------------------------
    def _read(self, attachment: int) -> np.ndarray:
        color, depth, fbo = self._targets
        w, h = color.size
        raw = np.frombuffer(fbo.read(components=4, attachment=attachment, dtype="f4"), np.float32)
        return raw.reshape(h, w, 4)[::-1]

    def read_rgb(self, background=(0.0, 0.0, 0.0)) -> np.ndarray:
        """(H, W, 3) float32 colour composited over ``background``."""
        c = self._read(0)
        return np.ascontiguousarray(c[..., :3] + (1.0 - c[..., 3:4]) * np.asarray(background, np.float32))

    def read_alpha(self) -> np.ndarray:
        """(H, W) accumulated opacity."""
        return np.ascontiguousarray(self._read(0)[..., 3])

    def read_depth(self) -> np.ndarray:
        """(H, W) expected z-depth (0 where alpha ~ 0), like RenderOutput.depth."""
        d = self._read(1)
        a = d[..., 3]
        # as fixer4d.render.api: every blended pixel has alpha >= ALPHA_MIN; empty ones stay 0
        return (d[..., 0] / np.maximum(a, ALPHA_MIN)).astype(np.float32)

    def read_display(self) -> np.ndarray:
        """(H, W, 3) uint8 of the last ``resolve`` (row 0 at the top)."""
        tex, fbo = self._display
        w, h = tex.size
        return np.frombuffer(fbo.read(components=3), np.uint8).reshape(h, w, 3)[::-1].copy()

    def release(self) -> None:
        self.sorter.close()
        for obj in [self._param_tex, self._flag_tex, self._scalar_tex, self._order_buf, self._vao, self._prep_vao,
                    self._feedback_buf, self.prep_prog,
                    *(self._targets or ()), *(self._display or ())]:
            if obj is not None:
                obj.release()
