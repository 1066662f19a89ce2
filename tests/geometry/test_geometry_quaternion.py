"""Quaternions: safe normalize, matrix round trips, SLERP at its hard cases."""
from __future__ import annotations

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from fixer4d.geometry import quaternion as quat

comp = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
quats = st.tuples(comp, comp, comp, comp).map(np.array)
unit_quats = quats.filter(lambda q: np.linalg.norm(q) > 1e-3).map(lambda q: q / np.linalg.norm(q))
alphas = st.floats(0.0, 1.0)


def same_rotation(a: np.ndarray, b: np.ndarray, atol: float = 1e-9) -> bool:
    return bool(np.allclose(a, b, atol=atol) or np.allclose(a, -b, atol=atol))


def test_normalize_zero_and_nonfinite_to_identity():
    q = quat.normalize(np.array([[0.0, 0, 0, 0], [np.inf, 0, 0, 0], [np.nan, 1, 0, 0], [0, 0, 2, 0]]))
    np.testing.assert_array_equal(q[:3], np.tile([1.0, 0, 0, 0], (3, 1)))
    np.testing.assert_array_equal(q[3], [0, 0, 1.0, 0])
    np.testing.assert_array_equal(quat.to_matrix(np.zeros(4)), np.eye(3))


@settings(max_examples=200, deadline=None)
@given(q=unit_quats)
def test_matrix_round_trip(q):
    R = quat.to_matrix(q)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) > 0.999999
    back = quat.from_matrix(R)
    assert back[0] >= 0.0
    assert same_rotation(back, q, atol=1e-9)
    np.testing.assert_allclose(quat.to_matrix(back), R, atol=1e-12)


def test_from_matrix_half_turns_and_batches():
    half_turns = [np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])]
    q = quat.from_matrix(np.stack(half_turns))
    assert q.shape == (3, 4)
    np.testing.assert_allclose(np.abs(q), np.eye(4)[1:], atol=1e-15)
    np.testing.assert_allclose(quat.to_matrix(q), np.stack(half_turns), atol=1e-15)


@settings(max_examples=100, deadline=None)
@given(a=unit_quats, b=unit_quats)
def test_multiply_composes_rotations(a, b):
    np.testing.assert_allclose(quat.to_matrix(quat.multiply(a, b)), quat.to_matrix(a) @ quat.to_matrix(b), atol=1e-10)


@settings(max_examples=200, deadline=None)
@given(q0=quats, q1=quats, a=st.lists(alphas, min_size=1, max_size=8))
def test_slerp_endpoints_exact_unit_and_finite(q0, q1, a):
    a = np.array([0.0, *a, 1.0])
    out = quat.slerp(q0, q1, a)
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-12)
    n0, n1 = quat.normalize(q0), quat.normalize(q1)
    np.testing.assert_array_equal(out[0], n0)  # bit-exact
    assert np.array_equal(out[-1], n1) or np.array_equal(out[-1], -n1)  # bit-exact up to the short-arc sign
    np.testing.assert_array_equal(quat.slerp(q0, q1, 0.0), n0)


@settings(max_examples=100, deadline=None)
@given(q0=unit_quats, q1=unit_quats, a=alphas, b=alphas)
def test_slerp_constant_angular_speed_along_the_short_arc(q0, q1, a, b):
    total = float(quat.angle_between(q0, q1))
    assume(total > 1e-3)
    qa, qb = quat.slerp(q0, q1, np.array([a, b]))
    np.testing.assert_allclose(quat.angle_between(qa, qb), abs(a - b) * total, atol=1e-7)
    assert total <= np.pi + 1e-12  # shorter arc: never more than a half turn


@settings(max_examples=100, deadline=None)
@given(q=unit_quats, a=alphas, eps=st.sampled_from([0.0, 1e-15, 1e-12, 1e-9, 1e-6]))
def test_slerp_identical_nearly_identical_and_antipodal(q, a, eps):
    near = quat.normalize(q + eps * np.array([0.3, -0.1, 0.7, 0.2]))
    out = quat.slerp(q, near, a)
    assert np.all(np.isfinite(out)) and abs(np.linalg.norm(out) - 1.0) < 1e-12
    assert float(quat.angle_between(out, q)) <= float(quat.angle_between(near, q)) + 1e-7
    anti = quat.slerp(q, -q, a)  # the same rotation: the path stays on it
    assert same_rotation(anti, q, atol=1e-12)


def test_slerp_zero_quaternion_is_identity():
    out = quat.slerp(np.zeros(4), np.array([0.0, 0, 0, 1]), np.linspace(0, 1, 5))
    np.testing.assert_array_equal(out[0], [1.0, 0, 0, 0])
    np.testing.assert_allclose(out[2], [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)], atol=1e-12)
    assert np.all(np.isfinite(out))


def test_torch_matrix_matches_numpy_and_keeps_batch_shape():
    import torch

    q = np.random.default_rng(3).normal(size=(2, 5, 4))
    q[0, 0] = 0.0
    q[1, 1] = [np.inf, 0, 0, 0]
    ours = quat.to_matrix_torch(torch.tensor(q))
    assert ours.shape == (2, 5, 3, 3) and ours.dtype == torch.float64
    np.testing.assert_allclose(ours.numpy(), quat.to_matrix(q), atol=1e-12)
    np.testing.assert_array_equal(ours[0, 0].numpy(), np.eye(3))
    np.testing.assert_array_equal(ours[1, 1].numpy(), np.eye(3))


def test_torch_matrix_zero_quaternion_has_a_finite_gradient():
    import torch

    q = torch.tensor([[0.0, 0.0, 0.0, 0.0], [0.3, -1.0, 2.0, 0.5]], dtype=torch.float64, requires_grad=True)
    (quat.to_matrix_torch(q) * torch.arange(9.0, dtype=torch.float64).reshape(3, 3)).sum().backward()
    assert torch.isfinite(q.grad).all()
    assert torch.equal(q.grad[0], torch.zeros(4, dtype=torch.float64))
    assert q.grad[1].abs().sum() > 0


def test_renderer_and_densify_use_the_one_torch_implementation():
    from fixer4d.model import densify
    from fixer4d.render import project

    assert project.quat_to_rotmat is quat.to_matrix_torch
    assert densify.quat_to_matrix is quat.to_matrix_torch
