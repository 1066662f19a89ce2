"""splaTV's ``.splatv``: one file holding a whole spacetime model for its WebGL viewer.

Byte layout (as the public splaTV viewer, github.com/antimatter15/splaTV, reads it; little-endian):

    uint32  magic 0x674b
    uint32  L, the byte length of the chunk list
    L bytes UTF-8 JSON: a list of chunk descriptors; the one the viewer renders is
            {"type": "splat", "size": bytes, "texwidth": 4096, "texheight": H,
             "cameras": [{"id", "img_name", "width", "height", "position": [3],
                          "rotation": 3x3 camera-to-world rows (OpenCV axes), "fx", "fy"}]}
    the chunks' bytes, in list order: the splat chunk is an RGBA32UI texture of
            texwidth x texheight texels, 4 texels (16 uint32 words) per Gaussian, row-major,
            texheight = ceil(4 N / texwidth); texels past the last Gaussian are zero

    word  0..2   position x y z, float32
    word  3, 4   rotation w x y z as float16 pairs (w, x), (y, z)
    word  5, 6   scale (linear std, not log) as float16 pairs (sx, sy), (sz, 0)
    word  7      colour and opacity as bytes r g b a (value * 255, a = opacity in [0, 1])
    word  8..12  motion m1 (xyz), m2 (xyz), m3 (xyz) as float16 pairs, last pair (m3z, 0)
    word 13, 14  angular velocity omega w x y z as float16 pairs
    word 15      temporal centre and temporal std (linear, not log) as a float16 pair

(a float16 pair packs the first value in the low 16 bits). The viewer evaluates, for its time
t in [0, 1] (fixer4d's clip time): dt = t - centre, opacity *= exp(-(dt / std)^2) and the splat
is skipped below 0.02, position + m1 dt + m2 dt^2 + m3 dt^3, normalize(rotation + omega dt).

What the format cannot hold, and what ``reduce`` does about it (the reduction error is measured
by rendering ``to_model``/``snapshot_at`` with fixer4d's renderer, ``fixer4d.eval.format_fidelity``):
view-dependent colour (SH bands above DC are dropped: colour = clamp(0.5 + C0 dc, 0, 1)),
8-bit colour and opacity, float16 rotation/scale/motion/time (values beyond float16's range
are clipped and counted; stds below its smallest normal 6.1e-5 are raised to it), the 0.02
temporal cut. Static Gaussians get zero motion and a temporal std of ``STATIC_TEMPORAL_STD``.
Gaussians are stored most important first (linear volume x opacity, as splaTV's own converter
orders them) so a progressively loading viewer shows the large ones first.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from fixer4d.atomic import atomic_path
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.model.snapshot import Snapshot
from fixer4d.model.sh import SH_C0, rgb_to_sh_dc
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians

MAGIC = 0x674B
TEXWIDTH = 4096  # texels per texture row: the viewer's shader addresses 1024 Gaussians per row
WORDS = 16  # uint32 words (4 RGBA32UI texels) per Gaussian
# The viewer skips a splat whose temporal opacity factor is below this.
TEMPORAL_CUT = 0.02
HALF_MAX = float(np.finfo(np.float16).max)  # 65504
HALF_MIN_NORMAL = float(np.finfo(np.float16).tiny)  # 6.1e-5
# Temporal std written for Gaussians without a temporal fade: exp(-(1 / 1e4)^2) = 1 - 1e-8 over
# the whole clip (dt <= 1), i.e. 1 to float32 precision, while staying inside float16's range.
STATIC_TEMPORAL_STD = 1.0e4


@dataclass
class SplatvFields:
    """N Gaussians as the format stores them (float16 fields already rounded to float16 values).

    positions (N,3) f32; rotations (N,4) wxyz; scales (N,3) linear std; rgba (N,4) uint8;
    motion (N,9) m1 m2 m3 xyz; omega (N,4); t_center (N,); t_std (N,) linear. ``order``: (N,)
    index of each stored Gaussian in the source model; ``clipped``: values clipped to float16's
    range while reducing.
    """

    positions: np.ndarray
    rotations: np.ndarray
    scales: np.ndarray
    rgba: np.ndarray
    motion: np.ndarray
    omega: np.ndarray
    t_center: np.ndarray
    t_std: np.ndarray
    order: np.ndarray | None = None
    clipped: int = 0

    def __len__(self) -> int:
        return int(self.positions.shape[0])


def _half(x: np.ndarray) -> tuple[np.ndarray, int]:
    """Round to float16 values (returned as float32), clipping to its finite range; (values, clipped)."""
    x = np.asarray(x, dtype=np.float64)
    clipped = int(np.count_nonzero(np.abs(x) > HALF_MAX))
    return np.clip(x, -HALF_MAX, HALF_MAX).astype(np.float16).astype(np.float32), clipped


def _to_byte(x: np.ndarray) -> np.ndarray:
    return np.round(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)


@torch.no_grad()
def reduce(model: SpacetimeGaussians) -> SplatvFields:
    """What of ``model`` the format can hold (see the module docstring); Gaussians whose 8-bit
    opacity is 0 are left out."""
    cfg = model.config
    logits = model.opacity_logits.detach().double().cpu().numpy()
    opacity = 1.0 / (1.0 + np.exp(-logits))
    log_scales = model.log_scales.detach().double().cpu().numpy()
    importance = np.exp(log_scales.sum(1)) * opacity
    alpha = _to_byte(opacity)
    order = np.argsort(-importance, kind="stable")
    order = order[alpha[order] > 0]

    def take(name: str, width: int) -> np.ndarray:
        return getattr(model, name).detach().double().cpu().numpy()[order].reshape(-1, width)

    dynamic = model.dynamic.cpu().numpy()[order] & cfg.has_time_terms
    quats = take("quats", 4)
    norm = np.linalg.norm(quats, axis=1, keepdims=True)
    zero = norm[:, 0] == 0.0
    quats[zero] = (1.0, 0.0, 0.0, 0.0)  # the snapshot contract: a zero quaternion is the identity
    norm[zero] = 1.0
    m = len(order)
    motion = np.zeros((m, 9))
    omega = np.zeros((m, 4))
    t_center = np.zeros(m)
    t_std = np.full(m, STATIC_TEMPORAL_STD)
    if cfg.motion_degree:
        motion[:, : 3 * cfg.motion_degree] = take("motion", 3 * cfg.motion_degree)
    if cfg.rotation_velocity:
        omega = take("omega", 4) / norm  # q and omega scaled together: normalize(q + omega dt) is unchanged
    if cfg.has_time_terms:
        t_center = take("t_center", 1)[:, 0]
    if cfg.temporal_opacity:
        t_std = np.exp(take("t_log_scale", 1)[:, 0])
    motion[~dynamic] = 0.0
    omega[~dynamic] = 0.0
    t_center[~dynamic] = 0.0
    t_std[~dynamic] = STATIC_TEMPORAL_STD
    rgb = 0.5 + SH_C0 * take("colors", 3)
    fields, clipped = {}, 0
    for name, values in (("rotations", quats / norm), ("scales", np.maximum(np.exp(log_scales[order]), HALF_MIN_NORMAL)),
                         ("motion", motion), ("omega", omega), ("t_center", t_center),
                         ("t_std", np.maximum(t_std, HALF_MIN_NORMAL))):
        fields[name], c = _half(values)
        clipped += c
    rgba = np.concatenate([_to_byte(rgb), alpha[order, None]], axis=1)
    return SplatvFields(positions=take("means", 3).astype(np.float32), rgba=rgba, order=order, clipped=clipped,
                        **fields)


def _pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) uint32 words packing float16 a (low 16 bits) and b (high 16 bits)."""
    return np.stack([a, b], axis=1).astype("<f2").view("<u4")[:, 0]


