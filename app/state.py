"""AppState: everything the viewer knows, with undo/redo for every edit and session persistence.

No GL and no imgui here, so the editing logic is testable on its own. Panels read and change
the state; every change the user may want to take back goes through ``AppState.apply`` as an
``Edit`` (trajectory add/delete/tune, keyframes, Gaussian deletion and isolation).
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from app.camera_control import ViewCamera
from app.gaussians import GaussianArrays
from fixer4d.atomic import write_json
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera

SESSION_VERSION = 1
# Undo history depth: each Gaussian edit keeps the removed Gaussians, so the stack is bounded.
MAX_UNDO = 100
# What the status line adds to a destructive edit.
UNDO_HINT = "Ctrl+Z undoes it"
# Default number of frames on a new trajectory (the paper's clips are short).
DEFAULT_TRAJECTORY_FRAMES = 16
# What the 3D view shows where no Gaussian lies: black makes holes stand out; "run" is the colour
# the run trained over (``ViewerSource.background``), so the view looks like its renders.
BACKGROUNDS = {"black": (0.0, 0.0, 0.0), "white": (1.0, 1.0, 1.0), "run": None}


@dataclass(frozen=True)
class TrajectorySpec:
    """An editable trajectory: a pair of train cameras (indices into the scene's train cameras)
    with arc amplitude A, or a list of keyframe cameras (custom). Immutable: edits replace it."""

    name: str
    pair: tuple[int, int] | None = None
    amplitude: float = 0.0
    n_frames: int = DEFAULT_TRAJECTORY_FRAMES
    reverse: bool = False
    arc_index: int | None = None
    keyframes: tuple[dict, ...] = ()  # Camera.to_dict() of each key (custom trajectories)
    visible: bool = True

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["pair"] = None if self.pair is None else list(self.pair)
        d["keyframes"] = list(self.keyframes)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "TrajectorySpec":
        pair = d.get("pair")
        return cls(name=str(d["name"]), pair=None if pair is None else (int(pair[0]), int(pair[1])),
                   amplitude=float(d.get("amplitude", 0.0)), n_frames=int(d.get("n_frames", DEFAULT_TRAJECTORY_FRAMES)),
                   reverse=bool(d.get("reverse", False)), arc_index=d.get("arc_index"),
                   keyframes=tuple(d.get("keyframes", ())), visible=bool(d.get("visible", True)))


@dataclass
class Edit:
    """One undoable change: ``do`` and ``undo`` mutate the state; ``label`` shows in the UI. A
    ``destructive`` edit (something removed or replaced) says how to take it back."""

    label: str
    do: Callable[["AppState"], None]
    undo: Callable[["AppState"], None]
    destructive: bool = False


@dataclass
class AppState:
    """The viewer's state. ``gaussians`` is the displayed set; ``selection`` a bool mask over it."""

    view: ViewCamera = field(default_factory=ViewCamera)
    frame: int = 0
    num_frames: int = 1
    fps: float = 30.0
    playing: bool = False
    loop: bool = True
    play_clock: float = 0.0
    trajectories: list[TrajectorySpec] = field(default_factory=list)
    selected_trajectory: int = -1
    preview_alpha: float = 0.5
    previewing: bool = False
    gaussians: GaussianArrays | None = None
    gaussians_version: int = 0
    selection: np.ndarray | None = None
    splat_mode: str = "color"
    debug_mode: str = "color"
    show_frusta: bool = True
    show_trajectories: bool = True
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    background_mode: str = "black"  # a key of BACKGROUNDS; ``background`` is its colour
    undo_stack: list[Edit] = field(default_factory=list)
    redo_stack: list[Edit] = field(default_factory=list)
    status: str = ""
    model_version: str | None = None  # file name of the model shown, within its run folder
    # Where the shown Gaussians come from: their indices (N,) in the model file ``origin_base``
    # (a path, or None for a model without a file) of ``origin_count`` Gaussians. Edits only
    # remove Gaussians, so these indices are the whole edit stack's effect (the autosave).
    origin: np.ndarray | None = None
    origin_base: str | None = None
    origin_count: int = 0
    saved_gaussians: Any = None  # the set last loaded or saved: anything else is unsaved

    # ---- time -------------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """t = f / T (STGS convention)."""
        return self.frame / float(max(self.num_frames, 1))

    def set_frame(self, frame: int) -> None:
        n = max(self.num_frames, 1)
        self.frame = int(frame) % n if self.loop else int(np.clip(frame, 0, n - 1))

    def advance(self, dt: float) -> None:
        """Playback: move ``fps * dt`` frames; stops at the end unless looping."""
        if not self.playing:
            return
        self.play_clock += dt * self.fps
        steps = int(self.play_clock)
        if steps <= 0:
            return
        self.play_clock -= steps
        nxt = self.frame + steps
        if not self.loop and nxt >= self.num_frames:
            self.frame = self.num_frames - 1
            self.playing = False
        else:
            self.set_frame(nxt)

    # ---- undo / redo --------------------------------------------------------------------------
    def apply(self, edit: Edit) -> None:
        edit.do(self)
        self.undo_stack.append(edit)
        del self.undo_stack[:-MAX_UNDO]
        self.redo_stack.clear()
        self.status = f"{edit.label}: {UNDO_HINT}" if edit.destructive else edit.label

    def undo(self) -> bool:
        if not self.undo_stack:
            return False
        edit = self.undo_stack.pop()
        edit.undo(self)
        self.redo_stack.append(edit)
        self.status = f"undo: {edit.label}"
        return True

    def redo(self) -> bool:
        if not self.redo_stack:
            return False
        edit = self.redo_stack.pop()
        edit.do(self)
        self.undo_stack.append(edit)
        self.status = f"redo: {edit.label}"
        return True

    # ---- trajectories -------------------------------------------------------------------------
    def set_trajectories(self, new: list[TrajectorySpec], label: str, selected: int | None = None,
                         destructive: bool = False) -> None:
        """Replace the trajectory list as one undoable edit (``destructive``: it removes or
        replaces trajectories, and the status line says how to undo it)."""
        before, before_sel = list(self.trajectories), self.selected_trajectory
        after = list(new)
        after_sel = self.selected_trajectory if selected is None else selected
        after_sel = min(after_sel, len(after) - 1)

        def do(s: AppState) -> None:
            s.trajectories, s.selected_trajectory = list(after), after_sel

        def undo(s: AppState) -> None:
            s.trajectories, s.selected_trajectory = list(before), before_sel

        self.apply(Edit(label, do, undo, destructive))

    def update_trajectory(self, index: int, label: str, **changes: Any) -> None:
        """Change fields of one trajectory (e.g. amplitude=0.3) as an undoable edit."""
        new = list(self.trajectories)
        new[index] = replace(new[index], **changes)
        self.set_trajectories(new, label, selected=index)

    def add_trajectory(self, spec: TrajectorySpec) -> None:
        self.set_trajectories(self.trajectories + [spec], f"add trajectory {spec.name}",
                              selected=len(self.trajectories))

    def delete_trajectory(self, index: int) -> None:
        name = self.trajectories[index].name
        self.set_trajectories(self.trajectories[:index] + self.trajectories[index + 1:], f"delete trajectory {name}",
                              selected=min(index, len(self.trajectories) - 2), destructive=True)

    def add_keyframe(self, index: int, camera: Camera) -> None:
        """Append the current view as a key of custom trajectory ``index``."""
        spec = self.trajectories[index]
        self.update_trajectory(index, f"add keyframe to {spec.name}", keyframes=spec.keyframes + (camera.to_dict(),))

    # ---- Gaussians ----------------------------------------------------------------------------
    def set_gaussians(self, g: GaussianArrays | None, base: str | Path | None = None) -> None:
        """Show a new Gaussian set (not an edit: a model loaded from the file ``base`` or
        published by training)."""
        self.gaussians = g
        self.selection = None if g is None else np.zeros(g.n, bool)
        self.gaussians_version += 1
        self.mark_saved(base)

    def mark_saved(self, base: str | Path | None) -> None:
        """The shown set is what the file ``base`` holds (just loaded or saved)."""
        g = self.gaussians
        self.saved_gaussians = g
        self.origin = None if g is None else np.arange(g.n)
        self.origin_base = None if base is None else str(base)
        self.origin_count = 0 if g is None else g.n

    @property
    def unsaved(self) -> bool:
        """Whether the shown Gaussians differ from the last loaded or saved set."""
        return self.gaussians is not None and self.gaussians is not self.saved_gaussians

    def autosave_dict(self) -> dict[str, Any] | None:
        """The edits since the model file was loaded, as the indices kept of it (None when the
        shown set has no file behind it)."""
        if self.origin is None or self.origin_base is None:
            return None
        return {"version": SESSION_VERSION, "base": self.origin_base, "base_count": self.origin_count,
                "keep": [int(i) for i in self.origin], "edits": [e.label for e in self.undo_stack]}

    def restore_autosave(self, d: dict[str, Any]) -> int:
        """Apply an ``autosave_dict`` made on the file shown now, unedited, as one undoable
        edit. Returns the Gaussians removed; InputError when it belongs to another model."""
        if d.get("base") != self.origin_base or int(d.get("base_count", -1)) != self.origin_count \
                or self.gaussians is None or self.origin is None or self.origin.size != self.origin_count:
            raise InputError(f"the autosaved edits are for {d.get('base')} ({d.get('base_count')} Gaussians), "
                             f"not the model shown; open that model to restore them")
        keep = np.zeros(self.origin_count, bool)
        keep[np.asarray(d.get("keep", []), int)] = True
        removed = int((~keep).sum())
        if removed:
            self._replace_gaussians(f"restore autosaved edits ({removed} Gaussians removed)", keep,
                                    np.zeros(self.origin_count, bool))
        return removed

    def set_selection(self, mask: np.ndarray | None) -> None:
        if self.gaussians is None:
            return
        self.selection = np.zeros(self.gaussians.n, bool) if mask is None else np.asarray(mask, bool).copy()
        self.gaussians_version += 1

    def _replace_gaussians(self, label: str, keep: np.ndarray, selection_after_undo: np.ndarray) -> None:
        g = self.gaussians
        if g is None:
            raise InputError("no model loaded: nothing to edit")
        keep = np.asarray(keep, bool)
        if keep.shape != (g.n,):
            raise InputError(f"selection mask has shape {keep.shape}, expected ({g.n},)")
        full, origin = g, (self.origin, self.origin_base, self.origin_count)
        edited: list = []  # the subset, made once: a redo shows the same set again

        def do(s: AppState) -> None:
            if not edited:
                edited.append(full.subset(keep))
            s.gaussians = edited[0]
            s.selection = np.zeros(s.gaussians.n, bool)
            s.origin = None if origin[0] is None else origin[0][keep]
            s.origin_base, s.origin_count = origin[1], origin[2]
            s.gaussians_version += 1

        def undo(s: AppState) -> None:
            s.gaussians = full
            s.selection = selection_after_undo.copy()
            s.origin, s.origin_base, s.origin_count = origin
            s.gaussians_version += 1

        self.apply(Edit(label, do, undo, destructive=True))

    def delete_selected(self) -> int:
        """Delete the selected Gaussians (undoable). Returns how many were removed."""
        sel = self._current_selection()
        if not sel.any():
            return 0
        self._replace_gaussians(f"delete {int(sel.sum())} Gaussians", ~sel, sel)
        return int(sel.sum())

    def isolate_selected(self) -> int:
        """Keep only the selected Gaussians (undoable). Returns how many remain."""
        sel = self._current_selection()
        if not sel.any():
            return 0
        self._replace_gaussians(f"isolate {int(sel.sum())} Gaussians", sel, sel)
        return int(sel.sum())

    def _current_selection(self) -> np.ndarray:
        if self.gaussians is None:
            return np.zeros(0, bool)
        return np.zeros(self.gaussians.n, bool) if self.selection is None else self.selection

    def choose_background(self, mode: str, run_rgb: tuple[float, float, float] | None) -> None:
        """Show ``mode`` (a key of ``BACKGROUNDS``) behind the Gaussians; "run" is ``run_rgb``, the
        run's own background, and falls back on black where the source has none."""
        if mode not in BACKGROUNDS:
            raise InputError(f"background {mode!r} is not one of {', '.join(BACKGROUNDS)}")
        rgb = BACKGROUNDS[mode] if mode != "run" else run_rgb
        if rgb is None:
            mode, rgb = "black", BACKGROUNDS["black"]
        self.background_mode, self.background = mode, tuple(float(x) for x in rgb)

    # ---- session ------------------------------------------------------------------------------
    def session_dict(self) -> dict[str, Any]:
        return {"version": SESSION_VERSION, "camera": self.view.to_dict(), "frame": self.frame,
                "loop": self.loop, "fps": self.fps, "selected_trajectory": self.selected_trajectory,
                "trajectories": [t.to_dict() for t in self.trajectories], "preview_alpha": self.preview_alpha,
                "splat_mode": self.splat_mode, "debug_mode": self.debug_mode, "show_frusta": self.show_frusta,
                "show_trajectories": self.show_trajectories, "background": self.background_mode,
                "model_version": self.model_version}

    def save_session(self, path: str | Path) -> Path:
        return write_json(path, self.session_dict())

    def load_session(self, path: str | Path) -> bool:
        """Restore a saved session; False (state untouched) when the file is absent. A corrupt
        or foreign file raises InputError naming it."""
        path = Path(path)
        if not path.is_file():
            return False
        try:
            d = json.loads(path.read_text())
            if int(d.get("version", 0)) != SESSION_VERSION:
                raise InputError(f"{path}: session version {d.get('version')} is not {SESSION_VERSION}; delete the file")
            view = ViewCamera.from_dict(d["camera"])
            trajectories = [TrajectorySpec.from_dict(t) for t in d.get("trajectories", [])]
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: unreadable viewer session ({exc}); delete the file to start fresh") from exc
        self.view = view
        self.trajectories = trajectories
        self.selected_trajectory = min(int(d.get("selected_trajectory", -1)), len(trajectories) - 1)
        self.set_frame(int(d.get("frame", 0)))
        self.loop = bool(d.get("loop", True))
        self.fps = float(d.get("fps", self.fps))
        self.preview_alpha = float(d.get("preview_alpha", 0.5))
        self.splat_mode = str(d.get("splat_mode", "color"))
        self.debug_mode = str(d.get("debug_mode", "color"))
        self.show_frusta = bool(d.get("show_frusta", True))
        self.show_trajectories = bool(d.get("show_trajectories", True))
        mode = str(d.get("background", "black"))
        self.background_mode = mode if mode in BACKGROUNDS else "black"  # its colour: the source's (``choose_background``)
        # the model version is chosen when the run opens (app.files.remembered_version); keep
        # the one actually shown
        return True
