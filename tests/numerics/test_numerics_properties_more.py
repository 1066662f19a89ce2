"""Property tests of the remaining public entry points (docs/numerics.md): restore, pipeline,
scene and the init cloud files. Finite input -> finite output or InputError (never NaN, never a
foreign exception). The last test enumerates every package's public names and checks each is
covered by a named test here or in test_numerics_properties.py, or exempted with a reason."""
from __future__ import annotations

import importlib
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from fixer4d.errors import InputError
from numerics_finite import finite
from fixer4d.geometry import Camera

SETTINGS = settings(max_examples=15, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])
FEW = settings(SETTINGS, max_examples=6)

# magnitudes spanning float32: tiny, unit-order and near overflow, either sign
MAG = st.sampled_from([0.0, 1e-30, 1e-6, 0.1, 0.5, 1.0, 7.0, 1e4, 1e20, 3e38])
SIGNED_MAG = st.builds(lambda m, s: m * s, MAG, st.sampled_from([-1.0, 1.0]))
ODD_NUMBERS = st.sampled_from([0, -1, 1, 2.5, -0.5, 1e-300, 1e308, -1e308, float("nan"), float("inf"),
                               float("-inf")])
FINITE_ODD = st.sampled_from([0, -1, 1, 2.5, -0.5, 1e-300, 1e308, -1e308])
ODD_VALUES = st.one_of(ODD_NUMBERS, st.sampled_from([None, True, False, "x", "", [1], [], {}, {"a": 1}]))


def _arrays(shape, elements=SIGNED_MAG):
    return hnp.arrays(np.float32, shape, elements=elements)


# ---- restore ---------------------------------------------------------------------------------
_H, _W = 5, 6
_CLIP = [Camera.look_at([x, 0.0, -3.0], [0.0, 0.0, 0.0], width=_W, height=_H, name=f"n{k}")
         for k, x in enumerate((-0.3, 0.3))]
_REFS = [Camera.look_at([x, 0.0, -3.0], [0.0, 0.0, 0.0], width=_W, height=_H, name=f"r{k}")
         for k, x in enumerate((-1.0, 1.0))]
DEPTH = st.one_of(st.floats(2.0, 4.0, width=32), SIGNED_MAG, st.sampled_from([float("nan"), float("inf")]))
UNIT = st.floats(0.0, 1.0, width=32)


@st.composite
def restore_requests(draw):
    """A tiny request (F <= 2 frames of 5 x 6) with colours of any finite magnitude and depths
    that may be 0, negative, NaN or inf (they mean "unknown")."""
    f = draw(st.integers(1, 2))
    colour = draw(st.sampled_from([UNIT, SIGNED_MAG]))
    from fixer4d.restore import RestoreRequest

    return RestoreRequest(
        rgb=draw(_arrays((f, _H, _W, 3), colour)), depth=draw(_arrays((f, _H, _W), DEPTH)),
        alpha=draw(_arrays((f, _H, _W), st.one_of(UNIT, SIGNED_MAG))), cameras=_CLIP[:f],
        time=draw(st.floats(0, 1)), frame=0,
        ref_images=[draw(_arrays((_H, _W, 3), colour)) for _ in range(2)], ref_cameras=_REFS,
        ref_depths=[draw(_arrays((_H, _W), DEPTH)) for _ in range(2)],
        ref_alphas=[draw(_arrays((_H, _W), st.one_of(UNIT, SIGNED_MAG))) for _ in range(2)],
        unobserved=draw(st.one_of(st.none(), _arrays((f, _H, _W), UNIT))))


@FEW
@given(restore_requests(), st.booleans())
def test_reference_warp_restore_finite_or_input_error(request, extra):
    from fixer4d.restore import ReferenceWarpConfig, ReferenceWarpRestorer

    restorer = ReferenceWarpRestorer(ReferenceWarpConfig(use_extra_views=extra, temporal_radius=1))
    out = restorer.restore(request)
    assert out.rgb.shape == request.rgb.shape
    assert finite(out.rgb) and finite(out.confidence) and finite(out.frame_confidence)
    assert float(out.confidence.min()) >= 0.0 and float(out.confidence.max()) <= 1.0


