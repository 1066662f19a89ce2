"""Bundle adjustment of a self-calibrated rig with per-camera focals, focal priors and the
covariance of the result: what the frames determine, camera by camera.

Each camera is a pinhole with focal f and principal point c (u = f x + c for x the normalised
image point; COLMAP's SIMPLE_PINHOLE) and a pose: a rotation increment w (radians,
R = R0 Exp(w), world-to-camera) and its centre C (world units). The adjustment fits every pose,
every focal (as g = log(f / f0), so that every parameter is of order one) and every point to the
observations (Huber loss beyond ``HUBER_PX``), plus one residual (f - f0) / sd per focal prior;
c stays as given (see ``adjust``).

The covariance is J^T J inverse at the solution, with the reprojection residuals whitened by
their own standard deviation (so it is scaled by the residual variance), points eliminated (Schur
complement) and the gauge fixed: the seven directions of a similarity transform of the whole rig
(rotation, translation, scale) change no residual, and the covariance is the one orthogonal to
them, i.e. of the rig relative to itself, as a similarity alignment to another rig compares it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

# Parameters per camera: w (3), C (3), g = log(f / f0), c (2, pixels).
CAMERA_PARAMS = 9
G, CX, CY = 6, 7, 8
# Matched keypoints reproject within ~1 px; beyond 2 px an observation counts linearly (a wrong
# match pooled from a moving object must not bend the rig).
HUBER_PX = 2.0
# Where the optical axis meets the image, as a standard deviation from the image centre (share of
# the image diagonal): lens mounting and sensor placement put it within about 1-2 % (the
# calibrated Panoptic HD cameras: 0.2-0.95 %). The frames of a few static views barely tell it
# from a rotation, so the adjustment holds it at the centre, and this uncertainty enters the
# covariance: the rotations' and focals' standard errors include what an unknown principal point
# leaves open (at 0.5 %, the XFeat-matched Panoptic rig passed with focals 2 % and a rotation
# 1.2 degrees off: three to four of its standard errors).
PRINCIPAL_POINT_SD_REL = 0.01
# Keypoints of one static feature found at different timestamps lie within about a pixel of each other.
REPEAT_RADIUS_PX = 1.0
# Levenberg-Marquardt iterations; started from COLMAP's solution it converges in a few.
MAX_ITERATIONS = 50


@dataclass
class Observations:
    """cam (M,) camera index, point (M,) point index, xy (M, 2) pixels (top-left pixel centre at
    (0.5, 0.5)); points (N, 3) initial world positions; weight (M,) how much of one independent
    measurement each observation is (``repeat_weights``)."""

    cam: np.ndarray
    point: np.ndarray
    xy: np.ndarray
    points: np.ndarray
    weight: np.ndarray


def repeat_weights(cam: np.ndarray, xy: np.ndarray, radius_px: float = REPEAT_RADIUS_PX) -> np.ndarray:
    """(M,) 1 / the number of observations of the same camera within ``radius_px`` of each one.

    Matches pooled over time repeat: a static corner is found at the same pixel at every
    timestamp and becomes one 3D point per timestamp, with the same localisation error each time.
    Counted T times, it would make the covariance T times too confident; weighed 1/T, it is one
    measurement."""
    from scipy.spatial import cKDTree

    w = np.ones(len(cam))
    for v in np.unique(cam):
        m = np.flatnonzero(cam == v)
        w[m] = 1.0 / np.asarray(cKDTree(xy[m]).query_ball_point(xy[m], radius_px, return_length=True), np.float64)
    return w


@dataclass
class CameraState:
    """Per camera: R (V, 3, 3) world-to-camera, C (V, 3) centres, f (V,) focal px, c (V, 2) principal point px."""

    R: np.ndarray
    C: np.ndarray
    f: np.ndarray
    c: np.ndarray


@dataclass
class Adjusted:
    """The adjusted cameras and points, the reprojection residual's standard deviation (px), the
    per-camera mean reprojection error (px) and standard errors: focal (px), rotation (degrees,
    the largest axis), centre (world units, the largest axis)."""

    cameras: CameraState
    points: np.ndarray
    sigma_px: float
    mean_error_px: np.ndarray
    focal_sd_px: np.ndarray
    rotation_sd_deg: np.ndarray
    centre_sd: np.ndarray


def project(R: np.ndarray, C: np.ndarray, f: np.ndarray, c: np.ndarray, cam: np.ndarray,
            X: np.ndarray) -> np.ndarray:
    """Pixels (M, 2) of world points X (M, 3) in cameras ``cam`` (M,) of a pinhole rig."""
    Xc = np.einsum("mij,mj->mi", R[cam], X - C[cam])
    return Xc[:, :2] / Xc[:, 2:3] * f[cam][:, None] + c[cam]


def _state(x_cams: np.ndarray, base: CameraState) -> tuple[np.ndarray, ...]:
    """(V, 9) camera parameters -> R (V, 3, 3), C (V, 3), f (V,), c (V, 2)."""
    R = base.R @ Rotation.from_rotvec(x_cams[:, :3]).as_matrix()
    return R, x_cams[:, 3:6], base.f * np.exp(x_cams[:, G]), x_cams[:, CX:CY + 1]


def _reprojection(x_cams: np.ndarray, X: np.ndarray, obs: Observations, base: CameraState) -> np.ndarray:
    """(M, 2) reprojection residuals in pixels."""
    R, C, f, c = _state(x_cams, base)
    return project(R, C, f, c, obs.cam, X[obs.point]) - obs.xy


def _jacobians(x_cams: np.ndarray, X: np.ndarray, obs: Observations, base: CameraState) -> tuple[np.ndarray, np.ndarray]:
    """Central differences: (M, 2, 9) d residual / d its camera's parameters, (M, 2, 3) d residual
    / d its point. Every residual depends on one camera and one point, so perturbing a parameter of
    all cameras (or all points) at once gives one column per observation."""
    eps = 1e-6
    Jc = np.empty((len(obs.cam), 2, CAMERA_PARAMS))
    Jp = np.empty((len(obs.cam), 2, 3))
    for k in range(CAMERA_PARAMS):
        d = np.zeros_like(x_cams)
        d[:, k] = eps
        Jc[:, :, k] = (_reprojection(x_cams + d, X, obs, base) - _reprojection(x_cams - d, X, obs, base)) / (2 * eps)
    for k in range(3):
        d = np.zeros_like(X)
        d[:, k] = eps
        Jp[:, :, k] = (_reprojection(x_cams, X + d, obs, base) - _reprojection(x_cams, X - d, obs, base)) / (2 * eps)
    return Jc, Jp


def _normal_equations(Jc, Jp, r, w, obs: Observations, V: int, N: int):
    """Weighted normal equations in blocks: U (P, P), W (P, N, 3), Vp (N, 3, 3), gradients bc (P,)
    and bp (N, 3) (of 0.5 * sum w |r|^2), for P = V * 9 camera parameters."""
    P = V * CAMERA_PARAMS
    wr = w[:, None] * r
    U = np.zeros((V, CAMERA_PARAMS, V, CAMERA_PARAMS))
    bc = np.zeros((V, CAMERA_PARAMS))
    for v in range(V):
        m = obs.cam == v
        U[v, :, v] = np.einsum("mi,mia,mib->ab", np.broadcast_to(w[m, None], (m.sum(), 2)), Jc[m], Jc[m])
        bc[v] = np.einsum("mi,mia->a", wr[m], Jc[m])
    Vp = np.zeros((N, 3, 3))
    np.add.at(Vp, obs.point, np.einsum("m,mia,mib->mab", w, Jp, Jp))
    bp = np.zeros((N, 3))
    np.add.at(bp, obs.point, np.einsum("mi,mia->ma", wr, Jp))
    W = np.zeros((V, CAMERA_PARAMS, N, 3))
    np.add.at(W, (obs.cam, slice(None), obs.point), np.einsum("m,mia,mib->mab", w, Jc, Jp))
    # np.add.at with a slice in the middle puts the advanced-index axis first: (M, 9, 3) rows
    return U.reshape(P, P), W.reshape(P, N, 3), Vp, bc.ravel(), bp


def _schur(U, W, Vp, damping: float = 0.0):
    """(S, Vinv): the camera block of the normal equations with the points eliminated."""
    Vd = Vp + damping * np.eye(3) * np.trace(Vp, axis1=1, axis2=2)[:, None, None] / 3
    Vinv = np.linalg.pinv(Vd, hermitian=True)  # a point seen along one ray only has a singular block
    return U - np.einsum("pnj,njk,qnk->pq", W, Vinv, W), Vinv


def _gauge(C: np.ndarray) -> np.ndarray:
    """(V*9, 7) the camera-parameter directions of an infinitesimal similarity of the world:
    rotation by omega (w -> w - omega, C -> C + omega x C), translation, scale (C -> C (1 + s))."""
    V = len(C)
    basis = np.zeros((V * CAMERA_PARAMS, 7))
    for v in range(V):
        o = v * CAMERA_PARAMS
        for k in range(3):
            e = np.eye(3)[k]
            basis[o:o + 3, k] = -e
            basis[o + 3:o + 6, k] = np.cross(e, C[v])
            basis[o + 3:o + 6, 3 + k] = e
        basis[o + 3:o + 6, 6] = C[v]
    return basis


def _hold(S: np.ndarray, index: np.ndarray) -> None:
    """Make the parameters ``index`` of the normal equations S (in place) constants: no step."""
    S[index, :] = 0.0
    S[:, index] = 0.0
    S[index, index] = 1.0


def camera_covariance(S: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(V*9, V*9) covariance of the camera parameters from the (whitened) Schur complement S,
    gauge fixed: the inverse on the complement of the similarity directions (``_gauge``)."""
    Q, _ = np.linalg.qr(_gauge(C), mode="complete")
    Qf = Q[:, 7:]
    return Qf @ np.linalg.pinv(Qf.T @ S @ Qf, hermitian=True) @ Qf.T


