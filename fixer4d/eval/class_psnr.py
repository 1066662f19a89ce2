"""PSNR per pixel class, pooled over many images: the diagnostic tables of
benchmarks/restoration_gate.py and benchmarks/fold_fill_check.py (which estimate wins on which
pixels).

    table = ClassPSNR(("render", "fill"), ("all", "unobserved"))
    table.add(truth, {"render": r, "fill": f}, {"all": ones, "unobserved": hidden})
    table.table()  # {class: {"fraction", "render", "fill"}} in dB
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from fixer4d.psnr import psnr_from_mse

# Cap of a class's PSNR (MSE 1e-12): the tables go to JSON, which cannot hold the inf of a
# perfect class.
MAX_DB = 120.0


class ClassPSNR:
    """Squared errors of named images against their truth, summed per pixel class."""

    def __init__(self, images: Sequence[str], classes: Sequence[str]) -> None:
        if "all" not in classes:
            raise ValueError(f"ClassPSNR: the classes {list(classes)} need an 'all' class (the shares' total)")
        self.images = tuple(images)
        self.classes = tuple(classes)
        self.sums = {c: dict.fromkeys(self.images, 0.0) for c in self.classes}
        self.counts = dict.fromkeys(self.classes, 0)

    def add(self, truth: np.ndarray, images: Mapping[str, np.ndarray], masks: Mapping[str, np.ndarray]) -> None:
        """truth and each image (H, W, 3) in [0, 1] (images are clipped to it); masks (H, W) bool per
        class. The error of a pixel is the mean over its channels."""
        errors = {k: ((np.clip(images[k], 0.0, 1.0) - truth) ** 2).mean(-1) for k in self.images}
        for c in self.classes:
            mask = masks[c]
            self.counts[c] += int(mask.sum())
            for k in self.images:
                self.sums[c][k] += float(errors[k][mask].sum())

    def table(self) -> dict[str, dict[str, float | None]]:
        """{class: {"fraction": its share of the "all"-class pixels, image: PSNR in dB (at most
        ``MAX_DB``) or None for an empty class}}."""
        total = self.counts["all"]
        return {c: {"fraction": self.counts[c] / total if total else 0.0,
                    **{k: (psnr_from_mse(self.sums[c][k] / self.counts[c], MAX_DB) if self.counts[c] else None)
                       for k in self.images}}
                for c in self.classes}

    def report(self, out: str | Path | None = None, **meta: Any) -> dict[str, Any]:
        """Print one line per class (its share in percent and each image's PSNR) and return
        ``{**meta, "psnr_db": table()}``, also written to ``out`` as JSON when given."""
        table = self.table()
        for c, row in table.items():
            print(f"{c:17s} {100 * row['fraction']:5.1f} % " + " ".join(
                f"{k} {row[k]:.2f}" if row[k] is not None else f"{k} n/a" for k in self.images))
        record = {**meta, "psnr_db": table}
        if out is not None:
            from fixer4d.atomic import write_json

            write_json(out, record)
        return record


__all__ = ["ClassPSNR"]
