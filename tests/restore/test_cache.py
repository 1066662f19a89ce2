"""RestoreCache: layout, round trip, atomic replacement, interrupted writes, resume."""
from __future__ import annotations

import json
import logging
import zipfile

import numpy as np
import pytest

import fixer4d.restore.cache as cache_mod
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.restore.base import RestoreResult
from fixer4d.restore.cache import CACHE_FORMAT, RestoreCache, settings_fingerprint

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
    # the half entry was not skipped silently: it was reported and moved aside
    assert not half.exists() and (tmp_path / "corrupt" / "round_0" / "t0003_1-2-0" / "frame_0000.png").is_file()
    assert [(p.name, d.name) for p, d, _ in cache.set_aside] == [("t0003_1-2", "t0003_1-2-0")]


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


def _damage_png(entry_dir):
    p = entry_dir / "frame_0001.png"
    p.write_bytes(p.read_bytes()[:-20])  # cut short: no IEND chunk


def _damage_meta(entry_dir):
    (entry_dir / "meta.json").write_text('{"format": 2, "key": ')


def _foreign_meta(entry_dir):
    (entry_dir / "meta.json").write_text('{"hello": "world"}')


def _drop_confidence_array(entry_dir):
    with zipfile.ZipFile(entry_dir / "confidence.npz", "w") as z:
        z.writestr("confidence.npy", b"")


def _camera_count(entry_dir):
    meta = json.loads((entry_dir / "meta.json").read_text())
    meta["num_frames"] = 7
    (entry_dir / "meta.json").write_text(json.dumps(meta))


@pytest.mark.parametrize("damage, reason", [
    (_damage_png, "frame_0001.png is missing or not a complete PNG"),
    (_damage_meta, "unreadable meta.json"),
    (_foreign_meta, "no cache format version"),
    (_drop_confidence_array, "confidence.npz lacks ['frame_confidence.npy']"),
    (_camera_count, "lists 3 cameras for 7 frames"),
])
def test_corrupt_entry_is_reported_moved_aside_and_recomputed(tmp_path, caplog, damage, reason):
    cache = RestoreCache(tmp_path)
    request = tiny_request()
    for k in ("t0003_0-1", "t0003_0-2"):
        cache.write(0, k, request, _result(request), META)
    damage(tmp_path / "round_0" / "t0003_0-1")
    with caplog.at_level(logging.WARNING, logger="fixer4d.restore"):
        assert [e.key for e in cache.entries(0)] == ["t0003_0-2"]
    aside = tmp_path / "corrupt" / "round_0" / "t0003_0-1-0"
    assert aside.is_dir() and not (tmp_path / "round_0" / "t0003_0-1").exists()
    [record] = [r for r in caplog.records if r.name == "fixer4d.restore"]
    assert "t0003_0-1" in record.getMessage() and reason in record.getMessage() and str(aside) in record.getMessage()
    # treated as missing, so the refresh restores it again; a second damage goes to -1
    assert not cache.has(0, "t0003_0-1")
    cache.write(0, "t0003_0-1", request, _result(request), META)
    assert cache.has(0, "t0003_0-1")
    damage(tmp_path / "round_0" / "t0003_0-1")
    assert cache.get(0, "t0003_0-1") is None and (tmp_path / "corrupt" / "round_0" / "t0003_0-1-1").is_dir()
    assert cache.rounds() == [0]  # the corrupt/ folder is not a round


def test_older_format_cache_gets_one_sentence_and_is_recomputed(tmp_path, caplog):
    cache = RestoreCache(tmp_path)
    request = tiny_request()
    for k in ("t0003_0-1", "t0003_0-2", "t0003_1-2"):
        entry = cache.write(0, k, request, _result(request), META)
        meta = json.loads((entry.path / "meta.json").read_text())
        meta["format"] = CACHE_FORMAT - 1
        (entry.path / "meta.json").write_text(json.dumps(meta))
    with caplog.at_level(logging.WARNING, logger="fixer4d.restore"):
        assert cache.entries(0) == [] and cache.latest_round() is None
    messages = [r.getMessage() for r in caplog.records if r.name == "fixer4d.restore"]
    assert len(messages) == 1
    assert f"cache format {CACHE_FORMAT - 1}, this fixer4d writes format {CACHE_FORMAT}" in messages[0]
    assert sorted(p.name for p in (tmp_path / "stale" / "round_0").iterdir()) == ["t0003_0-1-0", "t0003_0-2-0",
                                                                                  "t0003_1-2-0"]


def test_newer_format_entry_is_refused_and_left_alone(tmp_path):
    cache = RestoreCache(tmp_path)
    request = tiny_request()
    entry = cache.write(0, "t0003_0-1", request, _result(request), META)
    meta = json.loads((entry.path / "meta.json").read_text())
    meta["format"] = CACHE_FORMAT + 1
    (entry.path / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=f"cache format {CACHE_FORMAT + 1}, but this fixer4d reads format"):
        cache.get(0, "t0003_0-1")
    assert entry.path.is_dir() and not (tmp_path / "corrupt").exists()


def test_entries_of_other_settings_are_stale_not_served(tmp_path, caplog):
    old_settings = settings_fingerprint({"restorer": {"angle_sigma": 0.1}, "frames": 3})
    new_settings = settings_fingerprint({"restorer": {"angle_sigma": 0.2}, "frames": 3})
    assert old_settings != new_settings
    assert settings_fingerprint({"frames": 3, "restorer": {"angle_sigma": 0.1}}) == old_settings  # key order
    request = tiny_request()
    RestoreCache(tmp_path, fingerprint=old_settings).write(0, "t0003_0-1", request, _result(request), META)
    assert RestoreCache(tmp_path, fingerprint=old_settings).has(0, "t0003_0-1")
    assert RestoreCache(tmp_path).has(0, "t0003_0-1")  # no fingerprint (a viewer): any settings
    cache = RestoreCache(tmp_path, fingerprint=new_settings)
    with caplog.at_level(logging.WARNING, logger="fixer4d.restore"):
        assert not cache.has(0, "t0003_0-1") and cache.entries(0) == []
    assert (tmp_path / "stale" / "round_0" / "t0003_0-1-0").is_dir()
    assert any("other settings" in r.getMessage() for r in caplog.records)
    entry = cache.write(0, "t0003_0-1", request, _result(request), META)
    assert entry.meta["fingerprint"] == new_settings and cache.has(0, "t0003_0-1")
