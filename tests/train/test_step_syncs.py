"""A training step on the CUDA code path waits for the GPU at most MAX_SYNCS_PER_STEP times.

On CUDA every value read back to the host (``float(t)``, ``bool(t)``, ``.item()``, ``.tolist()``),
every boolean-mask index (its size is data-dependent: a nonzero count read back) and every copy
between host and device blocks the host until the GPU has caught up, so the host cannot queue the
next kernels while the GPU works. The step is run on the CPU here with the gsplat stand-in (the
trainer's CUDA code path: backend "gsplat"), and a dispatch mode counts the calls that would
synchronize on CUDA: scalar reads, nonzero / masked_select / boolean indexing, host data entering
a tensor (a host-to-device copy on CUDA), cross-device copies, and ``tolist`` / ``numpy`` / ``cpu``.
"""
from __future__ import annotations

import traceback

import numpy as np
import pytest
import torch
from torch.overrides import TorchFunctionMode
from torch.utils._python_dispatch import TorchDispatchMode

import gsplat_stand_in
from fixer4d.train.model_init import model_from_clouds
from fixer4d.train.trainer import Trainer

# The cap: a step may read back its scalars and flags, a few times at most.
MAX_SYNCS_PER_STEP = 3
# Steps measured: past the first steps (caches filled), inside the densification window (the
# statistics are gathered), with no densification step among them.
FIRST_MEASURED, MEASURED_STEPS = 21, 24

_SCALAR_READS = {"aten::_local_scalar_dense", "aten::item", "aten::is_nonzero", "aten::equal"}
_DATA_DEPENDENT = {"aten::nonzero", "aten::masked_select", "aten::nonzero_static"}
_HOST_DATA = {"aten::lift_fresh"}  # torch.tensor / from_numpy: on CUDA a host-to-device copy follows
_INDEXING = {"aten::index", "aten::index_put", "aten::index_put_", "aten::_index_put_impl_"}
_COPIES = {"aten::_to_copy", "aten::copy_"}
_HOST_METHODS = {"tolist", "numpy", "cpu"}


def _is_bool_index(args) -> bool:
    indices = args[1] if len(args) > 1 else ()
    return any(isinstance(i, torch.Tensor) and i.dtype in (torch.bool, torch.uint8) for i in indices or ())


def _crosses_devices(func, args, kwargs) -> bool:
    if func._schema.name == "aten::copy_":
        return args[0].device != args[1].device
    target = kwargs.get("device")
    return target is not None and torch.device(target) != args[0].device


class SyncCounter(TorchDispatchMode):
    """Records (op, where in fixer4d) for every call that would synchronize on CUDA."""

    def __init__(self) -> None:
        super().__init__()
        self.calls: list[tuple[str, str]] = []

    def record(self, name: str) -> None:
        frames = [f for f in traceback.extract_stack()[:-3] if "/fixer4d/" in f.filename]
        where = f"{frames[-1].filename.rsplit('/fixer4d/', 1)[1]}:{frames[-1].lineno}" if frames else "?"
        self.calls.append((name, where))

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        name = func._schema.name
        if (name in _SCALAR_READS or name in _DATA_DEPENDENT or name in _HOST_DATA
                or (name in _INDEXING and _is_bool_index(args))
                or (name in _COPIES and _crosses_devices(func, args, kwargs))):
            self.record(name)
        return func(*args, **kwargs)


class HostReads(TorchFunctionMode):
    """Tensor methods that read a tensor on the host without an ATen op on the CPU."""

    def __init__(self, counter: SyncCounter) -> None:
        super().__init__()
        self.counter = counter

    def __torch_function__(self, func, types, args=(), kwargs=None):
        if getattr(func, "__name__", "") in _HOST_METHODS:
            self.counter.record(f"Tensor.{func.__name__}")
        return func(*args, **(kwargs or {}))


