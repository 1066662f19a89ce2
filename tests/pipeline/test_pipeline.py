"""The whole pipeline on the tiny synthetic scene: report contract, resume, overrides."""
from __future__ import annotations

import json

import pytest

from fixer4d.errors import InputError
from fixer4d.pipeline import ROW_NAMES, PipelineConfig, SceneConfig, apply_overrides, run_pipeline, run_variant

TINY = {
    "stage1.iterations": 40, "stage2.rounds": 1, "stage2.refresh_every": 20,
    "trajectories.frames": 3, "trajectories.time_stride": 4, "init_frame_stride": 2, "eval_stride": 2,
    "init.mvs.planes": 24,
}


def _tiny_config() -> PipelineConfig:
    return apply_overrides(PipelineConfig(scene=SceneConfig(source="tiny")), TINY)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("run")
    report = run_pipeline(_tiny_config(), run_dir, progress=False)
    return run_dir, report


def test_report_contract(tiny_run):
    run_dir, report = tiny_run
    on_disk = json.loads((run_dir / "report.json").read_text())
    assert [r["method"] for r in on_disk["rows"]] == list(ROW_NAMES)
    for r in on_disk["rows"]:
        assert set(r) == {"method", "psnr", "dssim1", "dssim2", "lpips", "seconds"}
        assert r["psnr"] > 5.0 and 0.0 <= r["dssim1"] <= 1.0 and r["seconds"] > 0
    for name in ("report.md", "model_stage1.ply", "model_final.ply", "metrics.json", "config.json",
                 "baseline_sparse/model_stage1.ply", "init_mvs/init_report.json", "init_sparse/init_report.json"):
        assert (run_dir / name).exists(), name
    # the cache holds the 6 pairs + 2 arcs at the one restored timestamp, in round 0
    keys = sorted(p.name for p in (run_dir / "cache" / "round_0").iterdir() if not p.name.startswith("."))
    assert len(keys) == 8 and keys[0].startswith("t0000_")
    # rows accumulate time: Full includes stage 1 and stage 2
    rows = {r["method"]: r for r in on_disk["rows"]}
    assert rows["Full"]["seconds"] > rows["STGS w/ MVS"]["seconds"]


def test_resume_reuses_finished_stages(tiny_run):
    run_dir, report = tiny_run
    stages = json.loads((run_dir / "stages.json").read_text())
    again = run_pipeline(_tiny_config(), run_dir, progress=False)
    assert json.loads((run_dir / "stages.json").read_text()) == stages  # nothing was recomputed
    assert again["rows"] == report["rows"]


def test_other_config_in_same_folder_is_refused(tiny_run):
    run_dir, _ = tiny_run
    other = apply_overrides(_tiny_config(), {"stage1.iterations": 41})
    with pytest.raises(InputError, match="different configuration"):
        run_pipeline(other, run_dir, progress=False)


def test_overrides_relative_and_errors():
    cfg = apply_overrides(PipelineConfig(), {"stage1.iterations": 0.5, "init.mvs.planes": 0.5},
                          relative={"stage1.iterations", "init.mvs.planes"})
    assert cfg.stage1["iterations"] == PipelineConfig().stage1["iterations"] // 2
    assert isinstance(cfg.init["mvs"]["planes"], int)
    with pytest.raises(InputError, match="no section"):
        apply_overrides(PipelineConfig(), {"nonsense.key": 1})


def test_run_variant_for_the_study(tmp_path):
    res = run_variant("tiny", {"stage2.rounds": 0}, tmp_path / "v", progress=False, base=TINY)
    assert set(res) >= {"psnr", "dssim1", "dssim2", "lpips", "seconds"}
    assert res["seconds"]["total"] == pytest.approx(sum(v for k, v in res["seconds"].items() if k != "total"))
    assert res["method"] == "STGS w/ MVS"


def test_stage_cache_shares_init_and_stage1_between_variants(tmp_path):
    cache = tmp_path / "stage_cache"
    a = run_variant("tiny", {"stage2.rounds": 0}, tmp_path / "a", progress=False, base=TINY, stage_cache=cache)
    b = run_variant("tiny", {"stage2.rounds": 0, "eval_stride": 4}, tmp_path / "b", progress=False, base=TINY,
                    stage_cache=cache)
    # b copied a's init and stage-1 model and reports the seconds they originally cost
    assert b["seconds"]["init"] == a["seconds"]["init"] and b["seconds"]["stage1"] == a["seconds"]["stage1"]
    assert (tmp_path / "b" / "model_stage1.ply").read_bytes() == (tmp_path / "a" / "model_stage1.ply").read_bytes()
    # stage1.iterations is a relative knob in a variant: 0.75 x the base's 40 iterations
    c = run_variant("tiny", {"stage2.rounds": 0, "stage1.iterations": 0.75}, tmp_path / "c", progress=False,
                    base=TINY, stage_cache=cache)
    assert json.loads((tmp_path / "c" / "config.json").read_text())["pipeline"]["stage1"]["iterations"] == 30
    assert c["seconds"]["init"] == a["seconds"]["init"]  # same init, new stage 1
    assert (tmp_path / "c" / "model_stage1.ply").read_bytes() != (tmp_path / "a" / "model_stage1.ply").read_bytes()
