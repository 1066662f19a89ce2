"""World-space overlays drawn over the splats: camera frusta, trajectory paths and their camera
markers. Lines use the viewer camera's K-exact OpenGL projection, so a world point lands on
the same pixel as ``Camera.project`` says (a test checks it)."""
from __future__ import annotations

import moderngl
import numpy as np

from app.gl.programs import load_program
from fixer4d.geometry.camera import CV_TO_GL, Camera

# Clip planes of the overlay projection, relative to the scene radius: near enough to draw a
# frustum the viewer stands next to, far enough for any rig.
NEAR_FRACTION = 1e-3
FAR_FRACTION = 1e3
MARKER_SIZE = 7.0  # pixels, camera centres on a trajectory


def frustum_segments(cam: Camera, depth: float) -> np.ndarray:
    """(16, 3) endpoints of 8 segments: the 4 image corners at z = depth joined to the centre and
    to each other."""
    w, h = cam.width, cam.height
    corners = cam.backproject(np.array([[0, 0], [w, 0], [w, h], [0, h]], float), np.full(4, depth))
    c = cam.center
    segs = []
    for k in range(4):
        segs += [c, corners[k], corners[k], corners[(k + 1) % 4]]
    return np.asarray(segs)


def path_segments(points: np.ndarray) -> np.ndarray:
    """(2(M-1), 3) endpoints joining consecutive points (M, 3)."""
    p = np.asarray(points, float).reshape(-1, 3)
    if p.shape[0] < 2:
        return np.zeros((0, 3))
    return np.stack([p[:-1], p[1:]], 1).reshape(-1, 3)


def view_projection(cam: Camera, scene_radius: float) -> np.ndarray:
    """(4, 4) clip-from-world for ``cam`` (OpenGL clip space, K-exact)."""
    P = cam.projection_opengl(NEAR_FRACTION * scene_radius, FAR_FRACTION * scene_radius)
    return P @ CV_TO_GL @ cam.w2c


class OverlayRenderer:
    """Collects coloured segments and points for one frame, then draws them into the bound
    framebuffer."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self.prog = load_program(ctx, "lines.vert", "lines.frag")
        self._lines: list[tuple[np.ndarray, tuple]] = []
        self._points: list[tuple[np.ndarray, tuple]] = []

    def clear(self) -> None:
        self._lines.clear()
        self._points.clear()

    def add_segments(self, endpoints: np.ndarray, color: tuple[float, float, float, float]) -> None:
        if len(endpoints):
            self._lines.append((np.asarray(endpoints, np.float32).reshape(-1, 3), color))

    def add_points(self, points: np.ndarray, color: tuple[float, float, float, float]) -> None:
        if len(points):
            self._points.append((np.asarray(points, np.float32).reshape(-1, 3), color))

    def add_frustum(self, cam: Camera, depth: float, color) -> None:
        self.add_segments(frustum_segments(cam, depth), color)

    def add_path(self, cameras: list[Camera], color, markers: bool = True) -> None:
        centers = np.stack([c.center for c in cameras]) if cameras else np.zeros((0, 3))
        self.add_segments(path_segments(centers), color)
        if markers:
            self.add_points(centers, color)

    def _vertices(self, items: list[tuple[np.ndarray, tuple]]) -> np.ndarray:
        if not items:
            return np.zeros((0, 7), np.float32)
        rows = [np.concatenate([p, np.broadcast_to(np.asarray(c, np.float32), (p.shape[0], 4))], 1) for p, c in items]
        return np.ascontiguousarray(np.concatenate(rows), np.float32)

    def draw(self, cam: Camera, scene_radius: float) -> None:
        mvp = view_projection(cam, scene_radius)
        self.prog["u_mvp"].write(np.ascontiguousarray(mvp.T, np.float32).tobytes())
        self.prog["u_point_size"].value = MARKER_SIZE
        self.ctx.enable(moderngl.BLEND | moderngl.PROGRAM_POINT_SIZE)
        self.ctx.blend_func = (moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA)
        for items, mode in ((self._lines, moderngl.LINES), (self._points, moderngl.POINTS)):
            verts = self._vertices(items)
            if verts.shape[0] == 0:
                continue
            buf = self.ctx.buffer(verts.tobytes())
            vao = self.ctx.vertex_array(self.prog, [(buf, "3f 4f", "a_pos", "a_color")])
            vao.render(mode)
            vao.release()
            buf.release()
        self.ctx.disable(moderngl.BLEND | moderngl.PROGRAM_POINT_SIZE)

    def release(self) -> None:
        self.prog.release()