def _per_step_counts(trainer: Trainer, steps: int) -> list[list[tuple[str, str]]]:
    """The synchronizing calls of each of the next ``steps`` steps of ``trainer.train``, a step
    running from the start of one ``_step`` to the start of the next (what ``train`` does between
    two steps, reading its scalars, counts to the step before)."""
    counter = SyncCounter()
    starts: list[int] = []
    inner = trainer._step

    def marked():
        starts.append(len(counter.calls))
        inner()

    trainer._step = marked
    with HostReads(counter), counter:
        trainer.train(steps, progress=False)
    starts.append(len(counter.calls))
    return [counter.calls[a:b] for a, b in zip(starts, starts[1:])]


def _trainer(small_scene, small_clouds, make_config, response: bool = False, **overrides) -> Trainer:
    from fixer4d.model.camera_response import CameraResponse

    cfg = make_config(200, backend="gsplat", device="cpu", init_max_points=400, densify_from=10, densify_every=100,
                      densify_until=150, checkpoint_every=1000, **overrides)
    return Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg,
                   camera_response=CameraResponse(len(small_scene.train_ids)) if response else None)


@pytest.mark.parametrize("overrides", [{}, {"views_per_step": 3, "moving_loss_weight": 0.0}, {"response": True},
                                       {"opacity_decay": {"enabled": True, "start": 0}}])
def test_a_steady_training_step_on_the_cuda_path_syncs_at_most_three_times(small_scene, small_clouds, make_config,
                                                                          monkeypatch, overrides):
    gsplat_stand_in.install(monkeypatch)
    trainer = _trainer(small_scene, small_clouds, make_config, **overrides)
    trainer.train(FIRST_MEASURED - 1)
    assert trainer.schedule.gathers_stats(trainer.step_count + 1)
    counts = _per_step_counts(trainer, MEASURED_STEPS)
    worst = max(counts, key=len)
    assert len(worst) <= MAX_SYNCS_PER_STEP, f"{len(worst)} synchronizing calls in one step: {worst}"
    assert float(trainer.stats.denom.sum()) > 0  # the statistics were gathered on the measured steps


def test_a_non_finite_loss_is_reported_at_the_next_read_naming_its_step(small_scene, small_clouds, make_config,
                                                                       monkeypatch, tmp_path):
    """Nothing is read back per step, yet a diverged run is stopped: the read every CHECK_EVERY
    steps (and the one a checkpoint makes first) names the step whose loss went non-finite, and
    no checkpoint is written from the diverged model."""
    from fixer4d.errors import NumericalError
    from fixer4d.train.trainer import CHECK_EVERY

    gsplat_stand_in.install(monkeypatch)
    trainer = _trainer(small_scene, small_clouds, make_config)
    trainer.run_dir = tmp_path
    trainer.config.checkpoint_every = 15
    trainer.train(13)
    with torch.no_grad():
        trainer.model.colors[0] = float("nan")
    with pytest.raises(NumericalError, match="stage 1 step 14: the loss is nan"):
        trainer.train(CHECK_EVERY)
    assert [h["step"] for h in trainer.history] == list(range(1, 14))
    assert not list(tmp_path.glob("checkpoints/*15*"))


def test_one_batched_call_renders_what_one_call_per_camera_does(small_scene, monkeypatch):
    """``render_batch`` (the CUDA path's one gsplat call for a step's views) gives each camera the
    image, radii and projected centres of ``render`` on that camera alone, and the gradients."""
    from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians
    from fixer4d.render.api import render, render_batch

    gsplat_stand_in.install(monkeypatch)
    cams = [small_scene.cameras[c] for c in small_scene.train_ids[:2]]
    results = []
    for batched in (True, False):
        rng = np.random.default_rng(0)
        model = SpacetimeGaussians.from_points(rng.uniform(-0.5, 0.5, (50, 3)), rng.uniform(0, 1, (50, 3)),
                                               np.full(50, 0.5), ModelConfig(), scales=np.full(50, 0.05))
        snap = model.at(0.3)
        bg = torch.tensor([0.1, 0.2, 0.3])
        outs = render_batch(snap, cams, bg) if batched else [render(snap, c, bg, backend="gsplat") for c in cams]
        sum(o.rgb.sum() * (i + 1) for i, o in enumerate(outs)).backward()
        results.append((outs, model.means.grad))
    (batch, g_batch), (single, g_single) = results
    for b, s in zip(batch, single):
        for field in ("rgb", "alpha", "depth", "radii", "means2d"):
            torch.testing.assert_close(getattr(b, field), getattr(s, field))
        torch.testing.assert_close(b.means2d.grad, s.means2d.grad)
    torch.testing.assert_close(g_batch, g_single)


