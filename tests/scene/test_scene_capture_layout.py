"""A capture's layout as people bring it: no camera is left out silently (a folder without images,
videos beside image folders), and the image formats cameras write read as the same 8-bit RGB."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.scene.capture import CaptureFiles
from fixer4d.scene.video import write_video

FRAME = np.dstack([np.full((12, 16), v, np.uint8) for v in (30, 120, 210)])  # BGR as OpenCV writes it


def _images(folder, ext: str = ".png", frames: int = 2, image: np.ndarray = FRAME) -> None:
    folder.mkdir(parents=True)
    for i in range(frames):
        assert cv2.imwrite(str(folder / f"{i:06d}{ext}"), image)


def test_a_camera_folder_without_images_is_named(tmp_path):
    _images(tmp_path / "cam00")
    _images(tmp_path / "cam01")
    (tmp_path / "cam02").mkdir()
    (tmp_path / "cam03").mkdir()
    (tmp_path / "cam03" / "notes.txt").write_text("frames to come")
    with pytest.raises(InputError, match=r"without images: cam02 \(found nothing\); cam03 \(found \['.txt'\]\)"):
        CaptureFiles(tmp_path)


def test_videos_beside_image_folders_are_refused_naming_both(tmp_path):
    write_video(tmp_path / "cam00.mp4", [FRAME] * 2, 30.0)
    write_video(tmp_path / "cam01.mp4", [FRAME] * 2, 30.0)
    _images(tmp_path / "cam02")
    with pytest.raises(InputError, match=r"videos \(cam00.mp4, cam01.mp4\) and image folders \(cam02\)"):
        CaptureFiles(tmp_path)


def test_a_calibration_folder_is_no_camera(tmp_path):
    _images(tmp_path / "cam00")
    _images(tmp_path / "cam01")
    (tmp_path / "sparse" / "0").mkdir(parents=True)  # COLMAP's model beside the frames
    (tmp_path / ".cache").mkdir()
    assert CaptureFiles(tmp_path).names == ["cam00", "cam01"]


@pytest.mark.parametrize("ext, image", [
    (".jpg", None), (".tif", None), (".tiff", None), (".bmp", None), (".webp", None),
    (".png", FRAME.astype(np.uint16) * 257),                 # 16 bit: scaled to 8 bit
    (".png", cv2.cvtColor(FRAME, cv2.COLOR_BGR2BGRA)),       # alpha: dropped
    (".tif", FRAME.astype(np.uint16) * 257),
])
def test_image_formats_read_as_8_bit_rgb(tmp_path, ext, image):
    lossless = ext not in (".jpg", ".webp")
    for cam in ("cam00", "cam01"):
        _images(tmp_path / cam, ext, image=FRAME if image is None else image)
    files = CaptureFiles(tmp_path)
    rgb = files.frame(1, 0)
    assert rgb.dtype == np.uint8 and rgb.shape == (12, 16, 3)
    np.testing.assert_allclose(rgb.reshape(-1, 3).mean(0), [210, 120, 30], atol=0 if lossless else 3)


def test_grey_images_read_as_three_equal_channels(tmp_path):
    for cam in ("cam00", "cam01"):
        _images(tmp_path / cam, image=np.full((12, 16), 77, np.uint8))
    assert np.all(CaptureFiles(tmp_path).frame(0, 1) == 77)
