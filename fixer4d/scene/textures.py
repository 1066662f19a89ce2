"""Solid procedural textures of the synthetic scenes' ray-caster (fixer4d/scene/raycast.py).

A texture is evaluated at an object's local 3D coordinates (world units), so it moves and spins
with the object: solid colour, checker, stripes, multi-octave value noise and blends of two.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Value-noise lattice hash multipliers (large odd primes, the classic spatial-hash choice).
_HASH_PRIMES = (73856093, 19349663, 83492791, 2654435761)
# Lattice values: a fixed table of 2^16 uniform numbers (a fixed generator seed, so every
# machine renders the same pixels); the pattern repeats only every 65536 cells.
_NOISE_TABLE = np.random.default_rng(20260401).random(1 << 16)


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
