"""torch's intra-op thread count: ``with torch_threads(n): ...`` runs the block on ``n`` threads
(0 = every usable CPU, None = the current count) and puts the caller's count back on exit, also
when something inside (numba's OpenMP pool, which shares torch's libgomp) changed it;
``digit_threads()`` is the scope a run computes its digits in.
"""
from __future__ import annotations

import contextlib
from typing import Iterator

import torch

from fixer4d.cpus import usable_cpus

#: torch's thread count wherever a run computes (training steps, inits, merges, restores, metrics).
#: ATen splits an op over more than 32,768 elements (its grain) into one chunk per thread, and each
#: chunk's last, partial vector takes the scalar code path, whose exp / sigmoid / softplus round
#: differently from the vector path (and sums split by thread add in another order): the same
#: step on 1 and 2 threads parts in the last bits of the elements next to the chunk border. One
#: thread makes a run's digits independent of the core count; numba's kernels, fixed-order, keep
#: every granted core. It costs nothing: a 39.6k-Gaussian field's step takes 0.103 s on one torch
#: thread and 0.109 s on two, numba on two either way, idle 2-core host
#: (benchmarks/results/field_workers/torch_threads_step_cost_panoptic.json).
DIGIT_TORCH_THREADS = 1


@contextlib.contextmanager
def torch_threads(n: int | None = None) -> Iterator[None]:
    """Run the block with ``n`` torch threads (0 = every usable CPU, ``fixer4d.cpus``; None = keep
    the current count) and restore the previous count on exit."""
    previous = torch.get_num_threads()
    if n is not None:
        wanted = int(n) if int(n) > 0 else usable_cpus()
        if wanted != previous:
            torch.set_num_threads(wanted)
    try:
        yield
    finally:
        if torch.get_num_threads() != previous:
            torch.set_num_threads(previous)


def digit_threads():
    """The scope a run's computations execute in: ``DIGIT_TORCH_THREADS`` torch threads, numba's
    count left as it is."""
    return torch_threads(DIGIT_TORCH_THREADS)
