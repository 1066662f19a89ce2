"""SIGTERM ends a run like Ctrl-C: a short message and exit code 143, no native stack trace
(pycolmap's glog takes SIGTERM on import and printed one, reading like a crash), and the
rerun resumes from what was saved."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def test_sigterm_raises_terminated_after_pycolmap_took_the_signal():
    pytest.importorskip("pycolmap")
    code = ("import os, signal, time\n"
            "from fixer4d.signals import install_sigterm\n"
            "from fixer4d.errors import Terminated\n"
            "assert install_sigterm()\n"
            "from fixer4d.calib.colmap import pycolmap_module as _pycolmap\n"
            "_pycolmap()\n"
            "try:\n"
            "    os.kill(os.getpid(), signal.SIGTERM)\n"
            "    time.sleep(10)\n"
            "except Terminated as exc:\n"
            "    print('caught', exc)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert "caught signal SIGTERM" in out.stdout
    assert "Aborted" not in out.stderr


def test_a_terminated_run_says_so_and_resumes(tmp_path):
    pytest.importorskip("pycolmap")
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "fixer4d.cli", "run", "tiny", "--out", str(run), "--quiet", "--no-baseline",
           "--set", "training.iterations=200", "--set", "stage2.rounds=0", "--set", "eval.restoration_rows=false",
           "--set", "init_frame_stride=2"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # wait until stage 1 has started (the init is done), then stop it
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and proc.poll() is None:
        if (run / "init_mvs" / "init_report.json").exists() and any(run.rglob("checkpoints")):
            break
        time.sleep(0.2)
    assert proc.poll() is None, proc.communicate()[1][-2000:]
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err[-2000:]
    assert "terminated (SIGTERM)" in err and "Aborted" not in err and "stack trace" not in err
    assert not list(run.rglob("*.tmp*")), "a temporary file was left behind"
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert (run / "report.json").exists()


def test_an_interrupt_inside_a_numba_kernel_is_found_behind_its_system_error():
    # a handler that raises while a parallel numba kernel runs surfaces as numba's SystemError
    from fixer4d.errors import Terminated
    from fixer4d.signals import interrupt_behind

    try:
        try:
            raise Terminated("signal SIGTERM")
        except Terminated:
            raise SystemError("CPUDispatcher(<function _bin_tiles>) returned a result with an exception set")
    except SystemError as exc:
        assert isinstance(interrupt_behind(exc), Terminated)
    assert interrupt_behind(SystemError("a real fault")) is None
