"""Walking the viewer's UI as a user would, for the tooltip and layout tests: a ``Recorder``
notes every interactive item and every text the panels submit to imgui (where, in which
window, and how wide a space its column left it) and every tooltip shown; ``busy_viewer``
opens a viewer with every panel showing all it can (a model, a selected trajectory, a finished
video, queued restorations, a cached clip in Compare, paused stage-2 training, notifications,
Help and the run report)."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from imgui_bundle import imgui

# imgui's widgets a user can act on (their first argument is the label or id).
INTERACTIVE = ("button", "small_button", "arrow_button", "checkbox", "radio_button", "slider_float", "slider_int",
               "input_text", "input_text_with_hint", "input_int", "combo", "begin_combo", "selectable")
# Texts on one line (wrapped text wraps at its column and cannot be cut).
TEXT = ("text", "text_disabled", "text_colored")
# Windows of the docked panels and the viewer's own windows (not menus, popups or tooltips).
PANEL_WINDOWS = ("View & edit", "Timeline", "Trajectories", "Restore", "Compare", "Training", "Debug",
                 "Notifications", "Mouse and keys", "Run report")


@dataclass
class Item:
    """One submitted widget or text: ``rect`` (x0, y0, x1, y1) screen pixels, ``right`` the
    right edge of the space its column left it when it was submitted (pixels)."""

    kind: str
    label: str
    window: str
    rect: tuple[float, float, float, float]
    right: float
    visible: tuple[float, float, float, float]  # the window's inner (clipping) rectangle
    preview: str = ""  # a combo's shown choice
    width: float = 0.0  # a combo's frame width

    def cut(self) -> str | None:
        """Why its text does not fit its column (or a combo's choice its frame), else None."""
        x0, _, x1, _ = self.rect
        text = self.label.split("##")[0]
        if self.kind == "selectable":  # spans the column; its text must fit in it
            x1 = x0 + imgui.calc_text_size(text).x
        if x1 > self.right + 1.0:
            return f"{self.window}: {self.kind} {text!r} ends at {x1:.0f}, its column at {self.right:.0f}"
        if self.preview:
            style = imgui.get_style()
            need = imgui.calc_text_size(self.preview).x + imgui.get_frame_height() + 2.0 * style.frame_padding.x
            if need > self.width + 1.0:
                return f"{self.window}: combo {text!r} shows {self.preview!r} ({need:.0f} px) in {self.width:.0f} px"
        return None


class Recorder:
    """Wraps imgui's widget and text functions (``monkeypatch``) to note each call as an Item
    (``items``, cleared by ``clear``) and ``set_tooltip`` to note each tooltip (``tooltips``)."""

    def __init__(self, monkeypatch) -> None:
        self.items: list[Item] = []
        self.tooltips: list[str] = []
        for name in INTERACTIVE + TEXT:
            monkeypatch.setattr(imgui, name, self._wrap(name, getattr(imgui, name)))
        original = imgui.set_tooltip

        def set_tooltip(text: str, *args) -> None:
            self.tooltips.append(text)
            original(text, *args)

        monkeypatch.setattr(imgui, "set_tooltip", set_tooltip)

    def clear(self) -> None:
        self.items.clear()
        self.tooltips.clear()

    def _wrap(self, name: str, fn):
        def call(*args, **kwargs):
            right = imgui.get_cursor_screen_pos().x + imgui.get_content_region_avail().x
            width = imgui.calc_item_width()
            preview = ""
            if name == "begin_combo":
                preview = str(args[1])
            elif name == "combo" and 0 <= args[1] < len(args[2]):
                preview = str(args[2][args[1]])
            out = fn(*args, **kwargs)
            window = imgui.internal.get_current_window()
            if name == "begin_combo" and out:  # the combo's popup is current now
                window = window.parent_window or window
            root = window.root_window.name.split("##")[0] or window.root_window.name
            lo, hi = imgui.get_item_rect_min(), imgui.get_item_rect_max()
            inner = window.inner_clip_rect
            label = args[1] if name == "text_colored" else args[0] if args else ""
            self.items.append(Item(name, str(label), root, (lo.x, lo.y, hi.x, hi.y), right,
                                   (inner.min.x, inner.min.y, inner.max.x, inner.max.y), preview, width))
            return out
        return call

    def interactive(self) -> list[Item]:
        return [i for i in self.items if i.kind in INTERACTIVE and i.window in PANEL_WINDOWS]


class StepTrainer:
    """A stage-2-like trainer for the Training panel (lambda_gen, K), never stepped here."""

    def __init__(self, model) -> None:
        self.model, self.step_count, self.done = model, 0, False
        self.config = SimpleNamespace(iterations=1000)
        self.stage2 = SimpleNamespace(lambda_gen=0.5, refresh_every=10)

    def step(self) -> dict:
        self.step_count += 1
        return {"loss": 0.1, "loss_stg": 0.08, "loss_gen": 0.02, "psnr": 25.0}


def cached_clip(scene, folder: Path):
    """A cache entry of two train-camera frames with a gated pseudo-target (its confidence map)."""
    from fixer4d.restore.cache import CacheEntry

    cams = scene.train_cameras[:2]
    h, w = cams[0].height, cams[0].width
    rgb = np.stack([scene.frame(0, i) for i in scene.train_ids[:2]]).astype(np.float32)
    conf = np.full((2, h, w), 0.01, np.float32)
    entry = CacheEntry(path=folder, key="t0000_0-1_viewer_A0.000_F16_a_long_clip_name_for_the_list", round=0,
                       meta={"pseudo_target": "gated"}, cameras=cams, time=0.0, frame=0)
    entry.rgb = lambda: rgb
    entry.confidence = lambda: conf
    return entry


def busy_viewer(make_viewer, scene, tmp_path: Path, size: tuple[int, int]):
    """A Driver of a viewer of ``size`` whose every panel and window has its full content."""
    from app.session import TrainingSession
    from app.sources import app_services, initial_state
    from app.viewer import ViewerSource
    from viewer_helpers import scene_gaussians

    run = tmp_path / "runs" / "a_run_folder_with_a_rather_long_name_like_real_ones"
    run.mkdir(parents=True)
    (run / "report.json").write_text(json.dumps({"scene": "tiny", "rows": [
        {"method": "STGS w/ MVS", "psnr": 24.44, "psnr_unobserved": 20.1, "dssim1": 0.0712, "lpips": 0.2101,
         "seconds": 431.5},
        {"method": "Full (restoration + refinement)", "status": "failed: out of memory while refining"}]}))
    g = scene_gaussians(scene, stride=8)
    training = TrainingSession(lambda report: StepTrainer(g.to_model()))
    training.trainer, training.state = StepTrainer(g.to_model()), "paused"
    training.history = [training.trainer.step() for _ in range(20)]
    entry = cached_clip(scene, tmp_path / "clip")
    queued = SimpleNamespace(status="running", key="t0008_0-3_viewer_A1.140_F16_rev", progress=0.4, error=None,
                             job=None, cancel=lambda: None)
    failed = SimpleNamespace(status="failed", key="t0004_1-2_viewer_A0.000_F16", progress=1.0,
                             error="the restorer ran out of memory", job=None, cancel=lambda: None)
    restore = SimpleNamespace(kind="warp", items=[failed, queued], set_jobs=lambda jobs, kind: None,
                              shutdown=lambda: None)
    src = ViewerSource(scene=scene, label=str(run / "model_final.ply"), run_dir=run, training=training,
                       cache=SimpleNamespace(entries=lambda: [entry]), restore=restore)

    def video(render_fn, cameras, times, out, *, fps, progress, should_stop):
        Path(out).write_bytes(b"video")
        progress(1.0)
        return Path(out)

    st = initial_state(src, g)
    st.selected_trajectory = 0
    d = make_viewer(st, src, size=size, services=app_services(render_video=video, config_dir=tmp_path / "config"))
    v = d.viewer
    d.click_item("render_video")
    v.__dict__["_video_ui"]["job"].wait(60)
    v.notifications.error("restore", "a long message from a failed job that needs more than one line of the "
                                     "notifications area to say what went wrong and how to fix it")
    v.show_help = v.show_report = True
    x0, y0, x1, y1 = v.window_rects["viewport"]
    d.move((x0 + x1) / 2, (y0 + y1) / 2)  # the mouse rests on the 3D view: no tooltip in the way
    d.frame(3)
    return d


# Frames (of 0.1 s) the mouse rests on an item before its tooltip must show (imgui waits 0.15 s
# of stillness and 0.15 s of hovering).
TOOLTIP_FRAMES = 10


def hover_tooltip(d, rec: Recorder, item: Item) -> str | None:
    """Rest the mouse on ``item`` (near its left end: the frame of a labelled widget) and
    return the tooltip imgui shows for it, or None."""
    x0, y0, x1, y1 = item.rect
    d.move(x0 + min(12.0, (x1 - x0) / 2), (y0 + y1) / 2)
    for _ in range(TOOLTIP_FRAMES):
        rec.tooltips.clear()
        d.frame(dt=0.1)
        if rec.tooltips:
            return rec.tooltips[-1]
    return None


def walk_window(d, rec: Recorder, title: str) -> dict[tuple[str, str, int], str | None]:
    """Every interactive item of window ``title`` -> the tooltip it shows on hover (None: none),
    scrolling the window down until its last item has been seen. Keys: (kind, label, n) with n
    counting equal (kind, label) pairs in drawing order."""
    found: dict[tuple[str, str, int], str | None] = {}
    unreached: set[tuple[str, str, int]] = set()  # every item seen (a key not in found: never hovered)
    scroll = 0.0
    while True:
        window = imgui.internal.find_window_by_name(title)
        assert window is not None, title
        imgui.internal.set_scroll_y(window, scroll)
        d.frame(2)
        rec.clear()
        d.frame()
        seen: dict[tuple[str, str], int] = {}
        todo = []
        for item in rec.interactive():
            if item.window != title:
                continue
            n = seen[(item.kind, item.label)] = seen.get((item.kind, item.label), -1) + 1
            key = (item.kind, item.label, n)
            _, vy0, _, vy1 = item.visible
            unreached.add(key)
            if key not in found and vy0 <= (item.rect[1] + item.rect[3]) / 2 <= vy1:
                todo.append((key, item))
        for key, item in todo:
            found[key] = hover_tooltip(d, rec, item)
        if window.scroll.y >= window.scroll_max.y - 1.0:
            return {**{key: None for key in unreached}, **found}
        scroll = window.scroll.y + 0.7 * window.inner_rect.get_height()
