"""Video files through PyAV: atomic H.264 encoding and lazy, bounded-memory decoding.

``VideoReader`` keeps one open decoder per file and a small LRU of decoded frames, so reading a
clip frame by frame costs one decode per frame, random access costs a seek to the previous
keyframe, and memory never grows with the clip length.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from fixer4d.atomic import atomic_path
from fixer4d.errors import InputError

# x264 constant-rate factor for written scenes: 0 is lossless (not every player decodes it),
# 12 is visually lossless; loaders then see real codec artefacts of a fraction of a grey level.
VIDEO_CRF = 12
# Full chroma (4:4:4): the synthetic scenes' fine textures would lose colour detail to 4:2:0.
VIDEO_PIX_FMT = "yuv444p"
# Decoded frames kept per reader (uint8 RGB). 32 frames of 1352x1014 are ~130 MB per camera.
READER_CACHE_FRAMES = 32
# Decoding forward by up to this many frames is cheaper than a seek (which restarts from the
# previous keyframe, typically up to 250 frames back for x264 defaults).
SEEK_AHEAD_FRAMES = 48


def _corrupt(path: Path, detail: str, frame: int | None = None) -> InputError:
    where = "the video" if frame is None else f"frame {frame} (its header reads, its frames do not)"
    return InputError(f"{path}: cannot decode {where}: {detail}; the file is corrupt or truncated: "
                      f"re-download it or re-encode it (e.g. ffmpeg -i in.mp4 -c:v libx264 out.mp4)")


def to_uint8(frame: np.ndarray) -> np.ndarray:
    """(H, W, 3) float in [0, 1] (or uint8) -> contiguous uint8 RGB."""
    if frame.dtype == np.uint8:
        return np.ascontiguousarray(frame)
    return np.ascontiguousarray(np.clip(np.rint(np.asarray(frame, np.float64) * 255.0), 0, 255).astype(np.uint8))


def write_video(path: str | Path, frames: Iterable[np.ndarray], fps: float, *, crf: int = VIDEO_CRF,
                pix_fmt: str = VIDEO_PIX_FMT) -> Path:
    """Encode RGB frames ((H, W, 3) float32 in [0, 1] or uint8, all the same size) to an H.264
    mp4 at ``fps``, atomically. Width and height must be even for 4:2:0 formats."""
    import av
    from fractions import Fraction

    path = Path(path)
    rate = Fraction(fps).limit_denominator(1001)
    with atomic_path(path) as tmp:
        with av.open(str(tmp), mode="w", format="mp4") as out:
            stream = None
            for rgb in frames:
                img = to_uint8(rgb)
                if stream is None:
                    stream = out.add_stream("libx264", rate=rate)
                    stream.width, stream.height = img.shape[1], img.shape[0]
                    stream.pix_fmt = pix_fmt
                    stream.options = {"crf": str(int(crf)), "preset": "medium"}
                vf = av.VideoFrame.from_ndarray(img, format="rgb24").reformat(format=pix_fmt)
                for packet in stream.encode(vf):
                    out.mux(packet)
            if stream is None:
                raise InputError(f"{path}: no frames to write")
            for packet in stream.encode():
                out.mux(packet)
    return path


@dataclass(frozen=True)
class VideoInfo:
    width: int
    height: int
    num_frames: int
    fps: float


def probe_video(path: str | Path) -> VideoInfo:
    """Size, frame count and rate of a video file; InputError if missing or unreadable."""
    import av

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: video file not found; check the scene folder")
    try:
        with av.open(str(path)) as c:
            if not c.streams.video:
                raise _corrupt(path, "no video stream")
            s = c.streams.video[0]
            n = int(s.frames)
            if n <= 0:
                n = sum(1 for p in c.demux(s) if p.size)
            rate = s.average_rate or s.guessed_rate
            if n <= 0 or not rate:
                raise _corrupt(path, "no frames")
            return VideoInfo(int(s.codec_context.width), int(s.codec_context.height), n, float(rate))
    except av.error.FFmpegError as exc:
        raise _corrupt(path, str(exc)) from None


class VideoReader:
    """Lazy random access to the frames of one video file, bounded memory.

    ``frame(i)`` -> (H, W, 3) uint8 RGB. Thread-safe (one decoder per reader behind a lock).
    """

    def __init__(self, path: str | Path, cache_frames: int = READER_CACHE_FRAMES) -> None:
        self.path = Path(path)
        self.info = probe_video(self.path)
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._cache_frames = max(1, int(cache_frames))
        self._lock = threading.Lock()
        self._container = None
        self._decoder = None
        self._next = 0  # index of the frame the decoder yields next

    def __len__(self) -> int:
        return self.info.num_frames

    def close(self) -> None:
        with self._lock:
            self._close()

    def _close(self) -> None:
        if self._container is not None:
            self._container.close()
        self._container = self._decoder = None

    def _open_at(self, index: int) -> None:
        import av

        self._close()
        try:
            self._container = av.open(str(self.path))
            stream = self._container.streams.video[0]
            stream.thread_type = "AUTO"
            self._stream = stream
            if index > 0:
                tb = stream.time_base
                start = stream.start_time or 0
                self._container.seek(int(start + index / self.info.fps / tb), stream=stream, backward=True)
                self._next = -1  # unknown until the first decoded frame's timestamp
            else:
                self._next = 0
            self._decoder = self._container.decode(stream)
        except av.error.FFmpegError as exc:
            self._close()
            raise _corrupt(self.path, str(exc), index) from None

    def _index_of(self, frame) -> int:
        start = self._stream.start_time or 0
        return int(round(float((frame.pts - start) * self._stream.time_base) * self.info.fps))

    def _put(self, index: int, img: np.ndarray) -> None:
        self._cache[index] = img
        self._cache.move_to_end(index)
        while len(self._cache) > self._cache_frames:
            self._cache.popitem(last=False)

    def frame(self, index: int) -> np.ndarray:
        import av

        if not 0 <= index < self.info.num_frames:
            raise InputError(f"{self.path}: frame {index} out of range [0, {self.info.num_frames})")
        with self._lock:
            if index in self._cache:
                self._cache.move_to_end(index)
                return self._cache[index]
            if self._decoder is None or not (0 <= self._next <= index <= self._next + SEEK_AHEAD_FRAMES):
                self._open_at(index)
            try:
                while True:
                    try:
                        fr = next(self._decoder)
                    except StopIteration:
                        raise _corrupt(self.path, f"the stream ended before it, though the header declares "
                                                  f"{self.info.num_frames} frames", index) from None
                    if fr.pts is not None:
                        i = self._index_of(fr)
                    elif self._next >= 0:
                        i = self._next
                    else:
                        raise _corrupt(self.path, "frames carry no timestamps, so a seek cannot be resolved", index)
                    self._next = i + 1
                    if i >= index - self._cache_frames:
                        self._put(i, fr.to_ndarray(format="rgb24"))
                    if i >= index:
                        break
            except av.error.FFmpegError as exc:
                self._close()
                raise _corrupt(self.path, str(exc), index) from None
            if index not in self._cache:
                raise _corrupt(self.path, "no decoded frame has this index (variable frame rate or a gap)", index)
            return self._cache[index]


def validate_video(path: str | Path, frames: Iterable[int] | None = None) -> VideoInfo:
    """Decode ``frames`` of the video at ``path`` (default: its first and last frame) with a
    fresh reader; InputError naming the file and the first frame that does not decode.

    A probe that reads only the header accepts a file whose frame data is damaged; this is the
    fast check to run before training (a seek to the last frame decodes at most one GOP)."""
    reader = VideoReader(path, cache_frames=1)
    try:
        wanted = [0, reader.info.num_frames - 1] if frames is None else list(frames)
        for f in dict.fromkeys(int(i) for i in wanted):
            reader.frame(f)
        return reader.info
    finally:
        reader.close()
