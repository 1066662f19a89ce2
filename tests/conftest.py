"""Fixtures shared by every test folder.

tiny_scene: the bundled 8-camera, 64x48, 4-frame synthetic scene (assets/scenes/tiny.json).
panoptic_dir: the real Panoptic basketball subset in ../shared/data (skips when absent).
"""
from __future__ import annotations

from pathlib import Path

import pytest

import fixer4d  # noqa: F401  (first: sets the OpenMP wait policy before any test imports torch)

REPO_ROOT = Path(__file__).resolve().parents[1]
PANOPTIC_DIR = Path(__file__).resolve().parents[1].parent / "shared/data/panoptic_basketball"


@pytest.fixture(scope="session")
def tiny_scene():
    """SyntheticScene of assets/scenes/tiny.json (read-only: share it, do not mutate it)."""
    from fixer4d.scene.synthetic import SyntheticScene

    return SyntheticScene("tiny")


@pytest.fixture(scope="session")
def panoptic_dir() -> Path:
    """The Panoptic basketball folder (Dynamic3DGaussians layout), read-only."""
    if not (PANOPTIC_DIR / "train_meta.json").is_file():
        pytest.skip(f"real-data test skipped: the Panoptic basketball subset is not at {PANOPTIC_DIR} "
                    f"(expected ../shared/data/panoptic_basketball next to the repository)")
    return PANOPTIC_DIR
