"""Novel-view trajectories between pairs of train cameras (docs/design.md §10, Eq. 3) and their presets.

For a pair (i, j) and alpha in [0, 1]:

    c(alpha) = (1 - alpha) c_i + alpha c_j + A sin(pi alpha) n_ij
    q(alpha) = SLERP(q_i, q_j, alpha)          (camera-to-world rotation)
    K(alpha) = (1 - alpha) K_i + alpha K_j

n_ij is a unit vector perpendicular to the baseline c_j - c_i, chosen by ``arc_normal``: the
component of the rig's mean image-up direction orthogonal to the baseline (arcs rise "upward"
as the cameras see it); when the up direction is (nearly) parallel to the baseline (e.g. a
vertical or collinear rig stacked along up), the component of the mean viewing direction (arcs
bulge toward the scene); failing both, a fixed perpendicular. The camera at alpha = 0 and 1 is
the pair's camera itself, bit for bit.

Coincident centres: an arc (A != 0) needs a baseline, so it raises InputError; with A = 0 and
different orientations the path is a rotation in place (the centre stays, SLERP turns the
camera); identical cameras (same centre and orientation) have no trajectory and raise.

Presets: fixer4d's versioned JSON (``save_presets``/``load_presets``) and nerfstudio
``camera_path`` JSON (``save_nerfstudio``/``load_nerfstudio``: row-major 4x4 c2w in OpenGL axes,
vertical fov in degrees, per-frame ``render_time``). All writes are atomic.
"""
from __future__ import annotations

import itertools
import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from fixer4d.atomic import write_json
from fixer4d.errors import InputError
from fixer4d.geometry import quaternion as quat
from fixer4d.geometry.camera import Camera

PRESET_FORMAT = "fixer4d-trajectories"
PRESET_VERSION = 1

# Frames per trajectory when none are asked for: a short clip keeps restoration cheap on the CPU
# (the restore benchmark measures clips of this length).
DEFAULT_FRAMES = 16
# Arc amplitude drawn uniformly in this range times the pair's baseline when none is given: a
# 10-30% lift off the straight path reveals regions no train camera saw (the holes the restorer
# must fill) while staying close enough to the rig that the references still cover most pixels.
ARC_AMPLITUDE_RANGE = (0.1, 0.3)
# Centres closer than this, relative to their distance from the origin (at least 1), are the same
# point to float64 pose precision: no baseline, no arc.
COINCIDENT_REL = 1e-9
# Rotations whose matrices differ by at most this (entry-wise, ~ the angle in radians) are the
# same orientation: a rotation-only path between them would be a still frame. Compared on the
# matrices because arccos-based angles cannot resolve below ~1e-8.
SAME_ORIENTATION_TOL = 1e-12
# Poses read back from a cache's JSON agree with the originals to ~1e-15; a clip camera within
# this (entry-wise rotation difference) of a train camera at the same centre is that camera.
SAME_POSE_TOL = 1e-9
# A candidate normal direction is used only if its component orthogonal to the baseline keeps at
# least this length (unit vectors): below it (< 0.06 degrees from the baseline) pose noise would
# flip the arc's side.
MIN_PERPENDICULAR = 1e-3
# nerfstudio's default playback rate.
NERFSTUDIO_FPS = 30.0
# nerfstudio's camera_path holds one vertical fov per frame: square pixels and a centred principal
# point. A camera whose fx/fy or principal point (relative to the image size) differs by more
# than this round-off level is written as a different camera, so save_nerfstudio warns.
NERFSTUDIO_INTRINSICS_TOL = 1e-6


