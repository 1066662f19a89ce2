"""The rig's last bundle adjustment and its covariance (fixer4d.calib.adjust), focal priors weighed
against the frames (fixer4d.calib.priors) and the gate's per-camera verdict, on exact synthetic
observations: four cameras on an arc, one lens 25 % longer than the others."""
from __future__ import annotations

import numpy as np
import pytest

from fixer4d.calib.adjust import CameraState, Observations, adjust, project, repeat_weights
from fixer4d.calib.gate import MAX_FOCAL_SD_REL, undetermined
from fixer4d.calib.priors import FocalPrior, parse_focal_priors, weigh_priors
from fixer4d.errors import InputError

NAMES = ["cam0", "cam1", "cam2", "cam3"]
W, H = 640, 360


def _look_at(centre: np.ndarray) -> np.ndarray:
    z = -centre / np.linalg.norm(centre)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def _rig(arc_deg: float, focals: list[float], noise_px: float = 0.5, points: int = 3000, seed: int = 0):
    """(observations with pixel noise and perturbed starting points, a perturbed start, the true state)."""
    rng = np.random.default_rng(seed)
    ang = np.radians(np.linspace(-arc_deg / 2, arc_deg / 2, 4))
    C = np.stack([np.sin(ang), 0.1 * np.ones(4), -np.cos(ang)], 1)
    truth = CameraState(np.stack([_look_at(c) for c in C]), C, np.array(focals, float), np.tile([W / 2, H / 2], (4, 1)))
    X = rng.uniform(-0.3, 0.3, (points, 3))
    cam, pt, xy = [], [], []
    for v in range(4):
        uv = project(truth.R, truth.C, truth.f, truth.c, np.full(points, v), X)
        inside = np.flatnonzero((uv[:, 0] > 0) & (uv[:, 0] < W) & (uv[:, 1] > 0) & (uv[:, 1] < H))
        cam += [v] * len(inside)
        pt += list(inside)
        xy.append(uv[inside])
    xy = np.concatenate(xy) + rng.normal(0, noise_px, (len(cam), 2))
    obs = Observations(np.array(cam), np.array(pt), xy, X + rng.normal(0, 0.002, X.shape), np.ones(len(cam)))
    start = CameraState(truth.R, truth.C + rng.normal(0, 0.002, C.shape), truth.f * 1.01, truth.c)
    return obs, start, truth


@pytest.fixture
def known_principal_points(monkeypatch):
    """Principal points known to 0.1 % of the diagonal (a rig calibrated before): what the frames of
    a 70 degree arc then determine is every focal to better than 1 %."""
    import fixer4d.calib.adjust as A

    monkeypatch.setattr(A, "PRINCIPAL_POINT_SD_REL", 0.001)


def test_the_frames_alone_recover_each_focal_within_its_standard_error():
    obs, start, truth = _rig(70, [450, 450, 562.5, 450])
    fit = adjust(obs, start)
    assert fit.sigma_px == pytest.approx(0.5, rel=0.1)  # the pixel noise, per coordinate
    assert np.all(np.abs(fit.cameras.f - truth.f) < 3 * fit.focal_sd_px)
    assert np.all(fit.focal_sd_px > MAX_FOCAL_SD_REL * fit.cameras.f)  # the unknown principal points leave >1 %
    assert np.all(fit.mean_error_px < 1.0)


def test_known_principal_points_let_the_arc_determine_every_focal(known_principal_points):
    obs, start, truth = _rig(70, [450, 450, 562.5, 450])
    fit = adjust(obs, start)
    assert np.all(fit.focal_sd_px < MAX_FOCAL_SD_REL * fit.cameras.f)
    assert np.all(np.abs(fit.cameras.f - truth.f) < 3 * fit.focal_sd_px)


def test_cameras_that_all_face_the_same_way_do_not_determine_their_focals():
    obs, start, _ = _rig(0.5, [450] * 4)
    assert np.all(adjust(obs, start).focal_sd_px > 0.1 * 450)


def _weigh(arc_deg: float):
    """`--focal 450` for a rig whose third lens is 562.5 px (25 % longer), started where COLMAP
    left it (the prior held): (final fit, frames-only fit, verdicts, the gate's figures)."""
    obs, start, _ = _rig(arc_deg, [450, 450, 562.5, 450])
    start = CameraState(start.R, start.C, np.full(4, 450.0), start.c)
    final, free, verdicts = weigh_priors(obs, start, NAMES, parse_focal_priors(["450"], NAMES), MAX_FOCAL_SD_REL)
    figures = {n: {"focal_px": final.cameras.f[k], "focal_sd_px": final.focal_sd_px[k],
                   "rotation_sd_deg": final.rotation_sd_deg[k], "centre_sd_rel": final.centre_sd[k],
                   "frames_focal_px": free.cameras.f[k], "frames_focal_sd_px": free.focal_sd_px[k],
                   "prior": {"focal_px": 450.0, "sd_px": 4.5, "verdict": verdicts[n]}} for k, n in enumerate(NAMES)}
    return final, free, verdicts, figures


def test_frames_that_determine_a_focal_correct_the_prior_that_misstates_it(known_principal_points):
    final, free, verdicts, figures = _weigh(70)
    assert verdicts == {"cam0": "agrees", "cam1": "agrees", "cam2": "overruled by the frames", "cam3": "agrees"}
    assert abs(final.cameras.f[2] - 562.5) < 0.02 * 562.5
    assert undetermined(figures) == []


def test_frames_that_do_not_determine_a_focal_refuse_the_prior_they_contradict():
    final, free, verdicts, figures = _weigh(20)
    assert free.focal_sd_px[2] > MAX_FOCAL_SD_REL * free.cameras.f[2]
    assert verdicts["cam2"] == "contradicts the frames"
    named = [p for p in undetermined(figures) if p.startswith("camera cam2: the focal prior 450.0 +- 4.5 px contradicts")]
    assert len(named) == 1 and "which do not determine it either" in named[0]


def test_a_matching_prior_agrees_and_narrows_the_focal():
    obs, start, _ = _rig(70, [450] * 4)
    final, free, verdicts = weigh_priors(obs, start, NAMES, parse_focal_priors(["450"], NAMES), MAX_FOCAL_SD_REL)
    assert set(verdicts.values()) == {"agrees"}
    assert np.all(final.focal_sd_px < free.focal_sd_px)


def test_focal_prior_syntax():
    assert parse_focal_priors(["466", "cam2=515:2%", "cam3=520:4"], NAMES) == {
        "cam0": FocalPrior(466.0, 4.66), "cam1": FocalPrior(466.0, 4.66), "cam2": FocalPrior(515.0, 10.3),
        "cam3": FocalPrior(520.0, 4.0)}
    assert parse_focal_priors(["cam1=500"], NAMES) == {"cam1": FocalPrior(500.0, 5.0)}
    for bad, phrase in (("x", "expected"), ("-3", "positive"), ("cam9=500", "no camera 'cam9'"), ("500:0", "positive")):
        with pytest.raises(InputError, match=phrase):
            parse_focal_priors([bad], NAMES)


def test_a_static_corner_found_at_every_timestamp_counts_once():
    xy = np.array([[10.0, 10.0], [10.3, 10.2], [10.1, 9.9], [50.0, 50.0], [10.0, 10.0]])
    cam = np.array([0, 0, 0, 0, 1])
    np.testing.assert_allclose(repeat_weights(cam, xy), [1 / 3, 1 / 3, 1 / 3, 1.0, 1.0])
