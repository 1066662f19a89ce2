"""Exports opened in a real browser: gsplat.js (the npm package ``gsplat``) renders a frame of
``fixer4d export --format ply-sequence`` and a ``.splatv`` in headless Chromium, and the image is
compared with fixer4d's render of the same camera and clip time.

Needs Debian's chromium and the npm package in ``.cache/browser-viewer/``
(``bash benchmarks/browser_viewer_setup.sh``); skipped, with the reason, when either is missing.
FIXER4D_BROWSER_VIEWER (a folder holding ``node_modules/gsplat``) and FIXER4D_CHROMIUM (the browser
binary) say where else to look. The page is tests/output/browser/gsplat_frame.html.
FIXER4D_BROWSER_RESULT=FILE also writes what was measured to FILE (JSON; the committed one is
benchmarks/results/browser_viewer.json).
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import threading
import urllib.parse
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from plyfile import PlyData

from fixer4d.eval.metrics import psnr
from fixer4d.geometry.camera import Camera
from fixer4d.model.formats import splatv
from fixer4d.model.formats.ply_sequence import export_ply_sequence
from fixer4d.model.spacetime import ModelConfig
from fixer4d.render.constants import ALPHA_MIN
from fixer4d.render.views import model_render_fn
from output_scene import small_model

REPO_ROOT = Path(__file__).resolve().parents[2]
PAGE_DIR = Path(__file__).resolve().parent / "browser"
VIEWER_DIR = Path(os.environ.get("FIXER4D_BROWSER_VIEWER", REPO_ROOT / ".cache" / "browser-viewer"))
GSPLAT_JS = "node_modules/gsplat/dist/index.es.js"
CHROMIUM = os.environ.get("FIXER4D_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")

# Every effect of the motion model, and no SH bands above DC: gsplat.js reads only f_dc (its
# PLY loader drops f_rest_*), so view-dependent colour would measure the viewer, not the export.
CONFIG = ModelConfig(motion_degree=3, rotation_velocity=True, temporal_opacity=True, sh_degree=0)
TIME = 0.35  # a clip time where some Gaussians have faded out and the moving ones are off their t=0 place
# Floors in dB, from what was measured (docs/output.md) less a margin for another Chromium or
# SwiftShader build: the PLY frame measured 45.4 dB (the viewer's 8-bit colours, opacities and
# rotations), the .splatv 41.3 dB (the viewer orders moving splats by their position at their
# temporal centre, not at the shown time; 45.5 dB with static splats only). A wrong export
# (colour channels swapped, an axis flipped) measured 15.9-21.0 dB.
PLY_FLOOR_DB = 42.0
SPLATV_FLOOR_DB = 38.0
# gsplat 1.2.9's sort worker copies its splat-to-transform table (padded to a multiple of 1024
# entries) into a buffer sized for the splat count's next power of two: below 1024 splats the copy
# overruns the sort keys and the splats are drawn unsorted. The test frames stay above it.
GSPLAT_MIN_SPLATS = 1024
BROWSER_TIMEOUT_S = 120.0
# What the tests measured (PSNR in dB per export and per wrong export, versions, timings), written
# to FIXER4D_BROWSER_RESULT when that is set.
MEASURED: dict = {}


@pytest.fixture(scope="module", autouse=True)
def _write_measured():
    yield
    target = os.environ.get("FIXER4D_BROWSER_RESULT")
    if target and MEASURED:
        import datetime
        import platform

        record = {"command": "FIXER4D_BROWSER_RESULT=FILE .venv/bin/python -m pytest "
                             "tests/output/test_browser_viewer.py",
                  "date": datetime.date.today().isoformat(), "machine": platform.machine(),
                  "load_average": list(os.getloadavg()), "chromium": CHROMIUM, **MEASURED}
        Path(target).write_text(json.dumps(record, indent=1) + "\n")  # a cold Chromium start plus SwiftShader on a busy 2-core machine


def _require_browser() -> None:
    if CHROMIUM is None:
        pytest.skip("browser test skipped: no chromium on PATH (bash benchmarks/browser_viewer_setup.sh, "
                    "or set FIXER4D_CHROMIUM)")
    if not (VIEWER_DIR / GSPLAT_JS).is_file():
        pytest.skip(f"browser test skipped: gsplat.js is not at {VIEWER_DIR / GSPLAT_JS} "
                    "(bash benchmarks/browser_viewer_setup.sh, or set FIXER4D_BROWSER_VIEWER)")


class PageServer:
    """An HTTP server on 127.0.0.1 for one page load: GET /page/, /viewer/ and /data/ serve the
    browser page, the npm folder and ``data_dir``; the page POSTs its result to /result."""

    def __init__(self, data_dir: Path):
        routes = {"/page/": PAGE_DIR, "/viewer/": VIEWER_DIR, "/data/": data_dir}
        self.answer: dict = {}
        self.answered = threading.Event()
        owner = self

        class Handler(SimpleHTTPRequestHandler):
            def translate_path(self, path: str) -> str:
                path = urllib.parse.unquote(urllib.parse.urlsplit(path).path)
                for prefix, root in routes.items():
                    if path.startswith(prefix):
                        return str(root / path[len(prefix):])
                return str(data_dir / "no-such-route")

            def do_POST(self) -> None:
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                fields = dict(urllib.parse.parse_qsl(urllib.parse.urlsplit(self.path).query))
                self.send_response(204)
                self.end_headers()
                owner.answer = {"body": body, **fields}
                owner.answered.set()

            def log_message(self, *args) -> None:
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def browser_render(data_dir: Path, src: str, camera: Camera, **params) -> tuple[np.ndarray, dict]:
    """gsplat.js's image of ``data_dir/src`` from ``camera``: (H, W, 3) float in [0, 1] over black,
    and the page's timings (render_ms: one frame, total_ms: page start to image, frames)."""
    assert (camera.cx, camera.cy) == (camera.width / 2, camera.height / 2)  # the page's principal point
    server = PageServer(data_dir)
    query = {"lib": f"/viewer/{GSPLAT_JS}", "src": f"/data/{src}", "w": camera.width, "h": camera.height,
             "fx": camera.fx, "fy": camera.fy, **params}
    url = f"{server.url}/page/gsplat_frame.html?{urllib.parse.urlencode(query)}"
    log = data_dir / f"{src}.chromium.log"
    with open(log, "wb") as log_file:
        # --no-sandbox: root and containers without user namespaces cannot start the sandbox (the page
        # is local); SwiftShader: WebGL 2 on the CPU, the same on every machine.
        browser = subprocess.Popen(
            [CHROMIUM, "--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
             "--no-first-run", "--disable-extensions", f"--window-size={camera.width},{camera.height}",
             f"--user-data-dir={data_dir / 'chromium-profile'}", url],
            stdout=log_file, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            answered = server.answered.wait(BROWSER_TIMEOUT_S)
        finally:
            try:
                os.killpg(browser.pid, signal.SIGTERM)  # chromium and its GPU and renderer processes
            except ProcessLookupError:
                pass
            browser.wait(30)
            server.close()
    assert answered, f"no answer from the page in {BROWSER_TIMEOUT_S} s; chromium's log: {log}"
    answer = server.answer
    assert "error" not in answer, f"the page failed: {answer['error']}"
    w, h = int(answer["w"]), int(answer["h"])
    rgba = np.frombuffer(answer["body"], np.uint8).reshape(h, w, 4)[::-1]  # readPixels: bottom row first
    timings = {"render_ms": float(answer["render_ms"]), "total_ms": float(answer["total_ms"]),
               "frames": int(answer["frames"])}
    # gsplat blends front to back into premultiplied colour over a clear (0, 0, 0, 0): RGB is the image over black.
    return rgba[..., :3].astype(np.float32) / 255.0, timings


def gsplat_version() -> str:
    """The installed npm package's version (the floors were measured with 1.2.9)."""
    return json.loads((VIEWER_DIR / "node_modules/gsplat/package.json").read_text())["version"]


def save_pair(path: Path, browser: np.ndarray, ours: np.ndarray) -> None:
    """The browser's image left of fixer4d's, as one PNG to look at."""
    both = np.concatenate([browser, ours], axis=1)
    Image.fromarray(np.round(np.clip(both, 0.0, 1.0) * 255.0).astype(np.uint8)).save(path)


@pytest.fixture(scope="module")
def scene():
    """The model, the camera and fixer4d's render of it at TIME."""
    _require_browser()
    model = small_model(1200, config=CONFIG, seed=1)
    camera = oblique_camera()
    ours = model_render_fn(model, background=(0.0, 0.0, 0.0))(camera, TIME)
    assert ours.mean() > 0.05  # the scene is in view
    return model, camera, ours


def oblique_camera() -> Camera:
    """320x240, above and to the side of the model: a rotation about every axis, so that a transposed
    or mirrored pose convention moves the image."""
    return Camera.look_at([1.4, -1.1, -2.4], [0.0, 0.0, 0.0], up=(0.0, -1.0, 0.0), fov_y=np.radians(45.0),
                          width=320, height=240, name="oblique")


def ply_view(camera: Camera) -> dict:
    """The page's pose parameters for a PLY: the camera centre and its row-major c2w rotation."""
    return {"position": ",".join(map(repr, camera.center.tolist())),
            "rotation": ",".join(map(repr, camera.R.reshape(-1).tolist()))}


def rewrite_ply(src: Path, dst: Path, change) -> None:
    """``src`` with ``change(vertex_array)`` applied, as ``dst``."""
    ply = PlyData.read(str(src))
    change(ply["vertex"].data)
    ply.write(str(dst))


def test_ply_frame_renders_in_the_browser_like_fixer4d(scene, tmp_path):
    model, camera, ours = scene
    manifest = json.loads(export_ply_sequence(model, tmp_path / "seq", [0.0, TIME, 0.8], fps=12.0,
                                              min_opacity=ALPHA_MIN).read_text())
    assert manifest["gaussians"][1] >= GSPLAT_MIN_SPLATS
    theirs, timings = browser_render(tmp_path / "seq", "frame_00001.ply", camera, **ply_view(camera))
    save_pair(tmp_path / "ply_browser_vs_fixer4d.png", theirs, ours)
    value = psnr(theirs, ours)
    print(f"\nply frame: gsplat {gsplat_version()} vs fixer4d {value:.2f} dB, {timings}")
    MEASURED.update(gsplat=gsplat_version(), ply_psnr_db=value, ply_timings=timings)
    assert value >= PLY_FLOOR_DB, (value, tmp_path)

    def swap_red_blue(v):
        v["f_dc_0"], v["f_dc_2"] = v["f_dc_2"].copy(), v["f_dc_0"].copy()

    def flip_y(v):
        v["y"] = -v["y"]

    for name, change in (("colours_swapped", swap_red_blue), ("y_flipped", flip_y)):
        rewrite_ply(tmp_path / "seq" / "frame_00001.ply", tmp_path / "seq" / f"{name}.ply", change)
        wrong, _ = browser_render(tmp_path / "seq", f"{name}.ply", camera, **ply_view(camera))
        save_pair(tmp_path / f"{name}_browser_vs_fixer4d.png", wrong, ours)
        wrong_value = psnr(wrong, ours)
        print(f"{name}: {wrong_value:.2f} dB")
        MEASURED[f"ply_{name}_psnr_db"] = wrong_value
        assert wrong_value < PLY_FLOOR_DB - 5.0, (name, wrong_value)


def test_splatv_renders_in_the_browser_like_fixer4d(scene, tmp_path):
    model, camera, ours = scene
    fields = splatv.reduce(model)
    splatv.write_splatv(fields, tmp_path / "model.splatv", [camera])  # the page takes the pose from the file
    theirs, timings = browser_render(tmp_path, "model.splatv", camera, time=TIME)
    save_pair(tmp_path / "splatv_browser_vs_fixer4d.png", theirs, ours)
    value = psnr(theirs, ours)
    print(f"\nsplatv: gsplat {gsplat_version()} vs fixer4d {value:.2f} dB, {timings}")
    MEASURED.update(gsplat=gsplat_version(), splatv_psnr_db=value, splatv_timings=timings)
    assert value >= SPLATV_FLOOR_DB, (value, tmp_path)

    wrong_exports = {"colours_swapped": {"rgba": fields.rgba[:, [2, 1, 0, 3]]},
                     "y_flipped": {"positions": fields.positions * np.array([1.0, -1.0, 1.0], np.float32)}}
    for name, change in wrong_exports.items():
        splatv.write_splatv(splatv.SplatvFields(**{**vars(fields), **change}), tmp_path / f"{name}.splatv", [camera])
        wrong, _ = browser_render(tmp_path, f"{name}.splatv", camera, time=TIME)
        save_pair(tmp_path / f"splatv_{name}_browser_vs_fixer4d.png", wrong, ours)
        wrong_value = psnr(wrong, ours)
        print(f"splatv {name}: {wrong_value:.2f} dB")
        MEASURED[f"splatv_{name}_psnr_db"] = wrong_value
        assert wrong_value < SPLATV_FLOOR_DB - 5.0, (name, wrong_value)
