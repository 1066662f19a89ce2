"""The conditions a bench records beside its timings (fixer4d.bench.machine)."""
from __future__ import annotations

from fixer4d.bench import machine


def test_reference_speed_measures_one_and_every_thread(monkeypatch):
    monkeypatch.setattr(machine, "REF_ROUNDS", 4)  # a tiny workload: the fields, not the speed
    ref = machine.reference_speed(repeats=2)
    assert ref["single_ms"] > 0 and ref["parallel_ms"] > 0 and ref["threads"] >= 1
    # the two times are rounded to 0.01 ms before the ratio is formed from them here, the speedup
    # after: on this tiny workload (a third of a ms) that rounding alone moves the ratio by ~3 %
    ratio = ref["single_ms"] / ref["parallel_ms"]
    rounding = ratio * (0.005 / ref["single_ms"] + 0.005 / ref["parallel_ms"]) + 0.005
    assert abs(ref["parallel_speedup"] - ratio) <= rounding + 1e-9
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


def _idle_two_cores(**over):
    info = {"usable_cpus": 2, "cores": 2, "numba_threads": 2, "threads_per_core": 1.0,
            "load_avg_1_5_15min": [0.1, 0.1, 0.1],
            "reference": {"threads": 2, "parallel_speedup": 1.9, "steal_fraction": 0.0}}
    info.update(over)
    return info


def test_timing_caveats_are_empty_on_idle_real_cores():
    assert machine.timing_caveats(_idle_two_cores()) == []


def test_timing_caveats_name_each_condition_that_slows_a_timing():
    assert "numba runs 1 thread(s) on 2 usable CPUs" in machine.timing_caveats(_idle_two_cores(numba_threads=1))[0]
    shared = machine.timing_caveats(_idle_two_cores(
        threads_per_core=2.0, reference={"threads": 2, "parallel_speedup": 1.1, "steal_fraction": 0.0}))
    assert len(shared) == 1 and "share a physical core" in shared[0]  # one sentence, not two, for hyper-threads
    assert "hyper-threads" in machine.timing_caveats(_idle_two_cores(threads_per_core=2.0))[0]
    stolen = machine.timing_caveats(_idle_two_cores(
        reference={"threads": 2, "parallel_speedup": 1.9, "steal_fraction": 0.12}))
    assert stolen == ["the hypervisor took 12 % of the CPU time during the reference measurement: "
                      "rerun when the host is quieter"]
    assert "other jobs ran" in machine.timing_caveats(_idle_two_cores(load_avg_1_5_15min=[1.5, 1, 1]))[0]
    # without a reference measurement only what was read can be judged
    assert machine.timing_caveats({"usable_cpus": 2, "numba_threads": 2}) == []


def test_machine_info_records_its_caveats(capsys):
    info = machine.machine_info()
    assert info["caveats"] == machine.timing_caveats(info)
    machine.print_timing_caveats(_idle_two_cores(numba_threads=1))
    assert "timing caveats" in capsys.readouterr().out
    machine.print_timing_caveats(_idle_two_cores())
    assert capsys.readouterr().out == ""
