"""What a timing depends on besides the code: the machine's CPU, its threads, its load, the time
the hypervisor took away, and how fast its cores run a fixed workload.

Machines sold as the same kind ("2 cores") differ: another CPU model, two vCPUs that are the two
hyper-threads of one physical core, a slower clock, a busy host. ``machine_info`` records what
can be read; ``reference_speed`` measures what cannot, on a fixed numba workload that resembles
the rasterizer's inner loop (float32 exp and multiply-adds over an array that stays in L2):

- ``single_ms``: one thread, the whole workload: a core's speed;
- ``parallel_ms``: the same workload split over every numba thread: how much the second core
  adds (``parallel_speedup`` = single / parallel: about 2 on two real cores, about 1.0-1.3 when
  the two vCPUs share one core's execution units).

A bench row divided by ``single_ms`` compares across machines: the rasterizer's time per
fragment scales with the core speed and the parallel speedup as this workload does.
``steal_fraction`` reads /proc/stat's steal column around a measurement: time the hypervisor
gave the vCPUs to someone else.
"""
from __future__ import annotations

import os
import platform
import time

import numpy as np

from fixer4d.cpus import affinity_cpus, cgroup_cpu_quota, usable_cpus

# The reference workload: float32 values, each passed through exp and a chain of multiply-adds,
# REF_ROUNDS times over an array of REF_SIZE values (256 KiB: resident in L2 on any x86 server
# core, so the figure is compute, not memory). ~0.1-0.3 s on one core of a 2-4 GHz x86 CPU.
REF_SIZE = 65_536
REF_ROUNDS = 400
# Best of this many runs: the minimum is the machine's speed, the rest is other load.
REF_REPEATS = 5
# Below this single/parallel ratio on two or more threads the second vCPU adds little: two vCPUs
# that are real cores give 1.6-2.0 on the reference workload (1.67 on a 2-core Xeon whose turbo
# clock drops with both cores busy), two hyper-threads of one core 1.0-1.3.
SHARED_CORE_SPEEDUP = 1.5
# Above this share of stolen CPU time the hypervisor took enough to move a timing by as much.
STEAL_NOTICE = 0.05
# A 1-minute load average above this share of the usable CPUs means other jobs ran beside the bench.
BUSY_LOAD_FRACTION = 0.5

_KERNELS: dict[str, object] = {}


def _kernels():
    """The numba reference kernels (compiled once per process)."""
    if not _KERNELS:
        import numba

        def body(x, out, lo, hi, rounds):
            for i in range(lo, hi):
                v = x[i]
                acc = np.float32(0.0)
                for _ in range(rounds):
                    acc = acc * np.float32(0.999) + np.exp(v * np.float32(-0.5)) * np.float32(1.0001)
                    v = v + np.float32(1e-4)
                out[i] = acc

        single = numba.njit(cache=False, fastmath=True)(body)

        @numba.njit(parallel=True, cache=False, fastmath=True)
        def parallel(x, out, rounds, chunks):
            n = x.shape[0]
            step = (n + chunks - 1) // chunks
            for c in numba.prange(chunks):
                single(x, out, c * step, min(n, (c + 1) * step), rounds)

        _KERNELS["single"] = single
        _KERNELS["parallel"] = parallel
    return _KERNELS["single"], _KERNELS["parallel"]


def reference_speed(repeats: int = REF_REPEATS) -> dict:
    """{"single_ms", "parallel_ms", "parallel_speedup", "threads", "workload"}: best-of-``repeats``
    milliseconds of the reference workload (module docstring) on one thread and on every numba
    thread, after one compiling call."""
    import numba

    single, parallel = _kernels()
    x = np.linspace(0.0, 4.0, REF_SIZE, dtype=np.float32)
    out = np.empty_like(x)
    threads = numba.get_num_threads()
    chunks = 4 * threads
    single(x[:64], out[:64], 0, 64, 2)
    parallel(x[:64], out[:64], 2, chunks)

    def best(fn) -> float:
        times = []
        for _ in range(max(int(repeats), 1)):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        return 1000.0 * min(times)

    single_ms = best(lambda: single(x, out, 0, REF_SIZE, REF_ROUNDS))
    parallel_ms = best(lambda: parallel(x, out, REF_ROUNDS, chunks))
    return {"single_ms": round(single_ms, 2), "parallel_ms": round(parallel_ms, 2),
            "parallel_speedup": round(single_ms / max(parallel_ms, 1e-9), 2), "threads": threads,
            "threading_layer": numba.threading_layer(),
            "workload": f"{REF_SIZE} float32 x {REF_ROUNDS} rounds of exp + multiply-add, best of {repeats}"}


