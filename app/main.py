"""`fixer4d-view [RUN_DIR | SCENE]`: the desktop viewer/editor.

    fixer4d-view                      a window with a chooser (File > Open; recent runs, the demo)
    fixer4d-view MODEL.ply            a model file (with its run's scene when it sits in a run folder)
    fixer4d-view runs/demo            a run folder: model_final.ply (or model_stage1.ply), cache
    fixer4d-view path/to/scene        any scene load_scene opens, trained live
    fixer4d-view demo                 the built-in scene (a bare bundled name; ./demo is a folder)
    fixer4d-view --screenshot out.png --frames 30 [SOURCE]
                                      render 30 frames (after the first model arrives), save the
                                      window image, exit (scripts, bug reports)

A SOURCE that does not open (no such path, not a model) ends the program with one line on
stderr and exit status 2, before any window; with --errors-in-window (the desktop entry) the
window opens with the chooser and the message instead.
"""
from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from app.files import remember_recent
from app.notifications import LOG
from app.sources import LIVE_INIT_FRAMES, LIVE_INIT_METHOD, app_services, config_dir, initial_state, open_source
from app.viewer import INTERACTION_S, Viewer
from app.viewer_source import ViewerSource
from fixer4d.errors import Fixer4DError, InputError
from fixer4d.scene.synthetic import is_builtin_name

DEFAULT_SIZE = (1440, 900)
# Longest a --screenshot run waits for the first model (live init + model build) before it
# gives up with an error.
SCREENSHOT_MODEL_TIMEOUT_S = 900.0
# While live training runs the UI draws at most this many frames per second: on a CPU the
# window's drawing (software GL) competes with the trainer for the same cores, and 10 frames a
# second keeps orbiting usable while leaving the cores to training ...
TRAINING_UI_FPS = 10.0
# ... and this many while nobody touches the window (the panels' numbers and the published
# model still update a few times a second).
TRAINING_UI_FPS_UNATTENDED = 3.0
# ... and, unattended, the UI's frames take at most this share of the wall time (a frame that
# took X ms is followed by at least X (1 - share) / share ms of sleep): a frame's cost varies
# 10x with what it draws (a new published model re-sorts and redraws 30k splats on llvmpipe:
# 100-400 ms, a frame without a new image: 40-60 ms), so a fixed frame rate alone left the
# trainer anywhere from 0.6x to 1.07x of its speed without the viewer.
TRAINING_UI_SHARE_UNATTENDED = 0.05
# While live training runs, the UI thread's scheduling priority is lowered by this many nice
# steps (Linux: per thread; not raised again, which needs privileges): when a UI frame and a
# training step want the same core the step goes first. Measured cost of a UI frame to the
# trainer without it: ~3x the frame's own time (torch's OpenMP team stalls when one of its two
# threads is descheduled).
TRAINING_UI_NICE = 10
# Longest such pause (s): the panels' numbers and the loss plot still move every 2 s. Input ends
# a pause at once in the window (it waits for events, not a fixed sleep).
TRAINING_UI_MAX_PAUSE_S = 2.0
# With nothing moving, playing or training, the loop sleeps until an input event or this long
# (one frame a second then keeps clocks and file lists fresh; measured idle cost at 0.25 s:
# 17% of a core on llvmpipe under load).
IDLE_WAIT_S = 1.0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fixer4d-view", description=__doc__.splitlines()[0])
    p.add_argument("source", nargs="?", default=None,
                   help="a run folder (with config.json), a model file (.ply / .npz), a scene (folder, spec .json, "
                        "'demo'); without one the window opens with a chooser (--screenshot: the demo)")
    p.add_argument("--screenshot", metavar="FILE", help="render --frames frames, save the window image to FILE, exit")
    p.add_argument("--frames", type=int, default=30, help="frames to render before --screenshot (default 30)")
    p.add_argument("--size", default=f"{DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]}", help="window size WxH")
    p.add_argument("--scale", type=float, default=1.0, help="image scale when opening a scene (0.5 = half)")
    p.add_argument("--iterations", type=int, default=None, help="live training: stage-1 iterations")
    p.add_argument("--init", choices=("mvs", "sparse"), default=LIVE_INIT_METHOD,
                   help=f"live training: init method (default {LIVE_INIT_METHOD}; sparse starts in seconds)")
    p.add_argument("--init-frames", type=int, default=LIVE_INIT_FRAMES,
                   help=f"live training: evenly spaced frames with an init cloud (default {LIVE_INIT_FRAMES})")
    p.add_argument("--no-session", action="store_true", help="neither restore nor save the viewer session")
    p.add_argument("--verbose", action="store_true", help="errors with their traceback on stderr")
    p.add_argument("--errors-in-window", action="store_true",
                   help="a SOURCE that does not open is reported in the window, which opens with the chooser, "
                        "instead of exit status 2 (the desktop entry, started without a terminal)")
    return p


