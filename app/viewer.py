"""The viewer core, independent of the window system: one ``Viewer.frame()`` builds the imgui UI
(docked panels over a 3D viewport), draws the splats and overlays, and renders everything into
a framebuffer. ``app.main`` drives it from a glfw window; tests drive it headless on an EGL
context, feeding input through imgui's io.

Models reach the viewer through a ``ViewerSource`` (a run folder's model, a live trainer's
mailbox, a restoration cache); torch renders for compare/restore come from an injected render
function built from the displayed Gaussians, so the UI never touches a model's internals.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import moderngl
import numpy as np
from imgui_bundle import imgui, implot

from app.adaptive import FRAME_TARGET_MS, MAX_BUDGET_MS, MIN_BUDGET_MS, AdaptiveResolution
from app.gl.sync import finish
from app.gl.overlays import OverlayRenderer
from app.panels._layout import guard, panel
from app.gl.splats import SplatRenderer
from app.notifications import Notifications
from app.camera_control import ViewCamera
from app.session import RestoreQueue, TrainingSession
from app.state import AppState, TrajectorySpec
from fixer4d.geometry.camera import Camera

# Largest viewport render (pixels per side): keeps llvmpipe interactive on big windows.
MAX_RENDER_SIDE = 1600
# Largest render scale of the 3D view while live training runs: every full-size splat frame on a
# software GL takes CPU from the trainer (the view is upscaled; pausing training restores it).
TRAINING_RENDER_SCALE = 0.5
# Input within this many seconds counts as "the user is interacting" (app.main paces the UI by it).
INTERACTION_S = 1.5
# While live training runs and nobody interacts, a published model is taken at most this often
# (s): each new model is re-uploaded, re-sorted and redrawn (100-400 ms of software GL for 30k
# splats), CPU that the trainer on the same cores loses. Interacting, every published model is
# taken (at most one a second, session.PUBLISH_MIN_S).
MODEL_REFRESH_UNATTENDED_S = 5.0
# Brush radius for Gaussian selection, in viewport pixels.
BRUSH_RADIUS = 25.0
# Frustum drawing depth as a fraction of the scene radius.
FRUSTUM_DEPTH_FRACTION = 0.06
# Built trajectories kept (each a list of cameras); cleared whole when exceeded.
TRAJECTORY_CACHE_SIZE = 256
COLOR_TRAIN = (0.2, 0.9, 0.3, 1.0)
COLOR_TEST = (1.0, 0.65, 0.1, 1.0)
COLOR_TRAJECTORY = (0.3, 0.7, 1.0, 1.0)
COLOR_SELECTED = (1.0, 0.2, 0.9, 1.0)
COLOR_PREVIEW = (1.0, 1.0, 1.0, 1.0)


@dataclass
class ViewerSource:
    """What the viewer shows and drives.

    scene: the multi-view video (cameras, real frames), or None for a bare model.
    run_dir: the run folder (edits are saved there), or None.
    training: a live ``TrainingSession`` whose mailbox delivers models, or None.
    cache: a ``fixer4d.restore.cache.RestoreCache`` (the compare panel reads it), or None.
    restore: a ``RestoreQueue`` to queue restorations, or None.
    render_backend: the torch rasterizer backend for compare/restore renders.
    model_path: the model file shown, or None (live training).
    segments: a segmented run's ``app.segments.SegmentTimeline`` (the shown Gaussians follow the
      segment that owns the current frame), or None.
    """

    scene: Any = None
    run_dir: Path | None = None
    label: str = ""
    training: TrainingSession | None = None
    cache: Any = None
    restore: RestoreQueue | None = None
    render_backend: str = "auto"
    model_path: Path | None = None  # the model file shown (a run's version, or a bare model)
    segments: Any = None


class Viewer:
    """The application, minus the window. Call ``frame(dt, fbo)`` once per frame."""

    def __init__(self, ctx: moderngl.Context, state: AppState, source: ViewerSource, *,
                 ini_path: Path | None = None, session_path: Path | None = None,
                 platform_init: Callable[[], None] | None = None) -> None:
        self.ctx = ctx
        self.state = state
        self.source = source
        self.session_path = session_path
        self.imgui_ctx = imgui.create_context()
        self.implot_ctx = implot.create_context()
        io = imgui.get_io()
        io.config_flags |= imgui.ConfigFlags_.docking_enable.value
        self._ini_path = None if ini_path is None else str(ini_path)
        io.set_ini_filename(self._ini_path)
        # imgui's error recovery undoes what a failing panel left open (see panels._layout.guard);
        # its own assertion would turn every recovery into a second error
        io.config_error_recovery = True
        io.config_error_recovery_enable_assert = False
        io.config_error_recovery_enable_tooltip = False
        if platform_init is not None:
            platform_init()
        imgui.backends.opengl3_init("#version 330")
        self.splats = SplatRenderer(ctx)
        self.overlays = OverlayRenderer(ctx)
        self.tool = "navigate"  # navigate | box | brush
        self._drag_start: tuple[float, float] | None = None
        self._uploaded_version = -1
        self._segment: int | None = None  # a segmented run: the segment whose Gaussians are shown
        self._model_serial = 0
        self._model_taken = -1e9  # time.monotonic() when the last published model was taken
        self._torch_model: tuple[Any, Any] | None = None  # (version key, torch model)
        self.viewport_rect = (0.0, 0.0, 1.0, 1.0)  # screen x, y, w, h of the 3D image
        self.render_camera: Camera | None = None  # the camera of the last 3D image (maybe reduced)
        self.display_camera: Camera | None = None  # the full-size view camera (viewport pixels)
        self.depth_range = (0.1, 10.0)  # near, far of the depth colour map (last render)
        self.scalar_version = 0  # bumped when the blur/mask map changes
        self.adaptive = AdaptiveResolution()
        self.last_input = -1e9  # time.monotonic() of the last mouse/keyboard input
        self.heat_scale = 1.0  # speed at the top of the speed heatmap (scene units per clip time)
        self.blur_key: tuple | None = None  # the view the blur map was computed for
        self.mask_note = ""  # why the moving-content overlay shows nothing, if it does not
        self._masks: tuple | None = None  # (path, masks, camera ids, frames) of RUN/init_*/masks.npz
        self.frame_ms = 0.0
        self.frame_times: list[float] = []
        self.ui_ms: float | None = None  # running estimate of a frame's cost besides the splat draw
        self._draw_ms = 0.0  # the splat draw of the current frame
        self.images: dict[str, moderngl.Texture] = {}
        self._image_sources: dict[str, Any] = {}  # the array each named texture holds
        self.panel_errors: dict[str, str] = {}  # panel -> its current error (cleared when it draws again)
        self.notifications = Notifications()
        self._notifications_seen = 0
        self.show_notifications = False
        self.blur_max = 1.0  # top of the blur map's colour scale (set by the debug panel)
        # screen rectangles (x0, y0, x1, y1) of named widgets from the last frame, so scripts and
        # tests can click them through imgui's io like a user
        self.item_rects: dict[str, tuple[float, float, float, float]] = {}
        # screen rectangles of the panel windows this frame and last frame (panels._layout.alone)
        self.window_rects: dict[str, tuple[float, float, float, float]] = {}
        self.last_window_rects: dict[str, tuple[float, float, float, float]] = {}
        # every panel's latest rectangle (hidden ones included), whether it is docked, the
        # rectangles due after a window resize, and the window size they were laid out for
        # (panels._layout.rescale_layout)
        self.known_window_rects: dict[str, tuple[float, float, float, float]] = {}
        self.docked_windows: dict[str, bool] = {}
        self.pending_window_rects: dict[str, tuple[float, float, float, float]] = {}
        self._layout_size: tuple[float, float] | None = None
        self._trajectory_cache: dict[int, tuple[TrajectorySpec, list[Camera]]] = {}
        from app.panels import PANELS  # the panels import the viewer's helpers

        self.panels = PANELS
        self.home_view = ViewCamera.from_dict(state.view.to_dict())  # "reset view" returns here
        if session_path is not None:
            try:
                state.load_session(session_path)
            except Exception as exc:  # a bad session must not stop the app; say so
                state.status = str(exc)

    # ---- per-frame ------------------------------------------------------------------------------
    def frame(self, dt: float, fbo: moderngl.Framebuffer, platform_new_frame: Callable[[], None] | None = None) -> None:
        """Advance playback by ``dt`` seconds, build the UI, draw everything into ``fbo``."""
        tic = time.perf_counter()
        self._draw_ms = 0.0
        self.state.advance(dt)
        self._poll_models()
        io = imgui.get_io()
        io.delta_time = max(float(dt), 1e-4)
        if platform_new_frame is not None:
            platform_new_frame()
        else:
            io.display_size = imgui.ImVec2(float(fbo.size[0]), float(fbo.size[1]))
        imgui.backends.opengl3_new_frame()
        imgui.new_frame()
        self.last_window_rects, self.window_rects = self.window_rects, {}
        self._follow_window_size((io.display_size.x, io.display_size.y))
        if io.mouse_delta.x or io.mouse_delta.y or io.mouse_wheel or any(io.mouse_down) or io.want_text_input:
            self.last_input = time.monotonic()
        imgui.dock_space_over_viewport(0, imgui.get_main_viewport(),
                                       imgui.DockNodeFlags_.passthru_central_node.value)
        with guard(self, "menu"):
            self._menu()
        self._viewport_window()
        for name, draw in self.panels:
            draw(self)  # each panel guards its own body (panels._layout.panel)
        self._notifications_window()
        with guard(self, "file"):
            from app.panels import files

            files.draw_dialog(self)
        with guard(self, "shortcuts"):
            self._shortcuts()
        imgui.render()
        fbo.use()
        self.ctx.viewport = (0, 0, *fbo.size)
        bg = imgui.get_style().color_(imgui.Col_.window_bg.value)
        fbo.clear(bg.x, bg.y, bg.z, 1.0)  # the colour of panels drawn without background
        imgui.backends.opengl3_render_draw_data(imgui.get_draw_data())
        finish(self.ctx)  # (without the GIL) so the frame time includes the GL's work
        self.frame_ms = 1e3 * (time.perf_counter() - tic)
        self._plan_budget(self.frame_ms - self._draw_ms)
        self.frame_times.append(self.frame_ms)
        del self.frame_times[:-240]

    def _follow_window_size(self, size: tuple[float, float]) -> None:
        """Rescale the panels when the app window changed size (a minimized window, size 0, does not
        count: restoring it returns to the layout it had)."""
        if min(size) <= 0:
            return
        if self._layout_size is not None and size != self._layout_size:
            from app.panels._layout import rescale_layout

            rescale_layout(self, self._layout_size, size)
        self._layout_size = size

    def _plan_budget(self, ui_ms: float) -> None:
        """The splat draw's budget while moving: what is left of FRAME_TARGET_MS after the rest of
        the frame (panels, imgui's GL pass, the display), from a running estimate of it."""
        self.ui_ms = ui_ms if self.ui_ms is None else 0.5 * ui_ms + 0.5 * self.ui_ms
        self.adaptive.budget_ms = float(np.clip(FRAME_TARGET_MS - self.ui_ms, MIN_BUDGET_MS, MAX_BUDGET_MS))

    def report_error(self, source: str, exc: BaseException | str) -> None:
        """An error from a panel, menu or action: into the notifications area and the log (once
        per distinct error while it repeats every frame); the app keeps running."""
        text = exc if isinstance(exc, str) else f"{type(exc).__name__}: {exc}"
        if self.panel_errors.get(source) != text:
            self.notifications.error(source, exc)
        self.panel_errors[source] = text
        self.state.status = f"error in {source}: {text}"

    def _notifications_window(self) -> None:
        from app.panels._layout import error_text

        notes = self.notifications
        if notes.serial != self._notifications_seen:
            last = notes.items()[-1:]
            if last and last[0].level == "error":
                self.show_notifications = True  # an error opens the window
            self._notifications_seen = notes.serial
        if not self.show_notifications:
            return
        # over the bottom of the Compare panel's image: its controls (top) stay usable
        with panel(self, "notifications", "Notifications", 300, 765, 800, 130) as expanded:
            if not expanded:
                return
            if imgui.small_button("clear"):
                notes.clear()
                self.panel_errors.clear()
            imgui.same_line()
            if imgui.small_button("hide"):
                self.show_notifications = False
            for msg in reversed(notes.items()):
                stamp = time.strftime("%H:%M:%S", time.localtime(msg.when))
                line = f"{stamp}  [{msg.source}]  {msg.text}"
                if msg.level == "error":
                    error_text(line)
                else:
                    imgui.text_wrapped(line)

    def _poll_models(self) -> None:
        tr = self.source.training
        now = time.monotonic()
        waiting = tr is not None and self.state.gaussians is not None and tr.state == "running" \
            and now - self.last_input >= INTERACTION_S and now - self._model_taken < MODEL_REFRESH_UNATTENDED_S
        if tr is not None and not waiting:
            got = tr.models.take(self._model_serial)
            if got is not None:
                self._model_serial, g = got
                self._model_taken = now
                keep_selection = self.state.gaussians is not None and self.state.gaussians.n == g.n
                sel = self.state.selection if keep_selection else None
                self.state.set_gaussians(g)
                if sel is not None:
                    self.state.set_selection(sel)
        self._sync_model()

    def _sync_model(self) -> None:
        """Show the segment that owns the current frame (a segmented run) and upload the shown
        Gaussians when they changed."""
        timeline, st = self.source.segments, self.state
        if timeline is not None:
            k = timeline.segment_of(st.time)
            if k != self._segment:
                if self._segment is not None and st.gaussians is not None:
                    timeline.arrays[self._segment] = st.gaussians  # keep that segment's edits
                if self._segment is not None or st.gaussians is not timeline.arrays[k]:
                    st.set_gaussians(timeline.arrays[k])
                    st.undo_stack.clear()  # an undo would apply to another segment's Gaussians
                    st.redo_stack.clear()
                self._segment = k
        if st.gaussians is not None and st.gaussians_version != self._uploaded_version:
            self.splats.set_gaussians(st.gaussians, st.selection)
            self._uploaded_version = st.gaussians_version

    def model_time(self) -> float:
        """The time the shown Gaussians are evaluated at: the clip time, or for a segmented run
        the owning segment's local time."""
        timeline = self.source.segments
        return self.state.time if timeline is None else timeline.local_time(self.state.time)

    # ---- the 3D view ----------------------------------------------------------------------------
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

    def _view_key(self, cam: Camera) -> tuple:
        """Everything the 3D image depends on: when it is unchanged the last image stands."""
        st = self.state
        return (cam.K.tobytes(), cam.c2w.tobytes(), cam.width, cam.height, round(st.time, 9), st.gaussians_version,
                st.splat_mode, st.debug_mode, tuple(st.background), self.scalar_version, st.show_frusta,
                st.show_trajectories, id(st.trajectories), tuple(id(t) for t in st.trajectories),
                st.selected_trajectory, st.previewing, st.preview_alpha)

    def render_view(self, width: int, height: int, *, wait_sort: bool = False) -> moderngl.Texture | None:
        """Render splats + overlays at the current camera and time into the display texture
        (adaptive resolution: smaller while the view changes, full size once it rests, nothing
        new while it is unchanged). ``display_camera`` is the full-size view camera (viewport
        pixels), ``render_camera`` the one the image was drawn with (``wait_sort``: full size
        with the exact depth order, for tests and screenshots)."""
        st = self.state
        self._sync_model()  # the frame may have changed since the frame began (timeline panel)
        if st.gaussians is None:
            return None
        cam = self.view_camera(width, height)
        self.display_camera = cam
        tr = self.source.training
        training = tr is not None and tr.state in ("setup", "running")
        # live training shares the CPU: the 3D view then rests at a reduced size
        max_scale = TRAINING_RENDER_SCALE if training and not wait_sort else 1.0
        if max_scale != self.adaptive.max_scale:
            self.adaptive.max_scale = max_scale
            self.adaptive.invalidate()
        key = self._view_key(cam)
        self.adaptive.splats = st.gaussians.n
        if wait_sort:
            self.adaptive.last_key = key
            scale, self.adaptive.fraction = 1.0, 1.0
        else:
            scale = self.adaptive.plan(key)
        if scale is None and self.splats.display_texture is not None:
            return self.splats.display_texture
        if scale is None:  # nothing drawn yet: everything at full size
            scale, self.adaptive.fraction = 1.0, 1.0
        rcam = cam if scale >= 1.0 else cam.resized(max(1, int(round(cam.width * scale))),
                                                    max(1, int(round(cam.height * scale))))
        self.render_camera = rcam
        if st.splat_mode == "speed" and st.gaussians.n:
            speed = st.gaussians.speed_at(self.model_time())
            moving = speed[speed > 0]
            self.heat_scale = float(np.percentile(moving, 99)) if moving.size else 1.0
        t_model = self.model_time()
        stats = self.splats.render(rcam, t_model, mode=st.splat_mode, heat_scale=self.heat_scale, wait_sort=wait_sort,
                                   fraction=self.adaptive.fraction)
        self.adaptive.done(scale, stats.draw_ms, self.splats.order_matches(rcam, t_model), stats.fraction)
        self._draw_ms += stats.draw_ms
        self.depth_range = self._depth_range(rcam)
        mode = st.debug_mode
        if mode == "blur" and self.blur_stale:
            if self.adaptive.final:  # the view rests: recompute for it
                from app.panels.debug import compute_blur

                compute_blur(self)
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
        """Pose, intrinsics, time and model of the current full-size view (what a blur map is
        valid for)."""
        cam = self.display_camera
        if cam is None:
            return None
        st = self.state
        return (cam.c2w.tobytes(), cam.K.tobytes(), round(st.time, 9), st.gaussians_version)

    @property
    def blur_stale(self) -> bool:
        return self.blur_key is None or self.blur_key != self.view_signature()

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
        key = (idx, self.state.frame)
        if getattr(self, "_mask_key", None) == key:
            return
        self._mask_key = key
        names = [] if idx is None else [str(idx), str(scene.cameras[idx].name)]
        v = next((k for k, c in enumerate(ids) if c in names), None)
        if masks is None or v is None or self.state.frame not in frames:
            self.mask_note = ("no masks in this run (RUN/init_*/masks.npz)" if masks is None else
                              f"snap to a masked camera ({', '.join(ids)}) at a masked frame")
            self.splats.set_scalar_map(np.zeros((1, 1), np.float32))
        else:
            self.mask_note = ""
            self.splats.set_scalar_map(masks[v, frames.index(self.state.frame)].astype(np.float32))
        self.scalar_version += 1

    def _draw_legend(self, x0: float, y0: float, w: float, h: float) -> None:
        """The colour bar of the current heatmap over the bottom left of the 3D image."""
        from app.legends import legend

        lg = legend(self)
        if lg is None:
            return
        draw = imgui.get_window_draw_list()
        line = imgui.get_text_line_height()
        bw = min(320.0, w - 20.0)
        bx, by = x0 + 10.0, y0 + h - 10.0 - 14.0 - 2.2 * line - (line if lg.note else 0.0)
        draw.add_rect_filled(imgui.ImVec2(bx - 6, by - line - 6), imgui.ImVec2(bx + bw + 6, y0 + h - 4),
                             imgui.get_color_u32(imgui.ImVec4(0.0, 0.0, 0.0, 0.65)), 4.0)
        draw.add_text(imgui.ImVec2(bx, by - line - 2), imgui.get_color_u32(imgui.ImVec4(1, 1, 1, 1)), lg.title)
        self.item_rects["legend_bar"] = (bx, by + 2, bx + bw, by + 14)
        n = 32
        cols = lg.colors(n)
        for k in range(n):
            c = imgui.get_color_u32(imgui.ImVec4(*cols[k], 1.0))
            draw.add_rect_filled(imgui.ImVec2(bx + bw * k / n, by + 2), imgui.ImVec2(bx + bw * (k + 1) / n + 0.5, by + 14), c)
        if lg.kind != "swatch":
            white = imgui.get_color_u32(imgui.ImVec4(1, 1, 1, 1))
            hi = f"{lg.hi:.3g}"
            draw.add_text(imgui.ImVec2(bx, by + 16), white, f"{lg.lo:.3g}")
            draw.add_text(imgui.ImVec2(bx + bw - imgui.calc_text_size(hi).x, by + 16), white, hi)
        if lg.note:
            draw.add_text(imgui.ImVec2(bx, by + 16 + line), imgui.get_color_u32(imgui.ImVec4(1.0, 0.75, 0.3, 1)), lg.note)

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
        if tex is not None:
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
        else:
            imgui.text_wrapped(self._no_model_text())

    def _no_model_text(self) -> str:
        tr = self.source.training
        if tr is not None and tr.state == "failed":
            return f"training failed: {tr.error}"
        if tr is not None:
            return f"preparing the model ({tr.state}): {tr.setup_status or 'starting'} ..."
        return "no model loaded (File > Open a run folder or a model)"

    def is_idle(self) -> bool:
        """Nothing would change without input: no playback, training or restore work, and the
        3D view rests at full size (the window loop may then sleep until an event)."""
        st, src = self.state, self.source
        if st.playing or (st.gaussians is not None and not self.adaptive.final):
            return False
        if src.training is not None and src.training.state in ("setup", "running"):
            return False
        if src.restore is not None and any(i.status in ("rendering", "queued", "running", "submitted")
                                           for i in src.restore.items):
            return False
        # imgui hands queued input to later frames one event kind at a time (a quick Ctrl+Z arrives
        # as four events in one poll): waiting for the next OS event would leave the chord half-read
        if len(imgui.get_current_context().input_events_queue) > 0:
            return False
        return not imgui.get_io().want_text_input and not any(imgui.get_io().mouse_down)

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
    def _screen_positions(self) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) pixel positions in the viewport image and (N,) bool 'visible now' mask."""
        g, cam = self.state.gaussians, self.display_camera
        if g is None or cam is None:
            return np.zeros((0, 2)), np.zeros(0, bool)
        t = self.model_time()
        uv, z = cam.project(g.means_at(t))
        from fixer4d.render.constants import ALPHA_MIN, NEAR_PLANE

        live = (z > NEAR_PLANE) & (g.opacity_at(t) >= ALPHA_MIN) & np.all(np.isfinite(uv), axis=1)
        return uv, live

    def select_box(self, x0: float, y0: float, x1: float, y1: float, add: bool = False) -> int:
        """Select the Gaussians whose centre at the current time projects inside the box
        (viewport pixels). Returns the selection size."""
        uv, live = self._screen_positions()
        lo, hi = np.minimum([x0, y0], [x1, y1]), np.maximum([x0, y0], [x1, y1])
        with np.errstate(invalid="ignore"):
            inside = live & np.all((uv >= lo) & (uv <= hi), axis=1)
        return self._select(inside, add)

    def select_brush(self, x: float, y: float, radius: float, add: bool = True) -> int:
        uv, live = self._screen_positions()
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

    # ---- files ------------------------------------------------------------------------------------
    @property
    def output_dir(self) -> Path:
        """Where relative paths the user types resolve: the run folder, the shown model's
        folder, else the session folder (never the working directory)."""
        src = self.source
        if src.run_dir is not None:
            return Path(src.run_dir)
        if src.model_path is not None:
            return Path(src.model_path).parent
        if self.session_path is not None:
            return Path(self.session_path).parent
        from app.main import _config_dir

        return _config_dir()

    def output_path(self, text: str) -> Path:
        from app.files import resolve_output

        return resolve_output(text, self.output_dir)

    def model_versions(self) -> list[Path]:
        """The model files of the open run folder (or of the shown model's folder)."""
        from app.files import model_versions

        folder = self.source.run_dir or (None if self.source.model_path is None else Path(self.source.model_path).parent)
        return [] if folder is None else model_versions(Path(folder))

    def save_model(self, path: Path) -> Path:
        """Write the displayed Gaussians (edits included) to ``path`` (.ply or .npz)."""
        from fixer4d.model.io import save_model

        if self.state.gaussians is None:
            raise ValueError("no model to save")
        return save_model(self.state.gaussians.to_model(), path)

    def save_edited_model(self) -> Path | None:
        """Save the displayed (edited) Gaussians as a new model version next to the shown one:
        RUN/model_edit_<k>.ply, k = 1 + the highest existing (the session folder for a live
        scene; a segmented run: the shown segment's folder, app.segments.segment_model). It
        becomes the shown version, so the run reopens with it. Returns the path."""
        from app.files import next_edit_path

        g = self.state.gaussians
        if g is None:
            self.state.status = "no model to save"
            return None
        timeline = self.source.segments
        if timeline is not None and self._segment is not None:
            path = self.save_model(next_edit_path(timeline.paths[self._segment].parent))
            timeline.paths[self._segment] = path
            self.state.status = f"saved {path} ({g.n} Gaussians; segment {self._segment} opens with it)"
            self.notifications.info("file", self.state.status)
            return path
        path = self.save_model(next_edit_path(self.output_dir))
        self.source.model_path = path
        self.source.label = str(path)
        self.state.model_version = path.name
        self._save_session()
        self.state.status = f"saved {path} ({g.n} Gaussians)"
        self.notifications.info("file", self.state.status)
        return path

    def open_version(self, path: Path) -> str:
        """Show another model file of the same run (keeps camera, time and trajectories; edits
        of the previous version can no longer be undone)."""
        from app.gaussians import GaussianArrays
        from fixer4d.model.io import load_model

        g = GaussianArrays.from_model(load_model(path))
        st = self.state
        st.set_gaussians(g)
        st.undo_stack.clear()
        st.redo_stack.clear()
        self.source.model_path = Path(path)
        self.source.label = str(path)
        st.model_version = Path(path).name
        self._save_session()
        return f"opened {path} ({g.n} Gaussians)"

    def open_path(self, text: str) -> str:
        """File > Open: a run folder, a model file (a model of the open run switches the
        version), or a scene (folder, spec .json, bundled name such as "demo": trained live);
        anything but a version replaces the source, with its own session."""
        from app.files import is_model_file, is_run_folder, resolve_input
        from app.main import open_source
        from fixer4d.errors import InputError

        from app.files import remember_recent
        from app.main import _config_dir

        try:
            path = resolve_input(text, self.output_dir)
        except InputError:
            if Path(text).expanduser().is_absolute() or "/" in text:
                raise
            path = None  # a bundled scene name ("demo"): trained live
        if path is not None and self.source.run_dir is not None and path.is_file() \
                and path.parent == Path(self.source.run_dir) and is_model_file(path):
            return self.open_version(path)
        if path is not None and not (is_run_folder(path) or (path.is_file() and is_model_file(path)) or path.is_dir()
                                     or path.suffix == ".json"):
            raise InputError(f"{path}: not a run folder (with config.json), a model file (.ply / .npz) or a scene")
        src, g, session_dir = open_source(text if path is None else str(path))
        self.switch_source(src, g, session_dir)
        remember_recent(_config_dir(), text if path is None else str(path))
        return f"opened {src.label}"

    def switch_source(self, src: ViewerSource, gaussians: Any, session_dir: Path) -> None:
        """Replace what the viewer shows: the current session is saved and its background work
        stopped; the new source's state starts fresh or from its own saved session."""
        from app.main import initial_state

        self._save_session()
        old = self.source
        if old.training is not None:
            old.training.stop()
        if old.restore is not None:
            old.restore.shutdown()
        state = initial_state(src, gaussians)
        home = ViewCamera.from_dict(state.view.to_dict())
        if self.session_path is not None:
            session_dir.mkdir(parents=True, exist_ok=True)
            self.session_path = session_dir / "session.json"
            try:
                state.load_session(self.session_path)
            except Exception as exc:  # a bad session must not stop the open
                self.report_error("session", exc)
            if src.model_path is not None:
                state.model_version = src.model_path.name
        self.state, self.source = state, src
        self.home_view = home
        self._trajectory_cache.clear()
        self._torch_model = None
        self._uploaded_version = -1
        self._segment = None
        self.adaptive.invalidate()
        for key in ("_compare_ui", "_debug_ui"):
            self.__dict__.pop(key, None)
        if src.training is not None:
            src.training.start()

    def _save_session(self) -> None:
        if self.session_path is not None:
            Path(self.session_path).parent.mkdir(parents=True, exist_ok=True)
            self.state.save_session(self.session_path)

    # ---- trajectories and torch renders ----------------------------------------------------------
    def trajectory_cameras(self, spec: TrajectorySpec) -> list[Camera]:
        """The cameras of a trajectory spec (pair + A, or keyframes), reversed if asked."""
        from app.trajectories import build_cameras

        hit = self._trajectory_cache.get(id(spec))
        if hit is None or hit[0] is not spec:
            scene = self.source.scene
            hit = (spec, build_cameras(spec, [] if scene is None else scene.train_cameras))
            if len(self._trajectory_cache) > TRAJECTORY_CACHE_SIZE:
                self._trajectory_cache.clear()
            self._trajectory_cache[id(spec)] = hit  # specs are immutable: an edit makes a new one
        return hit[1]

    def torch_model(self) -> Any:
        """A ``SpacetimeGaussians`` of the displayed Gaussians (cached per edit)."""
        st = self.state
        if self._torch_model is None or self._torch_model[0] != st.gaussians_version:
            self._torch_model = (st.gaussians_version, None if st.gaussians is None else st.gaussians.to_model())
        return self._torch_model[1]

    def stitched_model(self) -> Any:
        """A segmented run's ``SegmentedModel`` of every segment's torch model (the shown
        segment with its edits), cached per edit and shown segment."""
        timeline, st = self.source.segments, self.state
        key = ("segments", st.gaussians_version, self._segment)
        if self._torch_model is None or self._torch_model[0] != key:
            arrays = [st.gaussians if k == self._segment and st.gaussians is not None else g
                      for k, g in enumerate(timeline.arrays)]
            self._torch_model = (key, timeline.stitched([g.to_model() for g in arrays]))
        return self._torch_model[1]

    def model_render_fn(self) -> Callable[[Camera, float], dict[str, np.ndarray]]:
        """``fn(camera, t) -> {"rgb", "depth", "alpha"}`` with the torch rasterizer on the
        displayed Gaussians (the same set the GL view shows, edits included) at clip time t (a
        segmented run: the segment that owns t, at its local time)."""
        import torch

        from fixer4d.render.api import render

        if self.source.segments is not None:
            stitched = self.stitched_model()
            snap = lambda t, center: stitched.at(t, camera_center=center)  # noqa: E731
        else:
            model = self.torch_model()
            snap = model.snapshot
        background = tuple(self.state.background)
        backend = self.source.render_backend

        def fn(camera: Camera, t: float) -> dict[str, np.ndarray]:
            with torch.no_grad():
                out = render(snap(t, camera.center), camera, background=background, backend=backend)
            return {"rgb": out.rgb.clamp(0, 1).numpy().astype(np.float32), "depth": out.depth.numpy().astype(np.float32),
                    "alpha": out.alpha.numpy().astype(np.float32)}
        return fn

    def image_texture(self, name: str, image: np.ndarray) -> moderngl.Texture:
        """Upload an (H, W, 3) float [0,1] or uint8 image as a named texture for imgui.image
        (row 0 at the top; show with uv0=(0,0), uv1=(1,1)). The same array object as last time
        is not uploaded again (panels pass their cached images every frame)."""
        tex = self.images.get(name)
        if tex is not None and self._image_sources.get(name) is image:
            return tex
        self._image_sources[name] = image  # held, so its id cannot be reused by a new array
        img = np.asarray(image)
        if img.dtype != np.uint8:
            img = (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        img = np.ascontiguousarray(img[..., :3])
        h, w = img.shape[:2]
        tex = self.images.get(name)
        if tex is None or tex.size != (w, h):
            if tex is not None:
                tex.release()
            tex = self.ctx.texture((w, h), 3, alignment=1)
            self.images[name] = tex
        tex.write(img.tobytes())
        return tex

    def record_item(self, name: str) -> None:
        """Remember the screen rectangle of the widget just submitted under ``name``."""
        lo, hi = imgui.get_item_rect_min(), imgui.get_item_rect_max()
        self.item_rects[name] = (lo.x, lo.y, hi.x, hi.y)

    # ---- menu and keys ----------------------------------------------------------------------------
    def _menu(self) -> None:
        from app.panels import files

        if not imgui.begin_main_menu_bar():
            return
        files.draw_menu(self)
        if imgui.begin_menu("Edit"):
            if imgui.menu_item("Undo", "Ctrl+Z", False, bool(self.state.undo_stack))[0]:
                self.state.undo()
            if imgui.menu_item("Redo", "Ctrl+Y", False, bool(self.state.redo_stack))[0]:
                self.state.redo()
            imgui.end_menu()
        imgui.text_disabled(f"  {self.source.label}   {self.frame_ms:.1f} ms/frame   {self.state.status}")
        imgui.end_main_menu_bar()

    def _shortcuts(self) -> None:
        io = imgui.get_io()
        if io.want_text_input:
            return
        if io.key_ctrl and imgui.is_key_pressed(imgui.Key.z, False):
            self.state.undo()
        if io.key_ctrl and imgui.is_key_pressed(imgui.Key.y, False):
            self.state.redo()
        if io.key_ctrl and imgui.is_key_pressed(imgui.Key.o, False):
            from app.panels import files

            files.ask(self, "open")
        if io.key_ctrl and imgui.is_key_pressed(imgui.Key.s, False) and self.state.gaussians is not None:
            self.save_edited_model()
        if imgui.is_key_pressed(imgui.Key.space, False) and not io.key_ctrl:
            self.state.playing = not self.state.playing

    # ---- lifetime ---------------------------------------------------------------------------------
    def screenshot(self, fbo: moderngl.Framebuffer) -> np.ndarray:
        """(H, W, 3) uint8 of the whole window as last drawn into ``fbo``."""
        w, h = fbo.size
        return np.frombuffer(fbo.read(components=3, alignment=1), np.uint8).reshape(h, w, 3)[::-1].copy()

    def close(self, platform_shutdown: Callable[[], None] | None = None) -> None:
        """Save the session and the imgui layout, stop background work, free GL objects
        (``platform_shutdown``: the window backend's, run before the imgui context goes)."""
        self._save_session()
        if self._ini_path is not None:
            imgui.save_ini_settings_to_disk(self._ini_path)
        if self.source.training is not None:
            self.source.training.stop()
        if self.source.restore is not None:
            self.source.restore.shutdown()
        imgui.backends.opengl3_shutdown()
        if platform_shutdown is not None:
            platform_shutdown()
        implot.destroy_context(self.implot_ctx)
        imgui.destroy_context(self.imgui_ctx)
        self.splats.release()
        self.overlays.release()
        for tex in self.images.values():
            tex.release()
