"""Portable numerics (fixer4d/numerics.py): the same bytes on any x86-64 host. Hosts are emulated on
this one machine by forcing each library's choice the way another CPU would make it (numba's CPU
name and features, ATen's capability, MKL's and OpenBLAS's code paths, numpy's dispatch): in host
mode the choices reach the bytes, in portable mode (the default) they do not, down to a whole
tiny pipeline's model and report. And across real hosts: ``fingerprint.json`` holds those bytes' hashes
as one host made them with the locked packages; on any other host with the same packages the test
below compares its own (``FIXER4D_UPDATE_FINGERPRINT=1`` writes the file anew)."""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fixer4d import numerics
from fixer4d.cpus import cpu_fields

from tests.pools import machine_pools_env

PROBE = Path(__file__).with_name("numerics_probe.py")
FINGERPRINT = Path(__file__).with_name("fingerprint.json")
UPDATE_FINGERPRINT = os.environ.get("FIXER4D_UPDATE_FINGERPRINT") == "1"
# What an AVX-512 Intel Xeon's libraries pick, and what an AVX2-only AMD EPYC's (Zen 3) pick.
INTEL_AVX512 = {"NUMBA_CPU_NAME": "skylake-avx512",
                "NUMBA_CPU_FEATURES": "+avx512f,+avx512dq,+avx512bw,+avx512vl,+avx512cd,+avx2,+fma,-prefer-256-bit",
                "ATEN_CPU_CAPABILITY": "avx512", "MKL_CBWR": "AVX512", "OPENBLAS_CORETYPE": "SkylakeX",
                "NPY_DISABLE_CPU_FEATURES": ""}
AMD_AVX2 = {"NUMBA_CPU_NAME": "znver3", "NUMBA_CPU_FEATURES": "+avx2,+fma,-avx512f", "ATEN_CPU_CAPABILITY": "avx2",
            "MKL_CBWR": "AVX2", "OPENBLAS_CORETYPE": "Zen", "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
            "ONEDNN_MAX_CPU_ISA": "AVX2", "OPENCV_CPU_DISABLE": "AVX512-SKX"}


def _avx512_host() -> bool:
    return "avx512f" in cpu_fields().get("flags", "").split()


def _env(mode: str, host: dict[str, str]) -> dict[str, str]:
    """A child's environment: the machine's thread pools (not an xdist worker's share), ``host``'s
    emulated choices and numerics ``mode``."""
    env = {k: v for k, v in machine_pools_env().items() if k not in numerics.PORTABLE_ENV and k != numerics.ENV_SAVED}
    return {**env, **host, numerics.ENV_MODE: mode}


