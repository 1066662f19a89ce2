"""Stage 2's self-check on a held-back train camera (pipeline.self_check): it never reads a
held-out camera, and a restorer that returns noise is caught (stage 2 is not run)."""
from __future__ import annotations

import numpy as np

from fixer4d.pipeline.run_folder import load_scene_for
from fixer4d.pipeline.self_check import decide
from fixer4d.pipeline.self_check_run import run_self_check
from fixer4d.restore.base import RestoreResult

from pipeline_tiny import HeldOutSpy, tiny_config

# the stage-2 settings of the paper's pseudo-targets (pipeline.config.PAPER_STAGE2)
PAPER_TARGETS = {"stage2.pseudo_target": "restored", "stage2.pseudo_mask": "all", "stage2.densify_stats": "all"}


class NoiseRestorer:
    """A restorer that returns bright noise with full confidence: pseudo-targets that can only harm."""

    name = "noise"

    def settings(self):
        return {}

    def restore(self, request, progress=None):
        rng = np.random.default_rng(request.frame)
        rgb = (0.7 + 0.3 * rng.random(request.rgb.shape)).astype(np.float32)
        conf = np.ones(request.rgb.shape[:3], np.float32)
        return RestoreResult(rgb, conf, conf.mean(axis=(1, 2)))


def test_decide_leaves_the_baseline_only_beyond_the_tie():
    assert decide({"skip": 20.0, "continue": 20.01, "refine": 20.015}, 0.02) == "skip"
    assert decide({"skip": 20.0, "continue": 20.5, "refine": 20.51}, 0.02) == "refine"  # the best, once past skip
    assert decide({"skip": 20.0, "continue": 20.5, "refine": 20.5}, 0.02) == "continue"  # exact tie: the simpler
    assert decide({"skip": 21.0, "continue": 20.5, "refine": 20.6}, 0.02) == "skip"
    # the fold figures of two demo seeds: +0.07 dB is within the fold's noise, +0.21 dB is not
    assert decide({"skip": 19.51, "continue": 19.57, "refine": 19.58}, 0.1) == "skip"
    assert decide({"skip": 19.11, "continue": 19.28, "refine": 19.32}, 0.1) == "refine"
    # without skip the check only asks whether pseudo-views pay against the same plain training
    assert decide({"skip": 21.0, "continue": 20.5, "refine": 20.6}, 0.02, allow_skip=False) == "refine"
    assert decide({"skip": 21.0, "continue": 20.5, "refine": 20.51}, 0.02, allow_skip=False) == "continue"
    assert decide({"continue": 20.5}, 0.1) == "continue"


def test_noise_pseudo_targets_are_caught_without_held_out_cameras(tmp_path):
    # the paper's stage 2 (restored targets on every pixel) with a heavy pseudo-loss on noise
    common = {"training.iterations": 120, "stage2.lambda_gen": 4.0, "stage2.refresh_every": 100,
              "self_check.scale": 1.0, "self_check.eval_frames": 2, "self_check.allow_continue": True}
    config = tiny_config(**common, **PAPER_TARGETS)
    scene = HeldOutSpy(load_scene_for(config))
    record = run_self_check(scene, config, tmp_path / "paper", NoiseRestorer())
    assert scene.violations == []  # no held-out frame, mask or depth was read
    psnr = record["psnr"]
    assert psnr["refine"] < psnr["skip"] - 1.0 and psnr["refine"] < psnr["continue"] - 1.0
    assert record["decision"] == ("skip" if psnr["continue"] <= psnr["skip"] + config.self_check.tie_db else "continue")
    # gated targets (the default) let the noise act only where the render is a hole or the train
    # cameras do not see: the same restorer costs far less
    gated = run_self_check(scene, tiny_config(**common), tmp_path / "gated", NoiseRestorer())["psnr"]
    assert gated["skip"] == psnr["skip"] and gated["refine"] > psnr["refine"] + 0.5
    assert record["held_back_camera"] == scene.train_ids[3] and record["held_back_camera"] not in record["fold_cameras"]
    assert (tmp_path / "paper" / "decision.json").is_file() and set(record["seconds"]) == {"init", "stage1", "continue", "refine"}


def test_no_fold_below_three_train_cameras(tmp_path):
    config = tiny_config()
    scene = load_scene_for(config)

    class Two:
        train_ids = scene.train_ids[:2]

    assert run_self_check(Two(), config, tmp_path, NoiseRestorer())["decision"] == "refine"


