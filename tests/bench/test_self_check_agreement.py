"""benchmarks/self_check_agreement.py: the fold's gains against the held-out cameras' gains."""
from __future__ import annotations

import json

import pytest


def _result(path, fold: dict, rows: dict, decision: str) -> None:
    path.write_text(json.dumps({"self_check": {"psnr": fold, "decision": decision},
                                "rows": [{"method": m, "status": "ok", "psnr": v} for m, v in rows.items()]}))


def test_pairs_every_runs_continue_and_the_chosen_refine(benchmark_script, tmp_path):
    bench = benchmark_script("self_check_agreement")
    folder = tmp_path / "quality"
    folder.mkdir()
    mvs, matched, full = "STGS w/ MVS", "STGS w/ MVS (matched iterations)", "Full"
    # fold continue gains +1, +2, +3 against held-out gains -0.1, -0.2, -0.3: perfectly opposed
    for seed, g in enumerate((1.0, 2.0, 3.0)):
        _result(folder / f"a_val_seed{seed}.json", {"skip": 20.0, "continue": 20.0 + g, "refine": 20.5},
                {mvs: 25.0, matched: 25.0 - g / 10, full: 25.0 - g / 10}, "continue")
    _result(folder / "a_seed0.json", {"skip": 20.0, "continue": 19.0, "refine": 20.5},
            {mvs: 24.0, matched: 23.5, full: 24.4}, "refine")
    (folder / "summary.json").write_text("{}")  # not a run's file: ignored
    _result(folder / "b_val_seed0.json", {"skip": 20.0}, {mvs: 25.0}, "skip")  # no fold candidates: ignored
    out = tmp_path / "agree.json"
    assert bench.main([str(folder), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    val = doc["folders"]["quality"]["validation"]
    assert val["continue"]["n"] == 3 and val["continue"]["correlation"] == pytest.approx(-1.0)
    assert val["continue"]["sign_agreement"] == 0.0
    assert val["chosen"] == {"left_stage1": 3, "lowered_heldout": 3, "mean_heldout_gain_db": pytest.approx(-0.2)}
    test = doc["folders"]["quality"]["test"]
    assert test["refine"]["n"] == 1 and test["refine"]["heldout_gain_mean"] == pytest.approx(0.4)
    assert test["continue"]["sign_agreement"] == 1.0  # the fold's -1 and the held-out -0.5 agree
    assert doc["all"]["validation"]["continue"]["n"] == 3


def test_a_folder_without_results_says_what_to_run(benchmark_script, tmp_path):
    bench = benchmark_script("self_check_agreement")
    with pytest.raises(SystemExit, match="fixer4d bench quality"):
        bench.main([str(tmp_path)])
