"""RestoreConfig: restorer kinds round-trip through dicts and JSON, settings keys are stable, and
build_restorer gives each kind or its clear error."""
from __future__ import annotations

import importlib.util
import json

import pytest

from fixer4d.errors import BackendUnavailable, InputError
from fixer4d.restore.config import LearnedRestorerConfig, RestoreConfig
from fixer4d.restore.factory import build_restorer
from fixer4d.restore.reference_warp import ReferenceWarpConfig, ReferenceWarpRestorer


def test_round_trip_through_json():
    cfg = RestoreConfig(kind="learned", warp=ReferenceWarpConfig(use_extra_views=False),
                        learned=LearnedRestorerConfig(steps=7, loo_scale=0.25))
    again = RestoreConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert again == cfg
    assert RestoreConfig.from_dict({}) == RestoreConfig() and RestoreConfig().kind == "warp"


def test_flat_warp_keys_are_warp_settings():
    cfg = RestoreConfig.from_dict({"use_extra_views": False, "kind": "learned"})
    assert cfg.kind == "learned" and cfg.warp.use_extra_views is False


@pytest.mark.parametrize("bad", [{"kind": "diffusion"}, {"nonsense": 1}, {"learned": {"stepz": 3}},
                                 {"learned": {"loo_scale": 0.0}}])
def test_bad_settings_are_refused(bad):
    with pytest.raises(InputError):
        RestoreConfig.from_dict(bad)


def test_settings_key_is_stable_and_names_what_changes_a_target():
    a = RestoreConfig(kind="learned")
    key = json.dumps(a.settings_key(), sort_keys=True)
    assert json.dumps(RestoreConfig.from_dict(a.to_dict()).settings_key(), sort_keys=True) == key
    assert RestoreConfig(kind="learned", learned=LearnedRestorerConfig(steps=11)).settings_key() != a.settings_key()
    assert RestoreConfig(kind="warp").settings_key() != a.settings_key()
    # the warp key ignores the learned settings (they do not change a warp target)
    assert (RestoreConfig(kind="warp", learned=LearnedRestorerConfig(steps=11)).settings_key()
            == RestoreConfig(kind="warp").settings_key())
    assert a.settings_key()["kind"] == "learned"


def test_build_restorer_kinds(tmp_path, monkeypatch):
    assert isinstance(build_restorer(RestoreConfig(kind="warp")), ReferenceWarpRestorer)
    with pytest.raises(InputError, match="--restorer learned"):
        build_restorer(RestoreConfig(kind="learned"), tmp_path / "restorer")
    with pytest.raises(InputError, match="train"):
        build_restorer(RestoreConfig(kind="learned"))


def test_cogvideo_unavailable_is_the_clear_error(monkeypatch):
    import torch

    if importlib.util.find_spec("diffusers") is not None and torch.cuda.is_available():
        pytest.skip("CogVideoX may be available on this machine")
    monkeypatch.delenv("FIXER4D_COGVIDEO_WEIGHTS", raising=False)
    with pytest.raises(BackendUnavailable, match="CogVideoX restorer unavailable"):
        build_restorer(RestoreConfig(kind="cogvideo"))


def test_cli_refuses_unavailable_cogvideo_before_any_work(tmp_path, capsys, monkeypatch):
    import torch

    from fixer4d.cli import main

    if importlib.util.find_spec("diffusers") is not None and torch.cuda.is_available():
        pytest.skip("CogVideoX may be available on this machine")
    monkeypatch.delenv("FIXER4D_COGVIDEO_WEIGHTS", raising=False)
    out = tmp_path / "run"
    assert main(["run", "tiny", "--out", str(out), "--restorer", "cogvideo", "--quiet"]) == 1
    assert "CogVideoX restorer unavailable" in capsys.readouterr().err
    assert not out.exists()
