"""What the command line does with what it is given: a path that does not open ends with one
line and exit status 2 (no window), a bundled scene name wins over a folder of the same name
with a notice, and only sources the user opened go into the recent list."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from app import main
from app.files import recent

ROOT = Path(__file__).resolve().parents[2]


def _cli(args: list[str], tmp_path: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, XDG_CONFIG_HOME=str(tmp_path / "cfg"), DISPLAY="",
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "app.main", *args], env=env, cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)


@pytest.mark.parametrize("kind", ["missing", "fake_ply"])
def test_a_source_that_does_not_open_exits_2_with_one_line(tmp_path, kind):
    if kind == "missing":
        source = "/no/such/path"
    else:
        source = str(tmp_path / "model.ply")
        Path(source).write_text("not a ply\n")
    proc = _cli([source], tmp_path)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fixer4d-view: error: cannot open ") and source in lines[0], lines
    assert proc.stdout == ""
    assert recent(tmp_path / "cfg" / "fixer4d" / "view") == []  # never opened: not remembered


def _args(*argv: str):
    return main.build_parser().parse_args(list(argv))


def test_a_bundled_name_is_the_bundled_scene_even_beside_a_folder_of_that_name(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tiny").mkdir()
    (tmp_path / "tiny" / "config.json").write_text("{}")  # looks like a run folder
    src, _, _, err = main.open_start_source(_args("tiny"), "tiny")
    assert err is None and src.scene is not None and src.scene.name == "tiny" and src.training is not None
    assert "./tiny" in src.notice and "built-in scene" in src.notice
    assert src.notice in capsys.readouterr().err  # said on the terminal too (and in the window: show_notice)
    from app import sources
    from app.viewer_source import ViewerSource

    monkeypatch.setattr(sources, "open_run", lambda run, model=None: (ViewerSource(label=f"run {run}"), None, run))
    src, _, _, _ = main.open_start_source(_args("./tiny"), "./tiny")  # a path is the folder
    assert src.label == f"run {(tmp_path / 'tiny').resolve()}" and src.notice == ""


def test_only_sources_the_user_opened_are_remembered(tmp_path, monkeypatch):
    from fixer4d.model.io import save_ply
    from viewer_helpers import make_gaussians

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    cfg = tmp_path / "cfg" / "fixer4d" / "view"
    model = tmp_path / "m.ply"
    save_ply(make_gaussians(n_static=16, n_moving=4).to_model(), model)
    main.open_start_source(_args("--screenshot", str(tmp_path / "s.png"), str(model)), str(model))
    assert recent(cfg) == []  # a scripted screenshot is not the user opening it
    with pytest.raises(main.SourceError):
        main.open_start_source(_args(str(tmp_path / "nope")), str(tmp_path / "nope"))
    assert recent(cfg) == []
    main.open_start_source(_args(str(model)), str(model))
    assert recent(cfg) == [str(model)]
