"""`fixer4d bench quality` (fixer4d/bench/quality.py): Student-t intervals, paired differences per
seed, resumable runs through the README's commands (a fake runner writes the run folders here)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from fixer4d import stats
from fixer4d.bench import quality as Q


def test_t_quantiles_and_intervals():
    for df, t in ((1, 12.7062), (2, 4.3027), (4, 2.7764), (30, 2.0423)):
        assert stats.student_t_quantile(0.975, df) == pytest.approx(t, abs=1e-3)
    iv = stats.interval([25.34, 24.57, 24.97, None])
    assert iv["n"] == 3 and iv["mean"] == pytest.approx(24.96)
    assert iv["sd"] == pytest.approx(0.3851, abs=1e-4)
    assert iv["ci95"] == pytest.approx(4.3027 * 0.3851 / math.sqrt(3), abs=1e-3)
    assert stats.interval([1.0])["ci95"] is None and stats.interval([])["mean"] is None


def _record(seed: int, mvs: float, full: float, matched: float, decision: str = "skip") -> dict:
    rows = [{"method": "STGS w/ MVS", "status": "ok", "psnr": mvs, "lpips": 0.1},
            {"method": "STGS w/ MVS (matched iterations)", "status": "ok", "psnr": matched, "lpips": 0.1},
            {"method": "Full", "status": "ok", "psnr": full, "lpips": 0.09},
            {"method": "STGS w/ COLMAP", "status": "failed", "reason": "no points"}]
    return {"seed": seed, "rows": rows, "self_check": {"decision": decision}}


def test_paired_differences_are_steadier_than_the_rows():
    # seeds move both rows by ±1 dB together; their difference is always about +0.2 dB
    records = [_record(0, 25.0, 25.2, 25.1), _record(1, 24.0, 24.21, 24.1), _record(2, 26.0, 26.19, 26.1, "refine")]
    s = Q.summarize_split(records)
    assert s["rows"]["STGS w/ MVS"]["psnr"]["ci95"] > 2.0
    diff = s["paired"]["Full - STGS w/ MVS"]["psnr"]
    assert diff["mean"] == pytest.approx(0.2, abs=1e-9) and diff["ci95"] < 0.05
    assert "STGS w/ COLMAP" not in s["rows"] and s["failed"] == ["STGS w/ COLMAP"]  # no figure to average
    assert "| failed |" in Q.markdown({"demo": {**s, "files": ["demo_seed0.json"]}})
    assert s["self_check"] == ["skip", "skip", "refine"]


def test_the_bench_runs_each_set_once_and_summarizes(tmp_path, monkeypatch, capsys):
    calls = []

    def fake_runner(argv, log):
        calls.append(argv[3:])
        verb = argv[3]
        if verb == "run":
            run = Path(argv[argv.index("--out") + 1])
            seed = int(argv[argv.index("--seed") + 1])
            run.mkdir(parents=True)
            (run / "config.json").write_text(json.dumps({"source_commit": "abc1234"}))
            rec = _record(seed, 24 + seed, 24.3 + seed, 24.2 + seed)
            (run / "report.json").write_text(json.dumps({"rows": rec["rows"], "self_check": rec["self_check"],
                                                         "numerics": {"mode": "portable", "portable": True}}))
        else:  # eval --cameras-from
            run = Path(argv[4])
            val = run / "heldout" / Path(argv[argv.index("--cameras-from") + 1]).name
            val.mkdir(parents=True)
            (val / "report.json").write_text(json.dumps({"rows": _record(0, 25, 25.1, 25.0)["rows"], "run": str(run)}))

    sets = Q.camera_sets(tmp_path / "data")
    for seed in (0, 1):
        Q.run_set(sets["demo"], seed, tmp_path / "runs", tmp_path / "out", log=lambda m: None, runner=fake_runner)
    assert [c[0] for c in calls] == ["run", "eval", "run", "eval"]
    Q.run_set(sets["demo"], 0, tmp_path / "runs", tmp_path / "out", log=lambda m: None, runner=fake_runner)
    assert len(calls) == 4  # a finished seed is read back, not run again
    summary = Q.summarize(tmp_path / "out")
    assert set(summary) == {"demo", "demo_val"}
    assert summary["demo"]["seeds"] == [0, 1] and summary["demo"]["numerics"] == ["portable"]
    assert summary["demo"]["paired"]["Full - STGS w/ MVS"]["psnr"]["mean"] == pytest.approx(0.3)
    table = Q.markdown(summary)
    assert "| [demo](benchmarks/results/quality/demo_seed0.json) (0, 1) |" in table and "+0.30 ± 0.00" in table
    assert table.index("| [demo]") < table.index("*demo_val*")  # test splits first
    # an option under test reaches the run's command and is recorded with it
    Q.run_set(sets["demo"], 2, tmp_path / "runs", tmp_path / "out", log=lambda m: None, runner=fake_runner,
              overrides=["training.opacity_decay.enabled=true"])
    assert calls[-2][-2:] == ["--set", "training.opacity_decay.enabled=true"]
    assert json.loads((tmp_path / "out" / "demo_seed2.json").read_text())["command"].endswith(
        "--set training.opacity_decay.enabled=true")
    # the printed table links the files where they are, not the committed table's folder
    capsys.readouterr()
    assert Q.main(["--summary-only", "--out", str(tmp_path / "out")]) == 0
    assert f"]({(tmp_path / 'out').resolve()}/demo_seed0.json)" in capsys.readouterr().out


def test_a_set_whose_data_is_absent_says_so(tmp_path):
    assert "absent" in Q.camera_sets(tmp_path / "nowhere")["panoptic"].available()
    assert Q.camera_sets(tmp_path)["demo"].available() is None


def test_the_readme_block_is_rewritten_from_the_summary(tmp_path):
    summary = {"demo": {**Q.summarize_split([_record(0, 25.0, 25.2, 25.1), _record(1, 24.0, 24.21, 24.1)]),
                        "files": ["demo_seed0.json", "demo_seed1.json"]}}
    page = tmp_path / "README.md"
    page.write_text(f"# x\n\n{Q.BEGIN}\nold\n{Q.END}\n\nafter\n")
    Q.write_block(page, summary)
    text = page.read_text()
    assert "old" not in text and text.endswith("\n\nafter\n") and Q.markdown(summary) in text
    bare = tmp_path / "bare.md"
    bare.write_text("no markers\n")
    with pytest.raises(SystemExit, match="no"):
        Q.write_block(bare, summary)


def test_the_readme_table_is_generated_from_the_committed_result_files():
    readme = (Q.REPO_ROOT / "README.md").read_text()
    committed = Q.summarize(Q.DEFAULT_OUT)
    assert committed, "no committed quality-bench result files"
    assert Q.block(committed) in readme, "README's QUALITY block is stale: fixer4d bench quality --summary-only --readme README.md"


def test_two_options_are_paired_seed_by_seed(tmp_path):
    this, that = tmp_path / "decay", tmp_path / "reset"
    for seed, (mvs_a, mvs_b) in enumerate(((25.5, 25.0), (24.4, 24.0), (26.6, 26.0))):
        Q._write(this / f"demo_val_seed{seed}.json", _record(seed, mvs_a, mvs_a + 0.1, mvs_a, "refine"))
        Q._write(that / f"demo_val_seed{seed}.json", _record(seed, mvs_b, mvs_b, mvs_b))
    Q._write(this / "demo_val_seed7.json", _record(7, 30.0, 30.0, 30.0))  # no partner: left out
    Q._write(that / "panoptic_seed0.json", _record(0, 20.0, 20.0, 20.0))  # a split only one side has
    c = Q.compare(this, that)
    assert set(c) == {"demo_val"} and c["demo_val"]["seeds"] == [0, 1, 2]
    mvs = c["demo_val"]["rows"]["STGS w/ MVS"]["psnr"]
    assert mvs["values"] == pytest.approx([0.5, 0.4, 0.6]) and mvs["mean"] == pytest.approx(0.5)
    assert mvs["ci95"] == pytest.approx(4.3027 * 0.1 / math.sqrt(3), abs=1e-3)
    assert c["demo_val"]["rows"]["Full"]["psnr"]["mean"] == pytest.approx(0.6)
    assert "Restoration (init)" not in c["demo_val"]["rows"]  # neither side has the row
    assert c["demo_val"]["self_check"] == [["refine"] * 3, ["skip"] * 3]
    table = Q.compare_markdown(c)
    assert "| demo_val (0, 1, 2) | +0.50 ± 0.25 (+0.50, +0.40, +0.60) |" in table and "rrr / sss" in table