def test_a_killed_check_resumes_to_the_same_decision(tmp_path, monkeypatch):
    import json

    from fixer4d.train.trainer import Trainer

    config = tiny_config(**{"training.checkpoint_every": 10, "self_check.scale": 1.0, "self_check.eval_frames": 2})
    scene = load_scene_for(config)
    whole = run_self_check(scene, config, tmp_path / "whole", NoiseRestorer())

    class Killed(Exception):
        pass

    step = Trainer._step
    kill_at = {"stage 1": 25, "refine": 5}  # the fold's stage 1 after its checkpoint at 20, then stage 2

    def killing_step(self):
        part = "refine" if self.stage2 is not None else "stage 1"
        if kill_at.get(part) is not None and self.step_count == kill_at[part] and self.config.iterations == 40:
            kill_at[part] = None
            raise Killed(part)
        return step(self)

    monkeypatch.setattr(Trainer, "_step", killing_step)
    out = tmp_path / "killed"
    for part in ("stage 1", "refine"):
        try:
            run_self_check(scene, config, out, NoiseRestorer())
        except Killed as exc:
            assert str(exc) == part
        else:
            raise AssertionError(f"the check was not interrupted in {part}")
        done = json.loads((out / "parts.json").read_text())["psnr"]
        assert set(done) == (set() if part == "stage 1" else {"skip"})  # continue is not a candidate
    model_written = (out / "model_stage1.ply").stat().st_mtime_ns
    resumed = run_self_check(scene, config, out, NoiseRestorer())
    assert (out / "model_stage1.ply").stat().st_mtime_ns == model_written  # the fold's stage 1 was not redone
    assert resumed["psnr"] == whole["psnr"] and resumed["decision"] == whole["decision"]
    assert not any(out.glob("*/checkpoints"))  # finished parts leave no checkpoints behind


def test_a_changed_tie_decides_again_from_the_finished_fold(tiny_run, tmp_path, monkeypatch):
    import json
    import shutil

    from fixer4d.cli import main
    from fixer4d.pipeline import self_check_run

    run_dir = tmp_path / "run"
    shutil.copytree(tiny_run[0], run_dir)
    before = json.loads((run_dir / "self_check" / "decision.json").read_text())
    parts = (run_dir / "self_check" / "parts.json").read_bytes()

    def no_training(*args, **kwargs):
        raise AssertionError("the fold was trained again")

    monkeypatch.setattr(self_check_run, "_train", no_training)
    # a tie larger than any fold gain: the stage-1 model, decided from the stored fold figures
    assert main(["refine", str(run_dir), "--set", "self_check.tie_db=100", "--quiet"]) == 0
    report = json.loads((run_dir / "report.json").read_text())
    after = report["self_check"]
    assert after["decision"] == "skip" and after["psnr"] == before["psnr"] and after["settings"]["tie_db"] == 100.0
    assert (run_dir / "self_check" / "parts.json").read_bytes() == parts
    rows = {r["method"]: r for r in report["rows"]}
    assert rows["Full"]["psnr"] == rows["STGS w/ MVS"]["psnr"]
    # the kept stage-1 model's rows are copied under the final rows' names, not rendered again
    for final, source in (("Full", "STGS w/ MVS"), ("Restoration (refined)", "Restoration (init)")):
        assert rows[final]["same_as"] == source and rows[final]["seconds"] > rows[source]["seconds"]
        assert {k: v for k, v in rows[final].items() if k not in ("method", "same_as", "seconds")} == \
            {k: v for k, v in rows[source].items() if k not in ("method", "seconds")}
    assert json.loads((run_dir / "metrics.json").read_text())["method"] == "Full"
    assert "more than 100 dB" in (run_dir / "report.md").read_text()


class HeldBackSpy:
    """A scene that records every read of one train camera's frame, mask or depth, and where it
    came from: reads made to score that camera (``_held_back_psnr`` on the call stack) are
    counted, any other is a violation (what, the innermost fixer4d function)."""

    SCORING = "_held_back_psnr"

    def __init__(self, scene, cam: int) -> None:
        self._scene, self.cam = scene, int(cam)
        self.violations: list[tuple[str, str]] = []
        self.scoring_reads = 0

    def __getattr__(self, name):
        return getattr(self._scene, name)

    def _check(self, what: str, cam: int) -> None:
        import inspect

        if int(cam) != self.cam:
            return
        stack = inspect.stack(context=0)
        if any(f.function == self.SCORING for f in stack):
            self.scoring_reads += 1
            return
        inner = next((f"{f.filename.split('fixer4d/')[-1]}:{f.function}" for f in stack[2:] if "/fixer4d/" in f.filename),
                     "?")
        self.violations.append((what, inner))

    def frame(self, frame, cam):
        self._check("frame", cam)
        return self._scene.frame(frame, cam)

    def mask(self, frame, cam):
        self._check("mask", cam)
        return self._scene.mask(frame, cam)

    def depth(self, frame, cam):
        self._check("depth", cam)
        return self._scene.depth(frame, cam)


