"""The per-camera colour response: gains measured from co-visible points, the evidence decision,
and the torch module's gauge (the rig's mean response is the identity)."""
from __future__ import annotations

import numpy as np
import torch

from fixer4d.model.camera_response import MIN_LOG_GAIN, CameraResponse, decide, view_gains


def _samples(gains: np.ndarray, noise: float, n: int = 4000, seed: int = 0):
    """(V, N, 3) colours of N grey-world points seen by every view through per-view gains."""
    rng = np.random.default_rng(seed)
    albedo = rng.uniform(0.1, 0.9, (n, 3))
    colors = gains[:, None, :] * albedo[None] + rng.normal(0, noise, (len(gains), n, 3))
    visible = rng.random((len(gains), n)) < 0.8
    return colors, visible


def test_gains_are_recovered_up_to_the_rig_mean():
    true = np.array([[1.08, 1.02, 0.95], [1.0, 1.0, 1.0], [0.93, 0.97, 1.04], [1.0, 1.01, 1.0]])
    log_gain, stderr, points = view_gains(*_samples(true, noise=0.01))
    expect = np.log(true) - np.log(true).mean(0)
    np.testing.assert_allclose(log_gain, expect, atol=0.005)
    assert (stderr < 0.002).all() and (points > 1000).all()


def test_identical_cameras_stay_off_and_different_ones_turn_it_on():
    same = view_gains(*_samples(np.ones((4, 3)), noise=0.02))
    on, reason = decide(same[0], same[1])
    assert not on and "0 of 4 cameras" in reason
    diff = view_gains(*_samples(np.array([[1.1, 1.1, 1.1], [1, 1, 1], [1, 1, 1], [1, 1, 1]]), noise=0.02))
    on, reason = decide(diff[0], diff[1])
    assert on
    assert decide(diff[0], diff[1], forced=False)[0] is False
    assert decide(same[0], same[1], forced=True)[0] is True


def test_noise_alone_does_not_turn_it_on():
    """Few points with much noise: a gain near MIN_LOG_GAIN is not trusted."""
    g = np.exp(np.array([[MIN_LOG_GAIN * 1.5] * 3, [0] * 3, [0] * 3, [0] * 3]))
    log_gain, stderr, _ = view_gains(*_samples(g, noise=0.2, n=120, seed=3))
    assert not decide(log_gain, stderr)[0]


def test_a_view_without_enough_points_is_not_measured():
    colors, visible = _samples(np.ones((3, 3)), noise=0.01, n=500)
    visible[2] = False
    visible[2, :10] = True
    log_gain, stderr, _ = view_gains(colors, visible)
    assert np.isinf(stderr[2]).all() and (log_gain[2] == 0).all()


def test_the_module_keeps_the_rig_mean_and_pulls_toward_identity():
    resp = CameraResponse(4)
    with torch.no_grad():
        resp.log_gain.copy_(torch.tensor([[0.2] * 3, [0.0] * 3, [0.0] * 3, [0.0] * 3]))
        resp.bias.copy_(torch.tensor([[0.1] * 3, [0.1] * 3, [0.1] * 3, [0.1] * 3]))
    gain, bias = resp.gains_biases()
    torch.testing.assert_close(torch.log(gain).mean(0), torch.zeros(3))
    torch.testing.assert_close(bias, torch.zeros(4, 3))  # a common offset is the model's colour, not a response
    rgb = torch.full((2, 2, 3), 0.5)
    assert torch.allclose(resp.apply(rgb, 0), 0.5 * gain[0])
    assert float(resp.regularizer().detach()) > 0
    assert CameraResponse(3).regularizer() == 0
    assert len(resp.summary()) == 4


def test_json_round_trip():
    resp = CameraResponse(3)
    with torch.no_grad():
        resp.log_gain.normal_()
        resp.bias.normal_()
    back = CameraResponse.from_json(resp.to_json())
    for a, b in zip(resp.gains_biases(), back.gains_biases()):
        torch.testing.assert_close(a, b)


def test_no_measurement_means_off_unless_forced():
    empty = np.zeros((0, 3))
    assert decide(empty, empty) == (False, "no per-camera colour measurement (an init without a static cloud)")
    assert decide(empty, empty, forced=True)[0] is True


def test_the_report_says_whether_and_why():
    from fixer4d.pipeline.report import camera_response_line

    resp = CameraResponse(2)
    on = camera_response_line({"reasons": {"camera_response": "largest ... 5.0%"}, "camera_response": resp.to_json()})
    assert on.startswith("Camera response: on (largest ... 5.0%)") and "1.000/1.000/1.000" in on
    off = camera_response_line({"reasons": {"camera_response": "largest ... 0.1%"}})
    assert off == "Camera response: off (largest ... 0.1%)."
