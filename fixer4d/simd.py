"""Let numba's LLVM vectorize the kernels' float32 lane loops 16 wide on AVX-512 machines.

LLVM's tuning for Intel server cores with AVX-512 (skylake-avx512, cascadelake, icelake-server,
...) includes the ``prefer-256-bit`` feature: auto-vectorized loops use 8-lane ymm registers
even though 16-lane zmm exist (a guard against AVX-512 frequency drops in scalar-heavy code).
The rasterizer's lane loops are long runs of float32 arithmetic where the wider vectors win:
measured on the train-step scene (30k Gaussians, 640x360, 2-core Cascade Lake, load 8.5-9.4,
two alternating pairs of processes) forward 8.5/7.8 -> 6.5/5.9 ns and backward 14.8/12.2 ->
11.2/10.1 ns of CPU per fragment, i.e. 1.2-1.3x.

numba reads the features once, when its CPU target is first set up (the first compilation or
cache load in the process), so this must run before any numba kernel is used. It is called at
import of fixer4d.jit, through which every kernel module imports numba; if some other numba
code has already run in the process, it has no effect (and says so through its return value). Set
FIXER4D_NUMBA_AVX512=0 to keep LLVM's default, or NUMBA_CPU_FEATURES to choose yourself (then
this does nothing).
"""
from __future__ import annotations

import os
import sys

ENV_SWITCH = "FIXER4D_NUMBA_AVX512"


def prefer_512_bit_vectors() -> str | None:
    """Set numba's CPU features to the host's minus ``prefer-256-bit`` when the host has
    AVX-512F. Returns the feature string set, or None when nothing was changed (no AVX-512,
    switched off, NUMBA_CPU_FEATURES already set, or numba's CPU target already built)."""
    if os.environ.get(ENV_SWITCH, "1") == "0" or "NUMBA_CPU_FEATURES" in os.environ:
        return None
    if "numba" in sys.modules:
        from numba.core.registry import cpu_target

        if "_toplevel_target_context" in vars(cpu_target):  # already built (a cached property): too late
            return None
    try:
        import llvmlite.binding as llvm

        features = llvm.get_host_cpu_features().flatten()
    except Exception:  # pragma: no cover - llvmlite missing or host query unsupported
        return None
    if "+avx512f" not in features.split(","):
        return None
    features += ",-prefer-256-bit"
    os.environ["NUMBA_CPU_FEATURES"] = features
    if "numba" in sys.modules:
        from numba.core import config

        config.reload_config()
    return features
