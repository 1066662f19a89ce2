"""Projection of 3D Gaussians to image-space splats (EWA splatting, as in 3DGS/gsplat).

Everything here is differentiable torch shared by every CPU backend: the oracle and the fast
kernel rasterize the same projected splats, and gradients reach means/quats/scales through
autograd of this module.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from fixer4d.geometry.camera import Camera
# The one torch quaternion->matrix (normalizes; zero -> identity); the name stays for callers.
from fixer4d.geometry.quaternion import to_matrix_torch as quat_to_rotmat
from fixer4d.model.snapshot import Snapshot
from fixer4d.render.constants import DET_MIN, LOWPASS_2D, NEAR_PLANE, SIGMA_EXTENT, TAN_FOV_MARGIN

# Largest stored radius (pixels), far below int32 overflow.
RADIUS_MAX = float(2 ** 30)
# Largest |entry| of the rows t0, t1 of T = J W R S (pixels per world unit of the scaled axes) of
# a splat that is drawn; larger ones are culled, by every backend and in every dtype (one rule).
# Radius <= 3 sqrt(|t0|^2 + |t1|^2 + 2 l) <= 7.4 T_ENTRY_MAX < RADIUS_MAX, and det <= 3 (2
# T_ENTRY_MAX^2)^2 ~ 4e33 stays far below float32's 3.4e38, so the float32 projection never
# overflows where the float64 one would not. Such a splat (radius > 1e8 px) needs a Gaussian
# thousands of scene units wide in front of the camera: none in a unit-order scene.
T_ENTRY_MAX = RADIUS_MAX / 8.0
# World-space bounds of a drawable Gaussian (see ``guard_extremes``). Scenes are normalised to
# unit order; 1e18 is far beyond any of them yet keeps fx x / z, z^2 and their gradients finite
# in float32.
MEAN_LIMIT = 1e18
SCALE_LIMIT = 1e18
# Quaternions with a component above this are divided by their largest |component| before
# projection: their squared norm would overflow float32 (at ~1.8e19) and the rotation would
# fall back to the identity in float32 but not in float64. The rotation is unchanged.
QUAT_RESCALE_ABOVE = 1e15
# Colours are clamped to +-COLOR_LIMIT: they are in [0, 1] (view-dependent colour overshoots
# a little); a colour this large is a diverged Gaussian, and the bound keeps sums of weighted
# colours and their gradients finite in float32.
COLOR_LIMIT = 1e4


def _peak(low: float, high: float) -> float:
    """The largest |value| of a field from its (min, max); NaN when either is NaN."""
    return math.nan if math.isnan(low) or math.isnan(high) else max(-low, high)


def guard_extremes(snapshot: Snapshot, camera: Camera,
                   ranges: dict[str, tuple[float, float]] | None = None) -> Snapshot:
    """``snapshot`` made safe to project in float32, unchanged (the same object) when no value is
    extreme. Gaussians with |mean| > MEAN_LIMIT or |scale| > SCALE_LIMIT are culled (mean moved
    to the camera centre, behind the near plane; zero gradient); quaternions with a component
    above QUAT_RESCALE_ABOVE are rescaled (same rotation); colours are clamped to +-COLOR_LIMIT
    (zero gradient beyond). Runs in the snapshot's dtype, before any cast to float32, so float32
    and float64 renders cull the same Gaussians. ranges: ``snapshot.ranges()`` where the caller
    has it (else read here)."""
    if len(snapshot) == 0:
        return snapshot
    ranges = snapshot.ranges() if ranges is None else ranges
    peaks = [_peak(*ranges[name]) for name in ("means", "scales", "quats", "colors")]
    if (peaks[0] <= MEAN_LIMIT and peaks[1] <= SCALE_LIMIT and peaks[2] <= QUAT_RESCALE_ABOVE
            and peaks[3] <= COLOR_LIMIT):
        return snapshot
    means, scales, quats, colors = snapshot.means, snapshot.scales, snapshot.quats, snapshot.colors
    with torch.no_grad():
        far = (means.detach().abs().amax(-1) > MEAN_LIMIT) | (scales.detach().abs().amax(-1) > SCALE_LIMIT)
    if bool(far.any()):
        centre = torch.as_tensor(camera.center, dtype=means.dtype, device=means.device).expand_as(means)
        means = torch.where(far[:, None], centre, means)
        scales = torch.where(far[:, None], torch.ones_like(scales), scales)
    if peaks[2] > QUAT_RESCALE_ABOVE:
        with torch.no_grad():
            top = quats.detach().abs().amax(-1, keepdim=True)
            big = top > QUAT_RESCALE_ABOVE
            divisor = torch.where(big, top, torch.ones_like(top))
        quats = quats / divisor
    if peaks[3] > COLOR_LIMIT:
        colors = colors.clamp(-COLOR_LIMIT, COLOR_LIMIT)
    return Snapshot(means=means, quats=quats, scales=scales, opacities=snapshot.opacities, colors=colors)


def guard_extremes_traced(snapshot: Snapshot) -> Snapshot:
    """``guard_extremes`` for a GPU's hot path and several cameras at once: the same bounds,
    applied to every Gaussian by elementwise selects instead of after reading the peaks back, so
    the host does not wait for the device. A Gaussian beyond MEAN_LIMIT or SCALE_LIMIT is made
    invisible where no camera can be in its way (at the origin, unit scales, opacity 0) rather
    than moved behind one camera; values within the bounds pass unchanged, bit for bit."""
    means, scales, quats = snapshot.means, snapshot.scales, snapshot.quats
    with torch.no_grad():
        far = ((means.detach().abs().amax(-1) > MEAN_LIMIT) | (scales.detach().abs().amax(-1) > SCALE_LIMIT))
        top = quats.detach().abs().amax(-1, keepdim=True)
        divisor = torch.where(top > QUAT_RESCALE_ABOVE, top, torch.ones_like(top))
    return Snapshot(means=torch.where(far[:, None], torch.zeros_like(means), means), quats=quats / divisor,
                    scales=torch.where(far[:, None], torch.ones_like(scales), scales),
                    opacities=torch.where(far, torch.zeros_like(snapshot.opacities), snapshot.opacities),
                    colors=snapshot.colors.clamp(-COLOR_LIMIT, COLOR_LIMIT))


@dataclass
class Projection:
    """N projected splats in one camera.

    means2d: (N, 2) pixel coordinates of the projected means (pixel (i, j) centre = (i+.5, j+.5)).
    conic_ldl: (N, 3) the inverse 2D covariance in LDL form (a, r, q): the exponent at pixel
        offset (dx, dy) from the mean is power = 0.5 (a (dx + r dy)^2 + q dy^2), i.e. the conic
        [[a, a r], [a r, a r^2 + q]]; a, q in pixels^-2, r unitless. Every rasterizer evaluates
        this form (see ``stable_conic``): unlike (a, b, c) it keeps long thin splats in float32.
    depths: (N,) camera-frame z of the means (world units).
    radii: (N,) int32 pixel radius of the 3-sigma extent; 0 = culled (behind the near plane,
        degenerate covariance, an entry of T above T_ENTRY_MAX, or off-screen). Not differentiable.
    opacities: (N,) and colors: (N, 3): the snapshot's, passed through.
    """

    means2d: torch.Tensor
    conic_ldl: torch.Tensor
    depths: torch.Tensor
    radii: torch.Tensor
    opacities: torch.Tensor
    colors: torch.Tensor

    @property
    def conics(self) -> torch.Tensor:
        """(N, 3) the conic as (a, b, c) = [[a, b], [b, c]] (pixels^-2), for display and probes;
        in float32 it loses the long axis of thin splats, so no rasterizer uses it."""
        a, r, q = self.conic_ldl.unbind(-1)
        return torch.stack([a, a * r, a * r * r + q], -1)


def stable_conic(t0: torch.Tensor, t1: torch.Tensor, lowpass: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(conic_ldl (N, 3), det (N,)) of the 2D covariance [[|t0|^2 + l, t0.t1], [t0.t1, |t1|^2 + l]].

    t0, t1: (N, 3) rows of T = J W R S (pixels per unit of the Gaussian's scaled axes); l: the
    low-pass (pixels^2). Written to stay accurate in float32 for splats whose long axis projects
    to thousands of pixels, where the textbook form fails: det = ca cc - cb^2 cancels (two
    terms ~L^4 for a result ~0.3 L^2, so it goes negative and the splat is culled), and the
    conic (a, b, c) = (cc, -cb, ca) / det has condition number ~L^2 / 0.3, beyond float32's
    1/eps ~ 1.7e7 once L is a few hundred pixels, so 0.5 (a dx^2 + c dy^2) + b dx dy along the
    long axis is mostly round-off (the splat deforms). Instead:

    * det by Lagrange's identity, a sum of non-negative terms (no cancellation):
      det = |t0 x t1|^2 + l (|t0|^2 + |t1|^2) + l^2.
    * the conic in LDL form around cc (>= l > 0): with a = cc / det, r = -cb / cc, q = 1 / cc,
      power = 0.5 (a (dx + r dy)^2 + q dy^2). Each of a, r, q has a relative error of a few
      ulp, and power's sensitivity to them is bounded by the pixel offsets themselves, so the
      error along the long axis is ~eps * extent (1e-3 px at 10^4 px), not eps * L^2.
    """
    ca = (t0 * t0).sum(-1) + lowpass
    cb = (t0 * t1).sum(-1)
    cc = (t1 * t1).sum(-1) + lowpass
    cross = torch.linalg.cross(t0, t1, dim=-1)
    det = (cross * cross).sum(-1) + lowpass * (ca + cc) - lowpass * lowpass
    return torch.stack([cc / det, -cb / cc, 1.0 / cc], -1), det