def read_cpu_times() -> dict[str, int] | None:
    """The aggregate line of /proc/stat in clock ticks ({"busy", "idle", "steal"}), or None where
    there is no /proc."""
    try:
        with open("/proc/stat") as fh:
            fields = [int(v) for v in fh.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    user, nice, system, idle, iowait, irq, softirq = fields[:7]
    steal = fields[7] if len(fields) > 7 else 0
    return {"busy": user + nice + system + irq + softirq, "idle": idle + iowait, "steal": steal}


def steal_fraction(before: dict[str, int] | None, after: dict[str, int] | None) -> float | None:
    """Share of the CPU time between two ``read_cpu_times`` readings that the hypervisor stole."""
    if before is None or after is None:
        return None
    d = {k: after[k] - before[k] for k in before}
    total = d["busy"] + d["idle"] + d["steal"]
    return round(d["steal"] / total, 4) if total > 0 else 0.0


def cpu_topology() -> dict:
    """CPU model, family/model/stepping, vector extensions and whether the logical CPUs are
    hyper-threads of fewer physical cores (from /proc/cpuinfo; empty fields where unknown)."""
    info: dict[str, object] = {"cpu": platform.processor(), "logical_cpus": os.cpu_count()}
    cores, flags = set(), set()
    try:
        with open("/proc/cpuinfo") as fh:
            block: dict[str, str] = {}
            for line in fh:
                if ":" not in line:
                    if block:
                        cores.add((block.get("physical id"), block.get("core id")))
                    block = {}
                    continue
                key, value = (s.strip() for s in line.split(":", 1))
                block[key] = value
                if key == "model name":
                    info["cpu"] = value
                elif key in ("cpu family", "model", "stepping", "microcode") and key not in info:
                    info[key.replace(" ", "_")] = value
                elif key == "flags" and not flags:
                    flags = set(value.split())
            if block:
                cores.add((block.get("physical id"), block.get("core id")))
    except OSError:
        pass
    info["physical_cores"] = len(cores) if cores and None not in {c for pair in cores for c in pair} else None
    info["threads_per_core"] = (round(info["logical_cpus"] / info["physical_cores"], 2)
                                if info["physical_cores"] and info["logical_cpus"] else None)
    info["vector_extensions"] = sorted(f for f in flags if f in ("avx", "avx2", "fma", "avx512f", "avx512bw",
                                                                   "avx512vl", "avx512_fp16"))
    info["hypervisor"] = "hypervisor" in flags
    return info


def timing_caveats(info: dict) -> list[str]:
    """Sentences, one per condition in ``info`` (a ``machine_info`` dict) that makes its timings
    slower than the same code on idle real cores, each with what to do; empty when none applies."""
    out = []
    usable = info.get("usable_cpus") or info.get("cores") or 1
    if info.get("numba_threads", usable) < usable:
        out.append(f"numba runs {info['numba_threads']} thread(s) on {usable} usable CPUs: the rasterizer's "
                   "parallel loops use part of the machine (unset NUMBA_NUM_THREADS or raise it)")
    ref = info.get("reference") or {}
    if ref.get("threads", 1) >= 2 and ref.get("parallel_speedup", 2.0) < SHARED_CORE_SPEEDUP:
        out.append(f"the reference workload runs only {ref['parallel_speedup']}x faster on {ref['threads']} threads "
                   "than on one: the vCPUs share a physical core (hyper-threads) or are throttled, so "
                   "parallel code gets about one core's work; compare per-core figures (reference.single_ms)")
    elif (info.get("threads_per_core") or 1) > 1:
        out.append(f"{info['threads_per_core']} logical CPUs per physical core: the CPUs are hyper-threads")
    if (ref.get("steal_fraction") or 0) > STEAL_NOTICE:
        out.append(f"the hypervisor took {100 * ref['steal_fraction']:.0f} % of the CPU time during the "
                   "reference measurement: rerun when the host is quieter")
    load = (info.get("load_avg_1_5_15min") or [0.0])[0]
    if load > BUSY_LOAD_FRACTION * usable:
        out.append(f"1-minute load average {load} on {usable} usable CPUs: other jobs ran beside the bench")
    return out


def print_timing_caveats(info: dict) -> None:
    """Print ``timing_caveats(info)`` under a heading, or nothing when there are none."""
    caveats = timing_caveats(info)
    if caveats:
        print("timing caveats (the result file's machine.caveats):")
        for line in caveats:
            print(f"  - {line}")


def machine_info(reference: bool = False) -> dict:
    """The conditions of a timing: CPU topology, threads, library versions, load; with
    ``reference`` also ``reference_speed()`` (about a second)."""
    import numba
    import torch

    out = {**cpu_topology(), "cores": os.cpu_count(), "affinity_cpus": affinity_cpus(),
           "cgroup_cpu_quota": cgroup_cpu_quota(), "usable_cpus": usable_cpus(),
           "numba_threads": numba.get_num_threads(),
           "torch_threads": torch.get_num_threads(), "python": platform.python_version(),
           # fixer4d/simd.py: 16-lane float32 loops on AVX-512 hosts unless switched off
           "numba_avx512_vectors": "-prefer-256-bit" in os.environ.get("NUMBA_CPU_FEATURES", ""),
           "torch": torch.__version__, "numba": numba.__version__, "platform": platform.platform(),
           "load_avg_1_5_15min": [round(x, 2) for x in os.getloadavg()]}
    if reference:
        before = read_cpu_times()
        out["reference"] = reference_speed()
        out["reference"]["steal_fraction"] = steal_fraction(before, read_cpu_times())
    out["caveats"] = timing_caveats(out)
    return out


__all__ = ["machine_info", "reference_speed", "cpu_topology", "read_cpu_times", "steal_fraction"]
