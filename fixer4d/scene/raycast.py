"""An analytic numpy ray-caster: the independent ground truth of the synthetic scenes.

Geometry is exact (ray/plane, ray/sphere, ray/oriented-box slabs, ray/capped-cylinder), never
Gaussians, so images and z-depth from it are an oracle for every later stage (docs/design.md §17).

World: any right-handed frame (the bundled specs use y up). Each object lives in its own local
frame (centre ``center``, rotation ``rotation``: local -> world); textures are solid procedural
textures evaluated at local coordinates, so they move and spin with the object.

Rays are cast through pixel centres (u + 0.5, v + 0.5) with camera-frame z = 1 directions, so
the ray parameter of a hit *is* its z-depth. Work is vectorized over rays and chunked
(``CHUNK_RAYS``) so memory stays bounded at any resolution.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fixer4d.geometry.camera import Camera

# Rays per vectorized chunk: 16k rays keep each float64 temporary (128 KB) in the CPU caches;
# measured fastest between 8k and 32k (65k rays was 2x slower per ray), and memory stays bounded.
CHUNK_RAYS = 1 << 14
# Hits closer than this ray parameter are ignored (the ray origin sits on no surface; this only
# guards against a hit at t = 0 from rounding).
T_MIN = 1e-9
# Value-noise lattice hash multipliers (large odd primes, the classic spatial-hash choice).
_HASH_PRIMES = (73856093, 19349663, 83492791, 2654435761)
# Lattice values: a fixed table of 2^16 uniform numbers (a fixed generator seed, so every
# machine renders the same pixels); the pattern repeats only every 65536 cells.
_NOISE_TABLE = np.random.default_rng(20260401).random(1 << 16)


# ---------------------------------------------------------------------------- textures
@dataclass(frozen=True)
class Texture:
    """A solid procedural texture evaluated at local 3D coordinates (world units).

    kind: "solid" (colors[0]), "checker" (cells of 1/scale units, parity of the cell index),
    "stripes" (bands of period 1/scale along ``direction``, ``duty`` fraction in colors[0]),
    "noise" (multi-octave value noise with base frequency ``scale``, contrast-stretched), or
    "blend" ((1 - weight) * a + weight * b).
    """

    kind: str
    colors: np.ndarray = field(default_factory=lambda: np.array([[0.8, 0.8, 0.8], [0.2, 0.2, 0.2]]))
    scale: float = 1.0
    direction: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    duty: float = 0.5
    octaves: int = 3
    contrast: float = 2.0
    seed: int = 0
    a: "Texture | None" = None
    b: "Texture | None" = None
    weight: float = 0.5


def value_noise(p: np.ndarray, octaves: int, seed: int) -> np.ndarray:
    """(N, 3) points -> (N,) smooth value noise in [0, 1]: trilinear with smoothstep weights,
    octaves at doubling frequency and halving amplitude (band-limited, so it anti-aliases)."""
    total = np.zeros(p.shape[0])
    norm = 0.0
    amp = 1.0
    freq = 1.0
    mask = _NOISE_TABLE.size - 1
    for octave in range(max(1, int(octaves))):
        q = p * freq
        i = np.floor(q)
        f = q - i
        w = f * f * (3.0 - 2.0 * f)
        ii = i.astype(np.int64)
        # Per-axis hash terms of the two lattice planes (the corner hash is their xor).
        sd = int(seed + 101 * octave) * _HASH_PRIMES[3]
        hx = ((ii[:, 0] * _HASH_PRIMES[0]) ^ sd, ((ii[:, 0] + 1) * _HASH_PRIMES[0]) ^ sd)
        hy = (ii[:, 1] * _HASH_PRIMES[1], (ii[:, 1] + 1) * _HASH_PRIMES[1])
        hz = (ii[:, 2] * _HASH_PRIMES[2], (ii[:, 2] + 1) * _HASH_PRIMES[2])
        wx = (1.0 - w[:, 0], w[:, 0])
        wy = (1.0 - w[:, 1], w[:, 1])
        wz = (1.0 - w[:, 2], w[:, 2])
        # Along an axis where every weight is 0 (a flat face zeroes its normal coordinate) the
        # +1 lattice plane contributes nothing: skip it (2D noise costs 4 lookups, not 8).
        steps = [(0, 1) if np.any(w[:, a] != 0.0) else (0,) for a in range(3)]
        acc = np.zeros(p.shape[0])
        for dx in steps[0]:
            for dy in steps[1]:
                hxy = hx[dx] ^ hy[dy]
                wxy = wx[dx] * wy[dy]
                for dz in steps[2]:
                    acc += wxy * wz[dz] * _NOISE_TABLE[(hxy ^ hz[dz]) & mask]
        total += amp * acc
        norm += amp
        amp *= 0.5
        freq *= 2.0
    return total / norm


def eval_texture(tex: Texture, p: np.ndarray) -> np.ndarray:
    """Albedo (N, 3) in [0, 1] of texture ``tex`` at local points ``p`` (N, 3)."""
    c0, c1 = tex.colors[0], tex.colors[1]
    if tex.kind == "solid":
        return np.broadcast_to(c0, p.shape).copy()
    if tex.kind == "checker":
        parity = np.sum(np.floor(p * tex.scale), axis=1).astype(np.int64) & 1
        return np.where(parity[:, None] == 0, c0, c1)
    if tex.kind == "stripes":
        s = p @ tex.direction * tex.scale
        frac = s - np.floor(s)
        return np.where((frac < tex.duty)[:, None], c0, c1)
    if tex.kind == "noise":
        n = value_noise(p * tex.scale, tex.octaves, tex.seed)
        n = np.clip(0.5 + (n - 0.5) * tex.contrast, 0.0, 1.0)[:, None]
        return (1.0 - n) * c0 + n * c1
    if tex.kind == "blend":
        return (1.0 - tex.weight) * eval_texture(tex.a, p) + tex.weight * eval_texture(tex.b, p)
    raise ValueError(f"unknown texture kind {tex.kind!r}")


# ---------------------------------------------------------------------------- shapes
@dataclass(frozen=True)
class Shape:
    """Canonical geometry in the object's local frame.

    plane: z = 0, normal +z, optionally bounded to |x| <= half[0], |y| <= half[1]
    (``half`` None = infinite). sphere: centred, ``radius``. box: centred, half extents
    ``half`` (3,). cylinder: axis local y, ``radius``, |y| <= half[1] (capped).
    """

    kind: str
    radius: float = 0.0
    half: np.ndarray | None = None

    @property
    def bound_radius(self) -> float | None:
        """Radius of a local-origin sphere enclosing the shape (None: unbounded plane)."""
        if self.kind == "sphere":
            return self.radius
        if self.kind == "cylinder":
            return float(np.hypot(self.radius, self.half[1]))
        if self.half is None:
            return None
        return float(np.linalg.norm(self.half))


def intersect_local(shape: Shape, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Nearest hit parameter t > T_MIN (N,) of rays o + t d (local frame), inf on a miss.

    o: (3,) the common origin (a pinhole camera's rays share it); d: (N, 3) directions.
    """
    n = d.shape[0]
    inf = np.full(n, np.inf)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if shape.kind == "plane":
            t = -o[2] / d[:, 2]
            ok = np.isfinite(t) & (t > T_MIN)
            if shape.half is not None:
                p = o + t[:, None] * d
                ok &= (np.abs(p[:, 0]) <= shape.half[0]) & (np.abs(p[:, 1]) <= shape.half[1])
            return np.where(ok, t, inf)
        if shape.kind == "sphere":
            a = np.einsum("ij,ij->i", d, d)
            b = d @ o
            c = float(o @ o) - shape.radius ** 2
            disc = b * b - a * c
            sq = np.sqrt(np.maximum(disc, 0.0))
            t0 = (-b - sq) / a
            t1 = (-b + sq) / a
            t = np.where(t0 > T_MIN, t0, t1)
            return np.where((disc >= 0) & (t > T_MIN), t, inf)
        if shape.kind == "box":
            inv = 1.0 / d
            ta = (-shape.half - o) * inv
            tb = (shape.half - o) * inv
            lo = np.minimum(ta, tb)
            hi = np.maximum(ta, tb)
            # fmax/fmin skip the NaN of 0 * inf (a ray parallel to a slab, starting on it).
            tnear = np.fmax(np.fmax(lo[:, 0], lo[:, 1]), lo[:, 2])
            tfar = np.fmin(np.fmin(hi[:, 0], hi[:, 1]), hi[:, 2])
            t = np.where(tnear > T_MIN, tnear, tfar)
            return np.where((tfar >= tnear) & (t > T_MIN), t, inf)
        if shape.kind == "cylinder":
            r, h = shape.radius, shape.half[1]
            a = d[:, 0] ** 2 + d[:, 2] ** 2
            b = o[0] * d[:, 0] + o[2] * d[:, 2]
            c = o[0] ** 2 + o[2] ** 2 - r * r
            disc = b * b - a * c
            sq = np.sqrt(np.maximum(disc, 0.0))
            best = inf.copy()
            for root in ((-b - sq) / a, (-b + sq) / a):
                y = o[1] + root * d[:, 1]
                ok = (disc >= 0) & (a > 0) & (root > T_MIN) & (np.abs(y) <= h)
                best = np.where(ok & (root < best), root, best)
            for cap in (-h, h):
                tc = (cap - o[1]) / d[:, 1]
                px = o[0] + tc * d[:, 0]
                pz = o[2] + tc * d[:, 2]
                ok = np.isfinite(tc) & (tc > T_MIN) & (px * px + pz * pz <= r * r)
                best = np.where(ok & (tc < best), tc, best)
            return best
    raise ValueError(f"unknown shape kind {shape.kind!r}")


