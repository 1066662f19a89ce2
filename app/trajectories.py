"""Trajectory specs <-> cameras, and preset files.

A ``TrajectorySpec`` (app.state) is what the editor changes; its cameras come from
``fixer4d.geometry.trajectory`` (Eq. 3: c(a) = (1-a) c_i + a c_j + A sin(pi a) n_ij, SLERP
rotations), with n_ij from the whole rig as ``scene_trajectories`` does. Custom trajectories
join their keyframes with A = 0 segments.

Files go through the library: the fixer4d preset JSON (``save_presets``: every trajectory with
its cameras, readable by `fixer4d` itself; the viewer adds its specs under ``meta`` so a preset
reloads exactly) and the nerfstudio ``camera_path`` JSON (``save_nerfstudio``).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from app.state import TrajectorySpec
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera

# Key under the preset's "meta" where the viewer keeps its editable specs.
SPECS_META_KEY = "viewer_specs"


def alphas(n_frames: int, reverse: bool = False) -> np.ndarray:
    """(F,) evenly spaced alpha in [0, 1] (both endpoints, the real cameras, included)."""
    a = np.linspace(0.0, 1.0, max(int(n_frames), 2))
    return a[::-1].copy() if reverse else a


def build_cameras(spec: TrajectorySpec, train_cameras: list[Camera]) -> list[Camera]:
    """The cameras of ``spec``: a pair of train cameras (indices into ``train_cameras``) with
    amplitude A, or its keyframes joined piecewise. Empty when the spec cannot be built (a pair
    index outside the rig, fewer than 2 keyframes)."""
    from fixer4d.geometry.trajectory import arc_normal, interpolate_pair

    if spec.pair is not None:
        i, j = spec.pair
        if not (0 <= i < len(train_cameras) and 0 <= j < len(train_cameras)):
            return []
        normal = None
        if spec.amplitude != 0.0:  # the rig's mean image-up and view, as scene_trajectories
            up = np.sum([-c.c2w[:3, 1] / np.linalg.norm(c.c2w[:3, 1]) for c in train_cameras], axis=0)
            forward = np.sum([c.forward for c in train_cameras], axis=0)
            normal = arc_normal(train_cameras[i].center, train_cameras[j].center, up, forward)
        return list(interpolate_pair(train_cameras[i], train_cameras[j], alphas(spec.n_frames, spec.reverse),
                                     spec.amplitude, normal, name=spec.name))
    keys = [Camera.from_dict(k) for k in spec.keyframes]
    if len(keys) < 2:
        return []
    n = max(int(spec.n_frames), len(keys))
    # frames per segment proportional to the segment's length (uniform speed along the path)
    lengths = np.array([np.linalg.norm(b.center - a.center) for a, b in zip(keys[:-1], keys[1:])]) + 1e-9
    counts = np.maximum(1, np.round(lengths / lengths.sum() * (n - 1)).astype(int))
    cams: list[Camera] = [keys[0]]
    for (a, b), m in zip(zip(keys[:-1], keys[1:]), counts):
        try:
            cams.extend(interpolate_pair(a, b, np.linspace(0.0, 1.0, int(m) + 1)[1:], 0.0, name=spec.name))
        except InputError:  # the same view keyed twice: no segment to add
            continue
    return cams[::-1] if spec.reverse else cams


def default_specs(train_cameras: list[Camera], n_frames: int, amplitude: float | None = None,
                  camera_ids: list[int] | None = None) -> list[TrajectorySpec]:
    """The 6 pair trajectories (A = 0) and the diagonal arcs, as the library proposes them.
    ``camera_ids``: the scene's id of each train camera; the names then use them ("0-15",
    "0-15_arc0"), as the restoration cache's clip keys do, so one pair has one name everywhere."""
    from fixer4d.geometry.trajectory import scene_trajectories

    specs = []
    for tr in scene_trajectories(train_cameras, n_frames, amplitude=amplitude, arcs=True):
        pair = None if tr.pair is None else (int(tr.pair[0]), int(tr.pair[1]))
        name = tr.name
        if camera_ids is not None and pair is not None:
            name = f"{camera_ids[pair[0]]}-{camera_ids[pair[1]]}" + \
                ("" if tr.arc_index is None else f"_arc{tr.arc_index}")
        specs.append(TrajectorySpec(name=name, pair=pair, amplitude=float(tr.amplitude), n_frames=int(n_frames),
                                    arc_index=tr.arc_index))
    return specs