def test_the_held_back_camera_reaches_nothing_in_its_fold(tmp_path):
    import json

    # a learned restorer: the run's learned from every train camera, so the fold trains its own
    config = tiny_config(**{"restorer.kind": "learned", "restorer.learned.loo_iterations": 10,
                            "restorer.learned.steps": 10, "restorer.learned.pair_frames": 2,
                            "self_check.eval_frames": 2})
    base = load_scene_for(config)
    held = base.train_ids[config.self_check.fold % len(base.train_ids)]
    scene = HeldBackSpy(base, held)
    record = run_self_check(scene, config, tmp_path / "check", restorer=None)
    assert scene.violations == []  # init, trainings, densification, restorer pairs, pseudo-views
    assert scene.scoring_reads > 0  # the spy is wired in: the score reads the camera
    assert record["held_back_camera"] == held and "restorer" in record["seconds"]
    fold_restorer = json.loads((tmp_path / "check" / "restorer" / "validation.json").read_text())
    assert fold_restorer["held_out_fold_camera"] in record["fold_cameras"]
    for pairs in (tmp_path / "check" / "restorer" / "pairs").glob("fold_*.npz"):
        with np.load(pairs) as data:
            assert held not in set(data["cams"].tolist())


def test_a_fold_view_refuses_the_held_back_camera(tiny_scene):
    import pytest

    from fixer4d.scene.train_view import HeldOutAccess, TrainOnlyView

    held, fold = tiny_scene.train_ids[3], tiny_scene.train_ids[:3]
    TrainOnlyView(tiny_scene, fold).frame(0, held)  # a plain fold view may score it
    with pytest.raises(HeldOutAccess):
        TrainOnlyView(tiny_scene, fold, readable=fold).frame(0, held)


def test_the_measured_margin_asks_for_more_than_the_frames_spread():
    from fixer4d.pipeline.self_check import gains, margin_db

    # +0.3 dB on average, but one frame carries it all: within the frames' own spread
    frames = {"skip": [20.0, 20.0, 20.0, 20.0], "continue": [20.0, 20.0, 20.0, 20.0], "refine": [20.0, 20.0, 20.0, 21.2]}
    psnr = {k: sum(v) / len(v) for k, v in frames.items()}
    assert decide(psnr, 0.1) == "refine"  # the fixed margin takes it
    assert decide(psnr, 0.1, margin="measured", frames=frames) == "skip"
    assert margin_db(0.1, "measured", frames["refine"], frames["skip"]) > 0.9
    # the same +0.3 dB on every frame is evidence under either rule
    steady = {"skip": [20.0] * 4, "continue": [20.0] * 4, "refine": [20.3] * 4}
    assert decide({k: v[0] for k, v in steady.items()}, 0.1, margin="measured", frames=steady) == "refine"
    g = gains(frames)
    assert abs(g["refine"]["gain_db"] - 0.3) < 1e-9 and abs(g["refine"]["se_db"] - 0.3) < 1e-9
    assert g["continue"]["se_db"] == 0.0
    # without per-frame figures (a fold from before they were kept) the measured rule is the fixed one
    assert decide(psnr, 0.1, margin="measured") == "refine"


def test_two_held_back_cameras_decide_on_the_spread_over_folds(tmp_path):
    import json

    config = tiny_config(**{"self_check.cameras": 2, "self_check.eval_frames": 2, "self_check.margin": "measured"})
    scene = load_scene_for(config)
    record = run_self_check(scene, config, tmp_path / "check", restorer=None)
    folds = record["folds"]
    held = [f["held_back_camera"] for f in folds]
    assert held == [scene.train_ids[3], scene.train_ids[0]]  # train cameras fold, fold + 1 (cyclic)
    for f in folds:
        assert f["held_back_camera"] not in f["fold_cameras"] and len(f["fold_cameras"]) == len(scene.train_ids) - 1
    assert (tmp_path / "check" / "fold1" / "model_stage1.ply").is_file()
    # each candidate's figure is the mean over the folds; the paired gain is per fold
    assert set(record["psnr"]) == {"skip", "refine"}
    for c in record["psnr"]:
        assert abs(record["psnr"][c] - np.mean([f["psnr"][c] for f in folds])) < 1e-9
    assert record["gain_unit"] == "fold" and record["settings"]["cameras"] == 2
    units = {c: [f["psnr"][c] for f in folds] for c in record["psnr"]}
    assert record["decision"] == decide(record["psnr"], config.self_check.tie_db, margin="measured", frames=units)
    diffs = [f["psnr"]["refine"] - f["psnr"]["skip"] for f in folds]
    assert abs(record["gains"]["refine"]["se_db"] - abs(diffs[0] - diffs[1]) / 2) < 1e-9
    # the seconds are the folds' together, and the record on disk is the one returned
    assert abs(record["seconds"]["stage1"] - sum(f["seconds"]["stage1"] for f in folds)) < 1e-9
    assert json.loads((tmp_path / "check" / "decision.json").read_text())["folds"] == folds
    from fixer4d.pipeline.report import self_check_line

    line = self_check_line(record)
    names = ", ".join(scene.cameras[c].name for c in held)
    assert f"on held-back train cameras {names}, one fold each" in line and "per fold: mean ± standard error" in line


