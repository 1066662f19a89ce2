"""Portable numerics: the same digits on every x86-64 host, Intel or AMD, AVX2 or AVX-512.

The libraries fixer4d computes with choose their machine code by the CPU they find at run time,
and the choices round differently:

* ATen (torch's CPU kernels): an AVX-512 or an AVX2 build of each vectorized op (exp, sums,
  reductions split by vector width);
* MKL (torch's matmul, LAPACK and vector math: exp, log, tanh...): ISA-specific kernels, and on a
  CPU not Intel's a generic branch whatever ``MKL_CBWR`` asks (fixer4d/mkl_vendor.py answers MKL's
  vendor question with Intel, so that the pin holds on every vendor's CPU);
* oneDNN (torch's convolutions: the learned restorer, LPIPS): JIT kernels per ISA;
* OpenBLAS (numpy's matmul) and numpy's own SIMD loops (exp, log, sin: AVX-512 variants with
  other last-bit results);
* numba (the rasterizer, the loss, the plane sweep): LLVM compiles for the host CPU's name and
  features, so vector widths, and with them every ``reassoc`` reduction, follow the host.

Left to themselves these made the same commit's demo rows differ by 0.25 dB between a 2-core
Intel Xeon and a 2-core AMD EPYC host, and the stage-2 self-check's fold by 1.9 dB.
``portable`` mode (the default) pins every one of them to the AVX2 + FMA code paths that every
x86-64 server of the last decade runs alike; ``host`` mode (``FIXER4D_NUMERICS=host``) leaves
them to pick the fastest path for the host, whose digits then depend on the CPU.

The pins are environment variables each library reads once, when it loads, so ``apply`` runs in
``fixer4d/__init__`` before torch, numpy or numba is imported; ``status`` reports what took
effect (a library imported before fixer4d keeps its own choice) and every run records it.
The thread count needs no pin: a run's torch computes on one thread (fixer4d/threads.py) and
numba's kernels sum in a fixed order. Not pinned: CUDA, whose atomics make gsplat's backward
non-deterministic in any case.

The libraries' versions decide the digits as much as the CPU: ``constraints.txt`` at the
repository's root locks them (``make setup`` installs with it), ``status`` records the installed
versions of ``DIGIT_PACKAGES`` and where they differ from the lock.
"""
from __future__ import annotations

import os
import re
import sys
from importlib import metadata
from pathlib import Path
from typing import Any

ENV_MODE = "FIXER4D_NUMERICS"
MODES = ("portable", "host")

# numba: the Haswell CPU model (AVX2, FMA) with no AVX-512 feature, whatever the host has;
# naming the features too keeps numba from adding the host's (it does whenever only the name is set).
NUMBA_CPU = "haswell"
NUMBA_FEATURES = "+64bit,+avx,+avx2,+fma,+f16c,+bmi,+bmi2,+lzcnt,+movbe,+popcnt,+sse4.2,+cx16,-avx512f"

#: Every library's pin in portable mode. numpy's names are its dispatch groups (2.x): X86_V4 is
#: its AVX-512 baseline group, AVX512_ICL / AVX512_SPR the later AVX-512 extensions; OpenCV's
#: wheel dispatches up to its AVX512-SKX group (an unknown name there prints a warning per process).
PORTABLE_ENV: dict[str, str] = {
    "ATEN_CPU_CAPABILITY": "avx2",
    "MKL_CBWR": "AVX2,STRICT",
    "MKL_ENABLE_INSTRUCTIONS": "AVX2",
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "DNNL_MAX_CPU_ISA": "AVX2",
    "OPENBLAS_CORETYPE": "Haswell",
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
    "NUMBA_CPU_NAME": NUMBA_CPU,
    "NUMBA_CPU_FEATURES": NUMBA_FEATURES,
    "OPENCV_CPU_DISABLE": "AVX512-SKX",
}


def portable_env() -> dict[str, str]:
    """``PORTABLE_ENV`` as this host needs it: OpenCV's AVX-512 switch only on a CPU with AVX-512,
    where alone OpenCV could take that path (elsewhere the name makes it print a warning in every
    process)."""
    from fixer4d.cpus import cpu_fields

    if "avx512f" in cpu_fields().get("flags", "").split():
        return dict(PORTABLE_ENV)
    return {k: v for k, v in PORTABLE_ENV.items() if k != "OPENCV_CPU_DISABLE"}


# Modules that read a pin when they load: apply() after any of them is too late for that pin.
_PIN_READERS = ("torch", "numpy", "numba", "cv2")