@SETTINGS
@given(st.integers(0, 2), st.integers(0, 3), st.integers(0, 3), st.sampled_from(["ok", "short", "wrong", "text"]))
def test_restore_request_and_result_validate_or_input_error(f, h, w, kind):
    from fixer4d.restore import RestoreRequest, RestoreResult

    rgb = np.zeros((f, h, w, 3), np.float32)
    conf = np.zeros((f, h, w) if kind != "wrong" else (f, h + 1, w), np.float32)
    frame_conf = np.zeros(f if kind != "short" else f + 1, np.float32) if kind != "text" else np.array(["a"] * f)
    try:
        res = RestoreResult(rgb, conf, frame_conf)
    except InputError:
        assert kind != "ok"
    else:
        assert (kind == "ok" or kind == "text" and f == 0) and res.num_frames == f
    cams = [Camera.look_at([0.0, 0.0, -3.0], [0, 0, 0], width=max(w, 1), height=max(h, 1))] * f
    try:
        RestoreRequest(rgb, conf, conf, cams, 0.0, 0, [rgb[0] if f else rgb] * 2, _REFS, [conf] * 2, [conf] * 2)
    except InputError:
        return
    raise AssertionError("a request with references of another size was accepted")


@SETTINGS
@given(st.integers(1, 2), st.sampled_from([UNIT, SIGNED_MAG]), st.sampled_from([UNIT, SIGNED_MAG]),
       st.booleans(), st.booleans(), st.data())
def test_blend_with_render_finite_in_unit_range(f, render_el, result_el, with_weight, with_hole, data):
    from fixer4d.restore import RestoreResult
    from fixer4d.restore.base import blend_with_render

    render = data.draw(_arrays((f, 3, 4, 3), render_el))
    result = RestoreResult(data.draw(_arrays((f, 3, 4, 3), result_el)), data.draw(_arrays((f, 3, 4), SIGNED_MAG)),
                           np.zeros(f, np.float32))
    weight = data.draw(_arrays((f, 3, 4), SIGNED_MAG)) if with_weight else None
    hole = data.draw(_arrays((f, 3, 4), SIGNED_MAG)) if with_hole else None
    out = blend_with_render(render, result, weight, hole)
    assert finite(out.rgb) and finite(out.confidence) and finite(out.frame_confidence)
    assert out.rgb.min() >= 0.0 and out.rgb.max() <= 1.0 and 0.0 <= out.confidence.min() <= out.confidence.max() <= 1.0
    with pytest.raises(InputError):
        blend_with_render(render[:, :2], result, weight)


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # alpha ~3e38 in the hole ramp: clipped to 1
@SETTINGS
@given(st.integers(1, 2), st.data())
def test_unobserved_weight_and_clip_finite_in_unit_range(f, data):
    from fixer4d.restore.visibility import TrainView, unobserved_clip, unobserved_fraction, unobserved_weight

    depths = data.draw(_arrays((f, _H, _W), DEPTH))
    alphas = data.draw(_arrays((f, _H, _W), st.one_of(UNIT, SIGNED_MAG)))
    train = [TrainView(c, data.draw(_arrays((_H, _W), DEPTH)), data.draw(_arrays((_H, _W), UNIT))) for c in _REFS]
    clip = unobserved_clip(_CLIP[:f], depths, alphas, train)
    assert clip.shape == (f, _H, _W) and finite(clip) and clip.min() >= 0.0 and clip.max() <= 1.0
    assert 0.0 <= unobserved_fraction(clip) <= 1.0
    with pytest.raises(InputError):
        unobserved_weight(_CLIP[0], depths[0][:, :2], alphas[0], train)


@SETTINGS
@given(st.one_of(st.integers(-10**6, 10**6), st.sampled_from([0.0, 2.5, -1.0, 1e300])), st.integers(-3, 30), st.integers(-3, 30),
       st.one_of(st.none(), st.integers(0, 9)), st.dictionaries(st.text(max_size=4), ODD_VALUES, max_size=3))
def test_cache_keys_and_fingerprints_or_input_error(frame, i, j, arc, settings_dict):
    from fixer4d.restore import RestoreCache
    from fixer4d.restore.cache import settings_fingerprint

    key = RestoreCache.key(frame, i, j, arc)
    assert key.startswith("t") and "/" not in key and key == RestoreCache.key(frame, i, j, arc)
    fp = settings_fingerprint(settings_dict)
    assert len(fp) == 16 and fp == settings_fingerprint(dict(settings_dict))


