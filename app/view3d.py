"""The 3D view: the image the viewport shows (splats, debug maps, overlays, colour bars).

``View3D`` is a part of ``app.viewer.Viewer``: while the camera moves the view draws less
(``app.adaptive``: smaller and, with level of detail, only the most important splats); once it
rests it draws everything at full size; while only the time changes (playback, scrubbing) each
frame is drawn at full quality once and shown from ``app.frame_cache`` after that.
"""
from __future__ import annotations

import time
from pathlib import Path

import moderngl
import numpy as np
from imgui_bundle import imgui

from fixer4d.geometry.camera import Camera

# Largest viewport render (pixels per side): keeps llvmpipe interactive on big windows.
MAX_RENDER_SIDE = 1600
# Frustum drawing depth as a fraction of the scene radius.
FRUSTUM_DEPTH_FRACTION = 0.06
COLOR_TRAIN = (0.2, 0.9, 0.3, 1.0)
COLOR_TEST = (1.0, 0.65, 0.1, 1.0)
COLOR_TRAJECTORY = (0.3, 0.7, 1.0, 1.0)
COLOR_SELECTED = (1.0, 0.2, 0.9, 1.0)
COLOR_PREVIEW = (1.0, 1.0, 1.0, 1.0)
# Image modes tinted by a map computed on the CPU for one resting view (the blur map, the
# undetermined map): hidden while the view moves, computed again when it rests; their picture is
# not a function of (view, frame) alone, so playback in them does not go through the frame cache.
UNCACHED_MODES = ("blur", "undetermined")
# The status line's words for an image of every splat at full size, exact depth order.
FULL_DETAIL = "full quality: 100% splats, full scale"