def _priors_terms(x_cams, base: CameraState, priors, prior_sd) -> tuple[np.ndarray, np.ndarray]:
    """Prior residuals on single parameters, (V, 9) each (0 where none), and their derivative in
    that parameter: (f - f0) / sd for the focal priors (in g = log f), (c - centre) / sd for the
    principal point (``PRINCIPAL_POINT_SD_REL`` of the image diagonal, about the image centre)."""
    r = np.zeros_like(x_cams)
    d = np.zeros_like(x_cams)
    has = np.isfinite(priors)
    f = base.f * np.exp(x_cams[:, G])
    r[:, G] = np.where(has, (f - np.where(has, priors, 0.0)) / prior_sd, 0.0)
    d[:, G] = np.where(has, f / prior_sd, 0.0)
    pp_sd = PRINCIPAL_POINT_SD_REL * 2 * np.linalg.norm(base.c, axis=1, keepdims=True)
    r[:, CX:CY + 1] = (x_cams[:, CX:CY + 1] - base.c) / pp_sd
    d[:, CX:CY + 1] = 1.0 / pp_sd
    return r, d


def _cost(x_cams, X, obs, base, sigma, priors, prior_sd) -> float:
    e = np.linalg.norm(_reprojection(x_cams, X, obs, base), axis=1) / sigma
    huber = HUBER_PX / sigma
    rho = np.where(e <= huber, e * e, 2 * huber * e - huber * huber)
    return float(np.sum(obs.weight * rho) + np.sum(_priors_terms(x_cams, base, priors, prior_sd)[0] ** 2))