def test_the_traced_guard_keeps_sane_values_and_hides_extreme_ones():
    """``guard_extremes_traced``: values within the bounds pass bit for bit; a Gaussian too far or
    too large becomes invisible at the origin, a huge quaternion keeps its rotation, a huge colour
    is clamped, as ``guard_extremes`` does, without reading a value back."""
    from fixer4d.model.snapshot import Snapshot
    from fixer4d.render.project import COLOR_LIMIT, MEAN_LIMIT, SCALE_LIMIT, guard_extremes_traced

    g = torch.Generator().manual_seed(1)
    snap = Snapshot(means=torch.randn(5, 3, generator=g), quats=torch.randn(5, 4, generator=g),
                    scales=torch.rand(5, 3, generator=g) + 0.01, opacities=torch.rand(5, generator=g),
                    colors=torch.rand(5, 3, generator=g))
    same = guard_extremes_traced(snap)
    for field in ("means", "quats", "scales", "opacities", "colors"):
        assert torch.equal(getattr(same, field), getattr(snap, field)), field
    snap.means[1, 0] = 10 * MEAN_LIMIT
    snap.scales[2, 1] = 10 * SCALE_LIMIT
    snap.quats[3] = torch.tensor([1e17, 0.0, 3e16, 0.0])
    snap.colors[4, 2] = 10 * COLOR_LIMIT
    out = guard_extremes_traced(snap)
    assert out.opacities[1] == 0 and out.opacities[2] == 0 and torch.equal(out.opacities[[0, 3, 4]],
                                                                            snap.opacities[[0, 3, 4]])
    assert torch.equal(out.means[1], torch.zeros(3)) and torch.equal(out.scales[2], torch.ones(3))
    torch.testing.assert_close(out.quats[3], torch.tensor([1.0, 0.0, 0.3, 0.0]))
    assert out.colors[4, 2] == COLOR_LIMIT
    assert all(bool(torch.isfinite(getattr(out, f)).all()) for f in ("means", "scales", "quats", "colors"))


@pytest.mark.parametrize("densify_stats", ["evidence", "all"])
def test_a_stage2_step_on_the_cuda_path_syncs_at_most_three_times(small_scene, small_clouds, make_config,
                                                                 monkeypatch, densify_stats):
    """Stage 2's pseudo-views too: their restored frames and weights decoded onto the device once,
    their cameras' matrices copied once, their L1 taken without reading values back."""
    from test_stage2_loss import FakeCache, _endpoint_clip

    from fixer4d.train.config import Stage2Config

    gsplat_stand_in.install(monkeypatch)
    cfg = make_config(200, backend="gsplat", device="cpu", init_max_points=400, densify_every=100)
    stage2 = Stage2Config(refresh_every=1000, rounds=1, batch_pseudo=2, densify_stats=densify_stats)
    trainer = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg, stage2=stage2,
                      cache=FakeCache({0: [_endpoint_clip(small_scene, nan_endpoints=False)]}))
    trainer.train(FIRST_MEASURED - 1)
    assert trainer.schedule.gathers_stats(trainer.step_count + 1)
    counts = _per_step_counts(trainer, MEASURED_STEPS)
    worst = max(counts, key=len)
    assert len(worst) <= MAX_SYNCS_PER_STEP, f"{len(worst)} synchronizing calls in one step: {worst}"
    assert trainer.history[-1]["loss"] > 0
