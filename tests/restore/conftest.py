"""Restore fixtures: small clips of the bench's analytic scene (exact images and depth)."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from fixer4d.bench.restore import make_request

SIZE = (128, 96)  # small enough that the whole folder runs in well under a minute on 2 cores
FRAMES = 8


@pytest.fixture(scope="session")
def clip():
    """(request, gt (F, H, W, 3)): a blurred render with holes between rig cameras 0 and 1, exact depth.
    Shared: tests that modify it take ``fresh(request)``."""
    return make_request(*SIZE, FRAMES, seed=0)


@pytest.fixture(scope="session")
def noisy_clip():
    """Like ``clip`` but every depth the restorer gets is 2% wrong (a smooth surface error)."""
    return make_request(*SIZE, FRAMES, seed=0, depth_noise=0.02)


def fresh(request):
    """A deep copy of a request that a test may modify."""
    return copy.deepcopy(request)


def tiny_request(frames: int = 3, width: int = 24, height: int = 18, seed: int = 0):
    """A very small random-content request for cache/jobs tests (content is irrelevant there)."""
    from fixer4d.bench.restore import rig_cameras, trajectory_cameras
    from fixer4d.restore.base import RestoreRequest

    rng = np.random.default_rng(seed)
    rig = rig_cameras(width, height)
    cams = trajectory_cameras(rig[0], rig[1], frames)
    shape = (frames, height, width)
    return RestoreRequest(
        rgb=rng.random(shape + (3,), dtype=np.float32), depth=np.full(shape, 4.0, np.float32),
        alpha=np.ones(shape, np.float32), cameras=cams, time=0.25, frame=3,
        ref_images=[rng.random((height, width, 3), dtype=np.float32) for _ in range(2)],
        ref_cameras=[rig[0], rig[1]], ref_depths=[np.full((height, width), 4.0, np.float32)] * 2,
        ref_alphas=[np.ones((height, width), np.float32)] * 2,
        trajectory={"name": "pair_0-1", "pair": [0, 1], "amplitude": 0.0})
