"""A real window under Xvfb: `fixer4d-view --screenshot FILE --frames N demo` (skipped cleanly
when Xvfb is not installed)."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from viewer_helpers import gl_ctx  # noqa: F401 (fixture)

pytestmark = pytest.mark.gl
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def xvfb_display():
    exe = shutil.which("Xvfb")
    if exe is None:
        pytest.skip("Xvfb is not installed (apt-get install xvfb)")
    r, w = os.pipe()
    proc = subprocess.Popen([exe, "-displayfd", str(w), "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                            pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(w)
    with os.fdopen(r) as fh:
        number = fh.readline().strip()
    if not number:
        proc.kill()
        pytest.skip("Xvfb did not start")
    yield f":{number}"
    proc.terminate()
    proc.wait(10)


def test_window_screenshot_on_demo(xvfb_display, tmp_path):
    from PIL import Image

    shot = tmp_path / "shot.png"
    env = dict(os.environ, DISPLAY=xvfb_display, XDG_CONFIG_HOME=str(tmp_path / "cfg"),
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-m", "app.main", "--screenshot", str(shot), "--frames", "5", "--size", "960x600",
           "--init", "sparse", "--init-frames", "2", "--iterations", "30", "demo"]
    proc = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    img = np.asarray(Image.open(shot))
    assert img.shape == (600, 960, 3)
    # the 3D viewport (centre of the window) shows the scene, not the empty window colour
    view = img[60:320, 250:700].astype(float)
    assert view.std() > 5.0
    assert (cfg := tmp_path / "cfg" / "fixer4d" / "view").is_dir() and any(cfg.rglob("session.json"))


def test_desktop_entry_names_the_viewer_and_its_icon():
    import configparser

    entry = configparser.ConfigParser(interpolation=None)
    entry.optionxform = str
    entry.read(ROOT / "assets" / "desktop" / "fixer4d-view.desktop")
    d = entry["Desktop Entry"]
    assert d["Type"] == "Application" and d["Terminal"] == "false"
    assert d["Exec"].split()[0] == "fixer4d-view" and "%f" in d["Exec"]  # make install-desktop makes it absolute
    assert "--errors-in-window" in d["Exec"].split()  # no terminal: a bad file is reported in the window
    assert (ROOT / "assets" / "desktop" / f"{d['Icon']}.svg").is_file()
    assert 'fixer4d-view = "app.main:main"' in (ROOT / "pyproject.toml").read_text()
    assert "install-desktop:" in (ROOT / "Makefile").read_text()


def test_a_source_that_fails_to_open_is_shown_in_the_window(xvfb_display, tmp_path):
    """--errors-in-window (the desktop entry, no terminal): the window opens and says why."""
    from PIL import Image

    shot = tmp_path / "shot.png"
    env = dict(os.environ, DISPLAY=xvfb_display, XDG_CONFIG_HOME=str(tmp_path / "cfg"),
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    missing = tmp_path / "no_such_run"
    cmd = [sys.executable, "-m", "app.main", "--screenshot", str(shot), "--frames", "4", "--size", "960x600",
           "--errors-in-window", str(missing)]
    proc = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1 and "no model to show" in proc.stderr
    img = np.asarray(Image.open(shot)).astype(int)
    # the error is written in the window (notifications area, error red; the chooser dialog
    # dims it), not only on stderr
    red = (img[..., 0] - img[..., 1] > 50) & (img[..., 0] - img[..., 2] > 50)
    assert red[int(0.6 * img.shape[0]):].sum() > 200
    log = (tmp_path / "cfg" / "fixer4d" / "view" / "viewer.log").read_text()
    assert "no_such_run" in log and "ERROR" in log


def _xdotool(display: str, *args: str) -> str:
    out = subprocess.run(["xdotool", *args], env=dict(os.environ, DISPLAY=display), capture_output=True, text=True,
                         timeout=30)
    return out.stdout.strip()


def test_1ms_key_presses_reach_the_viewer_in_a_real_window(xvfb_display, tmp_path):
    """xdotool on Xvfb: Ctrl+S and Ctrl+Q pressed for 1 ms each (down, 1 ms, up) save a new model
    version and quit: the glfw key callback hands every press to the viewer, however short."""
    import time

    if shutil.which("xdotool") is None:
        pytest.skip("xdotool is not installed (apt-get install xdotool)")
    from fixer4d.model.io import save_ply
    from viewer_helpers import make_gaussians

    model = tmp_path / "m.ply"
    save_ply(make_gaussians(n_static=100, n_moving=20).to_model(), model)
    env = dict(os.environ, DISPLAY=xvfb_display, XDG_CONFIG_HOME=str(tmp_path / "cfg"),
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-m", "app.main", "--size", "800x560", str(model)], env=env, cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        window = ""
        deadline = time.monotonic() + 120
        while not window and time.monotonic() < deadline and proc.poll() is None:
            window = _xdotool(xvfb_display, "search", "--name", "fixer4d-view").split("\n")[0]
            time.sleep(0.5)
        assert window, "the viewer window did not appear"
        time.sleep(2.0)  # the first frames
        _xdotool(xvfb_display, "windowfocus", "--sync", window)

        def press(chord: str) -> None:
            _xdotool(xvfb_display, "keydown", chord)
            time.sleep(0.001)
            _xdotool(xvfb_display, "keyup", chord)

        press("ctrl+s")
        edit = tmp_path / "model_edit_1.ply"
        while not edit.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert edit.is_file(), "Ctrl+S (1 ms) did not save a model version"
        press("ctrl+q")
        assert proc.wait(60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


def test_render_a_video_then_click_where_render_video_was_in_a_real_window(xvfb_display, tmp_path, gl_ctx,
                                                                           monkeypatch):
    """xdotool on Xvfb, as the walk that found it: render a video of the selected trajectory,
    then click where "render video" was. Before, the finished job's lines moved the panel's
    contents and that click hit "delete trajectory"; now it renders again and every trajectory
    is kept (the session written at quit lists them)."""
    import json
    import time

    import av

    if shutil.which("xdotool") is None:
        pytest.skip("xdotool is not installed (apt-get install xdotool)")
    from app.sources import app_services, open_source
    from app.viewer import Viewer
    from fixer4d.model.io import save_ply
    from fixer4d.scene import load_scene
    from viewer_helpers import Driver, scene_gaussians

    size = (1024, 640)
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"scene": {"source": "tiny"}}))
    save_ply(scene_gaussians(load_scene("tiny"), stride=8).to_model(), run / "model_final.ply")
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    # where the window will draw "render video": the same viewer, headless, at the same size
    from app.sources import initial_state

    src, g, _ = open_source(str(run))
    viewer = Viewer(gl_ctx, initial_state(src, g), src, services=app_services())
    try:
        d = Driver(viewer, gl_ctx, size)
        d.frame(3)
        x0, y0, x1, y1 = viewer.item_rects["render_video"]
        names = [t.name for t in viewer.state.trajectories]
        n_frames = viewer.state.trajectories[0].n_frames
    finally:
        viewer.close()
    assert names
    env = dict(os.environ, DISPLAY=xvfb_display, XDG_CONFIG_HOME=str(tmp_path / "cfg"),
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-m", "app.main", "--size", f"{size[0]}x{size[1]}", str(run)], env=env,
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 180
        window = ""
        while not window and time.monotonic() < deadline and proc.poll() is None:
            window = _xdotool(xvfb_display, "search", "--name", "fixer4d-view").split("\n")[0]
            time.sleep(0.5)
        assert window, "the viewer window did not appear"
        cx, cy = str(int((x0 + x1) / 2)), str(int((y0 + y1) / 2))

        def click() -> None:
            _xdotool(xvfb_display, "mousemove", "--window", window, cx, cy)
            time.sleep(0.5)  # imgui sees the pointer over the button before the press
            _xdotool(xvfb_display, "click", "1")

        videos = run / "viewer" / "videos"

        def written() -> list[Path]:  # (not the writer's hidden temporary file)
            return [p for p in videos.glob("*.mp4") if not p.name.startswith(".")]

        def click_until(done) -> None:
            """Click where "render video" is until ``done()`` (a loaded machine may still be
            drawing its first frames; while a video renders the button is disabled)."""
            while not done() and time.monotonic() < deadline:
                click()
                for _ in range(50):
                    if done():
                        return
                    time.sleep(0.2)

        click_until(written)
        (video,) = written()
        first = video.stat().st_mtime_ns
        time.sleep(2.0)  # the finished job's result line shows
        click_until(lambda: video.stat().st_mtime_ns != first)  # where "render video" was: it renders again
        assert video.stat().st_mtime_ns != first, "no click hit render video again"
        _xdotool(xvfb_display, "windowfocus", "--sync", window)
        _xdotool(xvfb_display, "key", "ctrl+q")
        assert proc.wait(60) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    session = json.loads((run / "viewer" / "session.json").read_text())
    assert [t["name"] for t in session["trajectories"]] == names  # no trajectory deleted
    with av.open(str(video)) as container:
        assert sum(1 for _ in container.decode(video=0)) == n_frames
