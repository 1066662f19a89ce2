"""The viewer core, independent of the window system: one ``Viewer.frame()`` builds the imgui UI
(docked panels over a 3D viewport), draws the splats and overlays, and renders everything into
a framebuffer. ``app.main`` drives it from a glfw window; tests drive it headless on an EGL
context, feeding input through imgui's io and key presses through ``key_event``.

The viewer is the shell; its parts live in their own modules and are mixed in: the viewport
(input, selection: ``app.viewport``), the 3D view (render, overlays, legends: ``app.view3d``)
and the document (open, save, versions, autosave, quit: ``app.document``). Models, renders
and restorers reach it through a ``ViewerSource`` and injected ``ViewerServices``
(``app.viewer_source``), so the UI never builds a model or a restorer itself.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

import moderngl
import numpy as np
from imgui_bundle import imgui, implot

from app.adaptive import FRAME_TARGET_MS, MAX_BUDGET_MS, MIN_BUDGET_MS, AdaptiveResolution
from app.camera_control import ViewCamera
from app.document import Document
from app.frame_cache import FrameCache
from app.gl.overlays import OverlayRenderer
from app.gl.splats import SplatRenderer
from app.gl.sync import finish
from app.notifications import Notifications
from app.panels._layout import guard, panel
from app.shortcuts import FIRST_LAUNCH_HINT, SHORTCUTS
from app.state import AppState, TrajectorySpec
from app.view3d import View3D
from app.viewer_source import GaussiansRenderFn, ViewerServices, ViewerSource
from app.viewport import Viewport
from fixer4d.geometry.camera import Camera

__all__ = ["Viewer", "ViewerSource", "ViewerServices", "INTERACTION_S", "SHORTCUTS"]

# Input within this many seconds counts as "the user is interacting" (app.main paces the UI by it).
INTERACTION_S = 1.5
# While live training runs and nobody interacts, a published model is taken at most this often
# (s): each new model is re-uploaded, re-sorted and redrawn (100-400 ms of software GL for 30k
# splats), CPU that the trainer on the same cores loses. Interacting, every published model is
# taken (at most one a second, session.PUBLISH_MIN_S).
MODEL_REFRESH_UNATTENDED_S = 5.0
# Built trajectories kept (each a list of cameras); cleared whole when exceeded.
TRAJECTORY_CACHE_SIZE = 256

class Viewer(Viewport, View3D, Document):
    """The application, minus the window. Call ``frame(dt, fbo)`` once per frame."""

    def __init__(self, ctx: moderngl.Context, state: AppState, source: ViewerSource, *,
                 services: ViewerServices | None = None, ini_path: Path | None = None,
                 session_path: Path | None = None, platform_init: Callable[[], None] | None = None,
                 first_launch: bool = False) -> None:
        self.ctx = ctx
        self.state = state
        self.source = source
        self.services = services if services is not None else ViewerServices()
        self.session_path = session_path
        self._init_imgui(ini_path, platform_init)
        self.splats = SplatRenderer(ctx)
        self.overlays = OverlayRenderer(ctx)
        self.frame_cache = FrameCache(ctx)
        self._init_view_fields()
        self._init_panel_fields(first_launch)
        from app.panels import PANELS

        self.panels = PANELS
        self.home_view = ViewCamera.from_dict(state.view.to_dict())  # "reset view" returns here
        if session_path is not None:
            try:
                state.load_session(session_path)
            except Exception as exc:  # a bad session must not stop the app; say so
                state.status = str(exc)
        state.choose_background(state.background_mode, source.background)
        self.check_autosave()
        self.show_notice(source)

    def _init_imgui(self, ini_path: Path | None, platform_init: Callable[[], None] | None) -> None:
        """The imgui and implot contexts (docking on, layout kept in ``ini_path`` or nowhere), the
        window backend (``platform_init``) and imgui's GL renderer."""
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

    def _init_view_fields(self) -> None:
        """What the 3D view, its tools and the model upload keep between frames."""
        self.use_frame_cache = True
        self.view_mode = "no model"  # which kind of image the 3D view shows (the status line says it)
        self._shown: moderngl.Texture | None = None  # the texture the viewport showed last
        self._last_base: tuple | None = None
        self._last_pose: tuple | None = None  # the view camera's K, pose and size last frame
        self.tool = "navigate"  # navigate | box | brush
        self.select_through = False  # box selection: front surface only unless set
        self._drag_start: tuple[float, float] | None = None
        self._uploaded_version = -1
        self._segment: int | None = None  # a segmented run: the segment whose Gaussians are shown
        self._model_serial = 0
        self._model_taken = -1e9  # time.monotonic() when the last published model was taken
        self._model_step = 0  # the live trainer's step when the shown model was taken
        self.viewport_rect = (0.0, 0.0, 1.0, 1.0)  # screen x, y, w, h of the 3D image
        self.render_camera: Camera | None = None  # the camera of the last 3D image (maybe reduced)
        self.display_camera: Camera | None = None  # the full-size view camera (viewport pixels)
        self.depth_range = (0.1, 10.0)  # near, far of the depth colour map (last render)
        self.scalar_version = 0  # bumped when the blur/undetermined/mask map changes
        self.scalar_key: tuple | None = None  # what that map was computed for (View3D.show_scalar_map)
        self.undetermined_share = 0.0  # share of the view's pixels the undetermined map marks
        self.adaptive = AdaptiveResolution()
        self.last_input = -1e9  # time.monotonic() of the last mouse/keyboard input
        self.heat_scale = 1.0  # speed at the top of the speed heatmap (scene units per clip time)
        self.mask_note = ""  # which cameras/frames carry masks, or why the overlay shows nothing
        self._masks: tuple | None = None  # (path, masks, camera ids, frames) of RUN/init_*/masks.npz
        self.frame_ms = 0.0
        self.frame_times: list[float] = []
        self.ui_ms: float | None = None  # running estimate of a frame's cost besides the splat draw
        self._draw_ms = 0.0  # the splat draw of the current frame
        self._trajectory_cache: dict[int, tuple[TrajectorySpec, list[Camera]]] = {}

    def _init_panel_fields(self, first_launch: bool) -> None:
        """What the panels, notifications, key presses, closing and the window layout keep
        between frames."""
        self.images: dict[str, moderngl.Texture] = {}
        self._image_sources: dict[str, Any] = {}  # the array each named texture holds
        self.panel_errors: dict[str, str] = {}  # panel -> its current error (cleared when it draws again)
        self.notifications = Notifications()
        self._notifications_seen = 0
        self.show_notifications = False
        self.show_help = False
        self.show_report = False  # File > Run report (panels.report)
        self.hint = FIRST_LAUNCH_HINT if first_launch else ""
        self.blur_max = 1.0  # top of the blur map's colour scale (set by the debug panel)
        self._pressed: list[tuple[str, bool]] = []  # key presses not handled yet: (key, ctrl)
        # closing: the unsaved-edits prompt, the decision, the autosave's state
        self.close_prompt = False
        self.quit_confirmed = False
        self.autosave_offer: dict | None = None
        self._autosave_mark: tuple | None = None
        self._autosave_changed = 0.0
        self._autosave_done = True
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
        self.tooltip_shown: str | None = None  # the tooltip text drawn this frame (tests read it)

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
        self.tooltip_shown = None
        self.last_window_rects, self.window_rects = self.window_rects, {}
        self._follow_window_size((io.display_size.x, io.display_size.y))
        if io.mouse_delta.x or io.mouse_delta.y or io.mouse_wheel or any(io.mouse_down) or io.want_text_input:
            self.last_input = time.monotonic()
        with guard(self, "shortcuts"):
            self._shortcuts()
        imgui.dock_space_over_viewport(0, imgui.get_main_viewport(),
                                       imgui.DockNodeFlags_.passthru_central_node.value)
        self._viewport_window()
        with guard(self, "menu"):  # after the 3D view: the status line says what this frame shows
            self._menu()
        for name, draw in self.panels:
            draw(self)  # each panel guards its own body (panels._layout.panel)
        self._notifications_window()
        from app.panels import files, help, prompts, report

        with guard(self, "file"):
            files.draw_dialog(self)
        with guard(self, "prompts"):
            prompts.draw(self)
        with guard(self, "help"):
            help.draw(self)
        with guard(self, "report"):
            report.draw(self)
        with guard(self, "autosave"):
            self.autosave_tick()
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
        from app.panels._layout import error_text, tip

        notes = self.notifications
        if notes.serial != self._notifications_seen:
            last = notes.items()[-1:]
            if last and last[0].level == "error":
                self.show_notifications = True  # an error opens the window
            self._notifications_seen = notes.serial
        if not self.show_notifications:
            return
        # over the bottom of the Compare panel's image: its controls (top) stay usable
        with panel(self, "notifications", "Notifications", 300, 765, 800, 130, front=True) as expanded:
            if not expanded:
                return
            if imgui.small_button("clear"):
                notes.clear()
                self.panel_errors.clear()
            tip("empty this list (the log file keeps every message)", self)
            imgui.same_line()
            if imgui.small_button("hide"):
                self.show_notifications = False
            tip("hide this window (a new error opens it again)", self)
            for msg in reversed(notes.items()):
                stamp = time.strftime("%H:%M:%S", time.localtime(msg.when))
                line = f"{stamp}  [{msg.source}]  {msg.text}"
                if msg.level == "error":
                    error_text(line)
                else:
                    imgui.text_wrapped(line)

    # ---- models ---------------------------------------------------------------------------------
    def _poll_models(self) -> None:
        tr = self.source.training
        now = time.monotonic()
        waiting = tr is not None and self.state.gaussians is not None and tr.state == "running" \
            and now - self.last_input >= INTERACTION_S and now - self._model_taken < MODEL_REFRESH_UNATTENDED_S
        if tr is not None and not waiting:
            got = tr.models.take(self._model_serial)
            if got is not None:
                self._model_serial, g = got
                self._model_taken, self._model_step = now, tr.step
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
                    unsaved = st.unsaved
                    st.set_gaussians(timeline.arrays[k])
                    if unsaved:  # an edit of another segment is still unsaved
                        st.saved_gaussians = None
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

    def gaussians_render_fn(self, background: tuple[float, float, float] | None = None) -> GaussiansRenderFn:
        """``fn(camera, t) -> {"rgb", "depth", "alpha"}``: torch renders of the displayed
        Gaussians (the set the GL view shows, edits included) at clip time t over ``background``
        (None: the view's), from the injected ``services.render``."""
        st, src = self.state, self.source
        key = (st.gaussians_version, self._segment, id(src))
        return self.services.render(key, st.gaussians, src.segments, self._segment,
                                    tuple(st.background if background is None else background), src.render_backend)

    def targets_background(self) -> tuple[float, float, float]:
        """What restorations render over: the run's background (as its pseudo-targets were made),
        else the view's."""
        return tuple(self.source.background if self.source.background is not None else self.state.background)

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
        from app.panels import files, help, status

        if not imgui.begin_main_menu_bar():
            return
        files.draw_menu(self)
        if imgui.begin_menu("Edit"):
            if imgui.menu_item("Undo", "Ctrl+Z", False, bool(self.state.undo_stack))[0]:
                self.state.undo()
            if imgui.menu_item("Redo", "Ctrl+Y", False, bool(self.state.redo_stack))[0]:
                self.state.redo()
            imgui.end_menu()
        help.draw_menu(self)
        status.draw(self)
        imgui.end_main_menu_bar()

    def key_event(self, key: str, down: bool, ctrl: bool = False) -> None:
        """A key went down or up (the window's key callback, or a test): a press is kept until
        the next frame handles it, so a press of any length (1 ms included) runs its shortcut.
        ``key``: a lower-case letter or "space"."""
        self.last_input = time.monotonic()
        if down:
            self._pressed.append((key, bool(ctrl)))

    def _shortcuts(self) -> None:
        pressed, self._pressed = self._pressed, []
        if imgui.get_io().want_text_input:  # typing: the text field has the keys
            return
        for key, ctrl in pressed:
            action = SHORTCUTS.get((key, ctrl), (None, ""))[0]
            if action is not None:
                self.run_shortcut(action)

    def run_shortcut(self, action: str) -> None:
        st = self.state
        self.hint = ""
        if action == "undo":
            st.undo()
        elif action == "redo":
            st.redo()
        elif action == "open":
            from app.panels import files

            files.ask(self, "open")
        elif action == "save" and st.gaussians is not None:
            self.save_edited_model()
        elif action == "quit":
            self.request_close()
        elif action == "play":
            st.playing = not st.playing

    def is_idle(self) -> bool:
        """Nothing would change without input: no playback, training or restore work, and the
        3D view rests at full size (the window loop may then sleep until an event)."""
        st, src = self.state, self.source
        if st.playing or (st.gaussians is not None and not self.adaptive.final) or self._pressed:
            return False
        if src.training is not None and src.training.state in ("setup", "running"):
            return False
        if src.restore is not None and any(i.status in ("rendering", "queued", "running", "submitted")
                                           for i in src.restore.items):
            return False
        video = self.__dict__.get("_video_ui", {}).get("job")
        if video is not None and video.running:
            return False
        if not self._autosave_done:
            return False
        # imgui hands queued input to later frames one event kind at a time (a quick Ctrl+Z arrives
        # as four events in one poll): waiting for the next OS event would leave the chord half-read
        if len(imgui.get_current_context().input_events_queue) > 0:
            return False
        return not imgui.get_io().want_text_input and not any(imgui.get_io().mouse_down)

    # ---- lifetime ---------------------------------------------------------------------------------
    def screenshot(self, fbo: moderngl.Framebuffer) -> np.ndarray:
        """(H, W, 3) uint8 of the whole window as last drawn into ``fbo``."""
        w, h = fbo.size
        return np.frombuffer(fbo.read(components=3, alignment=1), np.uint8).reshape(h, w, 3)[::-1].copy()

    def close(self, platform_shutdown: Callable[[], None] | None = None) -> None:
        """Save the session and the imgui layout, stop background work, free GL objects
        (``platform_shutdown``: the window backend's, run before the imgui context goes). Unsaved
        edits stay in the autosave (written now if it was due)."""
        self._save_session()
        try:  # due now, whatever the delay
            self._autosave_mark = (id(self.state.gaussians), self.state.origin_base)
            self._autosave_done, self._autosave_changed = False, -1e9
            self.autosave_tick()
        except Exception as exc:  # closing goes on; the log says why the autosave failed
            self.report_error("autosave", exc)
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
        self.frame_cache.release()
        self.splats.release()
        self.overlays.release()
        for tex in self.images.values():
            tex.release()
