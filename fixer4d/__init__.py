"""fixer4d: four synchronized cameras -> spacetime Gaussians, with the unseen views repaired.

Importing fixer4d never imports optional backends (gsplat, diffusers, MVSAnywhere, GL); they
are loaded lazily where used.
"""
from pathlib import Path

__version__ = "0.1.0"

#: Repository root when run from a checkout (assets/ and shaders/ live there).
PACKAGE_ROOT = Path(__file__).resolve().parent
ASSETS_DIR = PACKAGE_ROOT.parent / "assets"
