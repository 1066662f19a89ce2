"""A study-wide store of finished stage outputs, shared between the runs of the variants."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

from fixer4d import atomic


class StageCache:
    """Finished stage outputs shared between runs, e.g. the variants of a study.

    An output is keyed by everything it depends on (scene, init settings, frames, stage-1
    settings). A run that needs an output already computed copies it and records the seconds
    it originally took, so every variant still reports the full cost of its configuration.
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    def fetch(self, key: str, dest: Path) -> float | None:
        """Copy the stored output into ``dest`` (a folder); its original seconds, or None."""
        entry = self.root / key
        if not (entry / "done.json").exists():
            return None
        shutil.copytree(entry / "data", dest, dirs_exist_ok=True)
        return float(json.loads((entry / "done.json").read_text())["seconds"])

    def store(self, key: str, files: list[Path], seconds: float) -> None:
        """Store files and folders (copied under their names) as the output for ``key``."""
        with atomic.atomic_dir(self.root / key) as tmp:
            (tmp / "data").mkdir()
            for f in files:
                if f.is_dir():
                    shutil.copytree(f, tmp / "data" / f.name)
                else:
                    shutil.copy2(f, tmp / "data" / f.name)
            (tmp / "done.json").write_text(json.dumps({"seconds": seconds}))
