"""The scenes' frame cache is bounded by bytes, and holds a small clip's every frame."""
import numpy as np

from fixer4d.scene import load_scene
from fixer4d.scene.base import LRUCache


def test_lru_cache_is_bounded_by_bytes_and_keeps_the_newest():
    cache = LRUCache(max_bytes=3 * 800)
    for k in range(5):
        cache.get_or_compute(k, lambda: np.zeros(100))  # 800 bytes each
    assert len(cache) == 3 and cache.nbytes == 2400
    calls = []
    cache.get_or_compute(0, lambda: calls.append(0) or np.zeros(100))  # evicted: computed again
    cache.get_or_compute(4, lambda: calls.append(4) or np.zeros(100))  # still there
    assert calls == [0]
    big = cache.get_or_compute("big", lambda: np.zeros(1000))  # alone over the budget: kept
    assert len(cache) == 1 and cache.nbytes == big.nbytes
    cache.get_or_compute("none", lambda: None)  # 0 bytes, but the big one now goes (over budget)
    assert len(cache) == 1 and cache.nbytes == 0


def test_lru_cache_zero_budget_caches_nothing():
    cache = LRUCache(max_bytes=0)
    calls = []
    for _ in range(2):
        cache.get_or_compute("a", lambda: calls.append(1) or np.zeros(4))
    assert len(calls) == 2 and len(cache) == 0


def test_every_train_frame_of_the_demo_is_ray_cast_once(monkeypatch):
    # 20 frames x 4 train cameras, rgb + depth: 160 entries, more than the former 128-item cache
    scene = load_scene("demo", scale=0.1)
    loads = []
    real = type(scene)._load_frame
    monkeypatch.setattr(type(scene), "_load_frame", lambda self, f, c: loads.append((f, c)) or real(self, f, c))
    for _ in range(2):  # a second pass over the clip (as every training epoch does) hits the cache
        for f in range(scene.num_frames):
            for c in scene.train_ids:
                scene.frame(f, c)
                scene.depth(f, c)
    assert len(loads) == scene.num_frames * len(scene.train_ids)
