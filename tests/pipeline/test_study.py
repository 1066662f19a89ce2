"""The study machinery: Pareto fronts, tables, plots, budget and resume."""
from __future__ import annotations

import json

import pytest

from fixer4d.errors import InputError
from fixer4d.study import StudyConfig, StudyResult, fastest_within, markdown_table, pareto_front, run_study


def test_pareto_front_known_points():
    costs = [1.0, 2.0, 3.0, 4.0, 2.5]
    psnr = [20.0, 22.0, 21.0, 25.0, 22.0]
    # (3, 21) is dominated by (2, 22); (2.5, 22) is dominated by (2, 22) (same score, more time).
    assert pareto_front(costs, psnr, higher_is_better=True) == [0, 1, 3]
    lp = [0.30, 0.20, 0.25, 0.10, None]
    assert pareto_front(costs, lp, higher_is_better=False) == [0, 1, 3]


def test_pareto_front_ties_and_nan():
    assert pareto_front([1.0, 1.0], [5.0, 5.0]) == [0, 1]  # identical points do not dominate each other
    assert pareto_front([1.0, 2.0], [float("nan"), 3.0]) == [1]
    assert pareto_front([], []) == []


def _res(name, secs, psnr, lp=0.2):
    return StudyResult(name=name, overrides={}, psnr=psnr, dssim1=0.1, dssim2=0.05, lpips=lp,
                       seconds={"init": secs / 2, "stage1": secs / 2, "total": secs}, run_dir="x")


def test_fastest_within_and_table():
    rs = [_res("a", 10, 20.0), _res("b", 20, 24.7), _res("c", 40, 25.0)]
    assert fastest_within(rs, 0.5).name == "b"
    table = markdown_table(rs)
    assert table.splitlines()[2].startswith("| a |")  # sorted by time


def _fake_runner(calls):
    table = {"fast": (10.0, 21.0, 0.3), "slow": (30.0, 24.0, 0.2), "worse": (40.0, 22.0, 0.25)}

    def run(overrides, run_dir):
        calls.append(overrides["tag"])
        secs, psnr, lp = table[overrides["tag"]]
        return {"psnr": psnr, "dssim1": 0.1, "dssim2": 0.05, "lpips": lp,
                "seconds": {"init": secs * 0.2, "stage1": secs * 0.8, "total": secs}}

    return run


def test_run_study_writes_outputs_and_resumes(tmp_path):
    variants = [{"name": n, "tag": n} for n in ("fast", "slow", "worse")]
    calls: list[str] = []
    results = run_study(StudyConfig(source="demo", variants=variants), tmp_path, run_variant=_fake_runner(calls),
                        progress=False)
    assert calls == ["fast", "slow", "worse"]
    data = json.loads((tmp_path / "study.json").read_text())
    assert data["pareto_psnr"] == ["fast", "slow"]
    assert data["fastest_within_0.5db"] == "slow"
    for name in ("psnr_vs_time.png", "psnr_dynamic_vs_time.png", "psnr_static_vs_time.png", "lpips_vs_time.png",
                 "stage_seconds.png", "study.md"):
        assert (tmp_path / name).stat().st_size > 0
    assert {r.name for r in results if "psnr" in r.pareto} == {"fast", "slow"}
    # a second run reads finished variants back instead of running them again
    run_study(StudyConfig(source="demo", variants=variants), tmp_path, run_variant=_fake_runner(calls), progress=False)
    assert calls == ["fast", "slow", "worse"]


def test_budget_stops_new_variants(tmp_path):
    variants = [{"name": n, "tag": n} for n in ("fast", "slow")]
    calls: list[str] = []
    run_study(StudyConfig(source="demo", variants=variants, budget_minutes=0.0), tmp_path,
              run_variant=_fake_runner(calls), progress=False)
    # the budget is checked before starting each variant: with 0 minutes only the first starts
    assert calls == ["fast"]
    assert json.loads((tmp_path / "study.json").read_text())["skipped_over_budget"] == ["slow"]


def test_study_on_tiny_scene_with_the_real_pipeline(tmp_path):
    """Two real configurations of the pipeline on the tiny scene: results, front and plots."""
    base = {"training.iterations": 30, "stage2.refresh_every": 10, "trajectories.frames": 3,
            "trajectories.time_stride": 4, "init_frame_stride": 2, "eval.stride": 2, "init.mvs.planes": 24}
    variants = [{"name": "restore", "stage2.rounds": 1}, {"name": "no-restore", "stage2.rounds": 0}]
    results = run_study(StudyConfig(source="tiny", variants=variants, base=base), tmp_path, progress=False)
    assert [r.name for r in results] == ["restore", "no-restore"]
    by = {r.name: r for r in results}
    # skipping restoration and refinement is strictly cheaper
    assert by["no-restore"].total_seconds < by["restore"].total_seconds
    assert by["no-restore"].seconds["stage2"] == 0.0
    costs = [r.total_seconds for r in results]
    expected = {results[i].name for i in pareto_front(costs, [r.psnr for r in results])}
    data = json.loads((tmp_path / "study.json").read_text())
    assert set(data["pareto_psnr"]) == expected and "no-restore" in expected
    for name in ("psnr_vs_time.png", "lpips_vs_time.png", "stage_seconds.png"):
        assert (tmp_path / name).stat().st_size > 1000


