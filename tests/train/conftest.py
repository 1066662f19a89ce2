"""Fixtures of the training tests: the tiny synthetic scene at half resolution, a dense init from its ground-truth
depth, and one short stage-1 run shared by the stage-1 and stage-2 tests."""
from __future__ import annotations

import numpy as np
import pytest
import torch

# Tiny tensors: torch's intra-op thread pool costs far more than it saves on a busy 2-core
# machine (an Adam step over ~1k Gaussians goes from ~0.3 ms to tens of ms), so the training
# tests run single-threaded and restore the setting afterwards.
_TEST_THREADS = 1
# The tests train the tiny scene at half its resolution (32x24): a few seconds per hundred steps.
TEST_SCALE = 0.5
# Init from every 2nd pixel of the ground-truth depth (768 points per frame) and a Gaussian cap
# that lets densification roughly triple that.
INIT_STRIDE = 2
TEST_MAX_GAUSSIANS = 8000
# Stage-1 iterations of the shared run (the "a few hundred").
STAGE1_ITERATIONS = 300


@pytest.fixture(autouse=True)
def _single_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(_TEST_THREADS)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def small_scene():
    """The tiny scene at TEST_SCALE (read-only)."""
    from fixer4d.scene import load_scene

    return load_scene("tiny", scale=TEST_SCALE)


@pytest.fixture(scope="session")
def small_clouds(small_scene):
    from fixer4d.bench.iteration import depth_clouds

    return depth_clouds(small_scene, stride=INIT_STRIDE)


def small_config(iterations: int, **overrides):
    from fixer4d.train.config import TrainingConfig

    return TrainingConfig.for_iterations(iterations, **{"seed": 0, "progress": False,
                                                      "max_gaussians": TEST_MAX_GAUSSIANS, **overrides})


def heldout_psnr(scene, render_fn) -> float:
    """Mean PSNR over every held-out camera and frame."""
    from fixer4d.eval.metrics import psnr

    return float(np.mean([psnr(render_fn(scene.cameras[c], scene.time(f)), scene.frame(f, c))
                          for c in scene.test_ids for f in range(scene.num_frames)]))


@pytest.fixture(scope="session")
def stage1_run(small_scene, small_clouds):
    """(trainer after STAGE1_ITERATIONS, held-out PSNR of the init, held-out PSNR after)."""
    from fixer4d.train.model_init import model_from_clouds
    from fixer4d.train.trainer import Trainer

    before = torch.get_num_threads()
    torch.set_num_threads(_TEST_THREADS)
    try:
        cfg = small_config(STAGE1_ITERATIONS)
        trainer = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg)
        p_init = heldout_psnr(small_scene, trainer.render_fn())
        trainer.train()
        p_final = heldout_psnr(small_scene, trainer.render_fn())
    finally:
        torch.set_num_threads(before)
    return trainer, p_init, p_final


@pytest.fixture(scope="session")
def heldout():
    """The ``heldout_psnr(scene, render_fn)`` helper."""
    return heldout_psnr


@pytest.fixture(scope="session")
def make_config():
    """The ``small_config(iterations, **overrides)`` helper."""
    return small_config
