"""Procedural dynamic benchmark scenes from a JSON spec, ray-cast exactly (docs/design.md §7).

A spec describes a camera rig, a clip (frames, fps), textured primitives with optional motion,
and lighting. ``SyntheticScene`` is a ``MultiViewVideo`` whose frames and ground-truth depth
are ray-cast lazily by ``fixer4d.scene.raycast``; ``render_gt`` renders any camera at any time.
Only the effects the spec asks for are simulated (``scene.effects``).
"""
from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np

import fixer4d.scene.motion as motion
import fixer4d.scene.raycast as raycast
import fixer4d.scene.shapes as shapes
import fixer4d.scene.textures as textures
from fixer4d.errors import InputError
from fixer4d.geometry import quaternion
from fixer4d.geometry.camera import Camera
from fixer4d.geometry.rig import centre_camera, select_views
from fixer4d.jsonfile import read_json_object
from fixer4d.scene.base import FRAME_CACHE_MB, MultiViewVideo, SceneBounds

# Default supersampling (k x k rays per pixel) of ground-truth frames: 2 removes the staircase
# on texture and silhouette edges at 4x the rays; 1 is exact-at-centre and 4x faster.
DEFAULT_SUPERSAMPLE = 2
# Scene bounds are measured from depth maps of every camera at this fraction of the resolution:
# exact geometry, so a coarse sampling of the frustum only loosens the box slightly.
BOUNDS_RENDER_SCALE = 0.25
# near/far margins around the measured depth range (a small band so no content is clipped).
BOUNDS_NEAR_MARGIN = 0.9
BOUNDS_FAR_MARGIN = 1.1

SHAPES = ("plane", "sphere", "box", "cylinder")
TEXTURES = ("solid", "checker", "stripes", "noise", "blend")
MOTIONS = ("path", "spin", "bounce")