# Exit status for a SOURCE that does not open (the CLI's convention for bad input).
EXIT_BAD_SOURCE = 2


class SourceError(Exception):
    """The command line's SOURCE did not open (main: one line on stderr, EXIT_BAD_SOURCE)."""


# The window's keys that have shortcuts (app.viewer.SHORTCUTS), by glfw key code name.
SHORTCUT_KEYS = {"KEY_Z": "z", "KEY_Y": "y", "KEY_O": "o", "KEY_S": "s", "KEY_Q": "q", "KEY_SPACE": "space"}
# Marker in the config folder: the first-launch hint was shown once.
HINT_MARKER = "first_launch_hint_shown"


def first_launch(folder: Path) -> bool:
    """True once per user: the first launch shows a hint line (a marker file remembers it)."""
    marker = Path(folder) / HINT_MARKER
    if marker.exists():
        return False
    try:
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.write_text("the viewer showed its first-launch hint\n")
    except OSError:
        pass
    return True


def install_key_callback(glfw: Any, window: Any, viewer_ref: list) -> None:
    """Route the window's key presses to ``viewer.key_event`` (set before imgui's backend
    installs its callbacks, which then chain to this one): a shortcut runs on the press event
    itself, however short the press."""
    codes = {getattr(glfw, name): key for name, key in SHORTCUT_KEYS.items()}

    def on_key(win: Any, key: int, scancode: int, action: int, mods: int) -> None:
        name = codes.get(key)
        if name is not None and viewer_ref and action in (glfw.PRESS, glfw.RELEASE):
            viewer_ref[0].key_event(name, action == glfw.PRESS, ctrl=bool(mods & glfw.MOD_CONTROL))

    glfw.set_key_callback(window, on_key)


def run_window(args: argparse.Namespace) -> int:
    """Open the source ``args`` names (or the chooser), show it in a glfw window until the user
    quits (or, with --screenshot, until the image is saved). Returns the exit status."""
    import ctypes

    import glfw
    import moderngl
    from imgui_bundle import imgui

    source = args.source if args.source is not None or not args.screenshot else "demo"
    services = app_services()
    src, gaussians, session_dir, startup_error = open_start_source(args, source)
    state = initial_state(src, gaussians)
    window = open_gl_window(glfw, args, src.label)
    ctx = moderngl.create_context()
    if not args.no_session:  # --no-session writes nothing into a run folder (read-only or shared runs)
        session_dir.mkdir(parents=True, exist_ok=True)
    address = ctypes.cast(window, ctypes.c_void_p).value
    viewer_ref: list = []
    install_key_callback(glfw, window, viewer_ref)
    viewer = Viewer(ctx, state, src, services=services,
                    ini_path=None if args.no_session else session_dir / "imgui.ini",
                    session_path=None if args.no_session else session_dir / "session.json",
                    platform_init=lambda: imgui.backends.glfw_init_for_opengl(address, True),
                    first_launch=not args.screenshot and first_launch(config_dir()))
    viewer_ref.append(viewer)
    if startup_error is not None:
        viewer.report_error("open", startup_error)
    if src.scene is None and gaussians is None:
        from app.panels import files

        files.ask(viewer, "open", "" if source is None else source)
    if src.training is not None:
        src.training.start()
    try:
        return window_loop(glfw, window, ctx, viewer, args, startup_error)
    finally:
        viewer.close(platform_shutdown=imgui.backends.glfw_shutdown)
        glfw.destroy_window(window)
        glfw.terminate()


def open_start_source(args: argparse.Namespace, source: str | None) -> tuple[ViewerSource, Any, Path, Exception | None]:
    """What the window opens with: (ViewerSource, initial GaussianArrays or None, session folder,
    None). No source: the chooser's empty source. A source that does not open raises
    SourceError, or with --errors-in-window gives the chooser's source and the error as the
    fourth item."""
    if source is None:  # the desktop entry: open the window with the chooser
        return ViewerSource(label="nothing open: File > Open"), None, config_dir() / "start", None
    try:
        src, gaussians, session_dir = open_source(source, scale=args.scale, iterations=args.iterations,
                                                  init=args.init, init_frames=args.init_frames)
    except Exception as exc:
        report_startup_error(source, exc, args.verbose)
        if not args.errors_in_window:
            raise SourceError(f"cannot open {source}: {one_line_message(exc)}") from exc
        # started without a terminal: say it in the window
        return ViewerSource(label=f"could not open {source}"), None, config_dir() / "start", exc
    if not args.screenshot:  # a scripted screenshot is not the user opening something
        remember_recent(config_dir(), source if src.training is not None and is_builtin_name(source)
                        else str(Path(source).expanduser().resolve()))
    if src.notice:
        print(f"fixer4d-view: {src.notice}", file=sys.stderr)
    return src, gaussians, session_dir, None