def surface_local(shape: Shape, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Outward unit normals (N, 3) and texture coordinates (N, 3) at local surface points p.

    Flat faces zero the coordinate along their normal so a face never sits on a texture cell
    boundary (which would flicker between cells from rounding).
    """
    tc = p.copy()
    if shape.kind == "plane":
        nrm = np.zeros_like(p)
        nrm[:, 2] = 1.0
        tc[:, 2] = 0.0
        return nrm, tc
    if shape.kind == "sphere":
        return p / np.linalg.norm(p, axis=1, keepdims=True), tc
    if shape.kind == "box":
        axis = np.argmax(np.abs(p) / shape.half, axis=1)
        nrm = np.zeros_like(p)
        rows = np.arange(p.shape[0])
        nrm[rows, axis] = np.sign(p[rows, axis])
        tc[rows, axis] = 0.0
        return nrm, tc
    if shape.kind == "cylinder":
        radial = np.hypot(p[:, 0], p[:, 2])
        cap = np.abs(np.abs(p[:, 1]) - shape.half[1]) < np.abs(radial - shape.radius)
        nrm = np.zeros_like(p)
        side_scale = 1.0 / np.maximum(radial, 1e-12)
        nrm[:, 0] = np.where(cap, 0.0, p[:, 0] * side_scale)
        nrm[:, 2] = np.where(cap, 0.0, p[:, 2] * side_scale)
        nrm[:, 1] = np.where(cap, np.sign(p[:, 1]), 0.0)
        tc[:, 1] = np.where(cap, 0.0, tc[:, 1])
        return nrm, tc
    raise ValueError(f"unknown shape kind {shape.kind!r}")


# ---------------------------------------------------------------------------- motion
@dataclass(frozen=True)
class PathMotion:
    """Keyframed centre positions: times (K,) seconds ascending, positions (K, 3); linear or
    Catmull-Rom ("smooth"); clamped outside the keys."""

    times: np.ndarray
    positions: np.ndarray
    smooth: bool = False


@dataclass(frozen=True)
class SpinMotion:
    """Rotation about local-to-world ``axis`` (unit, world) at ``deg_per_s`` degrees per second."""

    axis: np.ndarray
    deg_per_s: float


@dataclass(frozen=True)
class BounceMotion:
    """Offset axis * height * |sin(pi * s / period)|: a ball bouncing ``height`` units every ``period`` s."""

    axis: np.ndarray
    height: float
    period: float


def axis_angle_matrix(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues rotation matrix (3, 3) about a unit ``axis`` by ``angle`` radians."""
    x, y, z = axis
    Kx = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + np.sin(angle) * Kx + (1.0 - np.cos(angle)) * (Kx @ Kx)


def path_position(m: PathMotion, s: float) -> np.ndarray:
    """Centre (3,) of a keyframed path at time ``s`` seconds."""
    times, pos = m.times, m.positions
    if len(times) == 1 or s <= times[0]:
        return pos[0].copy()
    if s >= times[-1]:
        return pos[-1].copy()
    k = int(np.searchsorted(times, s, side="right") - 1)
    u = (s - times[k]) / (times[k + 1] - times[k])
    if not m.smooth:
        return (1.0 - u) * pos[k] + u * pos[k + 1]
    p0 = pos[max(k - 1, 0)]
    p1, p2 = pos[k], pos[k + 1]
    p3 = pos[min(k + 2, len(pos) - 1)]
    # Uniform Catmull-Rom: C1, passes through every key.
    return 0.5 * ((2 * p1) + (-p0 + p2) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u * u
                  + (-p0 + 3 * p1 - 3 * p2 + p3) * u ** 3)


def apply_motion(center: np.ndarray, rotation: np.ndarray, motions: tuple, s: float) -> tuple[np.ndarray, np.ndarray]:
    """Pose (centre (3,), rotation (3, 3)) of an object at time ``s`` seconds under ``motions``."""
    c = center.copy()
    R = rotation.copy()
    for m in motions:
        if isinstance(m, PathMotion):
            c = path_position(m, s)
    for m in motions:
        if isinstance(m, BounceMotion):
            c = c + m.axis * m.height * abs(np.sin(np.pi * s / m.period))
        elif isinstance(m, SpinMotion):
            R = axis_angle_matrix(m.axis, np.radians(m.deg_per_s * s)) @ R
    return c, R


# ---------------------------------------------------------------------------- lighting
@dataclass(frozen=True)
class Specular:
    """Blinn-Phong highlight: strength * (n . h)^shininess, in light colour."""

    strength: float
    shininess: float


@dataclass(frozen=True)
class LightChange:
    """Lighting over time: intensity * (1 + amplitude * sin(2 pi s / period)), and the light
    direction turned about ``sweep_axis`` by ``sweep_deg_per_s`` * s degrees."""

    amplitude: float = 0.0
    period: float = 1.0
    sweep_deg_per_s: float = 0.0
    sweep_axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))


