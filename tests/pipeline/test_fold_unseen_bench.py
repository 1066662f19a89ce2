"""benchmarks/fold_unseen.py: the Gaussians no train camera sees, scored on a finished run's fold."""
from __future__ import annotations

import json

import numpy as np


def test_scores_the_fold_with_and_without_the_unseen_and_leaves_the_run_alone(benchmark_script, tiny_run, tmp_path):
    bench = benchmark_script("fold_unseen")
    run_dir, report = tiny_run
    before = {p: p.stat().st_mtime_ns for p in run_dir.rglob("*")}
    out, png = tmp_path / "unseen.json", tmp_path / "fold.png"
    assert bench.main([str(run_dir), "--png", str(png), "--out", str(out)]) == 0
    fold = json.loads(out.read_text())["fold"]
    check = report["self_check"]
    assert fold["held_back_camera"] == check["held_back_camera"] and fold["frames"] == check["frames"]
    # the fold's model as the check scored it: its skip figure
    assert abs(fold["psnr"] - check["psnr"]["skip"]) < 1e-6
    assert 0 <= fold["unseen_above_half"] <= fold["unseen"] <= fold["gaussians"]
    if fold["unseen"] == 0:
        assert fold["psnr_without_unseen"] == fold["psnr"]
    from PIL import Image

    width, height = Image.open(png).size  # the fold's render, the render without them, the frame
    assert width % 3 == 0 and width // 3 > 0 and height > 0
    assert {p: p.stat().st_mtime_ns for p in run_dir.rglob("*")} == before


def test_removing_rows_silences_exactly_them(benchmark_script):
    import torch

    from tests.model.test_terms import _init
    from fixer4d.model import terms as E

    bench = benchmark_script("fold_unseen")
    init = _init(n_dyn=40, degree=1, rotating=0.0, seed=1)
    model = E.model_from_decomposed(init, E.decide_terms(init), opacity=0.1, max_points=60, seed=0)
    rows = np.zeros(model.num_gaussians, bool)
    rows[::3] = True
    cut = bench._without(model, rows)
    assert torch.all(torch.sigmoid(cut.opacity_logits[torch.from_numpy(rows)]) < 1e-12)
    assert torch.equal(cut.opacity_logits[torch.from_numpy(~rows)], model.opacity_logits[torch.from_numpy(~rows)])
    census = bench._census(model, rows)
    assert census["unseen"] == int(rows.sum()) and census["unseen_above_half"] == 0