@SETTINGS
@given(st.sampled_from(["kind", "warp.lowpass_sigma", "warp.temporal_radius", "warp.hole_alpha_low", "learned.lr",
                        "learned.loo_scale", "learned.early_fraction", "use_extra_views", "nonsense"]),
       st.one_of(FINITE_ODD, st.sampled_from([None, True, "x", [1], {}])))
def test_restore_configs_from_dict_or_input_error(key, value):
    from fixer4d.restore import RestoreConfig, build_restorer

    section, _, name = key.rpartition(".")
    d = {section: {name: value}} if section else {name: value}
    try:
        cfg = RestoreConfig.from_dict(d)
    except InputError:
        return
    assert finite([v for v in (cfg.warp.__dict__ | cfg.learned.__dict__).values() if isinstance(v, float)])
    if cfg.kind == "warp":
        assert build_restorer(cfg).settings()


# ---- pipeline --------------------------------------------------------------------------------
def _config_leaves() -> list[str]:
    from fixer4d.pipeline import config_tree, resolve

    def leaves(tree, prefix=""):
        for k, v in tree.items():
            where = f"{prefix}.{k}" if prefix else k
            yield from (leaves(v, where) if isinstance(v, dict) else [where])

    return sorted(leaves(config_tree.to_dict(resolve("demo"))))


_LEAVES = _config_leaves()


@settings(SETTINGS, max_examples=60)
@given(st.sampled_from(_LEAVES), ODD_VALUES)
def test_resolve_odd_set_values_give_a_config_or_input_error(key, value):
    from fixer4d.pipeline import config_tree, resolve

    try:
        cfg = resolve("demo", overrides={key: value})
    except InputError:
        return
    tree = config_tree.to_dict(cfg)

    def numbers(t):
        for v in (t.values() if isinstance(t, dict) else t):
            if isinstance(v, (dict, list)):
                yield from numbers(v)
            elif isinstance(v, float):
                yield v
    assert all(math.isfinite(v) for v in numbers(tree)), (key, value)


@SETTINGS
@given(st.lists(st.text(max_size=12), max_size=3))
def test_parse_set_overrides_or_input_error(items):
    from fixer4d.pipeline import parse_set_overrides, resolve

    try:
        overrides = parse_set_overrides(items)
        resolve("demo", overrides=overrides)
    except InputError:
        return


@SETTINGS
@given(st.dictionaries(st.sampled_from(["skip", "continue", "refine"]), st.floats(-100, 100), max_size=3),
       st.floats(0, 5), st.booleans())
def test_self_check_decide_picks_a_candidate_or_input_error(psnr, tie_db, allow_skip):
    from fixer4d.pipeline.self_check import CHOICES, decide

    try:
        choice = decide(psnr, tie_db, allow_skip)
    except InputError:
        assert not [c for c in psnr if allow_skip or c != "skip"]
        return
    assert choice in CHOICES and choice in psnr and (allow_skip or choice != "skip")


@SETTINGS
@given(st.sampled_from(["STGS w/ MVS", "Full"]), st.dictionaries(st.sampled_from(["psnr", "dssim1", "lpips", "x"]),
                                                                 st.one_of(st.none(), st.floats(-50, 50)), max_size=4),
       st.one_of(st.none(), st.floats(0, 1e6)))
def test_report_rows_hold_every_metric_key(method, mean, seconds):
    from fixer4d.pipeline import ROW_NAMES
    from fixer4d.pipeline.report import METRIC_KEYS, copied_row, failed_row, metrics_row

    assert method in ROW_NAMES
    for row in (metrics_row(method, {"mean": mean}, seconds), copied_row(method, {"mean": mean, "method": "y"}),
                failed_row(method, "reason")):
        assert row["method"] == method and set(METRIC_KEYS) <= set(row) and finite(row)


# ---- scene -----------------------------------------------------------------------------------
@SETTINGS
@given(st.one_of(st.sampled_from([1.0, 0.5, 0.25]), ODD_VALUES),
       st.one_of(st.none(), st.tuples(st.integers(-2, 12), st.integers(-2, 12)), ODD_VALUES),
       st.one_of(st.none(), st.lists(st.integers(-2, 6), max_size=3), st.sampled_from([[1.5], ["a"], [float("nan")]])),
       st.one_of(st.none(), st.lists(st.integers(-2, 6), max_size=2)))