@dataclass(eq=False)
class Trajectory:
    """A camera path of F frames.

    cameras: F cameras; alphas: (F,) path parameter in [0, 1]; pair: indices (i, j) into the train
    cameras (None for a custom or imported path); amplitude: the arc amplitude A in world units
    (0 for a straight pair path); arc_index: which diagonal arc (None for a pair path); seed: the
    seed A was drawn with (None when A was given); times: optional (F,) per-frame render times
    in [0, 1) (None = render every frame at the clip time chosen by the caller); view_index: which
    pick of ``geometry.view_candidates`` the path reaches (None for a pair path or arc).
    """

    name: str
    cameras: list[Camera]
    alphas: np.ndarray
    pair: tuple[int, int] | None = None
    amplitude: float = 0.0
    arc_index: int | None = None
    seed: int | None = None
    times: np.ndarray | None = field(default=None)
    view_index: int | None = None

    def __post_init__(self) -> None:
        self.alphas = np.asarray(self.alphas, dtype=np.float64).reshape(-1)
        if len(self.cameras) != self.alphas.shape[0]:
            raise InputError(f"trajectory {self.name!r}: {len(self.cameras)} cameras but {self.alphas.shape[0]} alphas")
        if self.times is not None:
            self.times = np.asarray(self.times, dtype=np.float64).reshape(-1)
            if self.times.shape[0] != len(self.cameras):
                raise InputError(f"trajectory {self.name!r}: {self.times.shape[0]} times for {len(self.cameras)} frames")
        if self.pair is not None:
            self.pair = (int(self.pair[0]), int(self.pair[1]))

    @property
    def frames(self) -> int:
        return len(self.cameras)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "name": self.name, "pair": list(self.pair) if self.pair is not None else None,
            "amplitude": float(self.amplitude), "arc_index": self.arc_index, "frames": self.frames,
            "seed": self.seed, "alphas": self.alphas.tolist(), "cameras": [c.to_dict() for c in self.cameras],
        }
        if self.times is not None:
            d["times"] = self.times.tolist()
        if self.view_index is not None:
            d["view_index"] = int(self.view_index)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "preset") -> "Trajectory":
        try:
            cameras = [Camera.from_dict(c) for c in d["cameras"]]
            frames = int(d.get("frames", len(cameras)))
            if frames != len(cameras):
                raise InputError(f"{source}: trajectory {d.get('name')!r} says {frames} frames but has {len(cameras)} cameras")
            alphas = d.get("alphas")
            alphas = np.linspace(0.0, 1.0, frames) if alphas is None else np.asarray(alphas, dtype=np.float64)
            if not np.all(np.isfinite(alphas)):
                raise InputError(f"{source}: trajectory {d.get('name')!r} has non-finite alphas")
            return cls(name=str(d["name"]), cameras=cameras, alphas=alphas,
                       pair=tuple(d["pair"]) if d.get("pair") is not None else None,
                       amplitude=float(d.get("amplitude", 0.0)),
                       arc_index=None if d.get("arc_index") is None else int(d["arc_index"]),
                       seed=None if d.get("seed") is None else int(d["seed"]), times=d.get("times"),
                       view_index=None if d.get("view_index") is None else int(d["view_index"]))
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(f"{source}: malformed trajectory entry ({type(exc).__name__}: {exc}); "
                             "regenerate it with `fixer4d trajectories`") from exc


# ---- Eq. 3 ---------------------------------------------------------------------------------
def _coincident(a: np.ndarray, b: np.ndarray) -> bool:
    scale = max(1.0, float(np.linalg.norm(a)), float(np.linalg.norm(b)))
    return float(np.linalg.norm(b - a)) <= COINCIDENT_REL * scale


def same_pose(cam_i: Camera, cam_j: Camera) -> bool:
    """Whether two cameras share centre and orientation (no trajectory runs between them)."""
    return _coincident(cam_i.center, cam_j.center) and float(np.max(np.abs(cam_i.R - cam_j.R))) <= SAME_ORIENTATION_TOL


def _image_up(cam: Camera) -> np.ndarray:
    """World direction that points up in the image (OpenCV image-up is camera -y)."""
    return -cam.c2w[:3, 1] / np.linalg.norm(cam.c2w[:3, 1])


