"""Tiny captures made from the bundled synthetic scenes: videos or image folders, no calibration."""
from __future__ import annotations

from pathlib import Path

import pytest

from fixer4d.scene import load_scene
from fixer4d.scene.video import to_uint8, write_video


def write_capture(scene, root: Path, cams: list[int], *, kind: str = "videos", lead: dict[int, int] | None = None,
                  fps: dict[int, float] | None = None) -> list[str]:
    """Write cameras ``cams`` of ``scene`` as a capture: camNN.mp4 or camNN/000000.png; ``lead``
    prepends that many copies of frame 0 to a camera (a camera that started early); returns the names."""
    import cv2

    root.mkdir(parents=True, exist_ok=True)
    names = []
    for c in cams:
        name = scene.cameras[c].name
        frames = [scene.frame(0, c)] * (lead or {}).get(c, 0) + [scene.frame(f, c) for f in range(scene.num_frames)]
        if kind == "videos":
            write_video(root / f"{name}.mp4", frames, (fps or {}).get(c, scene.fps), crf=0)
        else:
            (root / name).mkdir()
            for i, img in enumerate(frames):
                cv2.imwrite(str(root / name / f"{i:06d}.png"), cv2.cvtColor(to_uint8(img), cv2.COLOR_RGB2BGR))
        names.append(name)
    return names


@pytest.fixture(scope="session")
def tiny4():
    """The tiny scene's four train cameras (64x48, 4 frames)."""
    scene = load_scene("tiny")
    return scene, list(scene.train_ids)


@pytest.fixture(scope="session")
def capture_writer():
    """``write_capture`` for tests."""
    return write_capture