@dataclass(frozen=True)
class Light:
    """Ambient + one directional light; ``direction`` points from surfaces toward the light."""

    direction: np.ndarray
    color: np.ndarray
    intensity: float
    ambient: float
    change: LightChange | None = None


def changed_light(light: Light, s: float) -> tuple[np.ndarray, float]:
    """(unit direction (3,), intensity) of a light with a ``change`` at time ``s`` seconds."""
    ch = light.change
    d = axis_angle_matrix(ch.sweep_axis, np.radians(ch.sweep_deg_per_s * s)) @ light.direction
    return d / np.linalg.norm(d), light.intensity * (1.0 + ch.amplitude * np.sin(2.0 * np.pi * s / ch.period))


def specular_term(n: np.ndarray, light_dir: np.ndarray, view_dir: np.ndarray, spec: Specular) -> np.ndarray:
    """(N,) Blinn-Phong highlight for unit normals n (N, 3), light direction (3,), unit
    directions toward the viewer (N, 3)."""
    h = view_dir + light_dir
    h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    return spec.strength * np.maximum(np.einsum("ij,ij->i", n, h), 0.0) ** spec.shininess


# ---------------------------------------------------------------------------- world
@dataclass(frozen=True)
class SceneObject:
    """One primitive: shape in its local frame, rest pose, texture, optional highlight and motions."""

    name: str
    shape: Shape
    center: np.ndarray
    rotation: np.ndarray
    texture: Texture
    specular: Specular | None = None
    motions: tuple = ()


