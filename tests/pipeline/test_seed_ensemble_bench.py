"""benchmarks/seed_ensemble.py: seed groups, their mean renders and the twin-mean pseudo-target."""
from __future__ import annotations

import copy

import numpy as np
import pytest
import torch


def test_groups_are_every_seed_neighbouring_pairs_triples_and_all(benchmark_script):
    bench = benchmark_script("seed_ensemble")
    groups = bench.combinations([0, 1, 2, 3, 4])
    assert groups["s3"] == [3] and groups["s4+s0"] == [4, 0] and groups["s3+s4+s0"] == [3, 4, 0]
    assert groups["all"] == [0, 1, 2, 3, 4]
    assert sum(len(m) == 2 for m in groups.values()) == 5 and sum(len(m) == 3 for m in groups.values()) == 5
    assert bench.combinations([7]) == {"s7": [7]}


def test_a_group_gain_is_against_the_mean_of_its_members(benchmark_script):
    bench = benchmark_script("seed_ensemble")
    groups = {"s0": [0], "s1": [1], "s2": [2], "s0+s1": [0, 1], "s1+s2": [1, 2]}
    scores = {"s0": {"psnr": 20.0}, "s1": {"psnr": 22.0}, "s2": {"psnr": 24.0},
              "s0+s1": {"psnr": 21.5}, "s1+s2": {"psnr": 22.5}}
    gains = bench.group_gains(scores, groups)
    assert gains["2"]["values"] == pytest.approx([0.5, -0.5])


def test_the_mean_render_averages_pixels_and_each_render_is_read_once(benchmark_script):
    bench = benchmark_script("seed_ensemble")
    calls = []

    def constant(value):
        def fn(camera, t):
            calls.append(value)
            return np.full((2, 3, 3), value, np.float32)
        return fn

    a, b = bench.memoized(constant(0.2)), bench.memoized(constant(0.6))
    cam = object()
    image = bench.mean_render([a, b])(cam, 0.5)
    assert image.dtype == np.float32 and np.allclose(image, 0.4)
    bench.mean_render([a])(cam, 0.5)
    assert calls == [0.2, 0.6]
    with pytest.raises(ValueError):
        bench.mean_render([])


def test_a_twin_equal_to_the_model_leaves_the_target_at_the_render(benchmark_script, tiny_run):
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.restoration import make_request
    from fixer4d.pipeline.run_folder import load_scene_for, read_run_config
    from fixer4d.render.views import render_views

    bench = benchmark_script("seed_ensemble")
    run_dir, _ = tiny_run
    scene = load_scene_for(read_run_config(run_dir))
    model = load_ply(run_dir / "model_stage1.ply")
    ids = (scene.train_ids[0], scene.train_ids[1])
    cams = [scene.cameras[ids[0]], scene.cameras[ids[1]]]
    request = make_request(model, scene, cams, 0, ids, background=(0.5, 0.5, 0.5))
    same = bench.TwinMean([model], "auto", (0.5, 0.5, 0.5)).restore(request)
    assert np.allclose(same.rgb, np.clip(request.rgb, 0, 1), atol=1e-6)
    assert np.all(same.confidence == 1.0)
    # another field: the target is the per-pixel mean of the two renders
    twin = copy.deepcopy(model)
    twin.prune(torch.arange(twin.num_gaussians) % 2 == 0)
    mixed = bench.TwinMean([twin], "auto", (0.5, 0.5, 0.5)).restore(request)
    twin_rgb = render_views(twin, cams, request.time, "auto", (0.5, 0.5, 0.5))[0]
    assert not np.allclose(twin_rgb, request.rgb, atol=1e-3)
    assert np.allclose(mixed.rgb, np.clip(0.5 * (request.rgb + twin_rgb), 0, 1), atol=1e-6)


def test_coreg_targets_feed_stage2s_pseudo_views(benchmark_script, tiny_run):
    """The in-memory clips of ``coreg`` are read by ``PseudoTargets`` as a cache round: only a
    clip's novel frames are pseudo-views, and the loss against a target equal to the render is 0."""
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.restoration import scene_trajectories_for
    from fixer4d.pipeline.run_folder import load_scene_for, read_run_config
    from fixer4d.render.views import render_views
    from fixer4d.train.config import Stage2Config
    from fixer4d.train.pseudo_targets import PseudoTargets

    bench = benchmark_script("seed_ensemble")
    run_dir, _ = tiny_run
    config = read_run_config(run_dir)
    scene = load_scene_for(config)
    model = load_ply(run_dir / "model_stage1.ply")
    trajectory, _ = scene_trajectories_for(scene, config.trajectories)[0]
    t = scene.time(0)
    image = render_views(model, trajectory.cameras, t, "auto")[0].astype(np.float32)
    cache = bench._Rounds()
    cache.rounds[0] = [bench._ClipTarget("r0_0", list(trajectory.cameras), t, image)]
    targets = PseudoTargets(Stage2Config(pseudo_target="restored", batch_pseudo=4), cache, None, scene.train_cameras)
    targets.load_round(cache.latest_round())
    assert targets.entry_frames[0].tolist() == list(range(1, len(trajectory.cameras) - 1))

    def render_view(snapshot, camera):
        from types import SimpleNamespace

        return SimpleNamespace(rgb=torch.from_numpy(render_views(model, [camera], t, "auto")[0][0].astype(np.float32)))

    timing = {"t_at": 0.0, "t_loss": 0.0}
    loss = targets.loss(model, np.random.default_rng(0), render_view, timing)
    assert float(loss) == pytest.approx(0.0, abs=1e-6)


def test_the_merge_rules_set_each_opacity_as_named(benchmark_script):
    from fixer4d.model.spacetime import SpacetimeGaussians

    bench = benchmark_script("seed_ensemble")
    rng = np.random.default_rng(0)
    fields = [SpacetimeGaussians.from_points(rng.normal(size=(4, 3)), rng.uniform(size=(4, 3)), rng.uniform(size=4))
              for _ in range(2)]
    alpha = torch.cat([torch.sigmoid(f.opacity_logits.detach().double()) for f in fields])

    def opacities(rule):
        return torch.sigmoid(bench.union(fields, rule).opacity_logits.detach().double())

    torch.testing.assert_close(opacities("halved"), alpha / 2, rtol=1e-6, atol=1e-9)
    torch.testing.assert_close(opacities("transmittance"), 1 - (1 - alpha).sqrt(), rtol=1e-5, atol=1e-7)
    torch.testing.assert_close(opacities("kept"), alpha, rtol=1e-6, atol=1e-7)
    with pytest.raises(ValueError):
        bench.union(fields, "doubled")
