"""A training step's digits do not depend on the compute thread count (fixer4d/threads.py).

torch splits an elementwise op over more than 32,768 elements into one chunk per thread, and the
elements at a chunk's end take another code path (scalar, not vector) whose sigmoid or softplus
rounds differently; a model past that size stepped on one thread and on two parted in the last
bits within a few steps. The trainer steps on ``DIGIT_TORCH_THREADS`` torch threads whatever the
caller's count, and numba's kernels sum in a fixed order: one and two compute threads give the
same bytes. The model has 39,121 Gaussians: past the grain, and odd, so that two threads split it
mid-vector (an even 40,000 splits on a vector border and would not show the fault).
"""
from __future__ import annotations

import copy
import hashlib

import numpy as np
import pytest
import torch

from fixer4d.init.cloud import FrameCloud
from fixer4d.jit import compute_threads, numba, set_compute_threads
from fixer4d.train.model_init import model_from_clouds
from fixer4d.train.trainer import Trainer
from fixer4d.threads import digit_threads

from tests.pools import pools_are_split, rerun_with_machine_pools
from tests.train.conftest import small_config

# Past ATen's grain (32,768 elements; below it every op runs on one thread whatever the count), and
# odd: two threads split it mid-vector.
GAUSSIANS = 39_121
STEPS = 4


def _big_model(scene, clouds, cfg):
    """GAUSSIANS Gaussians: the ground-truth depth clouds' points drawn again with a small seeded
    jitter, so that the model is large but still renders the scene."""
    rng = np.random.default_rng(0)
    per_frame = -(-GAUSSIANS // len(clouds))
    out = []
    for c in clouds:
        pick = rng.integers(0, len(c.points), per_frame)
        pts = np.asarray(c.points)[pick] + rng.normal(0.0, 0.01, (per_frame, 3))
        out.append(FrameCloud(c.frame, c.time, pts, np.asarray(c.colors)[pick]))
    with digit_threads():
        return model_from_clouds(out, scene, cfg)


def _state_after_steps(model, scene, cfg, threads: int) -> str:
    before, torch_before = compute_threads(), torch.get_num_threads()
    set_compute_threads(threads)
    try:
        trainer = Trainer(copy.deepcopy(model), scene, cfg)
        for _ in range(STEPS):
            trainer.step()
        h = hashlib.sha256()
        for _, t in sorted(trainer.model.tensors().items()):
            h.update(t.detach().numpy().tobytes())
        return h.hexdigest()
    finally:
        set_compute_threads(before)
        torch.set_num_threads(torch_before)


@pytest.mark.skipif(numba is None or (numba.config.NUMBA_NUM_THREADS < 2 and not pools_are_split()),
                    reason="needs two CPU threads")
def test_one_and_two_threads_give_the_same_model_past_the_grain(request, small_scene, small_clouds):
    if rerun_with_machine_pools(request):
        return
    cfg = small_config(50, init_max_points=GAUSSIANS, max_gaussians=GAUSSIANS + 10_000)
    model = _big_model(small_scene, small_clouds, cfg)
    assert model.num_gaussians == GAUSSIANS
    assert _state_after_steps(model, small_scene, cfg, 1) == _state_after_steps(model, small_scene, cfg, 2)