def project_gaussians(snapshot: Snapshot, camera: Camera) -> Projection:
    """Project a snapshot's Gaussians into ``camera`` (computed in the snapshot's dtype/device).

    2D covariance = J W R S (J W R S)^T + LOWPASS_2D I, with W the world-to-camera rotation, R S
    the Gaussian's rotation and scales and J the perspective Jacobian at the mean (tangent
    clamped to the widened field of view, like 3DGS). Writing it as a Gram matrix keeps it
    positive semi-definite in floating point; its determinant and inverse come from
    ``stable_conic``, exact enough in float32 for splats thousands of pixels long.
    """
    means, dtype, device = snapshot.means, snapshot.means.dtype, snapshot.means.device
    w2c = torch.tensor(camera.w2c.copy(), dtype=dtype, device=device)
    rot_w, trans_w = w2c[:3, :3], w2c[:3, 3]
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    W, H = camera.width, camera.height

    p_cam = means @ rot_w.T + trans_w
    x, y, z = p_cam.unbind(-1)
    in_front = z > NEAR_PLANE
    z_safe = torch.where(in_front, z, torch.ones_like(z))
    inv_z = 1.0 / z_safe
    means2d = torch.stack([fx * x * inv_z + cx, fy * y * inv_z + cy], -1)

    tan_x, tan_y = 0.5 * W / fx, 0.5 * H / fy
    lim_x_pos, lim_x_neg = (W - cx) / fx + TAN_FOV_MARGIN * tan_x, cx / fx + TAN_FOV_MARGIN * tan_x
    lim_y_pos, lim_y_neg = (H - cy) / fy + TAN_FOV_MARGIN * tan_y, cy / fy + TAN_FOV_MARGIN * tan_y
    tx = z_safe * torch.clamp(x * inv_z, -lim_x_neg, lim_x_pos)
    ty = z_safe * torch.clamp(y * inv_z, -lim_y_neg, lim_y_pos)
    # T = J W R S row by row, elementwise (a batched 3x3 matmul per Gaussian is far slower on
    # the CPU). J = [[fx/z, 0, -fx tx/z^2], [0, fy/z, -fy ty/z^2]].
    n = means.shape[0]
    world_rs = (quat_to_rotmat(snapshot.quats).transpose(1, 2).reshape(-1, 3) @ rot_w.T)
    world_rs = world_rs.reshape(n, 3, 3).transpose(1, 2) * snapshot.scales[:, None, :]  # W R diag(s)
    j_xz, j_yz = (-fx * tx * inv_z * inv_z)[:, None], (-fy * ty * inv_z * inv_z)[:, None]
    t0 = (fx * inv_z)[:, None] * world_rs[:, 0] + j_xz * world_rs[:, 2]
    t1 = (fy * inv_z)[:, None] * world_rs[:, 1] + j_yz * world_rs[:, 2]
    with torch.no_grad():
        tame = torch.maximum(t0.detach().abs().amax(-1), t1.detach().abs().amax(-1)) <= T_ENTRY_MAX
    if not bool(tame.all()):  # culled rows get zero rows, so no inf/NaN reaches the backward
        t0 = torch.where(tame[:, None], t0, torch.zeros_like(t0))
        t1 = torch.where(tame[:, None], t1, torch.zeros_like(t1))
    conic_ldl, det = stable_conic(t0, t1, LOWPASS_2D)
    ok = in_front & tame & (det > DET_MIN) & torch.isfinite(det)
    conic_ldl = torch.where(ok[:, None], conic_ldl, torch.ones_like(conic_ldl))

    with torch.no_grad():
        ca = (t0 * t0).sum(-1) + LOWPASS_2D
        cc = (t1 * t1).sum(-1) + LOWPASS_2D
        mid = 0.5 * (ca + cc)
        lam_max = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.0))
        radius = torch.ceil(SIGMA_EXTENT * torch.sqrt(torch.clamp(lam_max, min=0.0)))
        mx, my = means2d[:, 0], means2d[:, 1]
        on_screen = (mx + radius > 0) & (mx - radius < W) & (my + radius > 0) & (my - radius < H)
        keep = ok & on_screen & torch.isfinite(radius)
        # int32 headroom only: binning clips the extent to the image, so any radius this large
        # already covers every pixel it can reach
        radii = torch.where(keep, torch.clamp(radius, max=RADIUS_MAX), torch.zeros_like(radius)).to(torch.int32)
    return Projection(means2d=means2d, conic_ldl=conic_ldl, depths=z, radii=radii,
                      opacities=snapshot.opacities, colors=snapshot.colors)