def test_load_scene_odd_arguments_or_input_error(scale, frame_range, train_ids, test_ids):
    from fixer4d.scene import load_scene
    from fixer4d.scene.base import frame_time

    try:
        scene = load_scene("tiny", scale=scale, frame_range=frame_range, train_ids=train_ids, test_ids=test_ids)
    except InputError:
        return
    assert scene.num_frames >= 1 and scene.train_ids
    assert not set(scene.train_ids) & set(scene.test_ids)
    assert all(c.width >= 1 and c.height >= 1 and np.isfinite(c.K).all() for c in scene.cameras)
    assert all(math.isfinite(scene.time(f)) for f in (0, scene.num_frames - 1))
    assert math.isfinite(frame_time(scene.num_frames - 1, scene.num_frames))


@SETTINGS
@given(st.one_of(st.integers(-5, 100), FINITE_ODD), st.one_of(st.integers(-2, 100), FINITE_ODD))
def test_frame_time_finite_or_input_error(frame, num_frames):
    from fixer4d.scene.base import frame_time

    try:
        t = frame_time(frame, num_frames)
    except InputError:
        return
    assert math.isfinite(t)


@FEW
@given(st.one_of(st.none(), st.lists(st.integers(-1, 5), max_size=3)), st.one_of(st.sampled_from([1.0, 0.5]), ODD_NUMBERS),
       st.integers(0, 5))
def test_train_only_view_or_input_error(train_ids, scale, cam):
    from fixer4d.scene import load_scene
    from fixer4d.scene.train_view import HeldOutAccess, TrainOnlyView

    base = load_scene("tiny")
    try:
        view = TrainOnlyView(base, train_ids, scale)
    except InputError:
        return
    assert all(c.width >= 1 and c.height >= 1 and np.isfinite(c.K).all() for c in view.cameras)
    assert math.isfinite(view.time(0))
    if cam >= len(base.cameras):
        return
    try:
        img = view.frame(0, cam)
    except HeldOutAccess:
        assert cam not in base.train_ids
        return
    assert cam in base.train_ids and img.shape == (view.cameras[cam].height, view.cameras[cam].width, 3)
    assert finite(img)


def test_scene_names_and_layouts_or_input_error(tmp_path):
    from fixer4d.scene import builtin_scene_names, detect_layout, open_scene_checked, validate_scene

    names = builtin_scene_names()
    assert "tiny" in names and "demo" in names
    with pytest.raises(InputError):
        detect_layout(tmp_path)
    for frames in ("0:0", "x", "5:2", (0, 10**6), (-1, 2)):
        with pytest.raises(InputError):
            open_scene_checked("tiny", frame_range=frames)
    scene = open_scene_checked("tiny", frame_range="0:2", scale=0.5)
    validate_scene(scene)
    bounds = scene.bounds()
    assert finite([np.asarray(v, np.float64) for v in vars(bounds).values() if v is not None])


# ---- init cloud files ------------------------------------------------------------------------
@SETTINGS
@given(st.lists(st.tuples(st.integers(0, 40), hnp.arrays(np.float64, st.tuples(st.integers(0, 4), st.just(3)),
                                                          elements=st.one_of(st.floats(-5, 5), SIGNED_MAG))),
                max_size=3, unique_by=lambda t: t[0]),
       st.sampled_from([0.5, 0.0, 1.0, -3.0, 7.0, float("nan")]))
def test_frame_cloud_files_round_trip_finite_or_input_error(frames, colour):
    from fixer4d.init import FrameCloud, load_frame_clouds, save_frame_clouds

    clouds = []
    for frame, pts in frames:
        try:
            clouds.append(FrameCloud(frame, frame / 41, pts, np.full_like(pts, colour)))
        except InputError:
            continue
    with tempfile.TemporaryDirectory() as tmp:
        if not clouds:
            with pytest.raises(InputError):
                load_frame_clouds(Path(tmp) / "missing")
            return
        save_frame_clouds(tmp, clouds)
        back = load_frame_clouds(tmp)
    assert [c.frame for c in back] == sorted(c.frame for c in clouds)
    for c in back:
        assert finite((c.points, c.colors, c.times)) and ((c.colors >= 0.0) & (c.colors <= 1.0)).all()


