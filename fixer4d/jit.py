"""numba, set up once for every kernel module (render/cpu_kernels.py, render/project_cpu.py,
train/loss_cpu.py, init/mvs_kernel.py): the AVX-512 vector-width preference (fixer4d/simd.py),
which must be in place before numba builds its CPU target, the import guard (numba is a core
dependency, but each kernel module keeps a torch path that works without it), the guard that
keeps numba's thread pool from changing torch's thread count, and ``set_compute_threads`` /
``compute_threads`` (both libraries' counts for a task or worker process granted n CPUs, and
how many it was granted).

Kernel modules import ``njit``/``prange``/``numba`` from here and define their kernels under
``if njit is not None`` (``NUMBA_ERROR`` says why not).
"""
from __future__ import annotations

from fixer4d.simd import prefer_512_bit_vectors
from fixer4d.threads import torch_threads

prefer_512_bit_vectors()  # before numba builds its CPU target: 16-lane float32 loops (see simd.py)

try:
    import numba
    from numba import njit, prange
except ImportError as _exc:  # pragma: no cover - exercised only on broken installs
    numba = njit = prange = None
    NUMBA_ERROR: str | None = f"numba is not importable ({_exc})"
else:
    NUMBA_ERROR = None


def torch_threads_kept():
    """Run numba's parallel machinery without letting it change torch's intra-op thread count.

    numba's "omp" threading layer and torch share one libgomp (same soname), and numba's first
    use of its thread pool (a parallel kernel, or even numba.get_num_threads()) sets the OpenMP
    thread count to every core, silently raising ``torch.get_num_threads()`` from what the
    caller chose (e.g. 1) to 2. Under load every small torch op then pays a two-thread OpenMP
    barrier: a training iteration measured 1.9 s instead of 0.3 s (30k Gaussians, 320x180), and
    a 50k fwd+bwd render 4.3 s instead of 0.45 s. The count is restored on exit.
    """
    return torch_threads(None)


def compute_threads() -> int:
    """The threads this process may compute on: numba's count, what ``set_compute_threads`` granted
    (every core unless a task or worker was granted fewer). torch's own count is no measure of it:
    a run's torch computes on ``DIGIT_TORCH_THREADS`` (fixer4d/threads.py). torch's count where
    numba is missing."""
    if numba is None:
        import torch

        return torch.get_num_threads()
    with torch_threads_kept():
        return int(numba.get_num_threads())


def set_compute_threads(n: int) -> None:
    """torch's intra-op thread count and numba's parallel kernels' (up to numba's pool size) both
    ``n``: what a task or worker process granted ``n`` CPUs computes on."""
    import torch

    if numba is not None:  # first: its first use of the pool raises OpenMP's (and torch's) count
        numba.set_num_threads(min(int(n), numba.config.NUMBA_NUM_THREADS))
    torch.set_num_threads(int(n))
