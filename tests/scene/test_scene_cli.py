"""The make-scene verb and the raycast benchmark, through their entry points."""
from __future__ import annotations

import json

from fixer4d.cli import main


def test_bench_raycast_writes_rows(tmp_path, capsys):
    out = tmp_path / "raycast.json"
    assert main(["bench", "raycast", "--out", str(out), "--spec", "tiny", "--sizes", "40x30", "64x36",
                 "--supersample", "1", "2", "--repeats", "1"]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [(r["width"], r["height"], r["supersample"]) for r in rows] == [(40, 30, 1), (40, 30, 2), (64, 36, 1), (64, 36, 2)]
    assert all(r["ms"] > 0 and r["ms_median"] >= r["ms"] for r in rows)
    assert "64x36" in capsys.readouterr().out


def test_make_scene_reports_bad_spec(tmp_path, capsys):
    spec = tmp_path / "broken.json"
    spec.write_text(json.dumps({"frames": 2, "rig": {"layout": "grid"}, "objects": []}))
    assert main(["make-scene", str(spec), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "broken.json" in err and "objects" in err
    assert not (tmp_path / "out").exists()  # nothing half-written


def test_make_scene_options(tmp_path):
    from fixer4d.scene import SyntheticScene, load_scene

    out = tmp_path / "s"
    assert main(["make-scene", "tiny", "--out", str(out), "--scale", "0.5", "--frames", "1", "3",
                 "--supersample", "1", "--crf", "0", "--no-progress"]) == 0
    scene = load_scene(out)
    assert scene.num_frames == 2 and scene.cameras[0].width == 32
    ref = SyntheticScene("tiny", scale=0.5, frame_range=(1, 3), supersample=1)
    # crf 0 is lossless in YUV 4:4:4: only the RGB<->YUV rounding remains.
    assert abs(scene.frame(1, 3) - ref.frame(1, 3)).max() < 0.02
