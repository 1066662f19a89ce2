"""Object motion of the synthetic scenes: keyframed paths, spins and bounces (times in seconds).

``apply_motion`` poses an object (centre, local-to-world rotation) at a time; the light's sweep
(fixer4d/scene/raycast.py) turns with the same ``axis_angle_matrix``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
