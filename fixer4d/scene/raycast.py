"""An analytic numpy ray-caster: the independent ground truth of the synthetic scenes.

Geometry is exact (ray/plane, ray/sphere, ray/oriented-box slabs, ray/capped-cylinder), never
Gaussians, so images and z-depth from it are an oracle for every later stage (docs/design.md §17).

World: any right-handed frame (the bundled specs use y up). Each object lives in its own local
frame (centre ``center``, rotation ``rotation``: local -> world): its shape (scene/shapes.py), its
solid procedural texture evaluated at local coordinates (scene/textures.py), so it moves and
spins with the object, and its motions (scene/motion.py). This module lights, poses and renders.

Rays are cast through pixel centres (u + 0.5, v + 0.5) with camera-frame z = 1 directions, so
the ray parameter of a hit *is* its z-depth. Work is vectorized over rays and chunked
(``CHUNK_RAYS``) so memory stays bounded at any resolution.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fixer4d.geometry.camera import Camera
from fixer4d.scene.motion import apply_motion, axis_angle_matrix
from fixer4d.scene.shapes import Shape, intersect_local, surface_local
from fixer4d.scene.textures import Texture, eval_texture

# Rays per vectorized chunk: 16k rays keep each float64 temporary (128 KB) in the CPU caches;
# measured fastest between 8k and 32k (65k rays was 2x slower per ray), and memory stays bounded.
CHUNK_RAYS = 1 << 14


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
