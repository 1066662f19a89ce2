"""`fixer4d eval RUN --cameras-from demo_val` on a demo run: the bundled validation spec is
accepted by name and scores the run on its 9 validation cameras; a scene with the same cameras
but other pixels is refused."""
from __future__ import annotations

import json

import pytest

from fixer4d.errors import InputError
from fixer4d.cli.reconstruct import RECONSTRUCT_ONLY
from fixer4d.pipeline.other_cameras import evaluate_on_other_cameras

from pipeline_tiny import TINY

# The smallest demo reconstruction: 40x30 pixels, 4 frames, TINY's stage 1.
SMALL_DEMO = {**TINY, **RECONSTRUCT_ONLY, "scene.scale": 0.2, "scene.frame_range": [0, 4]}


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory, stage_cache):
    from fixer4d.pipeline.config import resolve
    from fixer4d.pipeline.run import run_pipeline

    run_dir = tmp_path_factory.mktemp("run") / "demo"
    run_pipeline(resolve("demo", overrides=SMALL_DEMO), run_dir, progress=False, stage_cache=stage_cache)
    return run_dir


def test_cameras_from_accepts_the_bundled_validation_spec(demo_run, capsys):
    from fixer4d.cli import main

    assert main(["eval", str(demo_run), "--cameras-from", "demo_val", "--quiet"]) == 0
    report = json.loads((demo_run / "heldout" / "demo_val" / "report.json").read_text())
    assert report["heldout_from"] == "demo_val"
    assert "9 held out" in report["scene"], report["scene"]
    psnr = report["rows"][0]["psnr"]
    assert report["rows"][0]["method"] == "STGS w/ MVS" and 5.0 < psnr < 60.0


def test_a_scene_with_the_same_cameras_and_other_pixels_is_refused(demo_run):
    # static_matte has the demo's rig and train cameras but no moving objects.
    with pytest.raises(InputError, match="images differ"):
        evaluate_on_other_cameras(demo_run, "static_matte", progress=False)