class _SettleMklOnImport:
    """Import hook (portable mode): when torch has been imported, make MKL's first calls, one vector
    math function and one matrix product, on the importing thread. MKL reads ``MKL_CBWR`` when it
    first dispatches, and when that first call comes from two OpenMP threads at once (torch.exp
    on a large tensor does this) it now and then dispatches without the pin: 4 of 225 runs of one
    exp on a loaded 2-core host, 0 of 290 with this hook (benchmarks/mkl_first_call.py)."""

    settled = False

    def find_spec(self, name, path=None, target=None):
        if name != "torch":
            return None
        sys.meta_path.remove(self)
        from importlib.util import find_spec

        spec = find_spec(name)
        if spec is None or spec.loader is None:
            return spec
        load = spec.loader.exec_module

        def exec_module(module):
            load(module)
            try:
                _settle_mkl(module)
            except Exception:  # noqa: BLE001  (a torch without these ops still imports; status() says unsettled)
                pass

        spec.loader.exec_module = exec_module
        return spec


def _settle_mkl(torch) -> None:
    # sizes below ATen's grain size run on this thread alone
    torch.exp(torch.zeros(8))
    torch.mm(torch.ones(2, 2), torch.ones(2, 2))
    _SettleMklOnImport.settled = True


#: The distributions whose versions reach the digits of a run: the kernels (torch, numpy, numba and
#: its LLVM, SciPy, scikit-image, OpenCV, Pillow) and pycolmap's SIFT and triangulation. The other
#: OpenCV wheels are listed because an extra that needs one (``fixer4d[sr]``, ``fixer4d[xfeat]``)
#: overwrites the locked wheel's ``cv2`` with its own build.
DIGIT_PACKAGES = ("torch", "numpy", "numba", "llvmlite", "scipy", "scikit-image", "pillow",
                  "opencv-contrib-python-headless", "opencv-python", "opencv-python-headless", "pycolmap")
#: The lock: ``name==version`` lines (pip constraints). Absent in an installed wheel: nothing to compare.
LOCK_FILE = Path(__file__).resolve().parents[1] / "constraints.txt"


def _canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def packages() -> dict[str, str]:
    """{distribution: installed version} of ``DIGIT_PACKAGES``; those not installed are left out."""
    out = {}
    for name in DIGIT_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return out


def read_lock(path: Path = LOCK_FILE) -> dict[str, str] | None:
    """{canonical name: version} of a constraints file's ``name==version`` lines; None without the file."""
    if not path.is_file():
        return None
    pins = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if "==" in line:
            name, version = line.split("==", 1)
            pins[_canonical(name)] = version.strip()
    return pins


def lock_differences(installed: dict[str, str] | None = None,
                     lock: dict[str, str] | None = None) -> dict[str, list[str | None]] | None:
    """{distribution: [installed, locked]} for each of ``DIGIT_PACKAGES`` whose installed version is
    not the lock's (None for a side that lacks it; a local label such as torch's ``+cpu`` is not a
    difference); None when there is no lock."""
    lock = read_lock() if lock is None else lock
    if lock is None:
        return None
    installed = packages() if installed is None else installed
    out: dict[str, list[str | None]] = {}
    for name in DIGIT_PACKAGES:
        have, want = installed.get(name), lock.get(_canonical(name))
        if (have.split("+", 1)[0] if have else None) != want:
            out[name] = [have, want]
    return out


def mode() -> str:
    """The numerics mode asked for by ``FIXER4D_NUMERICS`` (default ``portable``); ValueError for
    any other value (the command line refuses it; ``in_effect`` falls back to portable)."""
    value = os.environ.get(ENV_MODE, "portable").strip().lower() or "portable"
    if value not in MODES:
        raise ValueError(f"{ENV_MODE}={value!r}: choose one of {', '.join(MODES)}")
    return value


def in_effect() -> str:
    """The mode this process runs in: ``mode()``, or portable where the asked value is not a mode."""
    try:
        return mode()
    except ValueError:
        return "portable"


# The environment's own values of the pinned variables, kept while the pins stand in for them, so
# that a child process in host mode (``fixer4d --numerics host``) gets them back: JSON {name: value
# or null for unset}.
ENV_SAVED = "FIXER4D_NUMERICS_SAVED"


def apply() -> list[str]:
    """In portable mode, set every pin of ``portable_env()`` (overriding the environment: a host's own
    choice, e.g. an OPENBLAS_CORETYPE of its CPU, is what portable mode must not follow), make MKL
    take that branch on any vendor's CPU (``mkl_vendor.load_intel_answer``) and hook
    torch's import to make MKL's first calls on one thread (``_SettleMklOnImport``); in host mode,
    undo the pins a portable parent process left in the environment. Returns the names of the
    libraries already imported, for which it comes too late (empty when in time)."""
    import json

    saved = os.environ.get(ENV_SAVED)
    if in_effect() != "portable":
        if saved is not None:
            for key, value in json.loads(saved).items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value
            del os.environ[ENV_SAVED]
        return []
    if saved is None:
        os.environ[ENV_SAVED] = json.dumps({k: os.environ.get(k) for k in PORTABLE_ENV})
    pins = portable_env()
    for key in PORTABLE_ENV.keys() - pins.keys():
        os.environ.pop(key, None)
    os.environ.update(pins)
    from fixer4d.mkl_vendor import load_intel_answer

    load_intel_answer()
    if "torch" not in sys.modules and not any(isinstance(f, _SettleMklOnImport) for f in sys.meta_path):
        sys.meta_path.insert(0, _SettleMklOnImport())
    return [name for name in _PIN_READERS if name in sys.modules]


