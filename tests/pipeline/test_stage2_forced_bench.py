"""benchmarks/undetermined_views.py read on made-up run folders: a variant's copies
(``seed<S>_k<K><label>``) pair with the k = 0 control or, with ``control_label``, with an earlier
variant's copies."""
from __future__ import annotations

import json


def _rows(full: float, mvs: float = 20.0) -> list[dict]:
    return [{"method": m, "status": "ok", "psnr": v, "psnr_unobserved": v, "lpips": 0.1}
            for m, v in (("STGS w/ MVS", mvs), ("STGS w/ MVS (matched iterations)", mvs), ("Full", full))]


def _copy(runs, name: str, folder: str, validation: str, val_full: float, test_full: float) -> None:
    run = runs / name / folder
    (run / "heldout" / validation).mkdir(parents=True)
    (run / "stages.json").write_text(json.dumps({"stage2": {"done": True, "seconds": 10.0}}))
    (run / "report.json").write_text(json.dumps({"rows": _rows(test_full)}))
    (run / "heldout" / validation / "report.json").write_text(json.dumps({"rows": _rows(val_full)}))


def test_a_variant_pairs_with_the_control_it_names(benchmark_script, tmp_path):
    bench = benchmark_script("undetermined_views")
    validation = bench.VALIDATION["panoptic"].name
    base_out, runs = tmp_path / "out", tmp_path / "runs"
    base_out.mkdir()
    for suffix in ("_val", ""):
        (base_out / f"panoptic{suffix}_seed0.json").write_text(
            json.dumps({"rows": _rows(20.0), "self_check": {"decision": "skip"}}))
    _copy(runs, "panoptic", "seed0_k0", validation, 19.5, 24.0)
    _copy(runs, "panoptic", "seed0_k0_fill", validation, 19.8, 24.2)
    _copy(runs, "panoptic", "seed0_k0_lam", validation, 20.1, 24.1)

    plain = bench.seed_figures("panoptic", 0, 0, runs, "val", base_out, "_lam")
    assert plain["views"]["psnr"] == 20.1 and plain["control"]["psnr"] == 19.5
    named = bench.seed_figures("panoptic", 0, 0, runs, "val", base_out, "_lam", "_fill")
    assert named["control"]["psnr"] == 19.8
    test = bench.seed_figures("panoptic", 0, 0, runs, "test", base_out, "_lam", "_fill")
    assert (test["views"]["psnr"], test["control"]["psnr"]) == (24.1, 24.2)
    gain = bench.paired({"0": named})["psnr"]["views - control"]
    assert abs(gain["mean"] - 0.3) < 1e-9
    # a control that was never measured is missing, not the baseline's Full
    assert bench.seed_figures("panoptic", 0, 0, runs, "val", base_out, "_lam", "_other")["control"] is None
