"""fixer4d.cpus: the CPUs a process may keep busy, and the thread pools sized to a cgroup quota."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from fixer4d import cpus

ROOT = Path(__file__).resolve().parents[1]


def _v2(tmp_path, text):
    (tmp_path / "cpu.max").write_text(text)
    return tmp_path


def _v1(tmp_path, quota, period, sub="cpu"):
    (tmp_path / sub).mkdir()
    (tmp_path / sub / "cpu.cfs_quota_us").write_text(f"{quota}\n")
    (tmp_path / sub / "cpu.cfs_period_us").write_text(f"{period}\n")
    return tmp_path


@pytest.mark.parametrize("text, quota", [("150000 100000\n", 1.5), ("200000 100000", 2.0), ("max 100000", None),
                                         ("garbage", None), ("x 100000", None), ("100000 0", None)])
def test_cgroup_v2_quota(tmp_path, text, quota):
    assert cpus.cgroup_cpu_quota(_v2(tmp_path, text)) == quota


@pytest.mark.parametrize("quota, period, sub, cpus_", [(50000, 100000, "cpu", 0.5), (-1, 100000, "cpu", None),
                                                       (300000, 100000, "cpu,cpuacct", 3.0)])
def test_cgroup_v1_quota(tmp_path, quota, period, sub, cpus_):
    assert cpus.cgroup_cpu_quota(_v1(tmp_path, quota, period, sub)) == cpus_


def test_no_cgroup_files_means_no_quota(tmp_path):
    assert cpus.cgroup_cpu_quota(tmp_path) is None
    assert cpus.usable_cpus(tmp_path) == cpus.affinity_cpus()
    assert cpus.thread_env_defaults(tmp_path) == {}


def test_quota_caps_the_affinity_mask_rounding_up(tmp_path, monkeypatch):
    monkeypatch.setattr(cpus, "affinity_cpus", lambda: 8)
    assert cpus.usable_cpus(_v2(tmp_path, "150000 100000")) == 2
    assert cpus.thread_env_defaults(tmp_path) == {"NUMBA_NUM_THREADS": "2", "OMP_NUM_THREADS": "2"}
    (tmp_path / "cpu.max").write_text("50000 100000")   # half a CPU still runs one thread
    assert cpus.usable_cpus(tmp_path) == 1
    (tmp_path / "cpu.max").write_text("1600000 100000")  # a quota above the mask changes nothing
    assert cpus.usable_cpus(tmp_path) == 8 and cpus.thread_env_defaults(tmp_path) == {}


def test_importing_fixer4d_under_a_quota_sizes_numba_and_torch(tmp_path):
    """A whole process: the package, imported under a 1-CPU quota on a 2+ CPU mask, leaves numba
    and torch one thread each; a value the environment already sets wins."""
    if cpus.affinity_cpus() < 2:
        pytest.skip("needs an affinity mask of two or more CPUs")
    _v2(tmp_path, "100000 100000")
    code = f"""
import importlib.util, sys
spec = importlib.util.spec_from_file_location("fixer4d.cpus", {str(ROOT / "fixer4d" / "cpus.py")!r})
mod = importlib.util.module_from_spec(spec); spec.loader.exec_module(mod)
mod.CGROUP_ROOT = __import__("pathlib").Path({str(tmp_path)!r})
sys.modules["fixer4d.cpus"] = mod
import fixer4d, numba, torch
print(numba.get_num_threads(), torch.get_num_threads())
"""
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS")}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["1", "1"]
    env["NUMBA_NUM_THREADS"] = "2"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[0] == "2"


def test_cpu_fields_reads_the_first_processor_only(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nvendor_id\t: AuthenticAMD\nflags\t\t: fpu avx avx2 fma\n\n"
                    "processor\t: 1\nvendor_id\t: GenuineIntel\nflags\t\t: fpu avx512f\n")
    fields = cpus.cpu_fields(info)
    assert fields["vendor_id"] == "AuthenticAMD" and fields["flags"].split() == ["fpu", "avx", "avx2", "fma"]
    assert cpus.cpu_fields(tmp_path / "missing") == {}