class View3D:
    """Rendering of the 3D view (mixed into ``Viewer``; uses its state, source and renderers)."""

    def view_camera(self, width: int, height: int) -> Camera:
        """The camera the viewport shows in a width x height area: the trajectory preview
        camera while previewing, else the interactive camera; a preview or snapped camera keeps
        its own aspect and intrinsics (letterboxed, possibly smaller than the area)."""
        from app.camera_control import letterbox

        st = self.state
        if st.previewing and 0 <= st.selected_trajectory < len(st.trajectories):
            cams = self.trajectory_cameras(st.trajectories[st.selected_trajectory])
            if cams:
                k = int(round(st.preview_alpha * (len(cams) - 1)))
                return letterbox(cams[k], width, height)
        return st.view.camera(width, height)

    def _base_key(self, cam: Camera) -> tuple:
        """Everything the 3D image depends on except the time."""
        st = self.state
        return (cam.K.tobytes(), cam.c2w.tobytes(), cam.width, cam.height, st.gaussians_version,
                st.splat_mode, st.debug_mode, tuple(st.background), self.scalar_version, st.show_frusta,
                st.show_trajectories, id(st.trajectories), tuple(id(t) for t in st.trajectories),
                st.selected_trajectory, st.previewing, st.preview_alpha)

    def _view_key(self, cam: Camera) -> tuple:
        """Everything the 3D image depends on: when it is unchanged the last image stands."""
        return self._base_key(cam) + (round(self.state.time, 9),)

    def render_view(self, width: int, height: int, *, wait_sort: bool = False) -> moderngl.Texture | None:
        """Render splats + overlays at the current camera and time and return the texture to
        show: adaptive resolution and level of detail only while the camera moves; with the
        camera at rest every splat at full size (a new model from live training, an edit or a
        mode change included), from the frame cache while only the time changes, nothing new
        while nothing changed. ``display_camera`` is the full-size view camera (viewport
        pixels), ``render_camera`` the one the image was drawn with (``wait_sort``: full size
        with the exact depth order, for tests and screenshots). ``view_mode`` says which kind
        of image is showing."""
        st = self.state
        self._sync_model()  # the frame may have changed since the frame began (timeline panel)
        if st.gaussians is None:
            self.view_mode = "no model"
            return None
        cam = self.view_camera(width, height)
        self.display_camera = cam
        pose = (cam.K.tobytes(), cam.c2w.tobytes(), cam.width, cam.height)
        camera_rests, self._last_pose = pose == self._last_pose, pose
        base, key = self._base_key(cam), self._view_key(cam)
        self.adaptive.splats = st.gaussians.n
        cacheable = self.use_frame_cache and not wait_sort and st.debug_mode not in UNCACHED_MODES
        only_time_moved = base == self._last_base and key != self.adaptive.last_key
        time_only = cacheable and only_time_moved
        self._last_base = base
        if base != self.frame_cache.base and len(self.frame_cache):
            self.frame_cache.clear()  # camera, model, edit or mode changed: the frames are stale
        if time_only:  # the camera rests and the time moved: full quality, once per frame
            hit = self.frame_cache.get(base, st.frame)
            if hit is not None:
                self.adaptive.last_key, self.adaptive.final, self.adaptive.moving = key, True, False
                self.view_mode = f"playback from the frame cache ({len(self.frame_cache)} frames)"
                self._shown = hit
                return hit
            tic = time.perf_counter()
            tex = self._draw(cam, 1.0, 1.0, wait_sort=True)
            self.adaptive.last_key = key
            self.adaptive.final, self.adaptive.moving = True, False
            self.frame_cache.put(base, st.frame, self.splats.display_framebuffer,
                                 1e3 * (time.perf_counter() - tic))
            self.view_mode = f"{FULL_DETAIL}, filling the frame cache ({len(self.frame_cache)} frames)"
            self._shown = tex
            return tex
        # the camera rests but the picture changed (a model published by live training, an edit,
        # a mode): every splat at full size at once, not a level-of-detail image to refine later
        # (playback without the cache is motion and keeps level of detail)
        if wait_sort or (camera_rests and key != self.adaptive.last_key and not only_time_moved):
            self.adaptive.last_key, self.adaptive.rest, self.adaptive.moving = key, 0, False
            scale, self.adaptive.fraction, wait_sort = 1.0, 1.0, True
        else:
            scale = self.adaptive.plan(key)
        if scale is None and self._shown is not None:
            return self._shown
        if scale is None:  # nothing drawn yet: everything at full size
            scale, self.adaptive.fraction = 1.0, 1.0
        tex = self._draw(cam, scale, self.adaptive.fraction, wait_sort=wait_sort)
        self.view_mode = self._detail_line()
        self._shown = tex
        return tex

    def _detail_line(self) -> str:
        """What the last render drew, for the status line: full detail (every splat at full
        size; with live training, the step of the model shown) or the level of detail."""
        a, tr = self.adaptive, self.source.training
        if not a.final:
            share = self.splats.stats.fraction
            splats = f"{100 * share:.0f}% splats"  # the most visible ones (app.gl.lod)
            return f"moving: level of detail, {splats} at {a.scale:.2f} scale"
        if tr is not None and tr.state in ("setup", "running", "paused"):
            return f"{FULL_DETAIL}, training step {self._model_step}"
        return FULL_DETAIL

    def shown_image(self) -> np.ndarray | None:
        """(H, W, 3) uint8 of the image the 3D view showed last (row 0 at the top): a fresh
        render or a frame from the cache."""
        tex = self._shown
        if tex is None:
            return None
        w, h = tex.size
        return np.frombuffer(tex.read(), np.uint8).reshape(h, w, tex.components)[::-1, :, :3].copy()

    def _draw(self, cam: Camera, scale: float, fraction: float, *, wait_sort: bool) -> moderngl.Texture:
        """Draw splats, debug map and overlays for ``cam`` at ``scale`` drawing ``fraction`` of
        the splats; report the cost to the adaptive planner; return the display texture."""
        st = self.state
        rcam = cam if scale >= 1.0 else cam.resized(max(1, int(round(cam.width * scale))),
                                                    max(1, int(round(cam.height * scale))))
        self.render_camera = rcam
        t_model = self.model_time()
        if st.splat_mode == "speed" and st.gaussians.n:
            speed = st.gaussians.speed_at(t_model)
            moving = speed[speed > 0]
            self.heat_scale = float(np.percentile(moving, 99)) if moving.size else 1.0
        stats = self.splats.render(rcam, t_model, mode=st.splat_mode, heat_scale=self.heat_scale, wait_sort=wait_sort,
                                   fraction=fraction)
        self.adaptive.done(scale, stats.draw_ms, self.splats.order_matches(rcam, t_model), stats.fraction)
        self._draw_ms += stats.draw_ms
        self.depth_range = self._depth_range(rcam)
        mode = st.debug_mode
        if mode == "undetermined" and self.twin_pair() is None:
            mode = "color"  # no twin field: the legend says how to train one
        if mode in UNCACHED_MODES and self.map_stale:
            if self.adaptive.final:  # the view rests: recompute for it
                self._compute_map(mode)
            else:  # moving: no map rather than a wrong one
                mode = "color"
        if mode == "moving":
            self._update_mask(cam)
        tex = self.splats.resolve(st.background, mode, depth_range=self.depth_range,
                                  scalar_max=self.blur_max if mode == "blur" else 1.0)
        self.splats.display_framebuffer.use()
        self.overlays.clear()
        self._collect_overlays(rcam)
        self.overlays.draw(rcam, st.view.scene_radius)
        return tex

    def view_signature(self) -> tuple | None:
        """Image mode, pose, intrinsics, time, model and background of the current full-size view
        (what a blur or undetermined map is valid for)."""
        cam = self.display_camera
        if cam is None:
            return None
        st = self.state
        return (st.debug_mode, cam.c2w.tobytes(), cam.K.tobytes(), round(st.time, 9), st.gaussians_version,
                tuple(st.background))

    @property
    def map_stale(self) -> bool:
        """The scalar map was not computed for the current view and image mode."""
        return self.scalar_key is None or self.scalar_key != self.view_signature()

    def show_scalar_map(self, values: np.ndarray, key: tuple | None) -> None:
        """Upload the (H, W) map the blur, undetermined and moving modes tint the image with;
        ``key``: what it was computed for (``view_signature`` for a view's map)."""
        self.splats.set_scalar_map(values)
        self.scalar_version += 1
        self.scalar_key = key

    def _compute_map(self, mode: str) -> None:
        if mode == "blur":
            from app.panels.debug import compute_blur

            compute_blur(self)
        else:
            from app.undetermined import compute_undetermined

            compute_undetermined(self)

    def twin_pair(self) -> tuple[Path | None, Path] | None:
        """What the undetermined map compares (``app.files.twin_pair``; first None: the shown
        Gaussians), or None."""
        from app.files import twin_pair

        return twin_pair(self.source.model_path)

    def masks(self) -> tuple | None:
        """(masks (V,F,H,W) bool, camera ids, frames) from the run's RUN/init_*/masks.npz (the
        static/dynamic split of the init), or None when the run has none."""
        run = self.source.run_dir
        if run is None:
            return None
        paths = sorted(Path(run).glob("init_*/masks.npz"))
        if not paths:
            return None
        if self._masks is None or self._masks[0] != paths[0]:
            from fixer4d.init.masks import load_masks

            self._masks = (paths[0], *load_masks(paths[0]))
        return self._masks[1:]

    def _update_mask(self, cam: Camera) -> None:
        """Upload the moving-content mask of the camera the view is snapped to at the current
        frame (the mask is that camera's image, so it only lines up there)."""
        scene, got = self.source.scene, self.masks()
        masks, ids, frames = got if got is not None else (None, [], [])
        idx = None
        if scene is not None and self.state.view.snapped is not None:
            snap = self.state.view.snapped
            idx = next((i for i, c in enumerate(scene.cameras) if np.allclose(c.c2w, snap.c2w)), None)
        key = ("moving", idx, self.state.frame)
        if self.scalar_key == key:
            return
        names = [] if idx is None else [str(idx), str(scene.cameras[idx].name)]
        v = next((k for k, c in enumerate(ids) if c in names), None)
        if masks is None or v is None or self.state.frame not in frames:
            self.mask_note = ("no masks in this run (RUN/init_*/masks.npz)" if masks is None else
                              f"masks on cameras {', '.join(map(str, ids))}, frames {_frame_list(frames)}")
            self.show_scalar_map(np.zeros((1, 1), np.float32), key)
        else:
            self.mask_note = f"camera {ids[v]}, frame {self.state.frame} (frames {_frame_list(frames)})"
            self.show_scalar_map(masks[v, frames.index(self.state.frame)].astype(np.float32), key)

    def _draw_legend(self, x0: float, y0: float, w: float, h: float) -> None:
        """The colour bar of the current heatmap over the bottom left of the 3D image, with its
        numbers and unit; the box grows to hold its longest line (title and note may hold several)."""
        from app.legends import legend

        lg = legend(self)
        if lg is None:
            return
        draw = imgui.get_window_draw_list()
        line = imgui.get_text_line_height()
        title, note = imgui.calc_text_size(lg.title), imgui.calc_text_size(lg.note) if lg.note else imgui.ImVec2(0, 0)
        bw = max(40.0, min(max(320.0, title.x, note.x), w - 20.0))
        ticks = lg.ticks()
        bx = x0 + 10.0
        by = y0 + h - 10.0 - 14.0 - (2.2 * line if ticks else 0.6 * line) - note.y
        box = (bx - 6, by - title.y - 6, bx + bw + 6, y0 + h - 4)
        draw.add_rect_filled(imgui.ImVec2(*box[:2]), imgui.ImVec2(*box[2:]),
                             imgui.get_color_u32(imgui.ImVec4(0.0, 0.0, 0.0, 0.65)), 4.0)
        draw.push_clip_rect(imgui.ImVec2(*box[:2]), imgui.ImVec2(*box[2:]), True)
        white = imgui.get_color_u32(imgui.ImVec4(1, 1, 1, 1))
        draw.add_text(imgui.ImVec2(bx, by - title.y - 2), white, lg.title)
        self.item_rects["legend_bar"] = (bx, by + 2, bx + bw, by + 14)
        self.item_rects["legend_box"] = box
        n = 32
        cols = lg.colors(n)
        for k in range(n):
            c = imgui.get_color_u32(imgui.ImVec4(*cols[k], 1.0))
            draw.add_rect_filled(imgui.ImVec2(bx + bw * k / n, by + 2), imgui.ImVec2(bx + bw * (k + 1) / n + 0.5, by + 14), c)
        for pos, text in ticks:  # numbers under the bar: first left-aligned, last right-aligned
            tw = imgui.calc_text_size(text).x
            tx = min(max(bx + pos * bw - tw / 2, bx), bx + bw - tw)
            draw.add_text(imgui.ImVec2(tx, by + 16), white, text)
        if lg.note:
            draw.add_text(imgui.ImVec2(bx, by + 16 + (line if ticks else 0.0)),
                          imgui.get_color_u32(imgui.ImVec4(1.0, 0.75, 0.3, 1)), lg.note)
        draw.pop_clip_rect()

    def _depth_range(self, cam: Camera) -> tuple[float, float]:
        g = self.state.gaussians
        if g is None or g.n == 0:
            return (0.1, 10.0)
        z = g.means_at(self.model_time()) @ cam.w2c[2, :3].astype(np.float32) + np.float32(cam.w2c[2, 3])
        z = z[z > 0]
        return (float(np.percentile(z, 2)), float(np.percentile(z, 98))) if z.size else (0.1, 10.0)

    def _collect_overlays(self, cam: Camera) -> None:
        st, scene = self.state, self.source.scene
        depth = FRUSTUM_DEPTH_FRACTION * st.view.scene_radius
        if st.show_frusta and scene is not None:
            for i, c in enumerate(scene.cameras):
                if c.name == cam.name and np.allclose(c.c2w, cam.c2w):
                    continue
                self.overlays.add_frustum(c, depth, COLOR_TRAIN if i in scene.train_ids else COLOR_TEST)
        if st.show_trajectories:
            for k, spec in enumerate(st.trajectories):
                if not spec.visible:
                    continue
                cams = self.trajectory_cameras(spec)
                color = COLOR_SELECTED if k == st.selected_trajectory else COLOR_TRAJECTORY
                self.overlays.add_path(cams, color)
                if k == st.selected_trajectory and cams and not st.previewing:
                    j = int(round(st.preview_alpha * (len(cams) - 1)))
                    self.overlays.add_frustum(cams[j], depth, COLOR_PREVIEW)


def _frame_list(frames: list[int], most: int = 8) -> str:
    """'0, 10, 20' (or the first ``most`` and a count of the rest)."""
    shown = ", ".join(str(f) for f in frames[:most])
    return shown + (f" (+{len(frames) - most} more)" if len(frames) > most else "")
