"""MKL's Intel code branch on any x86-64 CPU (part of portable numerics, fixer4d/numerics.py).

MKL, inside torch's CPU library (torch.exp, log, tanh... through its vector math; matmul through its
BLAS), follows ``MKL_CBWR=AVX2`` only on a CPU whose cpuid says GenuineIntel. On an AMD CPU it keeps
its generic branch, whose vector exp rounds other last bits than the AVX2 branch's, and every digit
of a run after the first exp follows the vendor (docs/decisions/numerics.md). MKL asks one function
whether the CPU is Intel's, ``mkl_serv_intel_cpu_true``, which libtorch_cpu.so exports and calls
through its procedure linkage table, so a library that defines it and is loaded with RTLD_GLOBAL
before torch answers in its place. This module compiles that one-line library with the system's C
compiler (once per machine, cached) and loads it; MKL then takes the branch ``MKL_CBWR`` names on
every vendor's CPU, as it does on Intel's (where the library changes nothing).

    load_intel_answer() -> "loaded" | "unavailable: <why>" | "late: ..."   (call before torch loads)
    answer_state()      -> what the last load_intel_answer() returned (None: never called)
    unpinned_warning()  -> a line for stderr when MKL will not take the pinned branch here, else None
    mkl_branch()        -> MKL's code branch as MKL reports it ("AVX2", "AUTO", ...); None without MKL
    intel_answer_library(answer) -> the compiled library's path (answer 1: Intel; 0: another vendor,
                                    for tests that emulate an AMD CPU on an Intel host with LD_PRELOAD)
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

SYMBOL = "mkl_serv_intel_cpu_true"
#: MKL's branch codes (mkl_cbwr.h), as ``mkl_serv_cbwr_get(MKL_CBWR_BRANCH)`` returns them.
BRANCHES = {1: "OFF", 2: "AUTO", 3: "COMPATIBLE", 4: "SSE2", 6: "SSSE3", 7: "SSE4_1", 8: "SSE4_2", 9: "AVX",
            10: "AVX2", 11: "AVX512_MIC", 12: "AVX512", 13: "AVX512_MIC_E1", 14: "AVX512_E1"}
_CBWR_BRANCH = 1  # MKL_CBWR_BRANCH: ask for the branch alone, without the STRICT flag

_loaded: str | None = None


def _applies() -> bool:
    return sys.platform.startswith("linux") and platform.machine().lower() in ("x86_64", "amd64")


def _cache_dir() -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "fixer4d" / "native"


def intel_answer_library(answer: int = 1, cache: Path | None = None) -> Path:
    """The shared library whose ``mkl_serv_intel_cpu_true`` returns ``answer``, compiled into
    ``cache`` (default $XDG_CACHE_HOME/fixer4d/native) on first use; RuntimeError when no C compiler
    builds it."""
    source = f"int {SYMBOL}(void) {{ return {int(answer)}; }}\n"
    key = hashlib.sha256(f"{source}|{platform.machine()}".encode()).hexdigest()[:16]
    cache = _cache_dir() if cache is None else Path(cache)
    out = cache / f"mkl_intel_answer{int(answer)}-{key}.so"
    if out.is_file():
        return out
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if not compiler:
        raise RuntimeError("no C compiler (cc, gcc or $CC) to build it")
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        src, lib = Path(tmp) / "answer.c", Path(tmp) / "answer.so"
        src.write_text(source)
        try:
            done = subprocess.run([compiler, "-shared", "-fPIC", "-O1", "-o", str(lib), str(src)],
                                  capture_output=True, text=True, timeout=120)
        except (OSError, subprocess.SubprocessError) as e:
            raise RuntimeError(f"{compiler} could not run: {e}") from e
        if done.returncode != 0 or not lib.is_file():
            raise RuntimeError(f"{compiler} failed: {done.stderr.strip()[-300:]}")
        os.replace(lib, out)  # atomic: processes building it at once all load a whole file
    return out


def load_intel_answer() -> str:
    """Load the library that answers MKL's vendor question with Intel, before torch loads MKL.
    Returns what happened; never raises (the branch MKL then takes is what ``mkl_branch`` reports,
    and what portable numerics checks)."""
    global _loaded
    if _loaded is not None:
        return _loaded
    if not _applies():
        _loaded = "not needed: MKL's vendor branches are x86-64 Linux's"
        return _loaded
    if "torch" in sys.modules:  # libtorch_cpu.so may already be bound to its own function
        _loaded = "late: torch was imported before fixer4d"
        return _loaded
    try:
        ctypes.CDLL(str(intel_answer_library(1)), mode=ctypes.RTLD_GLOBAL)
    except (OSError, RuntimeError) as e:
        _loaded = f"unavailable: {e}"
    else:
        _loaded = "loaded"
    return _loaded


def unpinned_warning() -> str | None:
    """One line for a run's stderr when MKL will not take the pinned branch on this CPU (not Intel's,
    and the answer could not be loaded), else None."""
    from fixer4d.cpus import cpu_fields

    state, vendor = answer_state(), cpu_fields().get("vendor_id")
    if state is None or not state.startswith(("unavailable", "late")) or vendor in (None, "GenuineIntel"):
        return None
    fix = ("import fixer4d before torch" if state.startswith("late")
           else "install a C compiler (e.g. apt-get install gcc) so fixer4d can build its one-line answer")
    return (f"numerics: MKL keeps its own code branch on this {vendor} CPU ({state}): the digits will "
            f"differ from an Intel host's; {fix}")


def answer_state() -> str | None:
    """What ``load_intel_answer`` returned in this process; None when it was never called."""
    return _loaded


def mkl_branch() -> str | None:
    """The code branch MKL computes on in this process ("AVX2", "AUTO", ...), read from MKL itself;
    None when torch is not imported or has no MKL."""
    if "torch" not in sys.modules:
        return None
    torch = sys.modules["torch"]
    lib = Path(torch.__file__).parent / "lib" / "libtorch_cpu.so"
    try:
        get = ctypes.CDLL(str(lib)).mkl_serv_cbwr_get
    except (OSError, AttributeError):
        return None
    get.restype, get.argtypes = ctypes.c_int, [ctypes.c_int]
    code = get(_CBWR_BRANCH)
    return BRANCHES.get(code, f"code {code}")


__all__ = ["SYMBOL", "BRANCHES", "intel_answer_library", "load_intel_answer", "answer_state", "unpinned_warning",
           "mkl_branch"]