def one_line_message(exc: BaseException) -> str:
    """An exception as one line: the message alone for fixer4d's input errors (they name the
    problem and the fix), else ``Type: message``; line breaks folded."""
    text = str(exc) if isinstance(exc, Fixer4DError) else f"{type(exc).__name__}: {exc}"
    return " ".join(text.split())


def open_gl_window(glfw: Any, args: argparse.Namespace, label: str) -> Any:
    """A glfw window of ``args.size`` with a current OpenGL 3.3 core context (vsync off for
    --screenshot); InputError when there is no display or no such context."""
    w, h = (int(v) for v in args.size.lower().split("x"))
    if not glfw.init():
        raise InputError("glfw could not initialize a display; set DISPLAY (or run under Xvfb)")
    glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
    glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
    glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
    glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
    window = glfw.create_window(w, h, f"fixer4d-view - {label}", None, None)
    if not window:
        glfw.terminate()
        raise InputError("could not open an OpenGL 3.3 window; check the GPU driver or Mesa")
    glfw.make_context_current(window)
    glfw.swap_interval(0 if args.screenshot else 1)
    return window


def window_loop(glfw: Any, window: Any, ctx: Any, viewer: Viewer, args: argparse.Namespace,
                startup_error: Exception | None) -> int:
    """Draw frames until the user quits (the close button asks about unsaved edits first) or,
    with --screenshot, until the image is saved. Returns the exit status (1: a screenshot
    without a model)."""
    from imgui_bundle import imgui

    src = viewer.source
    frames_with_model = frames = 0
    started = time.monotonic()
    last = time.perf_counter()
    while not viewer.quit_confirmed:
        if glfw.window_should_close(window):  # the close button: unsaved edits ask first
            glfw.set_window_should_close(window, False)
            if args.screenshot or viewer.request_close():
                break
        if viewer.is_idle() and not args.screenshot:
            glfw.wait_events_timeout(IDLE_WAIT_S)  # no busy loop: wake on input
        else:
            glfw.poll_events()
        now = time.perf_counter()
        fbo = ctx.detect_framebuffer()
        viewer.frame(now - last, fbo, platform_new_frame=imgui.backends.glfw_new_frame)
        last = now
        if args.screenshot:
            frames += 1
            frames_with_model += viewer.state.gaussians is not None
            failed = (src.training is not None and src.training.state == "failed") or \
                (startup_error is not None and frames >= args.frames)
            if frames_with_model >= args.frames or failed or time.monotonic() - started > SCREENSHOT_MODEL_TIMEOUT_S:
                save_png(args.screenshot, viewer.screenshot(fbo))
                print(f"fixer4d-view: wrote {args.screenshot} after {frames_with_model} frames with a model")
                if viewer.state.gaussians is None:
                    why = startup_error or (src.training.error if src.training else "nothing to show")
                    print(f"fixer4d-view: no model to show: {why}", file=sys.stderr)
                    return 1
                return 0
        glfw.swap_buffers(window)
        pace_frame(viewer, now, glfw.wait_events_timeout)
    return 0


def pace_frame(viewer: Viewer, frame_start: float, wait: Callable[[float], Any] = time.sleep) -> None:
    """Sleep out the rest of the frame period while live training runs (TRAINING_UI_FPS while
    the user interacts; TRAINING_UI_FPS_UNATTENDED otherwise, and then at least long enough that
    the UI takes no more than TRAINING_UI_SHARE_UNATTENDED of the time), so the trainer gets the
    CPU the UI does not need. ``wait(seconds)``: how to pass the time (the window waits for
    input events, so the user's first move ends the pause)."""
    tr = viewer.source.training
    if tr is not None and tr.state in ("setup", "running"):
        lower_ui_priority()
        attended = time.monotonic() - viewer.last_input < INTERACTION_S
        spent = time.perf_counter() - frame_start
        rest = 1.0 / (TRAINING_UI_FPS if attended else TRAINING_UI_FPS_UNATTENDED) - spent
        if not attended:
            rest = max(rest, min(TRAINING_UI_MAX_PAUSE_S,
                                 spent * (1.0 - TRAINING_UI_SHARE_UNATTENDED) / TRAINING_UI_SHARE_UNATTENDED))
        if rest > 0:
            wait(rest)


