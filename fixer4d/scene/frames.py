"""The one frame-range syntax of fixer4d: ``"a:b"``, half-open, frames a..b-1 of the scene.

    parse_frame_range("0:20", 50)  -> (0, 20)
    parse_frame_range("10:", 50)   -> (10, 50)     (to the end)
    parse_frame_range(":5", 50)    -> (0, 5)
    check_frame_range((3, 80), 50) -> InputError: "... the scene has 50 frames ..."

Every command-line ``--frames a:b`` and every config ``scene.frame_range = [a, b]`` means the
same thing: the scene's frames a, a+1, ..., b-1 become frames 0..b-a-1 of the run, with times
t = (f - a) / (b - a) (``fixer4d.scene.load_scene``). Errors are one line naming the value,
the problem and a valid example for this scene.
"""
from __future__ import annotations

import re
from typing import Sequence

from fixer4d.errors import InputError

_RANGE_RE = re.compile(r"^\s*(\d*)\s*:\s*(\d*)\s*$")


def _valid_hint(num_frames: int | None) -> str:
    if num_frames is None:
        return "e.g. 0:20 for frames 0..19"
    return f"this scene has {num_frames} frames, so a:b with 0 <= a < b <= {num_frames}, e.g. 0:{num_frames}"


def parse_frame_range(text: str, num_frames: int | None = None, what: str = "--frames") -> tuple[int, int]:
    """``"a:b"`` (either end may be omitted: 0 and ``num_frames``) -> (a, b), half-open.

    num_frames: the scene's frame count; None checks the syntax and a < b only (the scene is
    not open yet; ``check_frame_range`` finishes the check once it is). Raises InputError
    naming ``what`` (the flag or config key) for anything else: a single number, a step, a
    comma list, negative values, an empty range, or a range past the scene's end.
    """
    m = _RANGE_RE.match(str(text))
    if m is None:
        raise InputError(f"{what} {text!r}: expected a:b, the half-open frame range a..b-1 "
                         f"({_valid_hint(num_frames)})")
    a_text, b_text = m.groups()
    start = int(a_text) if a_text else 0
    if b_text:
        stop = int(b_text)
    elif num_frames is not None:
        stop = int(num_frames)
    else:
        raise InputError(f"{what} {text!r}: an open end needs the scene's frame count; write a:b, e.g. {start}:{start + 20}")
    return check_frame_range((start, stop), num_frames, what)


def check_frame_range(frame_range: Sequence[int], num_frames: int | None = None,
                      what: str = "frame_range") -> tuple[int, int]:
    """Validate a half-open (a, b) against a scene of ``num_frames`` frames (None: only
    0 <= a < b); returns it as a tuple of ints, else one InputError line saying what to pass."""
    try:
        if isinstance(frame_range, (str, bytes)) or len(frame_range) != 2:
            raise TypeError
        start, stop = (int(v) for v in frame_range)
        if any(float(v) != int(v) for v in frame_range):
            raise TypeError
    except (TypeError, ValueError):
        raise InputError(f"{what} {frame_range!r}: expected two integers [a, b], the half-open frame range a..b-1 "
                         f"({_valid_hint(num_frames)})") from None
    if start < 0:
        raise InputError(f"{what} {start}:{stop}: frames start at 0 ({_valid_hint(num_frames)})")
    if stop <= start:
        raise InputError(f"{what} {start}:{stop}: empty range, b must be greater than a ({_valid_hint(num_frames)})")
    if num_frames is not None and stop > num_frames:
        raise InputError(f"{what} {start}:{stop}: out of range, {_valid_hint(num_frames)}")
    return start, stop