# ---------------------------------------------------------------------------- spec parsing
class _Spec:
    """Validated accessors over a raw spec dict; every error names the spec and the key."""

    def __init__(self, where: str) -> None:
        self.where = where

    def fail(self, key: str, msg: str) -> InputError:
        return InputError(f"scene spec {self.where}: {key}: {msg}")

    def vec(self, d: dict, key: str, n: int = 3, default=None, unit: bool = False) -> np.ndarray:
        v = d.get(key, default)
        if v is None:
            raise self.fail(key, f"required, a list of {n} numbers")
        try:
            arr = np.asarray(v, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise self.fail(key, f"expected {n} numbers, got {v!r}") from None
        if arr.shape != (n,) or not np.all(np.isfinite(arr)):
            raise self.fail(key, f"expected {n} finite numbers, got {v!r}")
        if unit:
            nrm = np.linalg.norm(arr)
            if nrm < 1e-12:
                raise self.fail(key, "must be a non-zero direction")
            arr = arr / nrm
        return arr

    def num(self, d: dict, key: str, default=None, positive: bool = False, minimum: float | None = None) -> float:
        v = d.get(key, default)
        if v is None:
            raise self.fail(key, "required number")
        try:
            x = float(v)
        except (TypeError, ValueError):
            raise self.fail(key, f"expected a number, got {v!r}") from None
        if not np.isfinite(x) or (positive and x <= 0) or (minimum is not None and x < minimum):
            cond = "> 0" if positive else (f">= {minimum}" if minimum is not None else "finite")
            raise self.fail(key, f"must be {cond}, got {v!r}")
        return x

    def texture(self, d: Any, key: str) -> textures.Texture:
        if d is None:
            return textures.Texture("solid", colors=np.array([[0.7, 0.7, 0.7], [0.7, 0.7, 0.7]]))
        if not isinstance(d, dict) or d.get("kind") not in TEXTURES:
            raise self.fail(key, f"a texture needs \"kind\" in {TEXTURES}, got {d!r}")
        kind = d["kind"]
        if kind == "blend":
            return textures.Texture("blend", a=self.texture(d.get("a"), f"{key}.a"),
                                    b=self.texture(d.get("b"), f"{key}.b"),
                                    weight=self.num(d, "weight", 0.5, minimum=0.0))
        cols = d.get("colors", d.get("color"))
        if cols is None:
            raise self.fail(f"{key}.colors", "required: one colour [r,g,b] (solid) or two [[r,g,b],[r,g,b]]")
        arr = np.asarray(cols, dtype=np.float64)
        if arr.shape == (3,):
            arr = np.stack([arr, arr])
        if arr.shape != (2, 3) or not np.all((arr >= 0) & (arr <= 1)):
            raise self.fail(f"{key}.colors", f"expected two RGB colours in [0, 1], got {cols!r}")
        return textures.Texture(
            kind, colors=arr, scale=self.num(d, "scale", 1.0, positive=True),
            direction=self.vec(d, "direction", default=[1.0, 0.0, 0.0], unit=True),
            duty=self.num(d, "duty", 0.5, minimum=0.0), octaves=int(self.num(d, "octaves", 3, minimum=1)),
            contrast=self.num(d, "contrast", 2.0, positive=True), seed=int(self.num(d, "seed", 0)))

    def rotation(self, d: dict, key: str) -> np.ndarray:
        if "rotation" not in d:
            return np.eye(3)
        return quaternion.to_matrix(self.vec(d, "rotation", 4))

    def motions(self, d: Any, key: str) -> tuple:
        if d is None:
            return ()
        items = d if isinstance(d, list) else [d]
        out = []
        for i, m in enumerate(items):
            k = f"{key}[{i}]"
            if not isinstance(m, dict) or m.get("kind") not in MOTIONS:
                raise self.fail(k, f"a motion needs \"kind\" in {MOTIONS}, got {m!r}")
            if m["kind"] == "path":
                keys = np.asarray(m.get("keys", []), dtype=np.float64)
                if keys.ndim != 2 or keys.shape[1] != 4 or keys.shape[0] < 1 or not np.all(np.isfinite(keys)):
                    raise self.fail(f"{k}.keys", "expected a list of [seconds, x, y, z] keyframes")
                if np.any(np.diff(keys[:, 0]) <= 0):
                    raise self.fail(f"{k}.keys", "keyframe times must increase strictly")
                interp = m.get("interp", "linear")
                if interp not in ("linear", "smooth"):
                    raise self.fail(f"{k}.interp", f"\"linear\" or \"smooth\", got {interp!r}")
                out.append(motion.PathMotion(keys[:, 0].copy(), keys[:, 1:].copy(), interp == "smooth"))
            elif m["kind"] == "spin":
                out.append(motion.SpinMotion(self.vec(m, "axis", default=[0, 1, 0], unit=True),
                                             self.num(m, "deg_per_s")))
            else:
                out.append(motion.BounceMotion(self.vec(m, "axis", default=[0, 1, 0], unit=True),
                                               self.num(m, "height", positive=True),
                                               self.num(m, "period", positive=True)))
        return tuple(out)

    def obj(self, d: Any, i: int) -> raycast.SceneObject:
        key = f"objects[{i}]"
        if not isinstance(d, dict) or d.get("type") not in SHAPES:
            raise self.fail(key, f"an object needs \"type\" in {SHAPES}, got {d!r}")
        kind = d["type"]
        name = str(d.get("name", f"{kind}{i}"))
        if kind == "plane":
            normal = self.vec(d, "normal", unit=True)
            up = self.vec(d, "up", default=[0.0, 1.0, 0.0] if abs(normal[1]) < 0.9 else [0.0, 0.0, -1.0], unit=True)
            x = np.cross(up, normal)
            if np.linalg.norm(x) < 1e-9:
                raise self.fail(f"{key}.up", "must not be parallel to the plane normal")
            x /= np.linalg.norm(x)
            y = np.cross(normal, x)
            R = np.stack([x, y, normal], 1)
            half = None
            if "size" in d:
                half = 0.5 * self.vec(d, "size", 2)
            shape = shapes.Shape("plane", half=half)
            center = self.vec(d, "point")
        else:
            R = self.rotation(d, key)
            center = self.vec(d, "center")
            if kind == "sphere":
                shape = shapes.Shape("sphere", radius=self.num(d, "radius", positive=True))
            elif kind == "box":
                size = self.vec(d, "size")
                if np.any(size <= 0):
                    raise self.fail(f"{key}.size", f"box sizes must be > 0, got {d['size']!r}")
                shape = shapes.Shape("box", half=0.5 * size)
            else:
                h = self.num(d, "height", positive=True)
                shape = shapes.Shape("cylinder", radius=self.num(d, "radius", positive=True),
                                     half=np.array([0.0, 0.5 * h, 0.0]))
        spec = None
        if d.get("specular") is not None:
            s = d["specular"]
            if not isinstance(s, dict):
                raise self.fail(f"{key}.specular", "expected {\"strength\": s, \"shininess\": n}")
            strength = self.num(s, "strength", positive=True)
            spec = raycast.Specular(strength, self.num(s, "shininess", 32.0, positive=True))
        return raycast.SceneObject(name, shape, center, R, self.texture(d.get("texture"), f"{key}.texture"),
                                   spec, self.motions(d.get("motion"), f"{key}.motion"))

    def light(self, d: Any) -> raycast.Light:
        d = d or {}
        change = None
        if d.get("change") is not None:
            c = d["change"]
            change = raycast.LightChange(
                amplitude=self.num(c, "amplitude", 0.0, minimum=0.0), period=self.num(c, "period", 1.0, positive=True),
                sweep_deg_per_s=self.num(c, "sweep_deg_per_s", 0.0),
                sweep_axis=self.vec(c, "sweep_axis", default=[0, 1, 0], unit=True))
            if change.amplitude == 0.0 and change.sweep_deg_per_s == 0.0:
                change = None
        return raycast.Light(direction=self.vec(d, "direction", default=[0.3, 1.0, 0.5], unit=True),
                             color=self.vec(d, "color", default=[1.0, 1.0, 1.0]),
                             intensity=self.num(d, "intensity", 0.7, minimum=0.0),
                             ambient=self.num(d, "ambient", 0.35, minimum=0.0), change=change)


def read_spec(source: str | Path | dict) -> tuple[dict, str]:
    """A spec dict and a label for messages from a dict, a .json path or a bundled name
    ("demo", "tiny", "static_matte", "slow_rigid", "fast_thin": assets/scenes/<name>.json)."""
    if isinstance(source, dict):
        return copy.deepcopy(source), str(source.get("name", "<dict>"))
    path = Path(source)
    if is_builtin_name(source):
        path = builtin_spec_path(str(source))
    if not path.is_file():
        raise InputError(f"scene spec {path}: file not found; pass a spec .json path or one of "
                         f"{sorted(p.stem for p in _assets_dir().glob('*.json'))}")
    spec = read_json_object(path, f"scene spec {path}", "fix the file")
    spec.setdefault("name", path.stem)
    return spec, str(path)


def _assets_dir() -> Path:
    from fixer4d import ASSETS_DIR

    return ASSETS_DIR / "scenes"


def is_builtin_name(source: str | Path) -> bool:
    """True for a bare name ("demo", "tiny", ...) of a bundled spec: no suffix, no folder part."""
    text = str(source)
    return "/" not in text and "\\" not in text and not Path(text).suffix and builtin_spec_path(text).is_file()


def builtin_spec_path(name: str) -> Path:
    """Path of a bundled spec (assets/scenes/<name>.json)."""
    return _assets_dir() / f"{name}.json"


def build_world(spec: dict, where: str = "<spec>") -> raycast.World:
    """The ray-caster's World (objects, light, background) described by a spec dict."""
    p = _Spec(where)
    objs = spec.get("objects")
    if not isinstance(objs, list) or not objs:
        raise p.fail("objects", "required: a non-empty list of objects")
    objects = tuple(p.obj(o, i) for i, o in enumerate(objs))
    return raycast.World(objects, p.light(spec.get("lighting")), p.vec(spec, "background", default=[0.5, 0.6, 0.7]))


def build_rig(spec: dict, where: str = "<spec>") -> list[Camera]:
    """Cameras cam00..camNN of the spec's rig (docs/design.md §7)."""
    p = _Spec(where)
    rig = spec.get("rig")
    if not isinstance(rig, dict):
        raise p.fail("rig", "required: an object with layout, count, resolution, ...")
    width = int(p.num(rig, "width", positive=True))
    height = int(p.num(rig, "height", positive=True))
    fov_y = np.radians(p.num(rig, "fov_y_deg", 45.0, positive=True))
    target = p.vec(rig, "target", default=[0.0, 0.0, 0.0])
    up = p.vec(rig, "up", default=[0.0, 1.0, 0.0], unit=True)
    layout = rig.get("layout", "grid")
    if layout == "grid":
        rows = int(p.num(rig, "rows", positive=True))
        cols = int(p.num(rig, "cols", positive=True))
        centre = p.vec(rig, "center")
        sx, sy = p.vec(rig, "spacing", 2)
        fwd = target - centre
        if np.linalg.norm(fwd) < 1e-9:
            raise p.fail("rig.target", "must differ from rig.center")
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, up)
        if np.linalg.norm(right) < 1e-9:
            raise p.fail("rig.up", "must not be parallel to the viewing direction")
        right /= np.linalg.norm(right)
        true_up = np.cross(right, fwd)
        positions = [(r, c) for r in range(rows) for c in range(cols)] + _extra_grid_positions(rig, p)
        eyes = [centre + (c - (cols - 1) / 2) * sx * right - (r - (rows - 1) / 2) * sy * true_up
                for r, c in positions]
        # Forward-facing like Neural3DV: every camera looks along the rig's axis, offset by its
        # position, so optical axes stay parallel (no convergence).
        targets = [e + fwd for e in eyes] if rig.get("parallel", True) else [target] * len(eyes)
    elif layout == "arc":
        if rig.get("extra") is not None:
            raise p.fail("rig.extra", "extra cameras at grid positions need layout \"grid\"")
        count = int(p.num(rig, "count", positive=True))
        radius = p.num(rig, "radius", positive=True)
        span = np.radians(p.num(rig, "arc_deg", 60.0, positive=True))
        height_off = p.num(rig, "height_offset", 0.0)
        azimuth0 = np.radians(p.num(rig, "azimuth_deg", 0.0))
        angles = azimuth0 + (np.linspace(-0.5, 0.5, count) * span if count > 1 else np.zeros(1))
        # Arc in the plane orthogonal to ``up`` through the target, starting from +z (world).
        ref = np.array([0.0, 0.0, 1.0]) - up * up[2]
        if np.linalg.norm(ref) < 1e-9:
            ref = np.array([1.0, 0.0, 0.0]) - up * up[0]
        ref /= np.linalg.norm(ref)
        side = np.cross(up, ref)
        eyes = [target + radius * (np.cos(a) * ref + np.sin(a) * side) + height_off * up for a in angles]
        targets = [target] * len(eyes)
    else:
        raise p.fail("rig.layout", f"\"grid\" or \"arc\", got {layout!r}")
    K = Camera.intrinsics_from_fov(fov_y, width, height)
    return [Camera(K, look_at_c2w(e, t, up), width, height, f"cam{i:02d}") for i, (e, t) in enumerate(zip(eyes, targets))]