# ---- every public name is covered or exempt --------------------------------------------------
_PROPS = "test_numerics_properties.py"
_MORE = "test_numerics_properties_more.py"
_REGR = "test_numerics_regressions.py"

#: public name -> the test (file, function) that checks it
COVERED: dict[str, tuple[str, str]] = {
    "geometry.Camera": (_PROPS, "test_camera_validates_or_projects_like_the_renderer"),
    "geometry.rig_extent": (_PROPS, "test_camera_validates_or_projects_like_the_renderer"),
    "init.FrameCloud": (_PROPS, "test_frame_clouds_finite_or_input_error"),
    "init.merge_clouds": (_PROPS, "test_frame_clouds_finite_or_input_error"),
    "init.save_frame_clouds": (_MORE, "test_frame_cloud_files_round_trip_finite_or_input_error"),
    "init.load_frame_clouds": (_MORE, "test_frame_cloud_files_round_trip_finite_or_input_error"),
    "model.ModelConfig": (_PROPS, "test_model_files_round_trip_finite"),
    "model.Snapshot": (_PROPS, "test_render_finite_image_and_gradients_or_input_error"),
    "model.SpacetimeGaussians": (_PROPS, "test_from_points_and_at_finite_or_input_error"),
    "model.save_model": (_PROPS, "test_model_files_round_trip_finite"),
    "model.load_model": (_PROPS, "test_model_files_round_trip_finite"),
    # save_model/load_model dispatch on the suffix to these; the property test runs both suffixes
    "model.save_npz": (_PROPS, "test_model_files_round_trip_finite"),
    "model.load_npz": (_REGR, "test_npz_with_string_arrays_is_an_input_error"),
    "model.save_ply": (_PROPS, "test_model_files_round_trip_finite"),
    "model.load_ply": (_PROPS, "test_model_files_round_trip_finite"),
    "render.render": (_PROPS, "test_render_finite_image_and_gradients_or_input_error"),
    "render.RenderOutput": (_PROPS, "test_render_finite_image_and_gradients_or_input_error"),
    "render.resolve_backend": (_PROPS, "test_resolve_backend_names_or_input_error"),
    "scene.parse_frame_range": (_PROPS, "test_frame_ranges_parse_or_input_error"),
    "scene.check_frame_range": (_PROPS, "test_frame_ranges_parse_or_input_error"),
    "scene.load_scene": (_MORE, "test_load_scene_odd_arguments_or_input_error"),
    "scene.SyntheticScene": (_MORE, "test_load_scene_odd_arguments_or_input_error"),
    "scene.MultiViewVideo": (_MORE, "test_load_scene_odd_arguments_or_input_error"),
    "scene.open_scene_checked": (_MORE, "test_scene_names_and_layouts_or_input_error"),
    "scene.detect_layout": (_MORE, "test_scene_names_and_layouts_or_input_error"),
    "scene.builtin_scene_names": (_MORE, "test_scene_names_and_layouts_or_input_error"),
    "scene.validate_scene": (_MORE, "test_scene_names_and_layouts_or_input_error"),
    "scene.SceneBounds": (_MORE, "test_scene_names_and_layouts_or_input_error"),
    "restore.RestoreRequest": (_MORE, "test_restore_request_and_result_validate_or_input_error"),
    "restore.RestoreResult": (_MORE, "test_restore_request_and_result_validate_or_input_error"),
    "restore.ReferenceWarpRestorer": (_MORE, "test_reference_warp_restore_finite_or_input_error"),
    "restore.ReferenceWarpConfig": (_MORE, "test_restore_configs_from_dict_or_input_error"),
    "restore.LearnedRestorerConfig": (_MORE, "test_restore_configs_from_dict_or_input_error"),
    "restore.RestoreConfig": (_MORE, "test_restore_configs_from_dict_or_input_error"),
    "restore.build_restorer": (_MORE, "test_restore_configs_from_dict_or_input_error"),
    "restore.RestoreCache": (_MORE, "test_cache_keys_and_fingerprints_or_input_error"),
    "pipeline.resolve": (_MORE, "test_resolve_odd_set_values_give_a_config_or_input_error"),
    "pipeline.RunConfig": (_MORE, "test_resolve_odd_set_values_give_a_config_or_input_error"),
    "pipeline.SceneConfig": (_MORE, "test_resolve_odd_set_values_give_a_config_or_input_error"),
    "pipeline.TrajectoryConfig": (_MORE, "test_resolve_odd_set_values_give_a_config_or_input_error"),
    "pipeline.EvalConfig": (_MORE, "test_resolve_odd_set_values_give_a_config_or_input_error"),
    "pipeline.parse_set_overrides": (_MORE, "test_parse_set_overrides_or_input_error"),
    "pipeline.ROW_NAMES": (_MORE, "test_report_rows_hold_every_metric_key"),
}

