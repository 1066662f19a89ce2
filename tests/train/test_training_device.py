"""Where the trainer optimizes (``TrainingConfig.device``, fixer4d/train/device.py).

Everywhere: how "auto", "cpu" and "cuda" resolve and what is refused; the device trained on is
a result's provenance: a CUDA training has its own stage keys (a CPU one keys as before), a
checkpoint records its device and resumes on it only; a stage hands on its model in host memory.

With CUDA and gsplat: stage 1 keeps every tensor of its state on the GPU while it steps, densifies,
writes checkpoints that a CUDA trainer resumes from and a CPU trainer refuses, and reaches the CPU
kernel's held-out quality.
"""
from __future__ import annotations

import importlib.util

import pytest
import torch

from fixer4d.errors import BackendUnavailable, InputError
from fixer4d.train.config import TrainingConfig
from fixer4d.train.device import training_device
from fixer4d.train.model_init import model_from_clouds
from fixer4d.train.trainer import Trainer

HAS_CUDA = torch.cuda.is_available()
HAS_GSPLAT = importlib.util.find_spec("gsplat") is not None
needs_gsplat = pytest.mark.skipif(not (HAS_CUDA and HAS_GSPLAT), reason="needs CUDA and gsplat")

# Iterations of the short CUDA run: densification three times and two checkpoints.
SHORT_ITERATIONS = 40


def test_cpu_is_the_cpu_and_auto_needs_cuda_and_gsplat():
    assert training_device("cpu", "auto") == torch.device("cpu")
    assert training_device("auto", "cpu") == torch.device("cpu")
    assert training_device("auto", "reference") == torch.device("cpu")
    from fixer4d.render.gsplat_backend import unavailable_reason

    expected = "cuda" if unavailable_reason() is None else "cpu"
    assert training_device("auto", "auto").type == expected


@pytest.mark.parametrize("device, backend, error, words", [
    ("tpu", "auto", InputError, "choose one of auto, cpu, cuda"),
    ("cuda", "cpu", InputError, "renders host tensors only"),
    ("cuda", "reference", InputError, "renders host tensors only"),
])
def test_bad_devices_are_refused_naming_the_fix(device, backend, error, words):
    with pytest.raises(error, match=words):
        training_device(device, backend)


@pytest.mark.skipif(HAS_CUDA, reason="checks the refusal on a machine without CUDA")
def test_cuda_without_cuda_says_so():
    with pytest.raises(BackendUnavailable, match="CUDA is not available.*training.device=cpu or auto"):
        training_device("cuda", "auto")


def test_the_config_refuses_an_unknown_device():
    with pytest.raises(InputError, match="device 'gpu'"):
        TrainingConfig(device="gpu")


# The stage keys of the tiny run on the CPU with the opacity reset, a black background and stage 2's
# targets falling back on the render, as every run folder made before the device entered the keys
# has them: a CPU training keys nothing more, so those folders resume as they were.
TINY_CPU_KEYS = {"stage1": "1c00029558a813f9", "stage2": "0c1352d62b391f77", "matched": "dfe1193473a0a083"}


def test_the_device_trained_on_keys_a_cuda_training_only(monkeypatch):
    import fixer4d.pipeline.keys as keys
    from fixer4d.pipeline.config import resolve

    def keys_of(config):
        return {"stage1": keys.stage1_key(config, "mvs"), "stage2": keys.stage2_key(config),
                "matched": keys.matched_key(config)}

    reset = {"training.opacity_decay.enabled": False, "training.background": [0, 0, 0],
             "stage2.fill_unobserved": False, "training.fields": 1}
    on_cpu = resolve("tiny", overrides={"training.device": "cpu", **reset})
    asked_auto = resolve("tiny", overrides={"training.device": "auto", **reset})
    assert on_cpu.training.device != asked_auto.training.device
    monkeypatch.setattr(keys, "device_kind", lambda device, backend: "cpu")
    assert keys_of(on_cpu) == keys_of(asked_auto) == TINY_CPU_KEYS  # the request is not the provenance
    monkeypatch.setattr(keys, "device_kind", lambda device, backend: "cuda")
    on_cuda = keys_of(asked_auto)
    assert all(on_cuda[k] != TINY_CPU_KEYS[k] for k in TINY_CPU_KEYS)  # a CUDA stage is not the CPU's


