"""``render_video``: render a model along cameras and times into an H.264 video or a PNG sequence.

    render_video(model, cameras, times, "out.mp4", fps=30)      # H.264 (PyAV, libx264)
    render_video(model, cameras, times, "frames/")               # frames/frame_00000.png, ...

Frames are rendered, encoded and dropped one at a time, so memory holds the model, one frame and
the encoder's look-ahead (``X264_OPTIONS``), whatever the length. The output appears only when
complete: the video is written to a temporary sibling and renamed, the PNGs to a temporary folder
that replaces the target. ``should_stop()`` returning True stops at the next frame, removes the
partial output and raises ``RenderCancelled``.
"""
from __future__ import annotations

from fractions import Fraction
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from fixer4d.atomic import atomic_dir, atomic_path
from fixer4d.errors import Fixer4DError, InputError
from fixer4d.geometry.camera import Camera
from fixer4d.model.formats.ply_sequence import check_output_folder
from fixer4d.render.api import render

# Suffix -> PyAV container format; any other suffix (or none) means a PNG folder.
VIDEO_FORMATS = {".mp4": "mp4", ".mov": "mov", ".mkv": "matroska"}
PNG_PATTERN = "frame_{:05d}.png"
# libx264 settings: CRF 18 is visually lossless for rendered content; a 10-frame rate-control
# look-ahead (x264 defaults to 40) bounds the frames the encoder holds, which is most of a
# video's memory at 640x360, at a small cost in bitrate.
X264_OPTIONS = {"crf": "18", "rc-lookahead": "10"}
# H.264 with 4:2:0 chroma needs even sizes: odd frames get one edge-replicated row/column.
PIX_FMT = "yuv420p"


class RenderCancelled(Fixer4DError):
    """``should_stop()`` asked to stop; the partial output was removed."""


RenderFn = Callable[[Camera, float], np.ndarray]


def is_video_path(out: str | Path) -> bool:
    """True when ``out`` names a video file (by suffix); else it is a PNG folder."""
    return Path(out).suffix.lower() in VIDEO_FORMATS


def model_frame_fn(model, backend: str = "auto", background: Sequence[float] | None = None) -> RenderFn:
    """``fn(camera, t) -> (H, W, 3)`` float RGB in [0, 1]: ``model`` at clip time t from ``camera``."""
    bg = None if background is None else torch.tensor(background, dtype=torch.float32)

    @torch.no_grad()
    def fn(camera: Camera, t: float) -> np.ndarray:
        snap = model.at(float(t), camera_center=camera.center)
        return render(snap, camera, background=bg, backend=backend).rgb.clamp(0, 1).cpu().numpy()

    return fn


def to_uint8(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) float in [0, 1] (or uint8) -> contiguous uint8."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise InputError(f"render_fn must return (H, W, 3) images, got shape {image.shape}")
    if image.dtype == np.uint8:
        return np.ascontiguousarray(image)
    return np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)


def _even(image: np.ndarray) -> np.ndarray:
    h, w = image.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return image
    return np.pad(image, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


class _VideoSink:
    """One H.264 stream in a container, opened at the first frame (when the size is known)."""

    def __init__(self, path: Path, container_format: str, fps: float) -> None:
        self.path, self.format, self.fps = path, container_format, fps
        self.container = None
        self.stream = None

    def write(self, image: np.ndarray) -> None:
        import av

        image = _even(image)
        if self.container is None:
            self.container = av.open(str(self.path), mode="w", format=self.format)
            self.stream = self.container.add_stream("libx264", rate=Fraction(self.fps).limit_denominator(1001),
                                                    options=dict(X264_OPTIONS))
            self.stream.width, self.stream.height = image.shape[1], image.shape[0]
            self.stream.pix_fmt = PIX_FMT
        frame = av.VideoFrame.from_ndarray(image, format="rgb24")
        for packet in self.stream.encode(frame):
            self.container.mux(packet)

    def finish(self) -> None:
        for packet in self.stream.encode():  # flush the encoder's delayed frames
            self.container.mux(packet)
        self.close()

    def close(self) -> None:
        if self.container is not None:
            self.container.close()
            self.container = None


def _is_png_frame(p: Path) -> bool:
    return p.name.startswith("frame_") and p.suffix == ".png"


def render_video(model, cameras: list[Camera], times: list[float], out: Path, *, fps: float = 30.0,
                 render_fn: RenderFn | None = None, progress: Callable[[int, int], None] | None = None,
                 should_stop: Callable[[], bool] | None = None) -> Path:
    """Render frame k = ``render_fn(cameras[k], times[k])`` for every k into ``out``; returns ``out``.

    out: a .mp4/.mov/.mkv file (H.264, yuv420p, ``fps`` frames per second) or, for any other
    name, a folder of frame_XXXXX.png (an existing folder is replaced only if it holds nothing
    but such frames). render_fn: default ``model_frame_fn(model)`` (automatic backend, black
    background); it may return a different size than the camera (e.g. side by side), but the
    same size for every frame. progress(done, total) after each frame. should_stop() is polled
    before each frame: True removes the partial output and raises ``RenderCancelled``.
    """
    out = Path(out)
    if len(cameras) != len(times):
        raise InputError(f"render_video: {len(cameras)} cameras but {len(times)} times; pass one time per camera")
    if not cameras:
        raise InputError("render_video: no frames to render (empty camera list)")
    if not fps > 0:
        raise InputError(f"render_video: fps must be > 0, got {fps}")
    fn = render_fn if render_fn is not None else model_frame_fn(model)
    total = len(cameras)
    size: tuple[int, ...] | None = None

    def frames():
        nonlocal size
        for k, (cam, t) in enumerate(zip(cameras, times)):
            if should_stop is not None and should_stop():
                raise RenderCancelled(f"{out}: rendering cancelled after {k} of {total} frames; nothing was written")
            image = to_uint8(fn(cam, float(t)))
            if size is None:
                size = image.shape
            elif image.shape != size:
                raise InputError(f"frame {k} is {image.shape[1]}x{image.shape[0]}, frame 0 was {size[1]}x{size[0]}; "
                                 "a video has one size: give every camera the same resolution")
            yield k, image
            if progress is not None:
                progress(k + 1, total)

    if is_video_path(out):
        with atomic_path(out) as tmp:
            sink = _VideoSink(tmp, VIDEO_FORMATS[out.suffix.lower()], float(fps))
            try:
                for _, image in frames():
                    sink.write(image)
                sink.finish()
            finally:
                sink.close()
        return out
    from PIL import Image

    check_output_folder(out, _is_png_frame)
    with atomic_dir(out) as tmp:
        for k, image in frames():
            Image.fromarray(image).save(tmp / PNG_PATTERN.format(k))
    return out
