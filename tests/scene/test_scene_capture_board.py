"""A capture's board/ folder (the calibration board's videos and board.json) is never read as a
camera, in either layout: camera videos or one image folder per camera."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from fixer4d.calib.board import BOARD_FOLDER, BoardSpec
from fixer4d.errors import InputError
from fixer4d.scene.capture import CaptureFiles, is_capture
from fixer4d.scene.video import write_video

NAMES = ["cam00", "cam01"]


def _image_folder(folder, frames: int = 2) -> None:
    folder.mkdir(parents=True)
    for i in range(frames):
        cv2.imwrite(str(folder / f"{i:06d}.png"), np.full((12, 16), 40 * i, np.uint8))


def _board_folder(root) -> None:
    """CAPTURE/board/ as a user leaves it: the printed board image and its board.json beside the
    board's own image folders (so the folder itself holds an image)."""
    board = root / BOARD_FOLDER
    for name in NAMES:
        _image_folder(board / name, frames=3)
    cv2.imwrite(str(board / "board.png"), np.zeros((12, 16), np.uint8))
    BoardSpec().write(board / "board.json")


@pytest.mark.parametrize("kind", ["images", "videos"])
def test_the_board_folder_is_not_a_camera(tmp_path, kind):
    for name in NAMES:
        if kind == "images":
            _image_folder(tmp_path / name)
        else:
            write_video(tmp_path / f"{name}.mp4", [np.zeros((12, 16, 3), np.uint8)] * 2, 30.0)
    _board_folder(tmp_path)
    files = CaptureFiles(tmp_path)
    assert files.names == NAMES and files.num_frames == 2
    assert CaptureFiles(tmp_path / BOARD_FOLDER).names == NAMES  # the board videos are a capture of their own


def test_a_folder_with_only_board_videos_is_no_capture(tmp_path):
    _board_folder(tmp_path)
    assert not is_capture(tmp_path)
    with pytest.raises(InputError, match="no camera videos"):
        CaptureFiles(tmp_path)