def encode_texture(f: SplatvFields) -> np.ndarray:
    """(texheight * TEXWIDTH * 4,) uint32 little-endian texture words of the splat chunk."""
    n = len(f)
    texheight = max(1, math.ceil(4 * n / TEXWIDTH))
    words = np.zeros((texheight * TEXWIDTH * 4 // WORDS, WORDS), dtype="<u4")
    w = words[:n]
    zeros = np.zeros(n, np.float32)
    w[:, 0:3] = f.positions.astype("<f4").view("<u4")
    w[:, 3] = _pairs(f.rotations[:, 0], f.rotations[:, 1])
    w[:, 4] = _pairs(f.rotations[:, 2], f.rotations[:, 3])
    w[:, 5] = _pairs(f.scales[:, 0], f.scales[:, 1])
    w[:, 6] = _pairs(f.scales[:, 2], zeros)
    w[:, 7] = np.ascontiguousarray(f.rgba, dtype=np.uint8).view("<u4")[:, 0]
    for k in range(4):
        w[:, 8 + k] = _pairs(f.motion[:, 2 * k], f.motion[:, 2 * k + 1])
    w[:, 12] = _pairs(f.motion[:, 8], zeros)
    w[:, 13] = _pairs(f.omega[:, 0], f.omega[:, 1])
    w[:, 14] = _pairs(f.omega[:, 2], f.omega[:, 3])
    w[:, 15] = _pairs(f.t_center, f.t_std)
    return words.reshape(-1)


def camera_entry(camera: Camera, index: int) -> dict[str, Any]:
    """One camera of the chunk list (the viewer starts at the first and cycles through them)."""
    return {"id": index, "img_name": camera.name or f"{index:05d}", "width": camera.width, "height": camera.height,
            "position": camera.center.tolist(), "rotation": camera.R.tolist(), "fx": camera.fx, "fy": camera.fy}


def write_splatv(fields: SplatvFields, path: str | Path, cameras: Sequence[Camera]) -> Path:
    """Write ``fields`` (``reduce``) and the viewer's start cameras to ``path``, atomically."""
    if not cameras:
        raise InputError(f"{path}: a .splatv needs at least one camera for the viewer to start from")
    texture = encode_texture(fields)
    chunk = {"type": "splat", "size": int(texture.nbytes), "texwidth": TEXWIDTH,
             "texheight": int(texture.size // (TEXWIDTH * 4)), "cameras": [camera_entry(c, i) for i, c in enumerate(cameras)]}
    header = json.dumps([chunk], separators=(",", ":")).encode("utf-8")
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(np.array([MAGIC, len(header)], dtype="<u4").tobytes())
            fh.write(header)
            fh.write(texture.tobytes())
    return Path(path)


def _unpair(words: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    h = np.ascontiguousarray(words, dtype="<u4").view("<f2").reshape(-1, 2).astype(np.float32)
    return h[:, 0], h[:, 1]


def read_splatv(path: str | Path, count: int | None = None) -> tuple[SplatvFields, list[dict[str, Any]]]:
    """(fields, cameras) of a .splatv. The texture does not record N: trailing all-zero Gaussians
    (the texture's padding) are dropped unless ``count`` is given."""
    data = Path(path).read_bytes()
    if len(data) < 8:
        raise InputError(f"{path}: too short for a .splatv header")
    magic, length = np.frombuffer(data[:8], dtype="<u4")
    if magic != MAGIC:
        raise InputError(f"{path}: magic {int(magic):#x} is not {MAGIC:#x}; not a .splatv file")
    try:
        chunks = json.loads(data[8:8 + int(length)].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: unreadable .splatv chunk list ({exc})") from None
    offset = 8 + int(length)
    for chunk in chunks:
        size = int(chunk["size"])
        if chunk.get("type") == "splat":
            words = np.frombuffer(data[offset:offset + size], dtype="<u4").reshape(-1, WORDS)
            break
        offset += size
    else:
        raise InputError(f"{path}: no 'splat' chunk")
    if count is None:
        nonzero = np.flatnonzero(words.any(axis=1))
        count = int(nonzero[-1]) + 1 if nonzero.size else 0
    w = words[:count]
    r0, r1 = _unpair(w[:, 3])
    r2, r3 = _unpair(w[:, 4])
    s0, s1 = _unpair(w[:, 5])
    s2, _ = _unpair(w[:, 6])
    motion = np.stack([v for k in range(4) for v in _unpair(w[:, 8 + k])] + [_unpair(w[:, 12])[0]], axis=1)
    o0, o1 = _unpair(w[:, 13])
    o2, o3 = _unpair(w[:, 14])
    tc, ts = _unpair(w[:, 15])
    fields = SplatvFields(positions=np.ascontiguousarray(w[:, 0:3]).view("<f4").astype(np.float32),
                          rotations=np.stack([r0, r1, r2, r3], 1), scales=np.stack([s0, s1, s2], 1),
                          rgba=np.ascontiguousarray(w[:, 7]).view(np.uint8).reshape(-1, 4).copy(), motion=motion,
                          omega=np.stack([o0, o1, o2, o3], 1), t_center=tc, t_std=ts)
    return fields, chunk.get("cameras", [])


def to_model(f: SplatvFields) -> SpacetimeGaussians:
    """The format's content as a fixer4d model (cubic motion, omega, temporal opacity, RGB),
    to render with fixer4d's renderer; ``snapshot_at`` adds the viewer's temporal cut."""
    rgb = f.rgba[:, :3].astype(np.float64) / 255.0
    # 8-bit opacity 255 is 1.0, whose logit is infinite; 1 - 2^-24 is the largest float32 below
    # 1 and every rasterizer clamps alpha far below either (0.99), so nothing renders differently.
    a = np.clip(f.rgba[:, 3].astype(np.float64) / 255.0, 1e-12, 1.0 - 2.0 ** -24)
    tensors = {"means": f.positions, "log_scales": np.log(f.scales.astype(np.float64)),
               "quats": f.rotations, "opacity_logits": np.log(a) - np.log1p(-a), "colors": rgb_to_sh_dc(rgb),
               "t_center": f.t_center, "t_log_scale": np.log(f.t_std.astype(np.float64)), "motion": f.motion,
               "omega": f.omega, "dynamic": np.ones(len(f), dtype=bool)}
    cfg = ModelConfig(motion_degree=3, rotation_velocity=True, temporal_opacity=True, sh_degree=0)
    return SpacetimeGaussians.from_tensors(cfg, {k: np.asarray(v, dtype=np.float32) if k != "dynamic" else v
                                                 for k, v in tensors.items()}, source="splatv")


@torch.no_grad()
def snapshot_at(model: SpacetimeGaussians, f: SplatvFields, t: float) -> Snapshot:
    """``model`` (= ``to_model(f)``) at time t as the viewer draws it: splats whose temporal
    factor exp(-((t - centre) / std)^2) is below ``TEMPORAL_CUT`` are skipped."""
    snap = model.snapshot(t)
    dt = (t - f.t_center.astype(np.float64)) / f.t_std.astype(np.float64)
    shown = torch.from_numpy(np.exp(-dt * dt) >= TEMPORAL_CUT)
    return Snapshot(snap.means, snap.quats, snap.scales, snap.opacities * shown.to(snap.opacities.dtype), snap.colors)