def test_plot_labels_of_close_points_do_not_overlap():
    """Points a few pixels apart (the base and a variant equal to it) get label boxes that do
    not intersect; front labels are placed first."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from fixer4d.study import _label_points

    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    pts = [(100.0, 24.05, "base", True), (101.0, 24.05, "restorer-warp", False), (100.5, 24.04, "rounds-2", False),
           (40.0, 20.0, "far", False)]
    ax.scatter([p[0] for p in pts], [p[1] for p in pts])
    _label_points(ax, fig, pts)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    boxes = {t.get_text(): t.get_window_extent(renderer) for t in ax.texts}
    assert set(boxes) == {"base", "restorer-warp", "rounds-2", "far"}
    names = sorted(boxes)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert not boxes[a].overlaps(boxes[b]), (a, b)
    plt.close(fig)


def test_the_study_ranks_by_the_moving_pixels(tmp_path):
    """Dynamic / static PSNR in the table, their own fronts, and --rank psnr_dynamic
    picks a different variant than PSNR when the moving pixels disagree with the mean."""
    table = {"cheap": (10.0, 24.0, 18.0, 24.2), "moving": (20.0, 23.9, 23.0, 23.9), "slow": (40.0, 24.1, 18.5, 24.3)}

    def run(overrides, run_dir):
        secs, psnr, dyn, static = table[overrides["tag"]]
        return {"psnr": psnr, "psnr_dynamic": dyn, "psnr_static": static, "dssim1": 0.1, "dssim2": 0.05,
                "lpips": 0.2, "seconds": {"stage1": secs, "total": secs}}

    variants = [{"name": n, "tag": n} for n in table]
    by_psnr = run_study(StudyConfig(source="demo", variants=variants), tmp_path / "a", run_variant=run, progress=False)
    assert fastest_within(by_psnr, 0.5).name == "cheap"
    assert fastest_within(by_psnr, 0.5, "psnr_dynamic").name == "moving"
    run_study(StudyConfig(source="demo", variants=variants, rank="psnr_dynamic"), tmp_path / "b", run_variant=run,
              progress=False)
    data = json.loads((tmp_path / "b" / "study.json").read_text())
    assert data["rank"] == "psnr_dynamic" and data["fastest_within_0.5db"] == "moving"
    assert data["pareto_psnr_dynamic"] == ["cheap", "moving"] and data["pareto_psnr"] == ["cheap", "slow"]
    text = (tmp_path / "b" / "study.md").read_text()
    assert "| PSNR dyn. | PSNR static |" in text and "| moving | 23.90 | 23.00 | 23.90 |" in text
    assert "best PSNR dyn.: **moving**" in text
    # a variant without moving pixels is shown as n/a and never ranked by them
    assert fastest_within([_res("x", 5, 30.0)], 0.5, "psnr_dynamic") is None
    assert "| x | 30.00 | n/a | n/a |" in markdown_table([_res("x", 5, 30.0)])
    with pytest.raises(InputError, match="rank"):
        fastest_within(by_psnr, 0.5, "lpips")


def test_variants_are_checked_and_a_finished_variant_is_not_reused_under_other_settings(tmp_path):
    """A scripted probe found a rerun into the same --out reporting the old numbers for new settings,
    two variants of one name sharing a run folder, and tracebacks for malformed variant files."""
    calls: list[str] = []
    runner = _fake_runner(calls)
    for bad, match in (({"name": "a"}, "non-empty JSON list"), ([1, 2], "#0"), ([{"tag": "fast"}], "name"),
                       ([], "non-empty"), ([{"name": ""}], "name"), ([{"name": ".."}], "name"),
                       ([{"name": "a", "tag": "fast"}, {"name": "a", "tag": "slow"}], "share the run folder")):
        with pytest.raises(InputError, match=match):
            run_study(StudyConfig(source="demo", variants=bad), tmp_path / "bad", run_variant=runner, progress=False)
    assert calls == [] and not (tmp_path / "bad").exists()
    v = [{"name": "fast", "tag": "fast"}]
    run_study(StudyConfig(source="demo", variants=v, base={"training.iterations": 20}), tmp_path / "s",
              run_variant=runner, progress=False)
    # the same settings: read back, not run again
    run_study(StudyConfig(source="demo", variants=v, base={"training.iterations": 20}), tmp_path / "s",
              run_variant=runner, progress=False)
    assert calls == ["fast"]
    with pytest.raises(InputError, match=r"base training.iterations: 20 -> 300"):
        run_study(StudyConfig(source="demo", variants=v, base={"training.iterations": 300}), tmp_path / "s",
                  run_variant=runner, progress=False)
    with pytest.raises(InputError, match="overrides"):
        run_study(StudyConfig(source="demo", variants=[{"name": "fast", "tag": "slow"}], base={"training.iterations": 20}),
                  tmp_path / "s", run_variant=runner, progress=False)
    assert calls == ["fast"]
