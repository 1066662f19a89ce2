"""benchmarks/thread_count_probe.py: the model-state hash tells equal states from unequal ones."""
from __future__ import annotations

import torch


class _Model:
    def __init__(self, tensors):
        self._tensors = tensors

    def tensors(self):
        return self._tensors


def test_the_hash_sees_one_changed_value_and_not_the_dict_order(benchmark_script):
    bench = benchmark_script("thread_count_probe")
    a = {"means": torch.arange(6.0).reshape(2, 3), "opacity_logits": torch.zeros(2)}
    b = {"opacity_logits": torch.zeros(2), "means": torch.arange(6.0).reshape(2, 3)}
    assert bench.state_hash(_Model(a)) == bench.state_hash(_Model(b))
    c = {"means": torch.arange(6.0).reshape(2, 3), "opacity_logits": torch.tensor([0.0, 1e-7])}
    assert bench.state_hash(_Model(a)) != bench.state_hash(_Model(c))


class _Trainer:
    """Records the torch thread count each step sees inside the trainer's scope."""

    def __init__(self):
        self.seen = []
        self.model = type("M", (), {"num_gaussians": 5})()

    def step(self):
        from fixer4d.threads import digit_threads

        with digit_threads():
            self.seen.append(torch.get_num_threads())


def test_timing_takes_turns_and_puts_the_rule_back(benchmark_script):
    from fixer4d import threads

    bench = benchmark_script("thread_count_probe")
    trainer = _Trainer()
    before = torch.get_num_threads()
    out = bench.time_torch_threads(trainer, 2, blocks=2)
    step = bench.BLOCK_STEPS
    assert trainer.seen == ([1] * step + [2] * step) * 2
    assert threads.DIGIT_TORCH_THREADS == 1 and torch.get_num_threads() == before
    assert set(out["mean_seconds_per_step"]) == {"1", "2"} and len(out["blocks"]["2"]) == 2