def arc_normal(c_i: np.ndarray, c_j: np.ndarray, up: np.ndarray | None = None,
               forward: np.ndarray | None = None) -> np.ndarray:
    """Unit n_ij perpendicular to the baseline c_j - c_i (see the module docstring).

    up, forward: (3,) the rig's mean image-up and viewing directions (not necessarily unit).
    Raises InputError for coincident centres (no baseline, no perpendicular).
    """
    c_i = np.asarray(c_i, np.float64)
    c_j = np.asarray(c_j, np.float64)
    if _coincident(c_i, c_j):
        raise InputError(f"no trajectory exists between identical centres {c_i.tolist()}: "
                         "an arc needs a baseline; use amplitude 0 or pick two distinct cameras")
    b = (c_j - c_i) / np.linalg.norm(c_j - c_i)
    fallback = np.eye(3)[int(np.argmin(np.abs(b)))]  # the axis least aligned with the baseline
    for cand in (up, forward, fallback):
        if cand is None:
            continue
        v = np.asarray(cand, np.float64)
        norm = np.linalg.norm(v)
        if not np.isfinite(norm) or norm == 0.0:
            continue
        v = v / norm
        perp = v - np.dot(v, b) * b
        length = np.linalg.norm(perp)
        if length >= MIN_PERPENDICULAR:
            return perp / length
    raise AssertionError("unreachable: the least-aligned axis always has a perpendicular component")


def interpolate_pair(cam_i: Camera, cam_j: Camera, alphas: Sequence[float] | np.ndarray, amplitude: float = 0.0,
                     normal: np.ndarray | None = None, name: str = "path") -> list[Camera]:
    """Cameras along Eq. 3 from ``cam_i`` (alpha 0) to ``cam_j`` (alpha 1).

    alphas: (F,) values in [0, 1]. amplitude: A in world units. normal: n_ij (3,), default
    ``arc_normal`` with the pair's own mean up and viewing directions. The cameras at alpha 0
    and 1 are copies of cam_i / cam_j (bit-exact K and c2w). Both cameras must share an image size.
    """
    a = np.asarray(alphas, dtype=np.float64).reshape(-1)
    if a.size == 0 or not np.all(np.isfinite(a)) or np.any(a < 0.0) or np.any(a > 1.0):
        raise InputError(f"trajectory {name!r}: alphas must be finite values in [0, 1], got {a.tolist()[:6]}")
    if (cam_i.width, cam_i.height) != (cam_j.width, cam_j.height):
        raise InputError(f"trajectory {name!r}: cameras {cam_i.name!r} ({cam_i.width}x{cam_i.height}) and "
                         f"{cam_j.name!r} ({cam_j.width}x{cam_j.height}) differ in size; resize them to one size first")
    amplitude = float(amplitude)
    if not np.isfinite(amplitude):
        raise InputError(f"trajectory {name!r}: amplitude must be finite, got {amplitude}")
    c_i, c_j = cam_i.center, cam_j.center
    q_i = quat.from_matrix(cam_i.R)
    q_j = quat.from_matrix(cam_j.R)
    if _coincident(c_i, c_j):
        if amplitude != 0.0:
            raise InputError(f"no trajectory exists between identical centres ({cam_i.name!r}, {cam_j.name!r}) "
                             f"with amplitude {amplitude}: an arc needs a baseline; use amplitude 0")
        if same_pose(cam_i, cam_j):
            raise InputError(f"no trajectory exists between identical centres ({cam_i.name!r}, {cam_j.name!r}): "
                             "the two cameras are the same; pick two distinct cameras")
        n = np.zeros(3)
    elif amplitude == 0.0:
        n = np.zeros(3)
    elif normal is None:
        n = arc_normal(c_i, c_j, _image_up(cam_i) + _image_up(cam_j), cam_i.forward + cam_j.forward)
    else:
        n = np.asarray(normal, np.float64).reshape(3)
        if not np.all(np.isfinite(n)) or np.linalg.norm(n) == 0.0:
            raise InputError(f"trajectory {name!r}: the arc normal must be a finite non-zero vector, got {n.tolist()}")
        n = n / np.linalg.norm(n)
    rotations = quat.to_matrix(quat.slerp(q_i, q_j, a))
    cameras = []
    for k, (alpha, R) in enumerate(zip(a, rotations)):
        cam_name = f"{name}_{k:03d}"
        if alpha == 0.0:
            cameras.append(Camera(cam_i.K, cam_i.c2w, cam_i.width, cam_i.height, cam_name))
            continue
        if alpha == 1.0:
            cameras.append(Camera(cam_j.K, cam_j.c2w, cam_j.width, cam_j.height, cam_name))
            continue
        c2w = np.eye(4)
        c2w[:3, :3] = R
        c2w[:3, 3] = (1.0 - alpha) * c_i + alpha * c_j + amplitude * np.sin(np.pi * alpha) * n
        K = (1.0 - alpha) * cam_i.K + alpha * cam_j.K
        cameras.append(Camera(K, c2w, cam_i.width, cam_i.height, cam_name))
    return cameras


