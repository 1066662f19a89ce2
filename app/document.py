"""The document: what is open (a run, a model version, a scene), saving it, and not losing it.

``Document`` is a part of ``app.viewer.Viewer``: File > Open, model versions, "save as new
model version", the session file, the autosave of unsaved edits (``RUN/viewer/autosave.json``:
the indices of the model file's Gaussians the edits kept, written a moment after each edit and
offered back at the next launch) and the close/quit decision (unsaved edits: save, discard or
cancel).
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from app.camera_control import ViewCamera
from fixer4d.atomic import write_json
from fixer4d.errors import InputError

# Seconds an edit rests before the autosave is written: a burst of edits (brush strokes, undo
# runs) costs one write; a crash loses at most this much.
AUTOSAVE_DELAY_S = 1.0
AUTOSAVE_NAME = "autosave.json"


class Document:
    """Open / save / autosave / quit (mixed into ``Viewer``)."""

    # ---- where files go -------------------------------------------------------------------------
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
        return Path(self.services.config_dir)

    def output_path(self, text: str) -> Path:
        from app.files import resolve_output

        return resolve_output(text, self.output_dir)

    @property
    def autosave_path(self) -> Path | None:
        """RUN/viewer/autosave.json (next to the session), or None without a session."""
        return None if self.session_path is None else Path(self.session_path).parent / AUTOSAVE_NAME

    def model_versions(self) -> list[Path]:
        """The model files of the open run folder (or of the shown model's folder)."""
        from app.files import model_versions

        folder = self.source.run_dir or (None if self.source.model_path is None else Path(self.source.model_path).parent)
        return [] if folder is None else model_versions(Path(folder))

    # ---- saving ---------------------------------------------------------------------------------
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

        g, st = self.state.gaussians, self.state
        if g is None:
            st.status = "no model to save"
            return None
        timeline = self.source.segments
        if timeline is not None and self._segment is not None:
            path = self.save_model(next_edit_path(timeline.paths[self._segment].parent))
            timeline.paths[self._segment] = path
            st.mark_saved(None)
            st.status = f"saved {path} ({g.n} Gaussians; segment {self._segment} opens with it)"
        else:
            path = self.save_model(next_edit_path(self.output_dir))
            self.source.model_path = path
            self.source.label = str(path)
            st.model_version = path.name
            st.mark_saved(path)
            self._save_session()
            st.status = f"saved {path} ({g.n} Gaussians)"
        self.notifications.info("file", st.status)
        self.remove_autosave()
        return path

    def _save_session(self) -> None:
        if self.session_path is not None:
            Path(self.session_path).parent.mkdir(parents=True, exist_ok=True)
            self.state.save_session(self.session_path)

    # ---- autosave -------------------------------------------------------------------------------
    def autosave_tick(self) -> None:
        """Write (or remove) the autosave once the shown Gaussians rested AUTOSAVE_DELAY_S after
        a change: unsaved edits on a model file are kept on disk, a saved or undone state leaves
        no autosave behind."""
        st, path = self.state, self.autosave_path
        if path is None or self.source.segments is not None or self.autosave_offer is not None:
            return
        mark = (id(st.gaussians), st.origin_base)
        if mark != self._autosave_mark:
            self._autosave_mark, self._autosave_changed = mark, time.monotonic()
            self._autosave_done = False
        if self._autosave_done or time.monotonic() - self._autosave_changed < AUTOSAVE_DELAY_S:
            return
        self._autosave_done = True
        data = st.autosave_dict() if st.unsaved else None
        if data is None:
            self.remove_autosave()
        else:
            data["saved_at"] = time.strftime("%Y-%m-%d %H:%M:%S")
            path.parent.mkdir(parents=True, exist_ok=True)
            write_json(path, data)

    def remove_autosave(self) -> None:
        path = self.autosave_path
        if path is not None and path.is_file():
            path.unlink()

    def check_autosave(self) -> None:
        """At launch (or a new source): an autosave made on the model shown now is offered back
        (``autosave_offer``; the prompt is ``app.panels.prompts``)."""
        self.autosave_offer = None
        path = self.autosave_path
        if path is None or not path.is_file():
            return
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            self.report_error("autosave", InputError(f"{path}: unreadable autosave ({exc}); it was left in place"))
            return
        st = self.state
        if data.get("base") == st.origin_base and int(data.get("base_count", -1)) == st.origin_count:
            self.autosave_offer = data

    def restore_autosave(self) -> int:
        """Apply the offered autosave (one undoable edit); returns the Gaussians it removed."""
        data, self.autosave_offer = self.autosave_offer, None
        removed = self.state.restore_autosave(data) if data is not None else 0
        self.state.status = f"restored the autosaved edits ({removed} Gaussians removed): save them with Ctrl+S"
        return removed

    def discard_autosave(self) -> None:
        self.autosave_offer = None
        self.remove_autosave()

    # ---- closing --------------------------------------------------------------------------------
    def request_close(self) -> bool:
        """The window's close button or File > Quit: True when the app may close now; with
        unsaved edits, False and the save / discard / cancel prompt opens (its choice sets
        ``quit_confirmed``)."""
        if not self.state.unsaved:
            self.quit_confirmed = True
            return True
        self.close_prompt = True
        return False

    def answer_close(self, choice: str) -> None:
        """The close prompt's answer: "save" (a new model version, then quit), "discard" (quit
        without saving; the autosave goes too) or "cancel" (keep working)."""
        self.close_prompt = False
        if choice == "save":
            if self.save_edited_model() is not None:
                self.quit_confirmed = True
        elif choice == "discard":
            self.remove_autosave()
            self._autosave_done = True
            self.state.saved_gaussians = self.state.gaussians  # nothing left to keep
            self.quit_confirmed = True

    # ---- opening --------------------------------------------------------------------------------
    def open_version(self, path: Path) -> str:
        """Show another model file of the same run (keeps camera, time and trajectories; edits
        of the previous version can no longer be undone)."""
        from app.gaussians import GaussianArrays
        from fixer4d.model.io import load_model

        g = GaussianArrays.from_model(load_model(path))
        st = self.state
        st.set_gaussians(g, base=path)
        st.undo_stack.clear()
        st.redo_stack.clear()
        self.source.model_path = Path(path)
        self.source.label = str(path)
        st.model_version = Path(path).name
        self._save_session()
        return f"opened {path} ({g.n} Gaussians)"

    def open_path(self, text: str) -> str:
        """File > Open: a run folder, a model file (a model of the open run switches the
        version), or a scene (folder, a capture folder of videos, spec .json, bundled name such
        as "demo": trained live); anything but a version replaces the source, with its own
        session."""
        from app.files import is_model_file, is_run_folder, remember_recent, resolve_input
        from fixer4d.scene.synthetic import is_builtin_name

        text = text.strip()
        try:  # a bundled scene name ("demo") names the scene, as everywhere in fixer4d
            path = None if is_builtin_name(text) else resolve_input(text, self.output_dir)
        except InputError:
            if Path(text).expanduser().is_absolute() or "/" in text:
                raise
            path = None  # not a file here: maybe a scene name load_scene knows
        if path is not None and self.source.run_dir is not None and path.is_file() \
                and path.parent == Path(self.source.run_dir) and is_model_file(path):
            return self.open_version(path)
        if path is not None and not (is_run_folder(path) or (path.is_file() and is_model_file(path)) or path.is_dir()
                                     or path.suffix == ".json"):
            raise InputError(f"{path}: not a run folder (with config.json), a model file (.ply / .npz), a scene "
                             "or a folder of videos")
        src, g, session_dir = self.services.open_source(text if path is None else str(path))
        self.switch_source(src, g, session_dir)
        remember_recent(Path(self.services.config_dir), text if path is None else str(path))
        return src.notice or f"opened {src.label}"

    def switch_source(self, src: Any, gaussians: Any, session_dir: Path) -> None:
        """Replace what the viewer shows: the current session is saved and its background work
        stopped; the new source's state starts fresh or from its own saved session."""
        self._save_session()
        old = self.source
        if old.training is not None:
            old.training.stop()
        if old.restore is not None:
            old.restore.shutdown()
        state = self.services.initial_state(src, gaussians)
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
        state.choose_background(state.background_mode, src.background)
        self.state, self.source = state, src
        self.home_view = home
        self._trajectory_cache.clear()
        self._uploaded_version = -1
        self._segment = None
        self.adaptive.invalidate()
        self.frame_cache.clear()
        for key in ("_compare_ui", "_debug_ui", "_video_ui"):
            self.__dict__.pop(key, None)
        self.check_autosave()
        self.show_notice(src)
        if src.training is not None:
            src.training.start()

    def show_notice(self, src: Any) -> None:
        """Say how the source was resolved when that needs saying (``ViewerSource.notice``): in
        the status line and the notifications."""
        if src.notice:
            self.state.status = src.notice
            self.notifications.info("open", src.notice)
