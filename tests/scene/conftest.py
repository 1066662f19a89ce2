"""Fixtures of the scene tests: a make-scene output folder written once per session."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def tiny_n3dv(tmp_path_factory) -> Path:
    """`fixer4d make-scene tiny --out DIR` run through the CLI entry point (real mp4 files)."""
    from fixer4d.cli import main

    out = tmp_path_factory.mktemp("n3dv") / "tiny"
    assert main(["make-scene", "tiny", "--out", str(out), "--no-progress"]) == 0
    return out


@pytest.fixture
def n3dv_copy(tiny_n3dv, tmp_path) -> Path:
    """A private, writable copy of the make-scene folder for tests that damage it."""
    dst = tmp_path / "scene"
    shutil.copytree(tiny_n3dv, dst)
    return dst
