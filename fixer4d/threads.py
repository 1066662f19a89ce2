"""One scope for torch's intra-op thread count: ``with torch_threads(n): ...`` runs the block on
``n`` threads (0 = every usable CPU, None = the current count) and puts the caller's count back on
exit, also when something inside (numba's OpenMP pool, which shares torch's libgomp) changed it.
"""
from __future__ import annotations

import contextlib
from typing import Iterator

import torch

from fixer4d.cpus import usable_cpus


@contextlib.contextmanager
def torch_threads(n: int | None = None) -> Iterator[None]:
    """Run the block with ``n`` torch threads (0 = every usable CPU, ``fixer4d.cpus``; None = keep
    the current count) and restore the previous count on exit."""
    previous = torch.get_num_threads()
    if n is not None:
        torch.set_num_threads(int(n) if int(n) > 0 else usable_cpus())
    try:
        yield
    finally:
        if torch.get_num_threads() != previous:
            torch.set_num_threads(previous)
