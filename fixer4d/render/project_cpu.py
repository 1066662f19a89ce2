"""The projection of fixer4d/render/project.py as two fused numba loops, with a hand-written backward.

Same function as ``project.project_gaussians`` (EWA: 2D covariance J W R S (J W R S)^T + 0.3 I,
tangent clamp, stable LDL conic, near-plane and determinant culling, 3-sigma radii): the torch
version stays the readable reference and the oracle's projection; this one is what the ``cpu``
backend uses. Why: the torch version is ~100 small ops over (N,)/(N, 3)/(N, 3, 3) tensors, many
of them strided, plus their autograd graph; on the demo (60k Gaussians, 200x150) its forward +
backward cost more CPU per view than the rasterization kernels themselves (measured ~160 ms vs
~105 ms at load 6, one torch thread). Here one pass per Gaussian does the forward, one the
backward (chain rule written out below, as gsplat's fully_fused_projection does).

Arithmetic is in the inputs' dtype (float32 for the cpu backend, float64 in the gradient tests)
in the same operation order as the torch version, so outputs agree with it to round-off
(tests/render/test_project_cpu.py: values, radii and gradients against torch autograd).
"""
from __future__ import annotations

import numpy as np
import torch

from fixer4d.geometry.camera import Camera
from fixer4d.jit import NUMBA_ERROR, njit, prange, torch_threads_kept
from fixer4d.model.snapshot import Snapshot
from fixer4d.render.constants import DET_MIN, LOWPASS_2D, NEAR_PLANE, SIGMA_EXTENT, TAN_FOV_MARGIN
from fixer4d.render.project import RADIUS_MAX, T_ENTRY_MAX, Projection

# quaternions with a norm at or below this (or non-finite) map to the identity with zero
# gradient: the same rule as fixer4d.geometry.quaternion.to_matrix_torch
_ZERO_NORM = 1e-12
# The kernels' one input row (in the snapshot's dtype): w2c rotation (9, row-major),
# translation (3), fx, fy, cx, cy, the four tangent limits of the clamp (x+, x-, y+, y-), width,
# height, then every constant the arithmetic uses. Constants come in the row because numba
# would promote a float32 combined with a Python number to float64, while torch rounds the
# number to float32 first: typed constants keep the float32 arithmetic that of the torch version.
(_K_ONE, _K_TWO, _K_HALF, _K_ZERO, _K_NEAR, _K_DET_MIN, _K_LP, _K_LP2, _K_SIGMA, _K_T_MAX) = range(22, 32)
_CAM_N = 32


def _camera_row(camera: Camera, dtype: np.dtype) -> np.ndarray:
    """(_CAM_N,) the camera's numbers in ``dtype``, as the torch version rounds them."""
    w2c = np.asarray(camera.w2c, np.float64)
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    W, H = camera.width, camera.height
    tan_x, tan_y = 0.5 * W / fx, 0.5 * H / fy
    lims = [(W - cx) / fx + TAN_FOV_MARGIN * tan_x, cx / fx + TAN_FOV_MARGIN * tan_x,
            (H - cy) / fy + TAN_FOV_MARGIN * tan_y, cy / fy + TAN_FOV_MARGIN * tan_y]
    consts = [1.0, 2.0, 0.5, 0.0, NEAR_PLANE, DET_MIN, LOWPASS_2D, LOWPASS_2D * LOWPASS_2D, SIGMA_EXTENT,
              T_ENTRY_MAX]
    row = np.array([*w2c[:3, :3].reshape(-1), *w2c[:3, 3], fx, fy, cx, cy, *lims, W, H, *consts], dtype)
    assert row.shape == (_CAM_N,)
    return row