def test_the_fold_budget_and_the_key_of_the_new_settings():
    from fixer4d.pipeline.keys import stage2_key, self_check_key
    from fixer4d.pipeline.run_folder import stage_key

    config = tiny_config()
    assert config.self_check.scale_budget  # the default: the fold's budget shrinks with its pixels
    fold = config.self_check.fold_training(config.training)
    share = config.self_check.scale ** 2
    assert fold.max_gaussians == round(config.training.max_gaussians * share)
    assert fold.init_max_points == round(config.training.init_max_points * share)
    unscaled = tiny_config(**{"self_check.scale_budget": False})
    assert unscaled.self_check.fold_training(unscaled.training) is unscaled.training  # the run's budget
    # a check at the settings every check had before cameras / scale_budget / fields existed keeps its key
    before = {k: v for k, v in unscaled.to_dict()["self_check"].items()
              if k not in ("tie_db", "allow_skip", "margin", "cameras", "scale_budget", "allow_continue", "fields")}
    one_field = tiny_config(**{"training.fields": 1, "self_check.scale_budget": False})
    assert self_check_key(one_field) == stage_key("self_check", stage2_key(one_field), before,
                                                  one_field.init_frame_stride)
    # a fold of several fields (the run's stage 1 merged) has its own key
    assert self_check_key(unscaled) == stage_key("self_check", stage2_key(unscaled), before,
                                                 unscaled.init_frame_stride, "fold_fields", unscaled.training.fields)
    assert len({self_check_key(config), self_check_key(unscaled),
                self_check_key(tiny_config(**{"self_check.cameras": 2}))}) == 3
    assert self_check_key(tiny_config(**{"self_check.allow_continue": True})) == self_check_key(config)


def test_a_check_without_continue_neither_trains_nor_chooses_it(tmp_path):
    import pytest

    from fixer4d.errors import InputError
    from fixer4d.pipeline.report import self_check_line
    from fixer4d.pipeline.self_check import SelfCheckConfig

    config = tiny_config(**{"self_check.eval_frames": 2})
    assert config.self_check.candidates() == ("skip", "refine")  # the default
    record = run_self_check(load_scene_for(config), config, tmp_path / "check", restorer=None)
    assert set(record["psnr"]) == {"skip", "refine"} and "continue" not in record["seconds"]
    assert record["gain_continue_db"] is None and set(record["gains"]) == {"refine"}
    assert record["decision"] == decide(record["psnr"], config.self_check.tie_db)
    line = self_check_line(record)
    assert "more training" not in line and "stage 2" in line
    with pytest.raises(InputError, match="refine alone"):
        SelfCheckConfig(allow_skip=False, allow_continue=False)


def test_allowing_continue_trains_only_continue_in_the_finished_fold(tiny_run, tmp_path, monkeypatch):
    import json
    import shutil

    from fixer4d.cli import main
    from fixer4d.pipeline import self_check_run

    run_dir = tmp_path / "run"
    shutil.copytree(tiny_run[0], run_dir)
    before = json.loads((run_dir / "self_check" / "decision.json").read_text())
    trained = []
    train = self_check_run._train

    def spy(trainer, progress):
        trained.append(trainer.run_dir.name)
        return train(trainer, progress)

    monkeypatch.setattr(self_check_run, "_train", spy)
    assert main(["refine", str(run_dir), "--set", "self_check.allow_continue=true", "--quiet"]) == 0
    after = json.loads((run_dir / "report.json").read_text())["self_check"]
    assert trained == ["continue"]  # the fold's stage 1 and refine were kept
    assert {k: after["psnr"][k] for k in before["psnr"]} == before["psnr"] and "continue" in after["psnr"]
    assert after["settings"]["allow_continue"] is True
    assert after["decision"] == decide(after["psnr"], after["settings"]["tie_db"])