def diagonal_pairs(centers: np.ndarray) -> list[tuple[int, int]]:
    """The longest baseline and the longest one that shares no camera with it (the diagonals of a
    4-camera rig); one pair for 3 cameras, none for fewer. Ties break by index order."""
    n = len(centers)
    pairs = list(itertools.combinations(range(n), 2))
    if not pairs:
        return []
    length = {p: float(np.linalg.norm(centers[p[1]] - centers[p[0]])) for p in pairs}
    ranked = sorted(pairs, key=lambda p: (-length[p], p))
    first = ranked[0]
    second = next((p for p in ranked if not set(p) & set(first)), None)
    return [first] if second is None else [first, second]


def alphas_for(frames: int) -> np.ndarray:
    """(F,) = linspace(0, 1, F) for F >= 2 frames."""
    if int(frames) != frames or frames < 2:
        raise InputError(f"a trajectory needs at least 2 frames (its two endpoints), got {frames}")
    return np.linspace(0.0, 1.0, int(frames))


def novel_frame_mask(cameras: Sequence[Camera], train_cameras: Sequence[Camera]) -> np.ndarray:
    """(F,) bool: which cameras of a clip are novel views, i.e. not one of ``train_cameras``.

    A pair trajectory's endpoints (alpha = 0 and 1) are its train cameras bit for bit; pseudo-
    supervision there would only repeat (a restored copy of) the real frame. Same camera = same
    size, centres coincident (``COINCIDENT_REL``) and orientations equal (``SAME_ORIENTATION_TOL``
    scaled up to tolerate a JSON round trip of the pose).
    """
    out = np.ones(len(cameras), dtype=bool)
    for k, cam in enumerate(cameras):
        for tc in train_cameras:
            if (cam.width, cam.height) == (tc.width, tc.height) and _coincident(cam.center, tc.center) \
                    and np.max(np.abs(cam.R - tc.R)) <= SAME_POSE_TOL:
                out[k] = False
                break
    return out


def _refuse_listed_twice(cameras: Sequence[Camera]) -> None:
    """InputError when one camera (the same name and pose) appears twice in ``cameras``: a list
    built wrongly, not a rig (two cameras of a rig have their own names)."""
    for i, j in itertools.combinations(range(len(cameras)), 2):
        a, b = cameras[i], cameras[j]
        if a is b or (a.name == b.name and same_pose(a, b)):
            raise InputError(f"train camera {a.name!r} is listed twice (positions {i} and {j}); "
                             "list each camera once")