def _probe(mode: str, host: dict[str, str]) -> dict:
    done = subprocess.run([sys.executable, str(PROBE)], env=_env(mode, host), capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def _sha1(data: bytes) -> str:
    return hashlib.sha1(data).hexdigest()


def _check_fingerprint(part: str, hashes: dict[str, str], torch_threads: int | None) -> None:
    """Compare ``hashes`` with the committed fingerprint's ``part``, made on another host (or write
    them there with FIXER4D_UPDATE_FINGERPRINT=1). Skips where this host's packages (or, for a part
    whose digits follow the torch thread count it was made on, ``torch_threads``; None: they do not)
    are not the fingerprint's: other library versions give other digits on any CPU."""
    from fixer4d.bench.machine import cpu_topology

    here = {"packages": numerics.packages(), **({} if torch_threads is None else {"torch_threads": torch_threads})}
    committed = json.loads(FINGERPRINT.read_text()) if FINGERPRINT.is_file() else {}
    if UPDATE_FINGERPRINT:
        cpu = cpu_topology()
        made_on = f"{cpu['cpu']} (family {cpu.get('cpu_family')}, model {cpu.get('model')})"
        FINGERPRINT.write_text(json.dumps({**committed, **here, "made_on": made_on, part: hashes}, indent=1,
                                          sort_keys=True) + "\n")
        return
    if part not in committed:
        pytest.skip(f"{FINGERPRINT.name} has no {part!r}: write it with FIXER4D_UPDATE_FINGERPRINT=1")
    for key in here:
        if here[key] != committed[key]:
            pytest.skip(f"this host's {key} ({here[key]}) is not the fingerprint's ({committed[key]}): "
                        f"install the locked set (constraints.txt) to compare digits across hosts")
    differ = sorted(k for k in hashes if hashes[k] != committed[part].get(k))
    assert not differ, f"the same packages give other bytes here than on {committed['made_on']}: {differ}"


def test_portable_mode_gives_the_same_bytes_under_every_emulated_host():
    intel, amd = _probe("portable", INTEL_AVX512), _probe("portable", AMD_AVX2)
    assert intel["portable"] and amd["portable"]
    assert intel["hashes"] == amd["hashes"]
    _check_fingerprint("probe", intel["hashes"], intel["torch_threads"])


@pytest.mark.skipif(not _avx512_host(), reason="emulating an AVX-512 host's code paths needs an AVX-512 CPU")
def test_host_mode_follows_the_host_so_the_emulation_reaches_the_libraries():
    intel, amd = _probe("host", INTEL_AVX512), _probe("host", AMD_AVX2)
    assert not intel["portable"] and not amd["portable"]
    differ = {k for k in intel["hashes"] if intel["hashes"][k] != amd["hashes"][k]}
    # OpenBLAS's kernels and numba's vector width round differently on the two hosts (what made the
    # same commit's rows differ between an Intel and an AMD machine)
    assert {"numpy_mm", "numba_reassoc"} <= differ


def test_status_reports_a_library_loaded_before_the_pins():
    code = ("import numpy, torch; import fixer4d; from fixer4d import numerics; "
            "import json; print(json.dumps(numerics.status()))")
    env = _env("portable", INTEL_AVX512)
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    status = json.loads(done.stdout.strip().splitlines()[-1])
    assert status["mode"] == "portable"
    if _avx512_host():  # numpy loaded with the emulated host's AVX-512 loops: reported, not hidden
        assert status["portable"] is False and status["numpy_avx512"]


def test_mkl_makes_its_first_calls_on_the_thread_that_imports_torch():
    # MKL's first dispatch from two threads at once sometimes ignored MKL_CBWR (the emulated hosts'
    # exp differed on a loaded CI host): the hook makes it on one thread, in portable mode only
    code = ("import sys, json; import fixer4d, torch; from fixer4d import numerics; "
            "print(json.dumps([numerics.status().get('mkl_settled'), "
            "[type(f).__name__ for f in sys.meta_path]]))")
    for mode, settled in (("portable", True), ("host", False)):
        done = subprocess.run([sys.executable, "-c", code], env=_env(mode, {}), capture_output=True, text=True,
                              timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
        was_settled, finders = json.loads(done.stdout.strip().splitlines()[-1])
        assert was_settled is settled and "_SettleMklOnImport" not in finders


def test_portable_mode_pins_only_what_the_cpu_has():
    # OpenCV warns in every process that disables a feature the CPU lacks; on a CPU without AVX-512
    # it cannot take that path anyway
    done = subprocess.run([sys.executable, "-c", "import fixer4d, cv2; from fixer4d import numerics; "
                           "print(numerics.status()['portable'])"], env=_env("portable", {}),
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.split()[-1] == "True"
    assert "OPENCV" not in done.stderr
    assert ("OPENCV_CPU_DISABLE" in numerics.portable_env()) is _avx512_host()


def test_an_unknown_mode_is_refused(monkeypatch, tmp_path):
    monkeypatch.setenv(numerics.ENV_MODE, "fast")
    with pytest.raises(ValueError, match="portable, host"):
        numerics.mode()
    assert numerics.in_effect() == "portable" and numerics.status()["mode"] == "portable"
    env = {**os.environ, numerics.ENV_MODE: "fast"}
    done = subprocess.run([sys.executable, "-m", "fixer4d.cli", "eval", str(tmp_path)], env=env, capture_output=True,
                          text=True, timeout=300)  # importing fixer4d works; the command refuses the value
    assert done.returncode == 2 and "FIXER4D_NUMERICS='fast': choose one of portable, host" in done.stderr


def test_a_tiny_pipeline_gives_the_same_model_and_report_on_two_emulated_hosts(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("pipeline_tiny", Path(__file__).parents[1] / "pipeline" / "pipeline_tiny.py")
    tiny = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tiny)
    TINY = tiny.TINY
    sets = [f"{k}={json.dumps(v) if not isinstance(v, str) else v}" for k, v in {**TINY, "baseline_sparse": False}.items()]
    outputs = []
    for name, host in (("intel", INTEL_AVX512), ("amd", AMD_AVX2)):
        run = tmp_path / name
        argv = [sys.executable, "-m", "fixer4d.cli", "run", "tiny", "--out", str(run), "--quiet"]
        for s in sets:
            argv += ["--set", s]
        done = subprocess.run(argv, env=_env("portable", host), capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stderr[-3000:]
        report = json.loads((run / "report.json").read_text())
        rows = [{k: v for k, v in r.items() if k != "seconds"} for r in report["rows"]]
        outputs.append(((run / "model_final.ply").read_bytes(), (run / "model_stage1.ply").read_bytes(), rows,
                        report["numerics"]["portable"]))
    assert outputs[0][3] and outputs[1][3]
    assert outputs[0][0] == outputs[1][0] and outputs[0][1] == outputs[1][1]
    assert outputs[0][2] == outputs[1][2]
    psnr = json.dumps({r["method"]: r.get("psnr") for r in outputs[0][2]}, sort_keys=True)
    _check_fingerprint("tiny_pipeline", {"model_final.ply": _sha1(outputs[0][0]),
                                         "model_stage1.ply": _sha1(outputs[0][1]), "rows_psnr": _sha1(psnr.encode())},
                       torch_threads=None)  # a run's torch computes on one thread (fixer4d/threads.py)


def test_a_host_mode_child_of_a_portable_process_gets_the_environment_back(monkeypatch):
    monkeypatch.delenv(numerics.ENV_SAVED, raising=False)
    monkeypatch.setenv("OPENBLAS_CORETYPE", "SkylakeX")
    monkeypatch.delenv("ATEN_CPU_CAPABILITY", raising=False)
    monkeypatch.setenv(numerics.ENV_MODE, "portable")
    numerics.apply()
    assert os.environ["OPENBLAS_CORETYPE"] == "Haswell" and os.environ["ATEN_CPU_CAPABILITY"] == "avx2"
    child = dict(os.environ)
    child[numerics.ENV_MODE] = "host"
    code = "import os, json, fixer4d; print(json.dumps([os.environ.get(k) for k in ('OPENBLAS_CORETYPE', 'ATEN_CPU_CAPABILITY')]))"
    done = subprocess.run([sys.executable, "-c", code], env=child, capture_output=True, text=True, timeout=300)
    assert json.loads(done.stdout.strip().splitlines()[-1]) == ["SkylakeX", None]


def test_the_command_line_switches_numerics_in_a_fresh_process(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != numerics.ENV_MODE}
    done = subprocess.run([sys.executable, "-m", "fixer4d.cli", "--numerics", "host", "eval", str(tmp_path / "none")],
                          env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2  # the verb ran (and refused the missing folder) ...
    assert "numerics: host" in done.stderr  # ... in a process started in host mode, which says so
    quiet = subprocess.run([sys.executable, "-m", "fixer4d.cli", "eval", str(tmp_path / "none")], env=env,
                           capture_output=True, text=True, timeout=300)
    assert quiet.returncode == 2 and "numerics" not in quiet.stderr


def test_the_lock_pins_every_package_that_reaches_the_digits():
    lock = numerics.read_lock()
    assert lock is not None, "constraints.txt is missing at the repository's root"
    wheels = {"opencv-python", "opencv-python-headless"}  # not installed by make setup: they overwrite cv2
    assert {n for n in numerics.DIGIT_PACKAGES if n not in wheels} <= set(lock)
    assert not wheels & set(lock)


def test_the_lock_differences_name_each_package_off_the_lock(tmp_path):
    constraints = tmp_path / "constraints.txt"
    constraints.write_text("# a comment\nnumpy==2.4.6  # pinned\ntorch==2.13.0\n"
                           "OpenCV_Contrib.Python-Headless==5.0.0.93\n")
    lock = numerics.read_lock(constraints)
    assert lock == {"numpy": "2.4.6", "torch": "2.13.0", "opencv-contrib-python-headless": "5.0.0.93"}
    installed = {"numpy": "2.5.5", "torch": "2.13.0+cpu", "opencv-contrib-python-headless": "5.0.0.93",
                 "opencv-python": "5.0.0.93"}
    differences = numerics.lock_differences(installed, lock)
    assert differences == {"numpy": ["2.5.5", "2.4.6"], "opencv-python": ["5.0.0.93", None]}
    note = numerics.lock_note(differences)
    assert "numpy 2.5.5 (locked: 2.4.6)" in note and "opencv-python 5.0.0.93 (locked: not installed)" in note
    assert numerics.lock_differences(installed, {k: v.split("+")[0] for k, v in installed.items()}) == {}
    assert numerics.lock_note({}) is None and numerics.read_lock(tmp_path / "absent.txt") is None
