"""The viewer's log: everything to ~/.config/fixer4d/view/viewer.log, warnings and errors (the
notifications' errors) to stderr too (a scripted walk found stderr empty while the window showed
errors)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("verbose", [False, True])
def test_errors_reach_stderr_as_one_line_and_the_log_file(tmp_path, verbose):
    """stderr gets one line per error (a traceback only with --verbose); the log file has all."""
    code = ("import logging\n"
            "from app.main import setup_logging\n"
            f"path = setup_logging(verbose={verbose})\n"
            "log = logging.getLogger('fixer4d.view')\n"
            "log.info('opened a run')\n"
            "try:\n"
            "    raise ValueError('deep inside')\n"
            "except ValueError as exc:\n"
            "    log.error('file: InputError: bad.ply', exc_info=exc)\n"
            "print(path)\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120,
                         env={**os.environ, "XDG_CONFIG_HOME": str(tmp_path)})
    assert out.returncode == 0, out.stderr
    assert "file: InputError: bad.ply" in out.stderr and "opened a run" not in out.stderr
    assert ("Traceback" in out.stderr) == verbose
    if not verbose:
        assert out.stderr.strip().splitlines() == ["fixer4d-view: file: InputError: bad.ply"]
    text = Path(out.stdout.strip()).read_text()
    assert "opened a run" in text and "bad.ply" in text and "Traceback" in text
    assert Path(out.stdout.strip()).parent == tmp_path / "fixer4d" / "view"
