"""The viewport: the 3D view's window, mouse and fly-key input, and Gaussian selection.

``Viewport`` is a part of ``app.viewer.Viewer``. Box selection is depth-aware: by default it
takes only the Gaussians on the front surface inside the box (their centre no farther than the
rendered depth at their pixel, with a tolerance), so a box around a pillar leaves the wall
behind it; "select through" takes everything whose centre projects inside the box.
"""
from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

from app.panels._layout import panel
from app.view3d import COLOR_SELECTED, MAX_RENDER_SIDE

# Brush radius for Gaussian selection, in viewport pixels.
BRUSH_RADIUS = 25.0
# Front-surface test of box selection: a Gaussian is on the front surface when its centre is no
# farther than the rendered depth at its pixel by more than this fraction of that depth or
# SURFACE_SIGMAS of its own largest std (a surface's Gaussians straddle the blended depth by
# about their size; an occluded one lies far behind it).
SURFACE_DEPTH_FRACTION = 0.05
SURFACE_SIGMAS = 3.0
# Accumulated opacity below which a pixel has no surface: Gaussians there are never occluded.
SURFACE_MIN_ALPHA = 0.5


class Viewport:
    """Input and selection of the 3D view (mixed into ``Viewer``)."""

    def _viewport_window(self) -> None:
        with panel(self, "viewport", "Viewport", 300, 30, 800, 470) as expanded:
            if expanded:
                self._viewport_body()

    def _viewport_body(self) -> None:
        avail = imgui.get_content_region_avail()
        aw = int(min(max(avail.x, 16), MAX_RENDER_SIDE))
        ah = int(min(max(avail.y - 4, 16), MAX_RENDER_SIDE))
        tex = self.render_view(aw, ah)
        area = imgui.get_cursor_screen_pos()
        self.item_rects["viewport_area"] = (area.x, area.y, area.x + aw, area.y + ah)
        if tex is None:
            imgui.text_wrapped(self._no_model_text())
            return
        w, h = self.display_camera.width, self.display_camera.height
        pos = imgui.ImVec2(area.x + (aw - w) // 2, area.y + (ah - h) // 2)
        # a letterboxed (snapped / preview) camera sits centred on black bars (only the bars
        # are filled: on a software GL every filled pixel costs)
        draw, black = imgui.get_window_draw_list(), imgui.get_color_u32(imgui.ImVec4(0, 0, 0, 1))
        for lo, hi in (((area.x, area.y), (area.x + aw, pos.y)), ((area.x, pos.y + h), (area.x + aw, area.y + ah)),
                       ((area.x, pos.y), (pos.x, pos.y + h)), ((pos.x + w, pos.y), (area.x + aw, pos.y + h))):
            if hi[0] > lo[0] and hi[1] > lo[1]:
                draw.add_rect_filled(imgui.ImVec2(*lo), imgui.ImVec2(*hi), black)
        self.viewport_rect = (pos.x, pos.y, float(w), float(h))
        imgui.set_cursor_screen_pos(pos)
        imgui.image(imgui.ImTextureRef(tex.glo), imgui.ImVec2(w, h), imgui.ImVec2(0, 1), imgui.ImVec2(1, 0))
        self._draw_legend(pos.x, pos.y, float(w), float(h))
        # an invisible button over the image takes the mouse, so drags steer the camera or
        # select instead of moving the window
        imgui.set_cursor_screen_pos(pos)
        buttons = imgui.ButtonFlags_.mouse_button_left.value | imgui.ButtonFlags_.mouse_button_right.value
        imgui.invisible_button("viewport_input", imgui.ImVec2(w, h), buttons)
        self._viewport_input(imgui.is_item_hovered(), imgui.is_item_active())

    def _no_model_text(self) -> str:
        tr = self.source.training
        if tr is not None and tr.state == "failed":
            return f"training failed: {tr.error}"
        if tr is not None:
            return f"preparing the model ({tr.state}): {tr.setup_status or 'starting'} ..."
        return "no model loaded (File > Open a run folder or a model)"

    def _viewport_input(self, hovered: bool, active: bool) -> None:
        io = imgui.get_io()
        st = self.state
        x0, y0, w, h = self.viewport_rect
        mx, my = io.mouse_pos.x - x0, io.mouse_pos.y - y0
        if self.tool == "navigate":
            if active and imgui.is_mouse_dragging(imgui.MouseButton_.left.value, 0.0):
                st.view.rotate(io.mouse_delta.x, io.mouse_delta.y, h)
            if active and imgui.is_mouse_dragging(imgui.MouseButton_.right.value, 0.0):
                st.view.pan(io.mouse_delta.x, io.mouse_delta.y, int(h))
            if hovered and io.mouse_wheel != 0.0:
                st.view.zoom(io.mouse_wheel)
            # fly keys are letters: not while a text field takes them, nor as part of a Ctrl/Alt chord (Ctrl+S saves)
            if hovered and st.view.mode == "fly" and not (io.want_text_input or io.key_ctrl or io.key_alt or io.key_super):
                step = 0.02 * st.view.scene_radius
                keys = {imgui.Key.w: (step, 0, 0), imgui.Key.s: (-step, 0, 0), imgui.Key.d: (0, step, 0),
                        imgui.Key.a: (0, -step, 0), imgui.Key.e: (0, 0, step), imgui.Key.q: (0, 0, -step)}
                for key, mv in keys.items():
                    if imgui.is_key_down(key):
                        st.view.move(*mv)
            return
        draw = imgui.get_window_draw_list()
        if self.tool == "box":
            if hovered and imgui.is_mouse_clicked(imgui.MouseButton_.left.value):
                self._drag_start = (mx, my)
            if self._drag_start is not None:
                sx, sy = self._drag_start
                draw.add_rect(imgui.ImVec2(x0 + sx, y0 + sy), imgui.ImVec2(x0 + mx, y0 + my),
                              imgui.get_color_u32(imgui.ImVec4(*COLOR_SELECTED)), 0.0, 1.5)
                if imgui.is_mouse_released(imgui.MouseButton_.left.value):
                    self.select_box(sx, sy, mx, my, add=io.key_shift)
                    self._drag_start = None
        elif self.tool == "brush" and hovered:
            draw.add_circle(imgui.ImVec2(x0 + mx, y0 + my), BRUSH_RADIUS,
                            imgui.get_color_u32(imgui.ImVec4(*COLOR_SELECTED)), 0, 1.5)
            if imgui.is_mouse_down(imgui.MouseButton_.left.value):
                self.select_brush(mx, my, BRUSH_RADIUS, add=True)

    # ---- selection (screen space, at the current time) -----------------------------------------
    def _screen_positions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, 2) pixel positions in the viewport image, (N,) camera depth and (N,) bool
        'visible now' mask."""
        g, cam = self.state.gaussians, self.display_camera
        if g is None or cam is None:
            return np.zeros((0, 2)), np.zeros(0), np.zeros(0, bool)
        t = self.model_time()
        uv, z = cam.project(g.means_at(t))
        from fixer4d.render.constants import ALPHA_MIN, NEAR_PLANE

        live = (z > NEAR_PLANE) & (g.opacity_at(t) >= ALPHA_MIN) & np.all(np.isfinite(uv), axis=1)
        return uv, z, live

    def front_surface(self, uv: np.ndarray, z: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        """(N,) bool: the ``candidates`` whose centre (pixel ``uv``, depth ``z``) is on the front
        surface of a full-quality render of the current view (see the module doc)."""
        cam = self.display_camera
        self.splats.render(cam, self.model_time(), wait_sort=True)
        depth, alpha = self.splats.read_depth(), self.splats.read_alpha()
        self.adaptive.invalidate()  # the display targets now hold this render: draw the view again
        idx = np.flatnonzero(candidates)
        col = np.clip(uv[idx, 0].astype(int), 0, cam.width - 1)
        row = np.clip(uv[idx, 1].astype(int), 0, cam.height - 1)
        d, a = depth[row, col], alpha[row, col]
        size = np.exp(self.state.gaussians.log_scales[idx].max(axis=1))
        tol = np.maximum(SURFACE_DEPTH_FRACTION * d, SURFACE_SIGMAS * size)
        front = (a < SURFACE_MIN_ALPHA) | (z[idx] <= d + tol)
        out = np.zeros_like(candidates)
        out[idx[front]] = True
        return out

    def select_box(self, x0: float, y0: float, x1: float, y1: float, add: bool = False,
                   through: bool | None = None) -> int:
        """Select the Gaussians whose centre at the current time projects inside the box
        (viewport pixels): on the front surface only, or all of them with ``through`` (default:
        the view panel's "select through" box). Returns the selection size."""
        uv, z, live = self._screen_positions()
        lo, hi = np.minimum([x0, y0], [x1, y1]), np.maximum([x0, y0], [x1, y1])
        with np.errstate(invalid="ignore"):
            inside = live & np.all((uv >= lo) & (uv <= hi), axis=1)
        if not (self.select_through if through is None else through) and inside.any():
            inside = self.front_surface(uv, z, inside)
        return self._select(inside, add)

    def select_brush(self, x: float, y: float, radius: float, add: bool = True) -> int:
        uv, _, live = self._screen_positions()
        with np.errstate(invalid="ignore"):
            inside = live & (np.sum((uv - np.array([x, y])) ** 2, axis=1) <= radius * radius)
        return self._select(inside, add)

    def _select(self, mask: np.ndarray, add: bool) -> int:
        st = self.state
        if st.gaussians is None:
            return 0
        sel = mask if not add or st.selection is None else (st.selection | mask)
        st.set_selection(sel)
        return int(sel.sum())
