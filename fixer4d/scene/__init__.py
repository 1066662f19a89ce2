"""fixer4d.scene: multi-view video sources (synthetic, Neural3DV, Panoptic) behind one loader.

``load_scene(source)`` is the only entry most code needs; the classes are exported for typing
and for callers that want a specific layout. ``parse_frame_range`` is the one ``a:b`` frame
range syntax (half-open); ``validate_scene`` decodes the first and last frame of every camera
so that damaged input files fail before training starts; ``open_scene_checked`` does all of
it (the call a run makes before writing anything).
"""
from __future__ import annotations

from pathlib import Path

import difflib
import numbers

from fixer4d.errors import InputError
from fixer4d.scene.base import MultiViewVideo, SceneBounds
from fixer4d.scene.frames import check_frame_range, parse_frame_range
from fixer4d.scene.synthetic import SyntheticScene, builtin_spec_path, is_builtin_name
from fixer4d.scene.validate import validate_scene

__all__ = ["load_scene", "open_scene_checked", "detect_layout", "builtin_scene_names", "parse_frame_range", "check_frame_range",
           "validate_scene", "MultiViewVideo", "SceneBounds", "SyntheticScene", "Neural3DVScene", "PanopticScene"]


def builtin_scene_names() -> list[str]:
    """Names of the bundled synthetic scene specs ("demo", "tiny", ...), sorted."""
    return sorted(p.stem for p in builtin_spec_path("demo").parent.glob("*.json"))