@dataclass(frozen=True)
class PosedObject:
    obj: SceneObject
    center: np.ndarray
    rotation: np.ndarray


@dataclass(frozen=True)
class World:
    """Everything the ray-caster needs: objects, light, background colour (3,) for misses."""

    objects: tuple[SceneObject, ...]
    light: Light
    background: np.ndarray

    @property
    def effects(self) -> frozenset[str]:
        """The time/appearance effects this world uses; only these are ever evaluated."""
        out = set()
        if any(o.motions for o in self.objects):
            out.add("motion")
        if any(o.specular is not None for o in self.objects):
            out.add("specular")
        if self.light.change is not None:
            out.add("light_change")
        return frozenset(out)

    def posed(self, s: float) -> list[PosedObject]:
        """Object poses at time ``s`` seconds; static objects skip the motion code entirely."""
        out = []
        for o in self.objects:
            if o.motions:
                c, R = apply_motion(o.center, o.rotation, o.motions, s)
            else:
                c, R = o.center, o.rotation
            out.append(PosedObject(o, c, R))
        return out


def _nearest(posed: list[PosedObject], o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit over all objects of rays from the common origin o (3,) along d (N, 3):
    (t (N,), object index (N,), -1 on a miss).

    Bounded shapes first test their bounding sphere (a handful of flops per ray) and run the
    exact intersection only on the rays that pass.
    """
    best = np.full(d.shape[0], np.inf)
    idx = np.full(d.shape[0], -1, dtype=np.int64)
    dd = None
    for k, po in enumerate(posed):
        oc = o - po.center
        rb = po.obj.shape.bound_radius
        if rb is None:
            cand = slice(None)
        else:
            if dd is None:
                dd = np.einsum("ij,ij->i", d, d)
            b = d @ oc
            cand = np.nonzero(b * b - dd * (float(oc @ oc) - rb * rb) >= 0)[0]
            if cand.size == 0:
                continue
        t = intersect_local(po.obj.shape, oc @ po.rotation, d[cand] @ po.rotation)
        closer = t < best[cand]
        best[cand] = np.where(closer, t, best[cand])
        idx[cand] = np.where(closer, k, idx[cand])
    return best, idx


def _shade(world: World, posed: list[PosedObject], light_dir: np.ndarray, intensity: float,
           o: np.ndarray, d: np.ndarray, t: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Colour (N, 3) of rays from origin o (3,) along d (N, 3) with nearest hits (t, idx)."""
    rgb = np.empty((d.shape[0], 3))
    rgb[:] = world.background
    light = world.light
    for k, po in enumerate(posed):
        sel = np.nonzero(idx == k)[0]
        if sel.size == 0:
            continue
        dk = d[sel]
        p_world = o + t[sel, None] * dk
        p_local = (p_world - po.center) @ po.rotation
        n_local, tc = surface_local(po.obj.shape, p_local)
        n = n_local @ po.rotation.T
        view = -dk / np.linalg.norm(dk, axis=1, keepdims=True)
        # Two-sided surfaces (planes): the normal faces the viewer.
        n = np.where((np.einsum("ij,ij->i", n, view) < 0)[:, None], -n, n)
        albedo = eval_texture(po.obj.texture, tc)
        lambert = np.maximum(n @ light_dir, 0.0)
        col = albedo * (light.ambient + intensity * lambert[:, None] * light.color)
        if po.obj.specular is not None:
            col = col + (intensity * specular_term(n, light_dir, view, po.obj.specular))[:, None] * light.color
        rgb[sel] = col
    return np.clip(rgb, 0.0, 1.0)


def _camera_rays(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """World directions (N, 3) with camera-frame z = 1 through continuous pixel coords uv (N, 2)."""
    Kinv = np.linalg.inv(camera.K)
    dc = np.concatenate([uv, np.ones((uv.shape[0], 1))], 1) @ Kinv.T
    return dc @ camera.R.T


def render(world: World, camera: Camera, s: float, supersample: int = 1,
           chunk_rays: int = CHUNK_RAYS, with_rgb: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
    """Ray-cast ``world`` at time ``s`` seconds from ``camera``.

    Returns (rgb (H, W, 3) float32 in [0, 1] or None when ``with_rgb`` is False,
    depth (H, W) float32 camera-frame z, inf where nothing is hit). With ``supersample`` = k the
    colour of a pixel is the mean of k x k sub-pixel rays on a regular grid; depth always comes
    from the ray through the pixel centre.
    """
    k = max(1, int(supersample)) if with_rgb else 1
    W, H = camera.width, camera.height
    posed = world.posed(s)
    light_dir, intensity = world.light.direction, world.light.intensity
    if with_rgb and world.light.change is not None:
        light_dir, intensity = changed_light(world.light, s)
    centres = camera.pixel_centers().reshape(-1, 2)
    n_pix = centres.shape[0]
    depth = np.empty(n_pix, dtype=np.float32)
    rgb = np.empty((n_pix, 3), dtype=np.float32) if with_rgb else None
    offsets = (np.arange(k) + 0.5) / k - 0.5
    sub = np.stack(np.meshgrid(offsets, offsets), -1).reshape(-1, 2)  # (k*k, 2) sub-pixel offsets
    centre_sub = int(np.argmin(np.abs(sub).sum(1))) if k % 2 == 1 else None
    origin = camera.center
    step = max(1, chunk_rays // (k * k))
    for a in range(0, n_pix, step):
        uv = centres[a:a + step]
        m = uv.shape[0]
        uvs = (uv[:, None, :] + sub[None, :, :]).reshape(-1, 2)
        d = _camera_rays(camera, uvs)
        t, idx = _nearest(posed, origin, d)
        if with_rgb:
            col = _shade(world, posed, light_dir, intensity, origin, d, t, idx)
            rgb[a:a + m] = col.reshape(m, k * k, 3).mean(1)
        if centre_sub is not None:
            depth[a:a + m] = t.reshape(m, k * k)[:, centre_sub]
        else:
            dc = _camera_rays(camera, uv)
            depth[a:a + m] = _nearest(posed, origin, dc)[0]
    depth = depth.reshape(H, W)
    return (rgb.reshape(H, W, 3) if with_rgb else None), depth


def hit_objects(world: World, camera: Camera, s: float, chunk_rays: int = CHUNK_RAYS) -> np.ndarray:
    """Index into ``world.objects`` (H, W) int64 of the first surface hit by the ray through
    each pixel centre at time ``s`` seconds, -1 where the ray hits nothing."""
    posed = world.posed(s)
    centres = camera.pixel_centers().reshape(-1, 2)
    out = np.empty(centres.shape[0], dtype=np.int64)
    for a in range(0, centres.shape[0], chunk_rays):
        out[a:a + chunk_rays] = _nearest(posed, camera.center, _camera_rays(camera, centres[a:a + chunk_rays]))[1]
    return out.reshape(camera.height, camera.width)


def moving_object_mask(world: World, camera: Camera, s: float) -> np.ndarray:
    """(H, W) bool: the first hit through the pixel centre is an object with a motion."""
    moving = np.array([bool(o.motions) for o in world.objects] + [False])  # index -1: a miss
    return moving[hit_objects(world, camera, s)]