if njit is not None:

    @njit(cache=True, inline="always")
    def _rotmat(w, x, y, z, one, two):
        """Rotation matrix entries (row-major) of the normalized quaternion (w, x, y, z)."""
        return (one - two * (y * y + z * z), two * (x * y - w * z), two * (x * z + w * y),
                two * (x * y + w * z), one - two * (x * x + z * z), two * (y * z - w * x),
                two * (x * z - w * y), two * (y * z + w * x), one - two * (x * x + y * y))

    @njit(cache=True, inline="always")
    def _quat_unit(q, i, one, zero):
        """(w, x, y, z, norm, ok): q[i] normalized, or the identity when its norm is tiny or
        non-finite (ok False)."""
        w, x, y, z = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        norm = np.sqrt(w * w + x * x + y * y + z * z)
        if norm > _ZERO_NORM and np.isfinite(norm):
            return w / norm, x / norm, y / norm, z / norm, norm, True
        return one, zero, zero, zero, one, False

    @njit(cache=True, inline="always")
    def _t_rows(means, quats, scales, cam, i):
        """The shared front half of forward and backward for Gaussian i: camera-frame point,
        clamp state and the rows t0, t1 of T = J W R S. Returns a flat tuple (see callers)."""
        m0, m1, m2 = means[i, 0], means[i, 1], means[i, 2]
        x = m0 * cam[0] + m1 * cam[1] + m2 * cam[2] + cam[9]
        y = m0 * cam[3] + m1 * cam[4] + m2 * cam[5] + cam[10]
        z = m0 * cam[6] + m1 * cam[7] + m2 * cam[8] + cam[11]
        fx, fy, one = cam[12], cam[13], cam[_K_ONE]
        in_front = z > cam[_K_NEAR]
        zs = z if in_front else one
        iz = one / zs
        cxr, cyr = x * iz, y * iz
        ccx = min(max(cxr, -cam[17]), cam[16])
        ccy = min(max(cyr, -cam[19]), cam[18])
        tx, ty = zs * ccx, zs * ccy
        qw, qx, qy, qz, qn, qok = _quat_unit(quats, i, one, cam[_K_ZERO])
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rotmat(qw, qx, qy, qz, one, cam[_K_TWO])
        # W R (camera rotation times the Gaussian's), then times diag(s) column by column
        s0, s1, s2 = scales[i, 0], scales[i, 1], scales[i, 2]
        a00 = cam[0] * r00 + cam[1] * r10 + cam[2] * r20
        a01 = cam[0] * r01 + cam[1] * r11 + cam[2] * r21
        a02 = cam[0] * r02 + cam[1] * r12 + cam[2] * r22
        a10 = cam[3] * r00 + cam[4] * r10 + cam[5] * r20
        a11 = cam[3] * r01 + cam[4] * r11 + cam[5] * r21
        a12 = cam[3] * r02 + cam[4] * r12 + cam[5] * r22
        a20 = cam[6] * r00 + cam[7] * r10 + cam[8] * r20
        a21 = cam[6] * r01 + cam[7] * r11 + cam[8] * r21
        a22 = cam[6] * r02 + cam[7] * r12 + cam[8] * r22
        jx = -fx * tx * iz * iz
        jy = -fy * ty * iz * iz
        ax, ay = fx * iz, fy * iz
        t00 = ax * (a00 * s0) + jx * (a20 * s0)
        t01 = ax * (a01 * s1) + jx * (a21 * s1)
        t02 = ax * (a02 * s2) + jx * (a22 * s2)
        t10 = ay * (a10 * s0) + jy * (a20 * s0)
        t11 = ay * (a11 * s1) + jy * (a21 * s1)
        t12 = ay * (a12 * s2) + jy * (a22 * s2)
        return (x, y, z, in_front, iz, cxr, cyr, ccx, ccy, tx, ty, qw, qx, qy, qz, qn, qok,
                a00, a01, a02, a10, a11, a12, a20, a21, a22, jx, jy, ax, ay,
                t00, t01, t02, t10, t11, t12)

    @njit(cache=True, inline="always")
    def _cov2d(t00, t01, t02, t10, t11, t12, lp, lp2):
        """The low-passed 2D covariance [[ca, cb], [cb, cc]] = T T^T + lp I of the rows t0, t1,
        the cross product k = t0 x t1 and det = |k|^2 + lp (ca + cc) - lp^2 (= ca cc - cb^2,
        written without the cancellation that loses long thin splats in float32)."""
        ca = (t00 * t00 + t01 * t01 + t02 * t02) + lp
        cb = t00 * t10 + t01 * t11 + t02 * t12
        cc = (t10 * t10 + t11 * t11 + t12 * t12) + lp
        k0 = t01 * t12 - t02 * t11
        k1 = t02 * t10 - t00 * t12
        k2 = t00 * t11 - t01 * t10
        det = (k0 * k0 + k1 * k1 + k2 * k2) + lp * (ca + cc) - lp2
        return ca, cb, cc, k0, k1, k2, det

    @njit(cache=True, inline="always")
    def _tame(t00, t01, t02, t10, t11, t12, t_max):
        """Whether every entry of the rows t0, t1 is within t_max (False for NaN): the
        projection's cull rule of project.T_ENTRY_MAX."""
        return (abs(t00) <= t_max and abs(t01) <= t_max and abs(t02) <= t_max and abs(t10) <= t_max
                and abs(t11) <= t_max and abs(t12) <= t_max)

    @njit(cache=True, parallel=True)
    def _project_fwd(means, quats, scales, cam, means2d, conic, depths, radii):
        """Forward for N Gaussians: fills means2d (N, 2), conic (N, 3) LDL (a, r, q), depths
        (N,) and radii (N,) int32, exactly the quantities of project.project_gaussians."""
        lp, lp2, one, zero, half = cam[_K_LP], cam[_K_LP2], cam[_K_ONE], cam[_K_ZERO], cam[_K_HALF]
        for i in prange(means.shape[0]):
            (x, y, z, in_front, iz, cxr, cyr, ccx, ccy, tx, ty, qw, qx, qy, qz, qn, qok,
             a00, a01, a02, a10, a11, a12, a20, a21, a22, jx, jy, ax, ay,
             t00, t01, t02, t10, t11, t12) = _t_rows(means, quats, scales, cam, i)
            u = cam[12] * x * iz + cam[14]
            v = cam[13] * y * iz + cam[15]
            means2d[i, 0] = u
            means2d[i, 1] = v
            depths[i] = z
            tame = _tame(t00, t01, t02, t10, t11, t12, cam[_K_T_MAX])
            if not tame:  # zero rows, as the torch version: no inf/NaN in the radius below
                t00 = t01 = t02 = t10 = t11 = t12 = zero
            ca, cb, cc, k0, k1, k2, det = _cov2d(t00, t01, t02, t10, t11, t12, lp, lp2)
            ok = in_front and tame and det > cam[_K_DET_MIN] and np.isfinite(det)
            if ok:
                conic[i, 0] = cc / det
                conic[i, 1] = -cb / cc
                conic[i, 2] = one / cc
            else:
                conic[i, 0] = one
                conic[i, 1] = one
                conic[i, 2] = one
            mid = half * (ca + cc)
            lam = mid + np.sqrt(max(mid * mid - det, zero))
            radius = np.ceil(cam[_K_SIGMA] * np.sqrt(max(lam, zero)))
            on = (u + radius > zero) and (u - radius < cam[20]) and (v + radius > zero) and (v - radius < cam[21])
            keep = ok and on and np.isfinite(radius)
            radii[i] = np.int32(min(radius, RADIUS_MAX)) if keep else 0

    @njit(cache=True, parallel=True)
    def _project_bwd(means, quats, scales, cam, g_m2d, g_conic, g_depth, g_means, g_quats, g_scales):
        """Backward of _project_fwd: from dL/d(means2d, conic, depths) to dL/d(means, quats,
        scales). The chain rule of the forward, written out (r_* the camera rotation W):

        conic (a, r, q) = (cc / det, -cb / cc, 1 / cc) (zero gradient where culled)
        det = |t0 x t1|^2 + l (ca + cc) - l^2, ca = |t0|^2 + l, cb = t0.t1, cc = |t1|^2 + l
        t0 = (fx/z) A[0] S + jx A[2] S, t1 = (fy/z) A[1] S + jy A[2] S, A = W R(q), S = diag(s)
        jx = -fx tx / z^2, tx = z clamp(x/z) (the clamp passes gradient inside its limits)
        means2d = (fx x / z + cx, fy y / z + cy), (x, y, z) = W m + t, z -> 1 behind the near plane
        R(q) of q / |q| (zero gradient for tiny or non-finite |q|).
        """
        lp, lp2, one, two = cam[_K_LP], cam[_K_LP2], cam[_K_ONE], cam[_K_TWO]
        fx, fy = cam[12], cam[13]
        for i in prange(means.shape[0]):
            (x, y, z, in_front, iz, cxr, cyr, ccx, ccy, tx, ty, qw, qx, qy, qz, qn, qok,
             a00, a01, a02, a10, a11, a12, a20, a21, a22, jx, jy, ax, ay,
             t00, t01, t02, t10, t11, t12) = _t_rows(means, quats, scales, cam, i)
            s0, s1, s2 = scales[i, 0], scales[i, 1], scales[i, 2]
            zero = cam[_K_ZERO]
            tame = _tame(t00, t01, t02, t10, t11, t12, cam[_K_T_MAX])
            ca, cb, cc, k0, k1, k2, det = _cov2d(t00, t01, t02, t10, t11, t12, lp, lp2)
            ok = in_front and tame and det > cam[_K_DET_MIN] and np.isfinite(det)
            # conic -> (ca, cb, cc, det) -> t0, t1
            g00 = g01 = g02 = g10 = g11 = g12 = zero
            if ok:
                ga, gr, gq = g_conic[i, 0], g_conic[i, 1], g_conic[i, 2]
                icc = one / cc
                idet = one / det
                g_det = -ga * cc * idet * idet
                g_cc = ga * idet + gr * cb * icc * icc - gq * icc * icc + lp * g_det
                g_cb = -gr * icc
                g_ca = lp * g_det
                h0, h1, h2 = two * g_det * k0, two * g_det * k1, two * g_det * k2  # dL/d(t0 x t1)
                # d(g.(t0 x t1))/dt0 = t1 x g, /dt1 = g x t0
                g00 = two * g_ca * t00 + g_cb * t10 + (t11 * h2 - t12 * h1)
                g01 = two * g_ca * t01 + g_cb * t11 + (t12 * h0 - t10 * h2)
                g02 = two * g_ca * t02 + g_cb * t12 + (t10 * h1 - t11 * h0)
                g10 = two * g_cc * t10 + g_cb * t00 + (h1 * t02 - h2 * t01)
                g11 = two * g_cc * t11 + g_cb * t01 + (h2 * t00 - h0 * t02)
                g12 = two * g_cc * t12 + g_cb * t02 + (h0 * t01 - h1 * t00)
            # t0, t1 -> A S (per column k: m_jk = a_jk s_k), ax, ay, jx, jy
            m00, m01, m02 = a00 * s0, a01 * s1, a02 * s2
            m10, m11, m12 = a10 * s0, a11 * s1, a12 * s2
            m20, m21, m22 = a20 * s0, a21 * s1, a22 * s2
            g_ax = g00 * m00 + g01 * m01 + g02 * m02
            g_ay = g10 * m10 + g11 * m11 + g12 * m12
            g_jx = g00 * m20 + g01 * m21 + g02 * m22
            g_jy = g10 * m20 + g11 * m21 + g12 * m22
            gm00, gm01, gm02 = ax * g00, ax * g01, ax * g02
            gm10, gm11, gm12 = ay * g10, ay * g11, ay * g12
            gm20, gm21, gm22 = jx * g00 + jy * g10, jx * g01 + jy * g11, jx * g02 + jy * g12
            g_scales[i, 0] = gm00 * a00 + gm10 * a10 + gm20 * a20
            g_scales[i, 1] = gm01 * a01 + gm11 * a11 + gm21 * a21
            g_scales[i, 2] = gm02 * a02 + gm12 * a12 + gm22 * a22
            # dL/dA = dL/d(A S) S, then dL/dR = W^T dL/dA
            ga00, ga01, ga02 = gm00 * s0, gm01 * s1, gm02 * s2
            ga10, ga11, ga12 = gm10 * s0, gm11 * s1, gm12 * s2
            ga20, ga21, ga22 = gm20 * s0, gm21 * s1, gm22 * s2
            G00 = cam[0] * ga00 + cam[3] * ga10 + cam[6] * ga20
            G01 = cam[0] * ga01 + cam[3] * ga11 + cam[6] * ga21
            G02 = cam[0] * ga02 + cam[3] * ga12 + cam[6] * ga22
            G10 = cam[1] * ga00 + cam[4] * ga10 + cam[7] * ga20
            G11 = cam[1] * ga01 + cam[4] * ga11 + cam[7] * ga21
            G12 = cam[1] * ga02 + cam[4] * ga12 + cam[7] * ga22
            G20 = cam[2] * ga00 + cam[5] * ga10 + cam[8] * ga20
            G21 = cam[2] * ga01 + cam[5] * ga11 + cam[8] * ga21
            G22 = cam[2] * ga02 + cam[5] * ga12 + cam[8] * ga22
            if qok:
                gw = two * (-qz * G01 + qy * G02 + qz * G10 - qx * G12 - qy * G20 + qx * G21)
                gx = two * (qy * G01 + qz * G02 + qy * G10 - two * qx * G11 - qw * G12 + qz * G20 + qw * G21
                          - two * qx * G22)
                gy = two * (-two * qy * G00 + qx * G01 + qw * G02 + qx * G10 + qz * G12 - qw * G20 + qz * G21
                          - two * qy * G22)
                gz = two * (-two * qz * G00 - qw * G01 + qx * G02 + qw * G10 - two * qz * G11 + qy * G12 + qx * G20
                          + qy * G21)
                dot = qw * gw + qx * gx + qy * gy + qz * gz  # through q / |q|
                g_quats[i, 0] = (gw - qw * dot) / qn
                g_quats[i, 1] = (gx - qx * dot) / qn
                g_quats[i, 2] = (gy - qy * dot) / qn
                g_quats[i, 3] = (gz - qz * dot) / qn
            else:
                g_quats[i, 0] = zero
                g_quats[i, 1] = zero
                g_quats[i, 2] = zero
                g_quats[i, 3] = zero
            # ax = fx iz, ay = fy iz, jx = -fx tx iz^2, tx = zs clamp(x iz), means2d
            g_iz = fx * g_ax + fy * g_ay - two * fx * tx * iz * g_jx - two * fy * ty * iz * g_jy
            g_tx = -fx * iz * iz * g_jx
            g_ty = -fy * iz * iz * g_jy
            zs = z if in_front else one
            g_zs = ccx * g_tx + ccy * g_ty
            g_x = zero
            g_y = zero
            if -cam[17] <= cxr and cxr <= cam[16]:
                g_c = zs * g_tx
                g_x += iz * g_c
                g_iz += x * g_c
            if -cam[19] <= cyr and cyr <= cam[18]:
                g_c = zs * g_ty
                g_y += iz * g_c
                g_iz += y * g_c
            gu, gv = g_m2d[i, 0], g_m2d[i, 1]
            g_x += fx * iz * gu
            g_y += fy * iz * gv
            g_iz += fx * x * gu + fy * y * gv
            g_zs += -iz * iz * g_iz
            g_z = g_depth[i] + (g_zs if in_front else zero)
            # (x, y, z) = W m + t
            g_means[i, 0] = cam[0] * g_x + cam[3] * g_y + cam[6] * g_z
            g_means[i, 1] = cam[1] * g_x + cam[4] * g_y + cam[7] * g_z
            g_means[i, 2] = cam[2] * g_x + cam[5] * g_y + cam[8] * g_z