def _numba_target() -> dict[str, str] | None:
    if "numba" not in sys.modules:
        return None
    from numba.core import config

    return {"cpu_name": config.CPU_NAME or "host", "cpu_features": config.CPU_FEATURES or "host"}


def status() -> dict[str, Any]:
    """What the libraries loaded so far actually use: ``{"mode", "portable": bool, ...}``.
    ``portable`` is True only when every loaded library follows its pin; a library not loaded yet
    is reported as None and will follow its pin when it loads."""
    out: dict[str, Any] = {"mode": in_effect()}
    checks: list[bool] = []
    if "torch" in sys.modules:
        import torch

        cap = torch.backends.cpu.get_cpu_capability()
        out["aten_cpu_capability"] = cap
        checks.append(cap in ("AVX2", "DEFAULT"))
        out["mkl_settled"] = _SettleMklOnImport.settled
        checks.append(_SettleMklOnImport.settled)
        from fixer4d.mkl_vendor import answer_state, mkl_branch

        out["mkl_branch"] = mkl_branch()
        out["mkl_intel_answer"] = answer_state()
        checks.append(out["mkl_branch"] in (None, "AVX2"))
        out["torch_threads"] = torch.get_num_threads()
    if "numpy" in sys.modules:
        try:
            from numpy._core._multiarray_umath import __cpu_features__
        except ImportError:  # numpy < 2
            from numpy.core._multiarray_umath import __cpu_features__
        on = sorted(k for k in ("X86_V4", "AVX512_SKX", "AVX512_ICL", "AVX512_SPR") if __cpu_features__.get(k))
        out["numpy_avx512"] = on
        checks.append(not on)
    target = _numba_target()
    if target is not None:
        out["numba"] = target
        checks.append(target["cpu_name"] == NUMBA_CPU and target["cpu_features"] == NUMBA_FEATURES)
    if "cv2" in sys.modules:
        import cv2

        wide = [f for f in cv2.getCPUFeaturesLine().split() if f.startswith("*AVX512") and not f.endswith("?")]
        out["opencv_avx512"] = wide
        checks.append(not wide)
    out["env"] = {k: os.environ.get(k) for k in PORTABLE_ENV}
    out["packages"] = packages()
    out["lock_differences"] = lock_differences(out["packages"])
    pins = portable_env()
    out["portable"] = out["mode"] == "portable" and all(checks) and all(
        os.environ.get(k) == pins.get(k) for k in PORTABLE_ENV)
    return out


def describe() -> str:
    """One line for logs and reports: the mode and whether it took effect."""
    s = status()
    if s["mode"] == "host":
        return "numerics: host (the libraries' fastest code paths for this CPU; digits depend on the CPU)"
    if s["portable"]:
        return "numerics: portable (AVX2 code paths pinned in ATen, MKL, oneDNN, OpenBLAS, numpy, numba, OpenCV)"
    if s.get("mkl_branch") not in (None, "AVX2") and not str(s.get("mkl_intel_answer")).startswith("late"):
        return (f"numerics: portable asked for but not in effect: MKL on its {s['mkl_branch']} branch "
                f"(its vendor answer: {s.get('mkl_intel_answer')})")
    late = [k for k in ("aten_cpu_capability", "mkl_branch", "numpy_avx512", "numba", "opencv_avx512") if k in s]
    return (f"numerics: portable asked for but not in effect ({', '.join(f'{k}={s[k]}' for k in late)}): a library "
            f"was imported before fixer4d; import fixer4d first")


def lock_note(differences: dict[str, list[str | None]] | None) -> str | None:
    """One sentence naming the packages that differ from the lock, or None when none does (or there
    is no lock)."""
    if not differences:
        return None
    named = ", ".join(f"{k} {have or 'absent'} (locked: {want or 'not installed'})"
                      for k, (have, want) in differences.items())
    return (f"installed packages differ from {LOCK_FILE.name}: {named}; the digits may differ from the committed "
            f"results (`pip install -c {LOCK_FILE.name} -e '.[all]'` installs the locked set)")


__all__ = ["ENV_MODE", "ENV_SAVED", "MODES", "PORTABLE_ENV", "portable_env", "DIGIT_PACKAGES", "LOCK_FILE", "mode",
           "in_effect", "apply", "status", "describe", "packages", "read_lock", "lock_differences", "lock_note"]
