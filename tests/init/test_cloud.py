import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.init.cloud import FrameCloud, load_frame_clouds, merge_clouds, save_frame_clouds


def test_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    clouds = [FrameCloud(f, f / 10, rng.normal(size=(50 + f, 3)), rng.random((50 + f, 3))) for f in (3, 0, 12)]
    paths = save_frame_clouds(tmp_path, clouds)
    assert sorted(p.name for p in paths) == ["frame_0000.ply", "frame_0003.ply", "frame_0012.ply"]
    back = load_frame_clouds(tmp_path)
    assert [c.frame for c in back] == [0, 3, 12]
    for c in back:
        orig = next(o for o in clouds if o.frame == c.frame)
        np.testing.assert_array_equal(c.points, orig.points)
        np.testing.assert_allclose(c.colors, orig.colors, atol=0.5 / 255 + 1e-6)
        assert c.time == orig.time
    pts, cols, times = merge_clouds(back)
    assert pts.shape == (165, 3) 
    np.testing.assert_allclose(np.unique(times), [0.0, 0.3, 1.2], rtol=1e-6)


def test_empty_cloud_round_trip(tmp_path):
    save_frame_clouds(tmp_path, [FrameCloud(7, 0.7, np.zeros((0, 3)), np.zeros((0, 3)))])
    (c,) = load_frame_clouds(tmp_path)
    assert len(c) == 0 and c.frame == 7 and c.time == pytest.approx(0.7)


def test_bad_clouds_raise(tmp_path):
    with pytest.raises(InputError, match="non-finite"):
        FrameCloud(0, 0.0, np.array([[0, np.nan, 0]]), np.zeros((1, 3)))
    with pytest.raises(InputError, match="colours"):
        FrameCloud(0, 0.0, np.zeros((2, 3)), np.zeros((1, 3)))
    with pytest.raises(InputError, match="fixer4d init"):
        load_frame_clouds(tmp_path / "missing")