#: public name -> why it has no property test of its own
EXEMPT: dict[str, str] = {
    "bench.positive_int": "argparse type of the bench CLI: raises argparse.ArgumentTypeError by contract",
    "calib.calibrate": "runs SfM on a video capture (minutes); its gate has tests in tests/calib",
    "calib.calibrate_capture": "calibrates a capture folder (board or SfM, seconds to minutes): "
                               "tests/calib/test_board.py, tests/calib/test_run_capture.py",
    "calib.resolve_rig": "needs a capture folder; covered by tests/calib",
    "calib.cache_path": "a hash of file names and sizes: no numbers in or out",
    "init.InitConfig": "a config dataclass: its fields are fuzzed through pipeline.resolve (init.*)",
    "init.run_init": "a whole stage (MVS over a scene, tens of seconds): tests/init",
    "init.METHODS": "constant",
    "init.REPORT_NAME": "constant",
    "pipeline.FORMAT_VERSION": "constant",
    "pipeline.RunFolder": "a run folder on disk (config.json, stage records): tests/pipeline",
    "pipeline.load_scene_for": "load_scene with a run folder's config: load_scene is fuzzed",
    "pipeline.StageContext": "plain container of a run's objects",
    "pipeline.StageFailed": "exception class",
    "pipeline.open_context": "opens a run folder and its scene: tests/pipeline",
    "pipeline.run_pipeline": "a whole run (minutes): CLI entry point, tests/pipeline",
    "pipeline.run_stages": "a whole run (minutes): CLI entry point, tests/pipeline",
    "render.BACKENDS": "constant",
    "restore.CacheEntry": "plain container of a cache directory read back by RestoreCache: tests/restore",
    "restore.Job": "a future-like handle of RestoreJobs: no numbers",
    "restore.RestoreJobs": "thread pool around a restorer: tests/restore",
    "restore.RestoreCancelled": "exception class",
    "restore.Restorer": "typing Protocol",
    "scene.Neural3DVScene": "needs a Neural3DV folder of mp4s: tests/scene, real data",
    "scene.PanopticScene": "needs a Panoptic folder of jpgs: tests/scene, real data",
}

PACKAGES = ("bench", "calib", "eval", "geometry", "init", "model", "pipeline", "render", "restore", "scene", "train")


def _public_names(pkg: str) -> list[str]:
    """``__all__`` of fixer4d.<pkg>, else the public functions and classes its __init__ defines or imports."""
    mod = importlib.import_module(f"fixer4d.{pkg}")
    if hasattr(mod, "__all__"):
        return list(mod.__all__)
    return [n for n, v in vars(mod).items() if not n.startswith("_") and (callable(v) and not isinstance(v, type(mod)))
            and getattr(v, "__module__", "").startswith("fixer4d")]


def test_every_public_name_is_covered_or_exempt():
    here = Path(__file__).parent
    sources = {name: (here / name).read_text() for name in (_PROPS, _MORE, _REGR)}
    names = {f"{pkg}.{n}" for pkg in PACKAGES for n in _public_names(pkg)}
    missing = sorted(names - set(COVERED) - set(EXEMPT))
    assert not missing, f"public names without a numerics property test or an exemption: {missing}"
    assert not set(COVERED) & set(EXEMPT)
    assert not (set(COVERED) | set(EXEMPT)) - names, "stale entries"
    for name, (path, test) in COVERED.items():
        assert f"def {test}(" in sources[path], f"{name}: {path}::{test} does not exist"
    assert all(EXEMPT.values())
