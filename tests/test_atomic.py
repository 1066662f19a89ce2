"""Atomic file output: a write that cannot start names the file asked for (a scripted walk saw a
permission error naming the hidden temporary `.x.ply.dio3p372.ply` instead of `x.ply`)."""
from __future__ import annotations

import errno
import tempfile

import pytest

from fixer4d import atomic


def test_a_refused_write_names_the_target_not_the_temporary(tmp_path, monkeypatch):
    def refuse(prefix, suffix, dir):
        raise PermissionError(errno.EPERM, "Operation not permitted", f"{dir}/{prefix}abc123{suffix}")

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(PermissionError) as exc:
        atomic.write_text(tmp_path / "x.ply", "data")
    assert exc.value.filename == str(tmp_path / "x.ply") and exc.value.errno == errno.EPERM
    assert not list(tmp_path.iterdir())


def test_a_write_replaces_the_file_whole(tmp_path):
    target = tmp_path / "a.json"
    atomic.write_json(target, {"k": 1})
    atomic.write_json(target, {"k": 2})
    assert target.read_text() == '{\n  "k": 2\n}\n' and [p.name for p in tmp_path.iterdir()] == ["a.json"]
