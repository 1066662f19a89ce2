"""Calibration from a ChArUco board: the spec and its printable image, a rig recovered from an
exact synthetic board capture (four converging 320x240 cameras, two with lens distortion, 30
board poses tilted up to 40 degrees) by `fixer4d calibrate` and by opening the capture (the
same rig, cached), and the refusal of a camera that never sees the board together with the others."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from fixer4d.calib.board import BOARD_FOLDER, BoardSpec, CornerDetector, parse_board
from fixer4d.calib.board_render import board_poses, write_board_capture
from fixer4d.calib.rig import RigCamera, distort_points, read_rig_json
from fixer4d.cli import main
from fixer4d.errors import InputError
from fixer4d.scene.synthetic import build_rig

# A board that fills a good part of a 320x240 view 1.5 m away.
SPEC = BoardSpec(7, 5, 0.12, 0.09, "DICT_4X4_50")
RIG = {"rig": {"layout": "arc", "count": 4, "radius": 1.5, "arc_deg": 70, "height_offset": 0.4, "width": 320,
               "height": 240, "fov_y_deg": 50, "target": [0.0, 0.1, 0.0]}}
LENSES = {"cam01": {"k1": -0.2, "k2": 0.08}, "cam03": {"k1": 0.1}}
VOLUME = (np.array([0.0, 0.1, 0.0]), np.array([0.3, 0.2, 0.3]))  # board centres: target +- spread (m)


def _capture(root, cameras, poses, **kw):
    """CAPTURE/ with one 1-frame image folder per camera (the scene) and CAPTURE/board/ (the board videos)."""
    for c in cameras:
        (root / c.name).mkdir(parents=True)
        cv2.imwrite(str(root / c.name / "000000.png"), np.full((c.height, c.width), 128, np.uint8))
    write_board_capture(SPEC, cameras, poses, root / BOARD_FOLDER, **kw)
    return root


@pytest.fixture(scope="module")
def board_capture(tmp_path_factory):
    """(true cameras, CAPTURE with its board videos in CAPTURE/board/ and no calibration file)."""
    cameras = build_rig(RIG)
    root = _capture(tmp_path_factory.mktemp("board") / "capture", cameras,
                    board_poses(SPEC, cameras, *VOLUME, count=30, tilt_deg=40.0, seed=0), distortion=LENSES)
    return cameras, root


@pytest.fixture(scope="module")
def board_run(board_capture):
    """(true cameras, the rig `fixer4d calibrate CAPTURE --out rig.json` wrote from CAPTURE/board/)."""
    cameras, root = board_capture
    out = root.parent / "rig.json"
    assert main(["calibrate", str(root), "--out", str(out), "--quiet"]) == 0
    return cameras, read_rig_json(out)


@pytest.mark.parametrize("text, expected", [
    ("7x5:0.05:0.0375:DICT_4X4_50", BoardSpec(7, 5, 0.05, 0.0375, "DICT_4X4_50")),
    ("9x6:0.03", BoardSpec(9, 6, 0.03, 0.0225, "DICT_4X4_50")),
    (" 5 x 7 : 0.04 : 0.03 : DICT_5X5_100 ", BoardSpec(5, 7, 0.04, 0.03, "DICT_5X5_100")),
    ("7x5", BoardSpec()),
])
def test_board_spec_strings(text, expected):
    assert parse_board(text) == expected


@pytest.mark.parametrize("text, phrase", [
    ("7-5:0.05", "expected COLSxROWS"),
    ("7x5:0.05:0.06", "smaller than the square"),
    ("7x5:0.05:0.03:DICT_9X9_1", "unknown ArUco dictionary"),
    ("11x11:0.05:0.03:DICT_4X4_50", "needs 60 markers"),
    ("missing.json", "not found"),
])
def test_bad_board_specs_are_refused(text, phrase):
    with pytest.raises(InputError, match=phrase):
        parse_board(text)


def test_write_board_prints_a_detectable_board_and_its_json(tmp_path, capsys):
    png = tmp_path / "board.png"
    assert main(["calibrate", "--board", "7x5:0.04:0.03", "--write-board", str(png)]) == 0
    assert "Print at 100 %" in capsys.readouterr().out
    spec = parse_board(tmp_path / "board.json")
    assert spec == BoardSpec(7, 5, 0.04, 0.03)
    image = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    assert image.shape[1] == pytest.approx((7 + 1) * 0.04 / 0.0254 * 300, abs=8)  # 300 dpi, half-square margins
    ids, _ = CornerDetector(spec).detect(cv2.resize(image, None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA))
    assert len(ids) == spec.num_corners


def test_the_board_rig_matches_the_true_cameras(board_run):
    from fixer4d.init.poses import compare_poses

    truth, rig = board_run
    assert rig.names() == [c.name for c in truth]
    est = [c.camera() for c in rig.cameras]
    for e, g in zip(est, truth):
        assert abs(e.fx / g.fx - 1) < 0.005 and abs(e.cx - g.cx) < 1.0 and abs(e.cy - g.cy) < 1.0
    err = compare_poses(est, truth)
    assert err["rotation_deg_max"] < 0.2 and err["center_error_rel_max"] < 0.005
    assert err["scale"] == pytest.approx(1.0, abs=0.005)  # the world unit is the board's metre
    for i in range(4):
        for j in range(i + 1, 4):
            rel = (est[i].R.T @ est[j].R).T @ (truth[i].R.T @ truth[j].R)
            assert np.degrees(np.arccos(np.clip((np.trace(rel) - 1) / 2, -1, 1))) < 0.2
    assert all(c.reprojection_error_px < 0.3 for c in rig.cameras)
    assert "metres" in rig.scale and "ChArUco" in rig.source


def test_the_board_rig_recovers_the_lenses(board_run):
    """Distorted cameras get their lens back (pixel displacement over the central 70 % of the
    image, where the board was seen); a pinhole camera gets no distortion it does not need."""
    truth, rig = board_run
    u, v = np.meshgrid(np.linspace(48, 272, 15), np.linspace(36, 204, 11))
    grid = np.stack([u.ravel(), v.ravel()], 1)
    for c, g in zip(rig.cameras, truth):
        true_lens = RigCamera(g.name, g.width, g.height, g.K, np.eye(4), LENSES.get(g.name, {}))
        assert np.abs(distort_points(c, grid) - distort_points(true_lens, grid)).max() < 0.5
    assert rig.checks["lens_model"]["cam01"].endswith("k1, k2")
    assert "k1" in rig.checks["lens_model"]["cam03"]


def test_opening_a_capture_calibrates_from_its_board_once(board_capture, board_run, tmp_path, monkeypatch):
    """The viewer's and `fixer4d init`'s path (``resolve_rig`` through ``load_scene``) takes the
    board in CAPTURE/board/, gives the rig `fixer4d calibrate` gives, and caches it."""
    from fixer4d.calib import board_calib, resolve_rig
    from fixer4d.scene import load_scene
    from fixer4d.scene.capture import CaptureFiles

    _, root = board_capture
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    rig, label = resolve_rig(CaptureFiles(root), progress=False)
    assert "from the board videos in" in label and str(tmp_path) in label
    assert "ChArUco" in rig.source and rig.names() == board_run[1].names()
    for c, ref in zip(rig.cameras, board_run[1].cameras):
        # to the fit's convergence: two board calibrations of one capture agree to ~1e-6 relative
        np.testing.assert_allclose(c.K, ref.K, rtol=1e-5)
        np.testing.assert_allclose(c.w2c, ref.w2c, atol=1e-5)

    def no_second_calibration(*args, **kwargs):
        raise AssertionError("the cached rig should have been used")

    monkeypatch.setattr(board_calib, "calibrate_board", no_second_calibration)
    scene = load_scene(root)
    assert "from the board videos in" in scene.describe()
    np.testing.assert_allclose(scene.rig.cameras[0].K, rig.cameras[0].K)


def test_a_camera_never_seeing_the_board_with_the_others_is_refused(tmp_path, capsys):
    """cam03 sees the board only in frames 0-5, the others only in 6-11: its pose cannot be tied
    to theirs. `fixer4d calibrate` and a run both refuse before writing a rig."""
    from fixer4d.pipeline.capture_rig import calibrate_into_run
    from fixer4d.pipeline.config import RunConfig

    cameras = build_rig(RIG)
    first, last = set(range(6)), set(range(6, 12))
    hidden = {c.name: (last if c.name == "cam03" else first) for c in cameras}
    root = _capture(tmp_path / "capture", cameras, board_poses(SPEC, cameras, *VOLUME, count=12, seed=1),
                    hidden=hidden)
    assert main(["calibrate", str(root), "--out", str(tmp_path / "rig.json"), "--quiet"]) == 2
    msg = capsys.readouterr().err.strip()
    assert "board calibration refused" in msg and "camera cam03 never sees the board at the same instant" in msg
    assert "seen together: cam00-cam01" in msg and "cam00-cam03 0" in msg and "To fix:" in msg and "\n" not in msg
    assert not (tmp_path / "rig.json").exists()
    cfg = RunConfig()
    cfg = dataclasses.replace(cfg, scene=dataclasses.replace(cfg.scene, source=str(root)))
    with pytest.raises(InputError, match="board calibration refused"):
        calibrate_into_run(cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run" / "rig.json").exists()


def test_a_camera_missing_from_the_board_videos_is_named(tmp_path, capsys):
    cameras = build_rig(RIG)
    root = _capture(tmp_path / "capture", cameras, board_poses(SPEC, cameras, *VOLUME, count=2), hidden={})
    (root / "cam04").mkdir()
    cv2.imwrite(str(root / "cam04" / "000000.png"), np.zeros((240, 320), np.uint8))
    assert main(["calibrate", str(root), "--out", str(tmp_path / "rig.json"), "--quiet"]) == 2
    assert "no board video for cameras ['cam04']" in capsys.readouterr().err



def test_focal_from_a_board_rig_gives_each_camera_its_prior(tmp_path, tiny4, capture_writer):
    """`--focal-from RIG`: each camera's focal at the videos' size (a board filmed at twice the
    size) as its prior, with the board's uncertainty; a distorting lens is refused."""
    from fixer4d.cli.calibrate import focal_from
    from fixer4d.calib.priors import DEFAULT_PRIOR_SD_REL
    from fixer4d.calib.rig import Rig
    from fixer4d.scene.capture import CaptureFiles

    scene, ids = tiny4
    names = capture_writer(scene, tmp_path / "cap", ids)
    files = CaptureFiles(tmp_path / "cap")
    focals = [300.0, 301.0, 330.0, 300.5]
    board_rig = Rig([RigCamera(n, 128, 96, [[f, 0, 64], [0, f, 48], [0, 0, 1]], np.eye(4))
                     for n, f in zip(names, focals)], checks={"focal_std_rel": {names[0]: 0.002}})
    board_rig.write(tmp_path / "board_rig.json")
    priors = focal_from(str(tmp_path / "board_rig.json"), files)
    assert [priors[n].focal_px for n in names] == pytest.approx([f / 2 for f in focals])
    assert priors[names[0]].sd_px == pytest.approx(0.002 * 150.0)
    assert priors[names[1]].sd_px == pytest.approx(DEFAULT_PRIOR_SD_REL * 150.5)
    Rig([RigCamera(n, 128, 96, [[300.0, 0, 64], [0, 300.0, 48], [0, 0, 1]], np.eye(4), {"k1": -0.5})
         for n in names]).write(tmp_path / "board_rig.json")
    with pytest.raises(InputError, match="lens moves the image corners"):
        focal_from(str(tmp_path / "board_rig.json"), files)
