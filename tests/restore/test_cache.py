"""RestoreCache: layout, round trip, atomic replacement, interrupted writes, resume."""
from __future__ import annotations

import json

import numpy as np
import pytest

import fixer4d.restore.cache as cache_mod
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.restore.base import RestoreResult
from fixer4d.restore.cache import RestoreCache

from .conftest import tiny_request


def _result(request, value: float | None = None, seed: int = 0) -> RestoreResult:
    rng = np.random.default_rng(seed)
    shape = request.rgb.shape
    rgb = np.full(shape, value, np.float32) if value is not None else rng.random(shape, dtype=np.float32)
    conf = rng.random(shape[:3], dtype=np.float32)
    return RestoreResult(rgb, conf, conf.reshape(shape[0], -1).mean(1))


META = {"step": 1200, "restorer": {"name": "reference_warp", "settings": {"angle_sigma": 0.1}}}


def test_key_format():
    assert RestoreCache.key(7, 0, 3) == "t0007_0-3"
    assert RestoreCache.key(12, 1, 2, arc=1) == "t0012_1-2_arc1"


def test_round_trip_and_layout(tmp_path):
    cache = RestoreCache(tmp_path / "cache")
    request = tiny_request()
    result = _result(request)
    key = cache.key(request.frame, 0, 1)
    entry = cache.write(2, key, request, result, META)
    d = tmp_path / "cache" / "round_2" / "t0003_0-1"
    assert entry.path == d and d.is_dir()
    assert sorted(p.name for p in d.iterdir()) == ["confidence.npz", "frame_0000.png", "frame_0001.png",
                                                  "frame_0002.png", "meta.json"]
    meta = json.loads((d / "meta.json").read_text())
    assert meta["step"] == 1200 and meta["restorer"]["name"] == "reference_warp"
    assert meta["frame"] == 3 and meta["time"] == 0.25 and meta["trajectory"]["pair"] == [0, 1]
    assert {"mean_confidence", "frame_confidence", "render_hole_fraction"} <= set(meta["scores"])
    assert entry.key == key and entry.round == 2 and entry.frame == 3 and entry.time == 0.25
    for a, b in zip(entry.cameras, request.cameras):
        np.testing.assert_allclose(a.c2w, b.c2w)
        np.testing.assert_allclose(a.K, b.K)
        assert isinstance(a, Camera) and a.name == b.name
    np.testing.assert_allclose(entry.rgb(), result.rgb, atol=0.5 / 255 + 1e-6)  # 8-bit PNG
    np.testing.assert_allclose(entry.confidence(), result.confidence, atol=1e-3)  # float16
    np.testing.assert_allclose(entry.frame_confidence(), result.frame_confidence, rtol=1e-6)
    assert cache.has(2, key) and not cache.has(1, key) and not cache.has(2, "t0004_0-1")
    assert [e.key for e in cache.entries()] == [key]
    assert cache.latest_round() == 2


def test_latest_round_and_entries(tmp_path):
    cache = RestoreCache(tmp_path)
    assert cache.latest_round() is None and cache.entries() == []
    request = tiny_request()
    cache.write(0, "t0003_0-1", request, _result(request), META)
    cache.write(0, "t0003_2-3_arc0", request, _result(request), META)
    cache.write(1, "t0003_0-1", request, _result(request), META)
    (tmp_path / "round_5").mkdir()  # an empty round (killed before its first entry) does not count
    assert cache.rounds() == [0, 1] and cache.latest_round() == 1
    assert [e.key for e in cache.entries()] == ["t0003_0-1"]
    assert [e.key for e in cache.entries(0)] == ["t0003_0-1", "t0003_2-3_arc0"]
    assert cache.entries(7) == []


def test_stale_entry_is_replaced_not_mixed(tmp_path):
    cache = RestoreCache(tmp_path)
    long_request = tiny_request(frames=5)
    cache.write(0, "k", long_request, _result(long_request, 0.2), META)
    short_request = tiny_request(frames=2)
    entry = cache.write(0, "k", short_request, _result(short_request, 0.8), {**META, "step": 2400})
    names = sorted(p.name for p in entry.path.iterdir())
    assert names == ["confidence.npz", "frame_0000.png", "frame_0001.png", "meta.json"]
    assert entry.meta["step"] == 2400 and entry.num_frames == 2
    np.testing.assert_allclose(entry.rgb(), 0.8, atol=1 / 255)
    assert [p.name for p in (tmp_path / "round_0").iterdir()] == ["k"]  # no temporary left behind


def test_interrupted_write_leaves_previous_entry_intact(tmp_path, monkeypatch):
    cache = RestoreCache(tmp_path)
    request = tiny_request(frames=4)
    cache.write(0, "k", request, _result(request, 0.25), META)
    calls = []
    real = cache_mod._write_png

    def dying_write(path, rgb8):
        calls.append(path)
        if len(calls) == 3:
            raise KeyboardInterrupt("killed mid-write")
        real(path, rgb8)

    monkeypatch.setattr(cache_mod, "_write_png", dying_write)
    with pytest.raises(KeyboardInterrupt):
        cache.write(0, "k", request, _result(request, 0.75), {**META, "step": 9999})
    monkeypatch.setattr(cache_mod, "_write_png", real)
    assert len(calls) == 3
    entry = cache.get(0, "k")
    assert entry is not None and entry.meta["step"] == 1200
    np.testing.assert_allclose(entry.rgb(), 0.25, atol=1 / 255)
    assert [p.name for p in (tmp_path / "round_0").iterdir()] == ["k"]


def test_killed_process_leftovers_are_skipped_and_cleaned(tmp_path):
    cache = RestoreCache(tmp_path)
    request = tiny_request()
    cache.write(0, "t0003_0-1", request, _result(request), META)
    # what a SIGKILL during atomic_dir leaves: a hidden temporary directory with some frames
    tmp = tmp_path / "round_0" / ".t0003_2-3.tmp.abc123"
    tmp.mkdir()
    (tmp / "frame_0000.png").write_bytes(b"\x89PNG")
    # and an entry directory without meta.json (e.g. copied by hand, half done)
    half = tmp_path / "round_0" / "t0003_1-2"
    half.mkdir()
    (half / "frame_0000.png").write_bytes(b"\x89PNG")
    assert [e.key for e in cache.entries(0)] == ["t0003_0-1"]
    assert not cache.has(0, "t0003_2-3") and not cache.has(0, "t0003_1-2")
    assert cache.clean_temporary() == 1 and not tmp.exists()


def test_resume_reuses_complete_entries(tmp_path):
    """A resumed refresh writes only the entries that are not complete yet."""
    cache = RestoreCache(tmp_path)
    request = tiny_request()
    keys = [cache.key(3, i, j) for i, j in [(0, 1), (0, 2), (1, 2)]]
    cache.write(0, keys[0], request, _result(request), META)  # the run was killed after one entry
    restored = [k for k in keys if not cache.has(0, k)]
    for k in restored:
        cache.write(0, k, request, _result(request), META)
    assert restored == keys[1:]
    assert [e.key for e in cache.entries(0)] == sorted(keys)


def test_bad_keys_and_mismatched_result_are_rejected(tmp_path):
    cache = RestoreCache(tmp_path)
    request = tiny_request(frames=3)
    for bad in ("", "../x", "a/b", ".hidden"):
        with pytest.raises(InputError):
            cache.write(0, bad, request, _result(request), META)
    with pytest.raises(InputError, match="shape"):
        cache.write(0, "k", request, _result(tiny_request(frames=2)), META)
