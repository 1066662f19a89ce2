"""Screenshots the tests take for docs/viewer.md: written to docs/img/ when FIXER4D_DOC_SHOTS=1
(a documentation run), else into the test's temporary folder (so a normal test run never
rewrites tracked files)."""
from __future__ import annotations

import os
from pathlib import Path

DOCS_IMG = Path(__file__).resolve().parents[2] / "docs" / "img"


def save_shot(image, name: str, tmp_path: Path) -> Path:
    """Write the (H, W, 3) uint8 ``image`` as ``name``.png; returns the path."""
    from PIL import Image

    folder = DOCS_IMG if os.environ.get("FIXER4D_DOC_SHOTS") == "1" else Path(tmp_path)
    path = folder / f"{name}.png"
    Image.fromarray(image).save(path)
    return path
