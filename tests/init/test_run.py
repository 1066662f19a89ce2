import json

import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.init import InitConfig, load_frame_clouds, run_init
from fixer4d.cli.init import parse_frames
from toyscene import ToyScene


@pytest.fixture(scope="module")
def scene():
    return ToyScene(96, 72, num_frames=3)


def _config():
    cfg = InitConfig()
    cfg.mvs.planes = 24
    return cfg


@pytest.mark.parametrize("method", ["sparse", "mvs"])
def test_run_init_writes_the_report_contract(scene, tmp_path, method):
    clouds, report = run_init(scene, method, tmp_path, frames=[0, 2], config=_config(), progress=False)
    on_disk = json.loads((tmp_path / "init_report.json").read_text())
    assert on_disk["method"] == method == report["method"]
    assert on_disk["frames"] == [0, 2]
    assert on_disk["points_per_frame"] == [len(c) for c in clouds]
    assert isinstance(on_disk["seconds"]["total"], float) and on_disk["seconds"]["total"] > 0
    assert on_disk["cpu_seconds"]["preparation"] > 0
    q = on_disk["quality"]
    assert set(q) >= {"accuracy", "completeness", "depth_abs_rel"}
    assert 0.0 <= q["completeness"] <= 1.0
    if method == "mvs":
        assert q["depth_abs_rel"] is not None and q["depth_abs_rel"] < 0.2
        assert 0 < q["valid_share"] <= 1 and q["coverage"] <= q["valid_share"]
    else:
        assert q["depth_abs_rel"] is None
    back = load_frame_clouds(tmp_path)
    assert [c.frame for c in back] == [0, 2]
    assert back[1].time == pytest.approx(2 / 3)
    assert all(np.all(np.isfinite(c.points)) for c in back)
    assert InitConfig.from_dict(on_disk["config"]) == _config()


def test_dense_cloud_is_more_complete(scene, tmp_path):
    _, sparse = run_init(scene, "sparse", tmp_path / "s", frames=[1], config=_config(), progress=False)
    _, dense = run_init(scene, "mvs", tmp_path / "d", frames=[1], config=_config(), progress=False)
    assert dense["quality"]["completeness"] > 3 * sparse["quality"]["completeness"]


def test_run_init_rejects_bad_requests(scene, tmp_path):
    with pytest.raises(InputError, match="unknown method"):
        run_init(scene, "dense", tmp_path, progress=False)
    with pytest.raises(InputError, match="outside"):
        run_init(scene, "sparse", tmp_path, frames=[5], progress=False)
    with pytest.raises(InputError, match="unknown key"):
        InitConfig.from_dict({"planes": 3})


def test_parse_frames():
    assert parse_frames("2:5") == [2, 3, 4]
    assert parse_frames("0:10:5") == [0, 5]
    assert parse_frames("1,4") == [1, 4]
    assert parse_frames(None) is None
    with pytest.raises(InputError, match="--frames"):
        parse_frames("a:b")
    with pytest.raises(InputError, match=r"frame\(s\) \[0\] listed twice"):
        parse_frames("0,0,3")
