"""The conditions a bench records beside its timings (fixer4d.bench.machine)."""
from __future__ import annotations

from fixer4d.bench import machine


def test_reference_speed_measures_one_and_every_thread(monkeypatch):
    monkeypatch.setattr(machine, "REF_ROUNDS", 4)  # a tiny workload: the fields, not the speed
    ref = machine.reference_speed(repeats=2)
    assert ref["single_ms"] > 0 and ref["parallel_ms"] > 0 and ref["threads"] >= 1
    assert abs(ref["parallel_speedup"] - ref["single_ms"] / ref["parallel_ms"]) < 0.01 + 0.01 * ref["parallel_speedup"]
    assert isinstance(ref["threading_layer"], str) and "best of 2" in ref["workload"]


def test_steal_fraction_is_the_stolen_share_of_the_interval():
    before = {"busy": 100, "idle": 50, "steal": 10}
    after = {"busy": 160, "idle": 80, "steal": 20}  # 60 busy + 30 idle + 10 stolen ticks
    assert machine.steal_fraction(before, after) == 0.1
    assert machine.steal_fraction(None, after) is None
    assert machine.steal_fraction(before, before) == 0.0


def test_cpu_topology_reads_the_host():
    topo = machine.cpu_topology()
    assert topo["logical_cpus"] >= 1 and isinstance(topo["vector_extensions"], list)
    if topo["physical_cores"]:
        assert topo["threads_per_core"] >= 1.0
    info = machine.machine_info()
    assert "reference" not in info and info["numba_threads"] >= 1
