"""`fixer4d run` and `fixer4d study`: argument handling and clear errors (no training here)."""
from __future__ import annotations

import pytest

from fixer4d.cli import main
from fixer4d.errors import InputError
from fixer4d.pipeline import parse_set_overrides


def test_set_overrides_parse_json_values():
    assert parse_set_overrides(["stage1.iterations=800", "scene.frame_range=[0, 30]", "init.method=sparse"]) == {
        "stage1.iterations": 800, "scene.frame_range": [0, 30], "init.method": "sparse"}
    with pytest.raises(InputError, match="KEY=VALUE"):
        parse_set_overrides(["stage1.iterations"])


@pytest.mark.parametrize("argv, message", [
    (["run", "tiny", "--out", "{tmp}/r", "--frames", "5:2"], "expected a:b"),
    (["run", "tiny", "--out", "{tmp}/r", "--set", "nosuch.section=1"], "no section"),
    (["run", "no/such/scene", "--out", "{tmp}/r"], "no such file"),
    (["study", "tiny", "--out", "{tmp}/s", "--only", "nope"], "unknown variant"),
])
def test_cli_errors_are_clear(tmp_path, capsys, argv, message):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 1
    assert message in capsys.readouterr().err