def _no_such_scene(source: str | Path) -> InputError:
    names = builtin_scene_names()
    close = difflib.get_close_matches(Path(str(source)).name, names, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    what = "spec file not found" if Path(str(source)).suffix == ".json" else "no such file, folder or bundled scene"
    return InputError(f"scene {str(source)!r}: {what}{hint}; pass a bundled name ({', '.join(names)}), "
                      f"a spec .json or a Neural3DV/Panoptic scene folder")


def detect_layout(path: str | Path) -> str:
    """"n3dv" (poses_bounds.npy + camXX.mp4), "panoptic" (train_meta.json + ims/) or "capture"
    (one video or image folder per camera, any names: ``fixer4d.scene.capture``) for a
    directory; raises InputError naming the folder and the expected files otherwise."""
    import re

    from fixer4d.scene.capture import is_capture

    path = Path(path)
    if (path / "poses_bounds.npy").is_file() and (any(re.match(r"^cam\d+\.mp4$", p.name) for p in path.iterdir())
                                                   or not is_capture(path)):
        return "n3dv"  # a capture with other video names reads poses_bounds.npy as its calibration
    if (path / "train_meta.json").is_file() and (path / "ims").is_dir():
        return "panoptic"
    if is_capture(path):
        return "capture"
    found = sorted(p.name for p in path.iterdir())[:8] if path.is_dir() else []
    raise InputError(
        f"{path}: unknown scene layout (found {found}). Expected a Neural3DV folder "
        f"(poses_bounds.npy + cam00.mp4, cam01.mp4, ...), a Dynamic3DGaussians/Panoptic folder "
        f"(train_meta.json, test_meta.json, ims/<cam>/<frame>.jpg), a capture (one video or image folder per "
        f"camera), a scene spec .json, or 'demo'; "
        f"write a synthetic one with `fixer4d make-scene demo --out DIR`")


def load_scene(source: str | Path, *, scale: float = 1.0, frame_range: tuple[int, int] | None = None,
               train_ids: list[int] | None = None, test_ids: list[int] | None = None,
               calibration: str | Path | None = None, offsets: dict[str, int] | None = None,
               holdout: list[str] | None = None) -> MultiViewVideo:
    """Open a scene.

    source: "demo" (or another bundled spec name: "tiny", "static_matte"; a bare name always
      means the bundled spec, write "./demo" for a folder of that name), a spec .json path
      (synthetic, ray-cast on demand), or a directory whose layout is detected (Neural3DV or
      Panoptic/Dynamic3DGaussians).
    scale: image scale (0.5 = half resolution); intrinsics scale with the image.
    frame_range: (a, b), half-open: keep frames a..b-1; times become t = (f - a) / (b - a).
    train_ids / test_ids: camera ids (the XX of camXX, the Panoptic cam_id, the synthetic
      camera index) overriding the layout's default split. A camera listed twice, or both train
      and held-out, is refused (InputError; ``validate.check_ids``).
    calibration / offsets / holdout: for a capture folder only (``fixer4d.scene.capture``): a
      calibration file (default: one beside the videos, else a cached self-calibration), the
      per-camera start frames {name: N}, and camera names to hold out (default: none).
    """
    from fixer4d.scene.validate import check_ids

    if isinstance(scale, bool) or not isinstance(scale, numbers.Real) or not 0 < scale < float("inf"):
        raise InputError(f"scene {source!s}: scale must be a number > 0 (0.5 = half resolution), got {scale!r}")
    if calibration is not None or offsets or holdout:
        src = Path(str(source))
        if not (src.is_dir() and detect_layout(src) == "capture"):
            raise InputError(f"{source}: --calibration, --offset and --holdout apply to a capture folder (one video "
                             f"or image folder per camera), not to this scene")
        scene = _open_capture(src, scale, frame_range, train_ids, test_ids, calibration, offsets, holdout)
    else:
        scene = _open_layout(source, scale, frame_range, train_ids, test_ids)
    check_ids(scene)
    return scene


def _open_layout(source: str | Path, scale: float, frame_range: tuple[int, int] | None, train_ids: list[int] | None,
                 test_ids: list[int] | None) -> MultiViewVideo:
    """``load_scene`` without the split check: the layout's reader."""
    if frame_range is not None:
        frame_range = check_frame_range(frame_range)  # 0 <= a < b here; each layout checks b <= its length
    if is_builtin_name(source):
        return SyntheticScene(builtin_spec_path(str(source)), scale=scale, frame_range=frame_range,
                              train_ids=train_ids, test_ids=test_ids)
    src = Path(source)
    if not src.exists():
        raise _no_such_scene(source)
    if src.is_dir():
        layout = detect_layout(src)
        if layout == "capture":
            return _open_capture(src, scale, frame_range, train_ids, test_ids, None, None, None)
        if layout == "n3dv":
            from fixer4d.scene.n3dv import Neural3DVScene

            return Neural3DVScene(src, scale=scale, frame_range=frame_range, train_ids=train_ids, test_ids=test_ids)
        from fixer4d.scene.panoptic import PanopticScene

        return PanopticScene(src, scale=scale, frame_range=frame_range, train_ids=train_ids, test_ids=test_ids)
    if src.suffix == ".json":
        return SyntheticScene(src, scale=scale, frame_range=frame_range, train_ids=train_ids, test_ids=test_ids)
    raise InputError(f"scene {source!s}: not a directory or a .json spec; pass 'demo', a spec .json or a scene folder")


def _open_capture(src: Path, scale: float, frame_range: tuple[int, int] | None, train_ids: list[int] | None,
                  test_ids: list[int] | None, calibration: str | Path | None, offsets: dict[str, int] | None,
                  holdout: list[str] | None) -> MultiViewVideo:
    """A capture folder with its rig (``fixer4d.calib.resolve_rig``)."""
    from fixer4d.calib import resolve_rig
    from fixer4d.scene.capture import CaptureFiles, CaptureScene

    if frame_range is not None:
        frame_range = check_frame_range(frame_range)
    files = CaptureFiles(src, offsets, frame_range)
    rig, label = resolve_rig(files, calibration)
    return CaptureScene(files, rig, label, scale=scale, holdout=holdout, train_ids=train_ids, test_ids=test_ids)


def open_scene_checked(source: str | Path, *, scale: float = 1.0, frame_range: str | tuple[int, int] | list[int] | None = None,
                       train_ids: list[int] | None = None, test_ids: list[int] | None = None,
                       what: str = "--frames") -> MultiViewVideo:
    """``load_scene`` with every input check a run needs before it writes anything.

    frame_range: "a:b" text (``parse_frame_range``) or (a, b); checked against the source's own
    length with one line naming ``what``, the value and the valid range. The scene's files are
    then probed with ``validate_scene`` (first and last frame of every camera decode). Raises
    InputError for a missing scene, a bad range or an undecodable file; returns the scene.
    """
    if frame_range is not None:
        full = load_scene(source, scale=scale, train_ids=train_ids, test_ids=test_ids)
        if isinstance(frame_range, str):
            frame_range = parse_frame_range(frame_range, full.num_frames, what)
        else:
            frame_range = check_frame_range(frame_range, full.num_frames, what)
    scene = load_scene(source, scale=scale, frame_range=frame_range, train_ids=train_ids, test_ids=test_ids)
    validate_scene(scene)
    return scene


def __getattr__(name: str):
    if name == "Neural3DVScene":
        from fixer4d.scene.n3dv import Neural3DVScene

        return Neural3DVScene
    if name == "PanopticScene":
        from fixer4d.scene.panoptic import PanopticScene

        return PanopticScene
    raise AttributeError(name)