def scene_trajectories(train_cameras: list[Camera], n_frames: int = DEFAULT_FRAMES, *,
                       amplitude: float | None = None, arcs: bool = True, seed: int = 0) -> list[Trajectory]:
    """The pair trajectories (A = 0) of every pair of train cameras (6 for 4 cameras), then the
    arcs on the diagonal pairs (``diagonal_pairs``). Two differently named cameras on one pose
    have no path between them: their pair is left out with a warning; InputError when no pair is
    left, or when one camera is listed twice (same name and pose).

    amplitude: the arcs' A in world units; None draws A / baseline uniformly from
    ``ARC_AMPLITUDE_RANGE`` with ``numpy.random.default_rng(seed)``. n_ij uses the whole rig's
    mean image-up and viewing directions, so all arcs bend the same way.
    """
    if len(train_cameras) < 2:
        raise InputError(f"trajectories need at least 2 train cameras, got {len(train_cameras)}")
    _refuse_listed_twice(train_cameras)
    alphas = alphas_for(n_frames)
    centers = np.stack([c.center for c in train_cameras])
    up = np.sum([_image_up(c) for c in train_cameras], axis=0)
    forward = np.sum([c.forward for c in train_cameras], axis=0)
    out = []
    distinct = [(i, j) for i, j in itertools.combinations(range(len(train_cameras)), 2)
                if not same_pose(train_cameras[i], train_cameras[j])]
    if not distinct:
        raise InputError(f"trajectories need two train cameras at different poses; all {len(train_cameras)} share one "
                         "pose (check the capture's camera poses)")
    shared = [(train_cameras[i].name, train_cameras[j].name)
              for i, j in itertools.combinations(range(len(train_cameras)), 2) if (i, j) not in set(distinct)]
    if shared:
        warnings.warn(f"train cameras {shared} share one pose: no trajectory between them (their other pairs are kept)",
                      UserWarning, stacklevel=2)
    for i, j in distinct:
        name = f"{i}-{j}"
        out.append(Trajectory(name, interpolate_pair(train_cameras[i], train_cameras[j], alphas, 0.0, name=name),
                              alphas, pair=(i, j), amplitude=0.0))
    if arcs:
        rng = np.random.default_rng(seed)
        diagonals = [p for p in diagonal_pairs(centers) if not _coincident(centers[p[0]], centers[p[1]])]
        for k, (i, j) in enumerate(diagonals):
            n = arc_normal(centers[i], centers[j], up, forward)
            if amplitude is None:
                amp = float(rng.uniform(*ARC_AMPLITUDE_RANGE) * np.linalg.norm(centers[j] - centers[i]))
            else:
                amp = float(amplitude)
            name = f"{i}-{j}_arc{k}"
            out.append(Trajectory(name, interpolate_pair(train_cameras[i], train_cameras[j], alphas, amp, n, name=name),
                                  alphas, pair=(i, j), amplitude=amp, arc_index=k,
                                  seed=seed if amplitude is None else None))
    return out


# ---- fixer4d presets -----------------------------------------------------------------------
def save_presets(trajectories: list[Trajectory], path: str | Path, meta: dict[str, Any] | None = None) -> Path:
    """Write fixer4d's versioned preset JSON atomically. ``meta`` (e.g. the scene source) is kept."""
    doc = {"format": PRESET_FORMAT, "version": PRESET_VERSION, **({"meta": meta} if meta else {}),
           "trajectories": [t.to_dict() for t in trajectories]}
    return write_json(path, doc)


def _read_json(path: Path, what: str) -> Any:
    if not path.is_file():
        raise InputError(f"{path}: no such {what} file")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid JSON ({exc}); re-export the {what}") from exc


def load_presets(path: str | Path) -> list[Trajectory]:
    """Read a preset file written by ``save_presets``."""
    path = Path(path)
    doc = _read_json(path, "trajectory preset")
    if not isinstance(doc, dict) or doc.get("format") != PRESET_FORMAT:
        raise InputError(f"{path}: not a fixer4d trajectory preset (format {doc.get('format') if isinstance(doc, dict) else None!r}); "
                         "nerfstudio camera paths load with load_nerfstudio")
    if int(doc.get("version", 0)) > PRESET_VERSION:
        raise InputError(f"{path}: preset version {doc.get('version')} is newer than this fixer4d ({PRESET_VERSION}); update fixer4d")
    return [Trajectory.from_dict(d, source=str(path)) for d in doc.get("trajectories", [])]


# ---- nerfstudio camera_path ----------------------------------------------------------------
def save_nerfstudio(trajectories: Trajectory | list[Trajectory], path: str | Path, *,
                    render_time: float | None = None, fps: float = NERFSTUDIO_FPS) -> Path:
    """Write a nerfstudio ``camera_path`` JSON playing the trajectories one after another.

    render_time: one clip time in [0, 1) for every frame; None uses each trajectory's ``times``
    when set, else sweeps time with the frames (frame k of K gets k / K). Camera poses go out in
    fixer4d's world frame (no nerfstudio dataparser transform), intrinsics as a vertical fov
    (nerfstudio assumes square pixels and a centred principal point: cameras that have neither
    are written with their vertical fov, and a UserWarning names them).
    """
    trajs = [trajectories] if isinstance(trajectories, Trajectory) else list(trajectories)
    cams = [c for t in trajs for c in t.cameras]
    if not cams:
        raise InputError(f"{path}: no cameras to export")
    if render_time is not None and not (0.0 <= render_time < 1.0):
        raise InputError(f"render_time must be in [0, 1), got {render_time}")
    if any((c.width, c.height) != (cams[0].width, cams[0].height) for c in cams):
        raise InputError(f"{path}: nerfstudio camera paths have one render size; resize the cameras to one size")
    if render_time is not None:
        times = np.full(len(cams), float(render_time))
    elif all(t.times is not None for t in trajs):
        times = np.concatenate([t.times for t in trajs])
    else:
        times = np.arange(len(cams)) / len(cams)
    w, h = cams[0].width, cams[0].height
    _warn_unrepresentable(cams, path)
    doc = {
        "camera_type": "perspective", "render_height": h, "render_width": w, "fps": float(fps),
        "seconds": len(cams) / float(fps), "smoothness_value": 0.0, "is_cycle": False, "keyframes": [],
        "camera_path": [{"camera_to_world": c.c2w_opengl().reshape(-1).tolist(), "fov": float(np.degrees(c.fov_y)),
                         "aspect": w / h, "render_time": float(tm)} for c, tm in zip(cams, times)],
    }
    return write_json(path, doc)