def _extra_grid_positions(rig: dict, p: _Spec) -> list[tuple[float, float]]:
    """The grid rig's "extra" cameras: (row, col) grid coordinates, fractional between grid
    positions (row 0.5 lies halfway between rows 0 and 1), numbered after the rows x cols grid."""
    extra = rig.get("extra")
    if extra is None:
        return []
    if not isinstance(extra, list):
        raise p.fail("rig.extra", f"a list of [row, col] grid positions, got {extra!r}")
    return [tuple(p.vec({f"rig.extra[{i}]": e}, f"rig.extra[{i}]", 2)) for i, e in enumerate(extra)]


def look_at_c2w(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(4, 4) OpenCV c2w at ``eye`` looking at ``target`` with world ``up`` upward in the image:
    z = forward, x = forward x up (right), y = z x x (down)."""
    z = np.asarray(target, np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise InputError(f"rig: camera at {eye.tolist()} looks along 'up'; choose another rig.up")
    x /= np.linalg.norm(x)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, np.cross(z, x), z, eye
    return c2w


# ---------------------------------------------------------------------------- the scene
class SyntheticScene(MultiViewVideo):
    """A procedural scene ray-cast from its spec.

    Args:
      spec: a spec dict, a spec .json path, or a bundled name ("demo", "tiny", "static_matte").
      scale: image scale of the rig (0.5 = half resolution; intrinsics scale exactly).
      frame_range: (a, b) keeps frames a..b-1 of the spec's clip; frame f then shows the clip at
        spec frame a + f, and t = f / (b - a).
      supersample: k x k rays per pixel for colour (default: the spec's "supersample", else 2).
      train_ids / test_ids: camera indices overriding the spec's choice.
    """

    def __init__(self, spec: str | Path | dict = "demo", scale: float = 1.0, frame_range: tuple[int, int] | None = None,
                 supersample: int | None = None, train_ids: list[int] | None = None,
                 test_ids: list[int] | None = None, cache_mb: float = FRAME_CACHE_MB) -> None:
        super().__init__(cache_mb)
        raw, where = read_spec(spec)
        self.spec: dict = raw
        self.source = where
        self.name = str(raw.get("name", "synthetic"))
        p = _Spec(where)
        total = int(p.num(raw, "frames", positive=True))
        self.fps = p.num(raw, "fps", 30.0, positive=True)
        if frame_range is None:
            frame_range = (0, total)
        a, b = int(frame_range[0]), int(frame_range[1])
        if not 0 <= a < b <= total:
            raise InputError(f"scene {where}: frame_range {frame_range} must satisfy 0 <= a < b <= {total}")
        self.frame_offset = a
        self.num_frames = b - a
        if scale <= 0 or not np.isfinite(scale):
            raise InputError(f"scene {where}: scale must be > 0, got {scale}")
        self.scale = float(scale)
        self.supersample = int(supersample if supersample is not None else raw.get("supersample", DEFAULT_SUPERSAMPLE))
        if self.supersample < 1:
            raise InputError(f"scene {where}: supersample must be >= 1, got {self.supersample}")
        self.world = build_world(raw, where)
        rig = build_rig(raw, where)
        self.cameras = [c.scaled(scale) if scale != 1.0 else c for c in rig]
        rig_spec = raw.get("rig", {})
        if rig_spec.get("extra") and rig_spec.get("train", "auto") in (None, "auto") and train_ids is None:
            # the automatic choice looks at every camera: added cameras would move the train ones
            raise InputError(f"scene spec {where}: rig.extra needs an explicit rig.train (camera indices), "
                             "so the added cameras cannot change which cameras train")
        spec_train, spec_test = select_views(self.cameras, rig_spec.get("train", "auto"), where, rig_spec.get("test"))
        self.train_ids = [int(i) for i in train_ids] if train_ids is not None else spec_train
        if test_ids is not None:
            self.test_ids = [int(i) for i in test_ids]  # overlap with train: load_scene refuses it (validate.check_ids)
        elif train_ids is not None:
            self.test_ids = [i for i in range(len(self.cameras)) if i not in self.train_ids]
        else:
            self.test_ids = spec_test
        for i in self.train_ids + self.test_ids:
            if not 0 <= i < len(self.cameras):
                raise InputError(f"scene {where}: camera id {i} outside [0, {len(self.cameras)}); "
                                 f"valid ids are 0..{len(self.cameras) - 1}")
        self.center_id = centre_camera(self.cameras)
        self._true_bounds: SceneBounds | None = None

    @property
    def effects(self) -> frozenset[str]:
        """Effects simulated for this spec ("motion", "specular", "light_change")."""
        return self.world.effects

    @property
    def has_depth(self) -> bool:
        return True

    def seconds(self, t: float) -> float:
        """Clip time in seconds of scene time t (t = f / num_frames of this scene)."""
        return (self.frame_offset + t * self.num_frames) / self.fps

    def render_gt(self, camera: Camera, t: float, supersample: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Exact render of any camera at scene time t: (rgb (H, W, 3) float32 in [0, 1],
        z-depth (H, W) float32, inf where nothing is hit)."""
        k = self.supersample if supersample is None else int(supersample)
        rgb, depth = raycast.render(self.world, camera, self.seconds(float(t)), supersample=k)
        return rgb, depth

    def _load_frame(self, frame: int, cam: int) -> np.ndarray:
        rgb, depth = self.render_gt(self.cameras[cam], self.time(frame))
        self._cache.get_or_compute(("depth", frame, cam), lambda: depth)
        return rgb

    def _load_depth(self, frame: int, cam: int) -> np.ndarray:
        return raycast.render(self.world, self.cameras[cam], self.seconds(self.time(frame)), with_rgb=False)[1]

    def moving_mask(self, frame: int, cam_index: int) -> np.ndarray:
        """Exact moving-content mask (H, W) bool of camera ``cam_index`` at ``frame``: pixels
        whose first hit (ray through the pixel centre) is an object with a motion. Ground truth:
        for tests and metrics only, never for training."""
        self._check(frame, cam_index)
        return raycast.moving_object_mask(self.world, self.cameras[cam_index], self.seconds(self.time(frame)))

    def true_bounds(self) -> SceneBounds:
        """Ground truth: depth range and box of everything the rig (held-out cameras included)
        sees at the first, middle and last frame, measured by ray-casting every camera at
        BOUNDS_RENDER_SCALE resolution. For tests and metrics only; ``bounds()`` (the train
        cameras' common view) is what reconstruction uses."""
        if self._true_bounds is None:
            depths, points = [], []
            for f in sorted({0, self.num_frames // 2, self.num_frames - 1}):
                s = self.seconds(self.time(f))
                for cam in self.cameras:
                    small = cam.scaled(BOUNDS_RENDER_SCALE)
                    z = raycast.render(self.world, small, s, with_rgb=False)[1].astype(np.float64)
                    ok = np.isfinite(z)
                    depths.append(z[ok])
                    points.append(small.backproject_depth(np.where(ok, z, 0.0))[ok])
            z = np.concatenate(depths)
            pts = np.concatenate(points)
            if z.size == 0:
                raise InputError(f"scene {self.source}: no camera sees any object; check the rig and objects")
            self._true_bounds = SceneBounds(float(z.min() * BOUNDS_NEAR_MARGIN), float(z.max() * BOUNDS_FAR_MARGIN),
                                       pts.min(0), pts.max(0))
        return self._true_bounds
