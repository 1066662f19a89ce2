"""MKL's vendor branch (fixer4d/mkl_vendor.py): on a CPU that is not Intel's, MKL ignores
``MKL_CBWR=AVX2`` and its vector exp rounds otherwise. The vendor is emulated on this one machine
by preloading a library that answers MKL's vendor question (Intel or not); portable mode must give
the Intel answer's bytes whatever the CPU, and report an MKL it could not pin."""
from __future__ import annotations

import json
import os
import platform
import subprocess
import sys

import pytest

from fixer4d import mkl_vendor, numerics
from fixer4d.cpus import cpu_fields

# exp over 100,003 normal draws (ATen hands a contiguous float tensor to MKL's vector math), and
# what MKL and portable numerics report; in host mode too MKL's first calls come from one thread (a
# first call from two threads at once now and then ignores MKL_CBWR: docs/decisions/numerics.md)
PROBE = ("import hashlib, json, fixer4d, torch; from fixer4d import numerics; "
         "torch.exp(torch.zeros(8)); torch.mm(torch.ones(2, 2), torch.ones(2, 2)); "
         "g = torch.Generator().manual_seed(0); x = torch.randn(100003, generator=g); "
         "h = hashlib.sha1(torch.exp(x).numpy().tobytes()).hexdigest(); s = numerics.status(); "
         "print(json.dumps([h, s.get('mkl_branch'), s['portable']]))")
# the pins MKL and ATen read, set alike in host mode so that only the vendor's answer differs
PINS = {"MKL_CBWR": "AVX2,STRICT", "MKL_ENABLE_INSTRUCTIONS": "AVX2", "ATEN_CPU_CAPABILITY": "avx2"}


def _libraries():
    if not (sys.platform.startswith("linux") and platform.machine().lower() in ("x86_64", "amd64")):
        pytest.skip("MKL's vendor branches are x86-64 Linux's")
    try:
        return {answer: mkl_vendor.intel_answer_library(answer) for answer in (0, 1)}
    except RuntimeError as e:
        pytest.skip(f"the vendor's answer cannot be built here: {e}")


def _probe(mode: str, preload=None, extra: dict[str, str] | None = None) -> tuple[str, str | None, bool]:
    env = {k: v for k, v in os.environ.items() if k not in numerics.PORTABLE_ENV and k != numerics.ENV_SAVED}
    env.update({numerics.ENV_MODE: mode, **(extra or {})})
    env.pop("LD_PRELOAD", None)
    if preload is not None:
        env["LD_PRELOAD"] = str(preload)
    done = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    digest, branch, portable = json.loads(done.stdout.strip().splitlines()[-1])
    if branch is None:
        pytest.skip("this torch has no MKL")
    return digest, branch, portable


def test_portable_mode_gives_the_intel_branch_bytes_on_any_vendor():
    libs = _libraries()
    other, other_branch, _ = _probe("host", libs[0], PINS)
    intel, intel_branch, _ = _probe("host", libs[1], PINS)
    assert (other_branch, intel_branch) == ("AUTO", "AVX2")  # another vendor's CPU: the AVX2 pin refused
    assert other != intel  # ... and the vendor reaches exp's bytes
    portable, branch, is_portable = _probe("portable")
    assert branch == "AVX2" and is_portable
    assert portable == intel


def test_portable_mode_reports_an_mkl_it_could_not_pin():
    libs = _libraries()
    # a preloaded answer comes before the one portable mode loads: MKL stays on its generic branch
    _, branch, is_portable = _probe("portable", libs[0])
    assert branch == "AUTO" and is_portable is False


def test_the_answer_is_built_once_and_a_missing_compiler_is_named(tmp_path, monkeypatch):
    _libraries()
    built = mkl_vendor.intel_answer_library(1, cache=tmp_path)
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    assert mkl_vendor.intel_answer_library(1, cache=tmp_path) == built  # cached: no compiler needed
    with pytest.raises(RuntimeError, match="no-such-compiler could not run"):
        mkl_vendor.intel_answer_library(0, cache=tmp_path / "fresh")


def test_a_run_says_when_mkl_cannot_be_pinned_on_this_cpu(tmp_path):
    _libraries()
    env = {k: v for k, v in os.environ.items() if k not in numerics.PORTABLE_ENV and k != numerics.ENV_SAVED}
    env.update({"CC": str(tmp_path / "no-such-compiler"), "XDG_CACHE_HOME": str(tmp_path / "cache")})
    env.pop(numerics.ENV_MODE, None)
    done = subprocess.run([sys.executable, "-m", "fixer4d.cli", "eval", str(tmp_path / "none")], env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2  # the verb ran (and refused the missing folder)
    warned = "MKL keeps its own code branch" in done.stderr and "install a C compiler" in done.stderr
    # on an Intel CPU MKL follows the pin without the answer: nothing to say
    assert warned is (cpu_fields().get("vendor_id") not in (None, "GenuineIntel")), done.stderr