def _warn_unrepresentable(cams: Sequence[Camera], path: str | Path) -> None:
    """Warn when a camera's intrinsics cannot be written to a nerfstudio camera path as they are:
    non-square pixels (fx != fy) or an off-centre principal point would be replaced by a square-
    pixel, centred camera with the same vertical fov (a different image)."""
    tol = NERFSTUDIO_INTRINSICS_TOL
    aspect = [c.name for c in cams if abs(c.fx - c.fy) > tol * c.fy]
    offset = [c.name for c in cams if abs(c.cx - 0.5 * c.width) > tol * c.width
              or abs(c.cy - 0.5 * c.height) > tol * c.height]
    lost = ([f"non-square pixels (fx != fy) of {aspect[:3]}{' ...' if len(aspect) > 3 else ''}"] if aspect else []) + \
           ([f"the off-centre principal point of {offset[:3]}{' ...' if len(offset) > 3 else ''}"] if offset else [])
    if lost:
        warnings.warn(f"{path}: a nerfstudio camera path holds one vertical fov with square pixels and a centred "
                      f"principal point; {' and '.join(lost)} cannot be written: nerfstudio will render a "
                      "different camera (use save_presets to keep the exact intrinsics)", UserWarning, stacklevel=3)


def load_nerfstudio(path: str | Path, name: str | None = None) -> Trajectory:
    """Read a nerfstudio ``camera_path`` JSON into one Trajectory (pair None, times from
    ``render_time`` when every frame has one). Cameras get square pixels and a centred principal
    point at render_width x render_height, as nerfstudio renders them."""
    path = Path(path)
    doc = _read_json(path, "nerfstudio camera path")
    try:
        if doc.get("camera_type", "perspective") != "perspective":
            raise InputError(f"{path}: camera_type {doc['camera_type']!r} is not supported; use a perspective path")
        w, h = int(doc["render_width"]), int(doc["render_height"])
        entries = doc["camera_path"]
        cameras, times = [], []
        for k, e in enumerate(entries):
            m = np.asarray(e["camera_to_world"], dtype=np.float64)
            fov = float(e["fov"])
            if m.size != 16 or not np.all(np.isfinite(m)) or not (0.0 < fov < 180.0):
                raise InputError(f"{path}: camera_path[{k}] needs 16 finite camera_to_world values and a fov in (0, 180)")
            K = Camera.intrinsics_from_fov(np.radians(fov), w, h)
            cameras.append(Camera(K, Camera.c2w_from_opengl(m.reshape(4, 4)), w, h, f"{path.stem}_{k:03d}"))
            times.append(e.get("render_time"))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        if isinstance(exc, InputError):
            raise
        what = f"no key {exc}" if isinstance(exc, KeyError) else f"{type(exc).__name__}: {exc}"
        raise InputError(f"{path}: malformed nerfstudio camera path ({what}); it needs render_width, "
                         "render_height and camera_path entries with camera_to_world (16 numbers) and fov") from exc
    if len(cameras) < 2:
        raise InputError(f"{path}: a camera path needs at least 2 cameras, got {len(cameras)}")
    has_times = all(t is not None for t in times)
    return Trajectory(name or path.stem, cameras, np.linspace(0.0, 1.0, len(cameras)),
                      times=np.asarray(times, dtype=np.float64) if has_times else None)