def unavailable_reason() -> str | None:
    """None when the numba projection can run, else why not."""
    return NUMBA_ERROR


def _np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().numpy())


class _ProjectCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, cam):
        m, q, s = _np(means), _np(quats), _np(scales)
        n, dt = m.shape[0], m.dtype
        means2d, conic = np.empty((n, 2), dt), np.empty((n, 3), dt)
        depths, radii = np.empty(n, dt), np.empty(n, np.int32)
        if n:
            with torch_threads_kept():
                _project_fwd(m, q, s, cam, means2d, conic, depths, radii)
        ctx.arrays = (m, q, s, cam)
        radii_t = torch.from_numpy(radii)
        ctx.mark_non_differentiable(radii_t)
        return torch.from_numpy(means2d), torch.from_numpy(conic), torch.from_numpy(depths), radii_t

    @staticmethod
    def backward(ctx, g_m2d, g_conic, g_depth, _g_radii):
        m, q, s, cam = ctx.arrays
        n, dt = m.shape[0], m.dtype

        def arr(g, shape):
            return np.zeros(shape, dt) if g is None else np.ascontiguousarray(g.detach().cpu().numpy().astype(dt))

        gm, gq, gs = np.zeros((n, 3), dt), np.zeros((n, 4), dt), np.zeros((n, 3), dt)
        if n:
            with torch_threads_kept():
                _project_bwd(m, q, s, cam, arr(g_m2d, (n, 2)), arr(g_conic, (n, 3)), arr(g_depth, (n,)),
                             gm, gq, gs)
        return torch.from_numpy(gm), torch.from_numpy(gq), torch.from_numpy(gs), None


def project_gaussians_cpu(snapshot: Snapshot, camera: Camera) -> Projection:
    """``project.project_gaussians`` computed by the numba loops above (CPU tensors, float32
    or float64, the snapshot's dtype); differentiable w.r.t. means, quats and scales through the
    hand-written backward. Opacities and colours pass through."""
    if NUMBA_ERROR is not None:
        from fixer4d.errors import BackendUnavailable

        raise BackendUnavailable(NUMBA_ERROR)
    dt = snapshot.means.dtype
    cam = _camera_row(camera, np.float32 if dt == torch.float32 else np.float64)
    means2d, conic, depths, radii = _ProjectCPU.apply(snapshot.means, snapshot.quats.to(dt),
                                                      snapshot.scales.to(dt), cam)
    return Projection(means2d=means2d, conic_ldl=conic, depths=depths, radii=radii,
                      opacities=snapshot.opacities, colors=snapshot.colors)
