"""Command-line values are checked before anything runs (a probe found `--repeats 0`, `--frames 0`
and `--iterations 0` ending in numpy tracebacks, and `make-scene --crf -5` in a PyAV one)."""
from __future__ import annotations

import types

import pytest

from fixer4d.cli import main
from fixer4d.errors import Fixer4DError, InputError


@pytest.mark.parametrize("argv, message", [
    (["bench", "at", "--n", "10", "--repeats", "0"], "--repeats: 0: must be >= 1"),
    (["bench", "restore", "--frames", "0"], "--frames: 0: must be >= 1"),
    (["bench", "iteration", "--scene", "tiny", "--iterations", "0"], "--iterations: 0: must be >= 1"),
    (["bench", "iteration", "--scene", "tiny", "--iterations", "x"], "expected a whole number >= 1"),
    (["make-scene", "tiny", "--out", "unused", "--crf", "-5"], "CRF is 0 (lossless) .. 51"),
])
def test_bad_counts_are_argument_errors(argv, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv + (["--out", str(tmp_path / "x.json")] if argv[0] == "bench" else []))
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_make_scene_names_scales_that_fit_the_llff_layout(tmp_path, capsys):
    # 0.27 rounds tiny's 64x48 to 17x13: the advice was to "undistort/crop" a synthetic render
    assert main(["make-scene", "tiny", "--out", str(tmp_path / "m"), "--scale", "0.27", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "17x13" in err and "scales near it that do: 0.25" in err and not (tmp_path / "m").exists()


def test_bench_all_names_files_like_each_benchmark(monkeypatch, tmp_path, capsys):
    """`bench all --out DIR` wrote train-step.json where the README and the committed results read
    train_step.json; `bench all --help` showed the first benchmark's help."""

    from fixer4d.cli import bench as bench_cli

    outs = {}

    class Fake:
        def __init__(self, name):
            self.name = name

        def main(self, argv):
            outs[self.name] = argv[argv.index("--out") + 1]
            return 0

    class FakeEntryPoint:  # a benchmark another package registers (the viewer's), not run for real
        name = "viewer"

        def load(self):
            return Fake("entry point viewer").main

    monkeypatch.setattr(bench_cli, "importlib", types.SimpleNamespace(import_module=Fake))
    monkeypatch.setattr(bench_cli, "entry_points", lambda group: [FakeEntryPoint()])
    assert main(["bench", "all", "--out", str(tmp_path)]) == 0
    assert outs[bench_cli.BENCHES["train-step"]] == f"{tmp_path}/train_step.json"
    assert outs["entry point viewer"] == f"{tmp_path}/viewer.json"
    assert main(["bench", "all", "--help"]) == 0
    assert "one after the other" in capsys.readouterr().out


def test_the_former_effects_flag_is_read_as_model_terms_with_a_note(capsys):
    import json

    assert main(["run", "tiny", "--effects", "static", "--print-config"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["config"]["model_terms"]["mode"] == "static"
    assert err.strip().splitlines()[-1] == "fixer4d run: --effects is now called --model-terms; read as --model-terms"
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    shown = capsys.readouterr().out
    assert "--model-terms" in shown and "--effects" not in shown


@pytest.mark.parametrize("error, code", [(InputError("bad frame"), 2), (Fixer4DError("failed"), 1)])
def test_an_error_under_a_progress_bar_gets_a_line_of_its_own(monkeypatch, capsys, error, code):
    import fixer4d.cli.eval as eval_cli
    from tqdm import tqdm

    def run(args):
        bar = tqdm(total=4, desc="calibrate: features and matches")
        bar.update(2)
        raise error

    monkeypatch.setattr(eval_cli, "run", run)
    assert main(["eval", "somewhere"]) == code
    lines = capsys.readouterr().err.replace("\r", "\n").splitlines()
    assert lines[-1] == f"fixer4d eval: error: {error}"
    assert "2/4" in lines[-2]  # the bar's last state stays above the error


def test_the_system_refusing_a_write_is_one_line_with_the_path(monkeypatch, capsys):
    import fixer4d.cli.export as export_cli

    def run(args):
        raise FileNotFoundError(2, "No such file or directory", "/proc/.out.tmp")

    monkeypatch.setattr(export_cli, "run", run)
    assert main(["export", "somewhere", "--out", "/proc/out"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == ("fixer4d export: error: No such file or directory: /proc/.out.tmp (FileNotFoundError); "
                   "check that the folder exists, is writable and has space")


def test_render_refuses_an_out_that_is_neither_video_nor_folder(tmp_path, capsys):
    assert main(["render", str(tmp_path / "no_run"), "--camera", "0", "--out", str(tmp_path / "clip.gif")]) == 2
    assert ".gif is not a video format" in capsys.readouterr().err and not (tmp_path / "clip.gif").exists()
