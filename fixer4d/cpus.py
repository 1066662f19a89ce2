"""How many CPUs this process may keep busy (the scheduler's affinity mask, capped by a cgroup CPU
quota), and what they are (``cpu_fields``). Containers and CI runners often grant a quota ("2
CPUs") on a larger host; the affinity mask, which numba and torch size their thread pools by, still
lists every host CPU there, and a pool of one thread per host CPU on a 2-CPU quota is throttled at
every parallel region. No heavy imports: ``fixer4d/__init__`` calls this before torch or numba load.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

CGROUP_ROOT = Path("/sys/fs/cgroup")
CPUINFO = Path("/proc/cpuinfo")


def _read(path: Path) -> str | None:
    try:
        return path.read_text().strip()
    except (OSError, UnicodeDecodeError):
        return None


def cpu_fields(path: Path | str | None = None) -> dict[str, str]:
    """The first processor's fields of ``path`` (default /proc/cpuinfo), e.g. ``vendor_id``,
    ``flags``; empty where it cannot be read."""
    text = _read(Path(CPUINFO if path is None else path)) or ""
    fields: dict[str, str] = {}
    for line in text.splitlines():
        if not line.strip():
            break
        if ":" in line:
            key, value = (part.strip() for part in line.split(":", 1))
            fields.setdefault(key, value)
    return fields


def cgroup_cpu_quota(root: Path | str | None = None) -> float | None:
    """The cgroup's CPU quota in CPUs (e.g. 1.5), or None where there is none. Reads cgroup v2's
    ``cpu.max`` ("QUOTA PERIOD" or "max PERIOD") or v1's ``cpu.cfs_quota_us`` / ``cpu.cfs_period_us``
    (-1: no quota) under ``root`` (default ``CGROUP_ROOT``; v1 under ``cpu/`` or ``cpu,cpuacct/``)."""
    root = Path(CGROUP_ROOT if root is None else root)
    v2 = _read(root / "cpu.max")
    if v2 is not None:
        parts = v2.split()
        try:
            if len(parts) == 2 and parts[0] != "max" and int(parts[1]) > 0:
                return int(parts[0]) / int(parts[1])
        except ValueError:
            return None
        return None
    for sub in ("cpu", "cpu,cpuacct", "cpuacct,cpu"):
        quota, period = _read(root / sub / "cpu.cfs_quota_us"), _read(root / sub / "cpu.cfs_period_us")
        if quota is None or period is None:
            continue
        try:
            q, p = int(quota), int(period)
        except ValueError:
            return None
        return q / p if q > 0 and p > 0 else None
    return None


def affinity_cpus() -> int:
    """CPUs in this process's affinity mask (``os.cpu_count()`` where the platform has none)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def usable_cpus(root: Path | str | None = None) -> int:
    """min(affinity CPUs, the cgroup quota rounded up), at least 1."""
    n = affinity_cpus()
    quota = cgroup_cpu_quota(root)
    if quota is not None:
        n = min(n, max(1, math.ceil(quota - 1e-9)))
    return max(1, n)


def thread_env_defaults(root: Path | str | None = None) -> dict[str, str]:
    """Environment defaults that size numba's and OpenMP's (torch's) pools to ``usable_cpus``
    where a quota makes it smaller than the affinity mask; empty otherwise (the libraries' own
    defaults are right then)."""
    n = usable_cpus(root)
    if n >= affinity_cpus():
        return {}
    return {"NUMBA_NUM_THREADS": str(n), "OMP_NUM_THREADS": str(n)}


__all__ = ["cgroup_cpu_quota", "affinity_cpus", "usable_cpus", "thread_env_defaults"]
