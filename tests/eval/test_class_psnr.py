"""ClassPSNR: squared errors pooled per pixel class, the benchmarks' per-class tables."""
from __future__ import annotations

import numpy as np
import pytest

from fixer4d.eval.class_psnr import MAX_DB, ClassPSNR


def test_pools_errors_per_class_over_images():
    truth = np.zeros((2, 4, 3), np.float32)
    left = np.zeros((2, 4), bool)
    left[:, :2] = True
    masks = {"all": np.ones_like(left), "left": left, "none": np.zeros_like(left)}
    table = ClassPSNR(("a", "b"), ("all", "left", "none"))
    a = np.full((2, 4, 3), 0.1, np.float32)  # mse 0.01 everywhere: 20 dB
    b = truth.copy()
    b[:, 2:] = 1.5  # clipped to 1: mse 1 on the right half
    table.add(truth, {"a": a, "b": b}, masks)
    table.add(truth, {"a": a, "b": b}, masks)  # pooling two images leaves every mse as it is
    t = table.table()
    assert t["all"]["fraction"] == 1.0 and t["left"]["fraction"] == 0.5 and t["none"]["fraction"] == 0.0
    assert t["all"]["a"] == pytest.approx(20.0) and t["left"]["a"] == pytest.approx(20.0)
    assert t["all"]["b"] == pytest.approx(10 * np.log10(2.0))  # mse 0.5 over all pixels
    assert t["left"]["b"] == MAX_DB  # a perfect class is capped, never inf
    assert t["none"]["a"] is None


def test_needs_an_all_class():
    with pytest.raises(ValueError, match="'all' class"):
        ClassPSNR(("a",), ("left",))