_UI_THREADS_LOWERED: set[int] = set()


def lower_ui_priority() -> None:
    """Lower the calling (UI) thread's CPU priority by TRAINING_UI_NICE, once per thread (a no-op
    where threads have no nice value of their own or the call is not allowed)."""
    tid = threading.get_native_id()
    if tid in _UI_THREADS_LOWERED:
        return
    _UI_THREADS_LOWERED.add(tid)
    try:
        os.setpriority(os.PRIO_PROCESS, tid, min(19, os.getpriority(os.PRIO_PROCESS, tid) + TRAINING_UI_NICE))
    except (OSError, AttributeError):
        pass


def save_png(path: str | Path, image: np.ndarray) -> None:
    from PIL import Image

    from fixer4d.atomic import atomic_path

    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp)


class OneLineFormatter:
    """A log formatter that leaves out tracebacks (stderr without --verbose: the user reads one
    line; the log file keeps the traceback)."""

    def __init__(self, fmt: str) -> None:
        import logging

        self._inner = logging.Formatter(fmt)

    def format(self, record: Any) -> str:
        saved = record.exc_info, record.exc_text, record.stack_info
        record.exc_info = record.exc_text = record.stack_info = None
        try:
            return self._inner.format(record).splitlines()[0] if record.getMessage() else ""
        finally:
            record.exc_info, record.exc_text, record.stack_info = saved


def setup_logging(verbose: bool = False) -> Path:
    """Log the viewer's messages (notifications, errors with tracebacks) to
    ~/.config/fixer4d/view/viewer.log (everything: a viewer started from the desktop has no
    terminal) and its warnings and errors to stderr as well. Returns the log file's path."""
    import logging

    path = config_dir() / "viewer.log"
    path.parent.mkdir(parents=True, exist_ok=True)
    log = logging.getLogger("fixer4d.view")
    if not log.handlers:
        form = logging.Formatter("%(asctime)s %(levelname)s %(message)s")
        to_file = logging.FileHandler(path, encoding="utf-8")
        to_stderr = logging.StreamHandler()  # sys.stderr
        to_stderr.setLevel(logging.WARNING)
        to_file.setFormatter(form)
        to_stderr.setFormatter(form if verbose else OneLineFormatter("fixer4d-view: %(message)s"))
        for handler in (to_file, to_stderr):
            log.addHandler(handler)
        log.setLevel(logging.INFO)
    return path


# Rasterizer threads of Mesa's software GL (llvmpipe) unless the user sets LP_NUM_THREADS:
# one. By default llvmpipe starts a thread per core; on a CPU the viewer shares with live
# training, every UI frame then makes three threads (UI + 2 rasterizers) compete with torch's
# 2-thread OpenMP team, whose barriers degrade badly under contention: a 50-60 ms UI frame cost
# the trainer ~0.4 s (demo, 441 Gaussians, load ~12; 4.06 vs 5.07 steps/s plain, with one
# rasterizer thread 5.60 vs 4.91, same protocol). An orbit frame at level of detail is bound by
# per-splat setup, which runs on one thread anyway (121 vs 125 ms per frame, load ~10). A GPU
# driver ignores the variable.
SOFTWARE_GL_THREADS = "1"


def configure_software_gl() -> None:
    """Set llvmpipe's thread count (SOFTWARE_GL_THREADS) unless the environment chose one; call
    before the first GL context of the process."""
    os.environ.setdefault("LP_NUM_THREADS", SOFTWARE_GL_THREADS)


def report_startup_error(source: str, exc: BaseException, verbose: bool) -> None:
    """A source that did not open: one line on stderr (the traceback with --verbose, and always
    in the log file); the window shows it too."""
    LOG.info("could not open %s (traceback)", source, exc_info=exc)  # the log file keeps the traceback
    if verbose:
        import traceback

        traceback.print_exception(type(exc), exc, exc.__traceback__, file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    setup_logging(verbose=args.verbose)
    configure_software_gl()
    try:
        status = run_window(args)
    except SourceError as exc:
        print(f"fixer4d-view: error: {exc}", file=sys.stderr)
        return EXIT_BAD_SOURCE
    except Fixer4DError as exc:
        print(f"fixer4d-view: error: {exc}", file=sys.stderr)
        return 1
    if threading.active_count() > 1:
        # A background init (MVS, COLMAP) cannot be interrupted; letting the interpreter tear
        # down under it aborts in C++ thread destructors. Session, layout and every output are
        # already written (atomically), so leave at once.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    return status


if __name__ == "__main__":
    sys.exit(main())