def adjust(obs: Observations, cams: CameraState, priors: np.ndarray | None = None,
           prior_sd: np.ndarray | None = None, sigma_px: float | None = None) -> Adjusted:
    """Refine every camera's pose and focal and every point (Levenberg-Marquardt on the
    points-eliminated normal equations); the principal points stay as ``cams`` has them (a few
    static views barely tell one from a rotation: freed, it bends the poses of a rig that cannot
    fix it). The covariance of the cameras includes the principal points' uncertainty
    (``PRINCIPAL_POINT_SD_REL``).

    priors / prior_sd: (V,) focal priors and their standard deviations in pixels (NaN: none).
    sigma_px: the reprojection noise (px) the priors are weighed against; None: estimated from
    this fit's residuals (the frames alone). A camera whose focal the frames and priors do not
    determine comes back with a large ``focal_sd_px``.
    """
    V, N = len(cams.f), len(obs.points)
    priors = np.full(V, np.nan) if priors is None else np.asarray(priors, np.float64)
    prior_sd = np.ones(V) if prior_sd is None else np.asarray(prior_sd, np.float64)
    sigma = 1.0 if sigma_px is None else float(sigma_px)
    xc = np.column_stack([np.zeros((V, 3)), cams.C, np.zeros(V), cams.c])
    X = obs.points.copy()
    cost = _cost(xc, X, obs, cams, sigma, priors, prior_sd)
    lam = 1e-3
    held = (np.arange(V)[:, None] * CAMERA_PARAMS + np.array([CX, CY])).ravel()
    for _ in range(MAX_ITERATIONS):
        S, W, Vinv, bc, bp = _system(xc, X, obs, cams, sigma, priors, prior_sd, lam)
        rhs = bc - np.einsum("pnj,njk,nk->p", W, Vinv, bp)
        _hold(S, held)
        rhs[held] = 0.0
        dc = -np.linalg.solve(S, rhs)
        dp = -np.einsum("njk,nk->nj", Vinv, bp + np.einsum("pnj,p->nj", W, dc))
        xn, Xn = xc + dc.reshape(V, CAMERA_PARAMS), X + dp
        new = _cost(xn, Xn, obs, cams, sigma, priors, prior_sd)
        if new < cost:
            converged = cost - new < 1e-9 * cost
            xc, X, cost, lam = xn, Xn, new, max(lam / 10, 1e-9)
            if converged:
                break
        else:
            lam *= 10
            if lam > 1e8:
                break
    r = _reprojection(xc, X, obs, cams)
    err = np.linalg.norm(r, axis=1)
    if sigma_px is None:
        inliers = err < HUBER_PX
        # per coordinate, over the independent measurements (weights), less the parameters fitted
        dof = max(2 * float(obs.weight[inliers].sum()) - (V * CAMERA_PARAMS + 3 * N - 7) * float(obs.weight.mean()), 1.0)
        sigma_px = max(float(np.sqrt(np.sum(obs.weight[inliers] * err[inliers] ** 2) / dof)), 1e-6)
    S = _system(xc, X, obs, cams, sigma_px, priors, prior_sd, 0.0)[0]
    R, C, f, c = _state(xc, cams)
    cov = camera_covariance(S, C)
    blocks = [cov[v * CAMERA_PARAMS:(v + 1) * CAMERA_PARAMS, v * CAMERA_PARAMS:(v + 1) * CAMERA_PARAMS]
              for v in range(V)]
    rot = np.array([np.sqrt(max(np.linalg.eigvalsh(b[:3, :3]).max(), 0.0)) for b in blocks])
    cen = np.array([np.sqrt(max(np.linalg.eigvalsh(b[3:6, 3:6]).max(), 0.0)) for b in blocks])
    focal_sd = f * np.sqrt(np.array([max(b[G, G], 0.0) for b in blocks]))
    mean_err = np.array([float(err[obs.cam == v].mean()) if np.any(obs.cam == v) else np.nan for v in range(V)])
    return Adjusted(CameraState(R, C, f, c), X, float(sigma_px), mean_err, focal_sd, np.degrees(rot), cen)


def _system(xc, X, obs, base, sigma, priors, prior_sd, lam):
    """The damped, whitened, Huber-weighted normal equations with the points eliminated:
    (S, W, Vinv, bc, bp) (see ``_normal_equations``)."""
    V, N = len(base.f), len(X)
    r = _reprojection(xc, X, obs, base) / sigma
    e = np.linalg.norm(r, axis=1)
    huber = HUBER_PX / sigma
    w = np.where(e <= huber, 1.0, huber / np.maximum(e, 1e-12))
    Jc, Jp = _jacobians(xc, X, obs, base)
    U, W, Vp, bc, bp = _normal_equations(Jc / sigma, Jp / sigma, r, w * obs.weight, obs, V, N)
    pr, dpr = _priors_terms(xc, base, priors, prior_sd)
    U[np.diag_indices_from(U)] += dpr.ravel() ** 2
    bc += (dpr * pr).ravel()
    U = U + lam * np.diag(np.diag(U))
    S, Vinv = _schur(U, W, Vp, lam)
    return S, W, Vinv, bc, bp
