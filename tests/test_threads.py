"""fixer4d.threads.torch_threads: the one scope for torch's thread count."""
from __future__ import annotations

import torch

from fixer4d.cpus import usable_cpus
from fixer4d.threads import torch_threads


def test_sets_and_restores_the_count():
    before = torch.get_num_threads()
    with torch_threads(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before


def test_zero_means_every_usable_cpu_and_none_keeps_the_count():
    before = torch.get_num_threads()
    with torch_threads(0):
        assert torch.get_num_threads() == usable_cpus()
    with torch_threads(None):
        assert torch.get_num_threads() == before
        torch.set_num_threads(1)  # something inside changes it (numba's OpenMP pool does)
    assert torch.get_num_threads() == before


def test_restores_after_an_exception():
    before = torch.get_num_threads()
    try:
        with torch_threads(1):
            raise RuntimeError("inside")
    except RuntimeError:
        pass
    assert torch.get_num_threads() == before