def to_trajectory(spec: TrajectorySpec, train_cameras: list[Camera]) -> Any:
    """The library's ``Trajectory`` for a spec (its cameras built)."""
    from fixer4d.geometry.trajectory import Trajectory

    cams = build_cameras(spec, train_cameras)
    if not cams:
        raise InputError(f"trajectory {spec.name!r} has no cameras (a custom path needs 2 keyframes)")
    a = np.linspace(0.0, 1.0, len(cams))
    return Trajectory(spec.name, cams, a[::-1].copy() if spec.reverse else a, pair=spec.pair,
                      amplitude=spec.amplitude, arc_index=spec.arc_index)


def from_trajectory(tr: Any) -> TrajectorySpec:
    """A spec for a library ``Trajectory``: pair paths stay editable (pair, A, frames), others
    become custom paths with every camera a keyframe."""
    reverse = len(tr.alphas) > 1 and tr.alphas[0] > tr.alphas[-1]
    if tr.pair is not None:
        return TrajectorySpec(name=tr.name, pair=(int(tr.pair[0]), int(tr.pair[1])), amplitude=float(tr.amplitude),
                              n_frames=len(tr.cameras), reverse=bool(reverse), arc_index=tr.arc_index)
    return TrajectorySpec(name=tr.name, keyframes=tuple(c.to_dict() for c in tr.cameras), n_frames=len(tr.cameras))


def save_preset(path: str | Path, specs: list[TrajectorySpec], train_cameras: list[Camera]) -> Path:
    """Write the fixer4d preset JSON (atomic) with the specs' cameras and the specs themselves."""
    from fixer4d.geometry.trajectory import save_presets

    trajs = [to_trajectory(s, train_cameras) for s in specs]
    return save_presets(trajs, path, meta={SPECS_META_KEY: [s.to_dict() for s in specs]})


def load_preset(path: str | Path) -> list[TrajectorySpec]:
    """Read a fixer4d preset: the viewer's own specs when it wrote them, else one spec per
    trajectory of the file."""
    from fixer4d.geometry.trajectory import load_presets

    trajs = load_presets(path)
    meta = json.loads(Path(path).read_text()).get("meta") or {}
    specs = meta.get(SPECS_META_KEY)
    if isinstance(specs, list) and len(specs) == len(trajs):
        try:
            return [TrajectorySpec.from_dict(d) for d in specs]
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: malformed viewer trajectory spec ({exc}); delete meta.{SPECS_META_KEY}") from exc
    return [from_trajectory(t) for t in trajs]


def save_camera_path(path: str | Path, spec: TrajectorySpec, train_cameras: list[Camera], time: float,
                     fps: float = 30.0) -> Path:
    """nerfstudio ``camera_path`` JSON for one trajectory rendered at clip time ``time``."""
    from fixer4d.geometry.trajectory import save_nerfstudio

    return save_nerfstudio(to_trajectory(spec, train_cameras), path, render_time=float(time), fps=fps)


def load_camera_path(path: str | Path) -> TrajectorySpec:
    """A custom trajectory whose keyframes are the camera_path's cameras."""
    from fixer4d.geometry.trajectory import load_nerfstudio

    return from_trajectory(load_nerfstudio(path))


def spec_meta(spec: TrajectorySpec) -> dict[str, Any]:
    """JSON metadata of a trajectory for restore requests and cache entries."""
    return {"name": spec.name, "pair": None if spec.pair is None else list(spec.pair), "amplitude": spec.amplitude,
            "arc_index": spec.arc_index, "n_frames": spec.n_frames, "reverse": spec.reverse}
