"""simd.prefer_512_bit_vectors: in host numerics (``FIXER4D_NUMERICS=host``) numba's float32
loops go 16 wide on AVX-512 hosts, and the switches that turn it off work; in portable numerics
(the default) they stay 8 wide on every host. Each case runs in a fresh interpreter (numba reads
its CPU features once per process)."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

llvm = pytest.importorskip("llvmlite.binding")
pytest.importorskip("numba")

HOST_AVX512 = "+avx512f" in llvm.get_host_cpu_features().flatten().split(",")

PROBE = """
import json, os
import numpy as np
if not os.environ.get("_FIXER4D_PROBE_PLAIN"):
    import fixer4d.render.cpu  # sets the features at import
import numba
from fixer4d import simd

@numba.njit
def scale(x, out):
    for i in range(x.shape[0]):
        out[i] = x[i] * np.float32(1.5) + np.float32(0.25)

x = np.ones(1024, np.float32)
scale(x, np.empty_like(x))
asm = next(iter(scale.inspect_asm().values()))
print(json.dumps({"features": os.environ.get("NUMBA_CPU_FEATURES"), "zmm": "zmm" in asm,
                  "again": simd.prefer_512_bit_vectors()}))
"""


def _probe(**env) -> dict:
    from fixer4d import numerics

    base = {k: v for k, v in os.environ.items()
            if k not in ("FIXER4D_NUMBA_AVX512", numerics.ENV_SAVED, *numerics.PORTABLE_ENV)}
    env.setdefault(numerics.ENV_MODE, "host")
    out = subprocess.run([sys.executable, "-c", PROBE], env={**base, **env}, capture_output=True, text=True,
                         check=True, cwd=os.path.dirname(os.path.dirname(os.path.dirname(__file__))))
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_wide_vectors_on_avx512_hosts_only():
    res = _probe()
    assert res["again"] is None  # once numba's target exists, a second call changes nothing
    if HOST_AVX512:
        assert res["features"].endswith(",-prefer-256-bit") and "+avx512f" in res["features"]
        assert res["zmm"]  # the loop really uses 16-lane registers
    else:
        assert res["features"] is None and not res["zmm"]


def test_switch_off():
    # off: fixer4d leaves numba's target alone, so the loop is what LLVM picks for this host by
    # itself (16 lanes on CPUs whose LLVM model has no 256-bit preference, e.g. AMD Zen 4)
    res = _probe(FIXER4D_NUMBA_AVX512="0")
    plain = _probe(FIXER4D_NUMBA_AVX512="0", _FIXER4D_PROBE_PLAIN="1")
    assert res["features"] is None and res["zmm"] == plain["zmm"]
    if not HOST_AVX512:
        assert not res["zmm"]


def test_portable_numerics_keep_8_lanes_on_every_host():
    from fixer4d import numerics

    res = _probe(**{numerics.ENV_MODE: "portable"})
    assert res["features"] == numerics.NUMBA_FEATURES and not res["zmm"]
