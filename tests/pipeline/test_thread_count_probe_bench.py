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
