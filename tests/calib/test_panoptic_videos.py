"""The shared four-video Panoptic capture (../shared/data/panoptic_basketball_videos; skipped when
absent): `fixer4d calibrate --focal 466`, one focal for all where two cameras' lenses are 515 and
524 px, is refused naming exactly those two cameras with the frames' figures."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

VIDEOS = Path(__file__).resolve().parents[2].parent / "shared/data/panoptic_basketball_videos"


@pytest.mark.skipif(not (VIDEOS / "cam18.mp4").is_file(), reason=f"real-data test: {VIDEOS} is absent")
def test_one_focal_for_all_is_refused_for_the_two_cameras_it_misstates(tmp_path, capfd):
    from fixer4d.cli import main

    assert main(["calibrate", str(VIDEOS), "--out", str(tmp_path / "rig.json"), "--quiet", "--focal", "466"]) == 2
    err = capfd.readouterr().err
    contradicted = re.findall(r"camera (\w+): the focal prior 466\.0 \+- 4\.7 px contradicts its frames", err)
    assert contradicted == ["cam18", "cam23"]
    assert not (tmp_path / "rig.json").exists()
