"""Pseudo-views where the model is undetermined (pipeline.undetermined_views): the score prefers a
view of surfaces no train camera sees, off changes nothing, and no held-out camera is read."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fixer4d.geometry.camera import Camera
from fixer4d.model.spacetime import SpacetimeGaussians
from fixer4d.pipeline.keys import stage2_key
from fixer4d.pipeline.restoration import make_refresh_callback
from fixer4d.pipeline.run_folder import load_scene_for
from fixer4d.pipeline.undetermined_views import score_views, undetermined_trajectories, unobserved_weight_fn
from fixer4d.restore.cache import RestoreCache
from fixer4d.restore.visibility import VisibilityConfig
from pipeline_tiny import HeldOutSpy, tiny_config

RADIUS = 3.0


def ball(n: int = 3000, seed: int = 0) -> SpacetimeGaussians:
    """Opaque static Gaussians on the surface of a unit sphere at the origin (it fills the views)."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p = p / np.linalg.norm(p, axis=1, keepdims=True)
    return SpacetimeGaussians.from_points(p, rng.uniform(size=(n, 3)), np.zeros(n), opacity=0.95,
                                          scales=np.full(n, 0.06), dynamic=np.zeros(n, bool))


def at_azimuth(deg: float, name: str) -> Camera:
    a = np.radians(deg)
    eye = RADIUS * np.array([np.sin(a), 0.3, np.cos(a)])
    return Camera.look_at(eye, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), fov_y=np.radians(30.0), width=64, height=48,
                          name=name)


@dataclass
class OneSidedRig:
    """What undetermined_trajectories reads of a scene: four train cameras on the +z side."""

    train_cameras: list
    train_ids: list

    def time(self, frame: int) -> float:
        return 0.0


def one_sided_rig() -> OneSidedRig:
    return OneSidedRig([at_azimuth(a, f"train{k}") for k, a in enumerate((-45.0, -15.0, 15.0, 45.0))], [0, 1, 2, 3])


def test_the_score_prefers_a_view_of_what_no_train_camera_sees():
    rig = one_sided_rig()
    weight = unobserved_weight_fn(ball(), rig.train_cameras, VisibilityConfig())
    front, back = at_azimuth(0.0, "front"), at_azimuth(180.0, "back")
    s_front, s_back = score_views([front, back], [0.0], weight)
    assert s_back > s_front + 0.3  # the far side of the ball is hidden from every train camera

    @dataclass
    class Picks:
        undetermined_views: int = 1
        undetermined_elevation_deg: float = 20.0
        undetermined_radius: float = 1.3
        undetermined_separation_deg: float = 25.0
        frames: int = 4

    (path, ids), = undetermined_trajectories(rig, Picks(), weight, [0.0])
    s_pick, = score_views([path.cameras[-1]], [0.0], weight)
    assert s_pick >= s_back - 1e-6  # the pick sees as little observed surface as the far side's view
    assert path.cameras[0].name.startswith("view0") and ids == tuple(path.pair)


def _tiny_model(scene) -> SpacetimeGaussians:
    from fixer4d.geometry.view_candidates import rig_frame

    rng = np.random.default_rng(1)
    center = rig_frame(scene.train_cameras).center
    return SpacetimeGaussians.from_points(rng.normal(size=(1500, 3)) * 0.3 + center, rng.uniform(size=(1500, 3)),
                                          np.zeros(1500), opacity=0.5)


def test_off_keeps_every_key_and_clip_and_on_adds_the_views(tmp_path):
    base = tiny_config(**{"restorer.kind": "warp"})
    # the undetermined views' own settings enter no key while the option is off
    assert stage2_key(tiny_config(**{"restorer.kind": "warp", "trajectories.undetermined_radius": 2.0})) == \
        stage2_key(base)
    assert stage2_key(tiny_config(**{"restorer.kind": "warp", "trajectories.undetermined_views": 2})) != \
        stage2_key(base)
    scene = load_scene_for(base)
    model = _tiny_model(scene)
    caches = {}
    for k in (0, 2):
        config = tiny_config(**{"restorer.kind": "warp", "trajectories.undetermined_views": k})
        make_refresh_callback(tmp_path / f"k{k}", scene, config, progress=False)(model, 0)
        caches[k] = {e.key: e for e in RestoreCache(tmp_path / f"k{k}" / "cache").entries(0)}
    assert not any("_view" in key for key in caches[0])
    views = sorted(set(caches[2]) - set(caches[0]))
    assert set(caches[0]) <= set(caches[2]) and len(views) == 2 and all("_view" in key for key in views)
    for key, entry in caches[0].items():  # the pair paths and arcs are restored as without the views
        assert np.array_equal(entry.rgb(), caches[2][key].rgb())


def test_the_views_read_no_held_out_camera(tmp_path):
    config = tiny_config(**{"restorer.kind": "warp", "trajectories.undetermined_views": 2})
    spy = HeldOutSpy(load_scene_for(config))
    make_refresh_callback(tmp_path, spy, config, progress=False)(_tiny_model(spy), 0)
    assert spy.violations == []
    assert any("_view" in e.key for e in RestoreCache(tmp_path / "cache").entries(0))
    # the spy is wired in: a read of a held-out frame outside the evaluation is caught
    spy.frame(0, spy.test_ids[0])
    assert spy.violations and spy.violations[0][1] == spy.test_ids[0]


def test_the_held_back_camera_picks_and_restores_no_view_in_its_fold(tmp_path):
    from fixer4d.pipeline.self_check_run import run_self_check
    from test_self_check import HeldBackSpy

    config = tiny_config(**{"restorer.kind": "warp", "trajectories.undetermined_views": 2,
                            "self_check.eval_frames": 2})
    base = load_scene_for(config)
    held = base.train_ids[config.self_check.fold % len(base.train_ids)]
    scene = HeldBackSpy(base, held)
    record = run_self_check(scene, config, tmp_path / "check", restorer=None)
    assert scene.violations == []  # the views' scores, paths and restorations read the fold's cameras only
    assert scene.scoring_reads > 0 and record["held_back_camera"] == held
    entries = RestoreCache(tmp_path / "check" / "cache").entries(0)
    views = [e for e in entries if "_view" in e.key]
    assert views and all(held not in e.meta["trajectory"]["pair"] for e in views)