def _tampered(path, **changes) -> None:
    state = torch.load(path, weights_only=True)
    for k, v in changes.items():
        if v is None:
            state.pop(k)
        else:
            state[k] = v
    torch.save(state, path)


def test_a_checkpoint_records_its_device_and_resumes_on_it_only(small_scene, small_clouds, make_config, tmp_path):
    cfg = make_config(8, checkpoint_every=4, init_max_points=400, device="cpu")
    Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg, run_dir=tmp_path).train(4)
    (ckpt,) = Trainer.list_checkpoints(tmp_path, 1)
    assert torch.load(ckpt, weights_only=True)["device"] == "cpu"
    other = make_config(8, checkpoint_every=2, keep_checkpoints=3, init_max_points=400, device="cpu")  # neutral
    resumed = Trainer(model_from_clouds(small_clouds, small_scene, other), small_scene, other, run_dir=tmp_path)
    assert resumed.resume() and resumed.step_count == 4
    _tampered(ckpt, device="cuda")
    again = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg, run_dir=tmp_path)
    with pytest.raises(InputError, match="trained on cuda, but this training runs on cpu"):
        again.resume()
    _tampered(ckpt, device=None)  # a checkpoint from before the device was recorded resumes as it did
    assert again.resume() and again.step_count == 4


def test_host_model_is_the_trained_model_in_host_memory(small_scene, small_clouds, make_config):
    cfg = make_config(2, init_max_points=300, device="cpu")
    trainer = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg)
    trainer.train()
    model = trainer.host_model()
    assert model is trainer.model
    assert all(p.device.type == "cpu" for p in model.parameters())


def _short_config(make_config, device: str) -> TrainingConfig:
    """40 iterations that densify at 10, 20 and 30 and checkpoint at 20 and 40."""
    return make_config(SHORT_ITERATIONS, device=device, init_max_points=500, densify_from=10, densify_every=10,
                       densify_until=30, checkpoint_every=20)


@needs_gsplat
def test_stage1_on_cuda_keeps_its_state_there_and_resumes_on_cuda_only(small_scene, small_clouds, make_config,
                                                                       tmp_path):
    cfg = _short_config(make_config, "cuda")
    gpu = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg, run_dir=tmp_path)
    gpu.train()
    assert gpu.model.means.device.type == "cuda"
    assert gpu.stats.grad_accum.device.type == "cuda"
    assert all(s["exp_avg"].device.type == "cuda" for s in gpu.optimizer.state.values())
    assert any(h["num_gaussians"] != gpu.history[0]["num_gaussians"] for h in gpu.history)  # it densified
    assert gpu.history[-1]["psnr"] > gpu.history[0]["psnr"] + 1.0

    # its last checkpoint resumes on CUDA, and the CPU refuses it: one training, one device
    resumed = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg, run_dir=tmp_path)
    assert resumed.resume() and resumed.step_count == SHORT_ITERATIONS
    assert torch.equal(resumed.model.means, gpu.model.means)
    cpu_cfg = _short_config(make_config, "cpu")
    on_cpu = Trainer(model_from_clouds(small_clouds, small_scene, cpu_cfg), small_scene, cpu_cfg, run_dir=tmp_path)
    with pytest.raises(InputError, match="trained on cuda, but this training runs on cpu"):
        on_cpu.resume()
    host = gpu.host_model()
    assert host is gpu.model and host.means.device.type == "cpu"


@needs_gsplat
def test_stage1_through_gsplat_reaches_the_cpu_kernels_quality(small_scene, small_clouds, make_config, heldout,
                                                               stage1_run):
    cpu_trainer, p_init, p_cpu = stage1_run
    cfg = make_config(cpu_trainer.total_iterations, device="cuda")
    trainer = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg)
    assert trainer.device.type == "cuda"
    trainer.train()
    p_gpu = heldout(small_scene, trainer.render_fn())
    # gsplat cuts splats at their tile box, the CPU kernel at 3 sigma: not the same numbers, the
    # same method. The CPU run gains over 4 dB on the init (test_stage1).
    assert p_gpu > p_init + 4.0, (p_init, p_gpu, p_cpu)
    assert abs(p_gpu - p_cpu) < 1.0, (p_gpu, p_cpu)
