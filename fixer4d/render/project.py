"""Projection of 3D Gaussians to image-space splats (EWA splatting, as in 3DGS/gsplat).

Everything here is differentiable torch shared by every CPU backend: the oracle and the fast
kernel rasterize the same projected splats, and gradients reach means/quats/scales through
autograd of this module.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from fixer4d.geometry.camera import Camera
from fixer4d.model.snapshot import Snapshot
from fixer4d.render.constants import DET_MIN, LOWPASS_2D, NEAR_PLANE, SIGMA_EXTENT, TAN_FOV_MARGIN

# Below this norm a quaternion is treated as zero and maps to the identity rotation
# (DESIGN.md §3); far below any quaternion an optimizer produces from a unit initialisation.
QUAT_NORM_MIN = 1e-12
# Largest stored radius (pixels), far below int32 overflow.
RADIUS_MAX = float(2 ** 30)


@dataclass
class Projection:
    """N projected splats in one camera.

    means2d: (N, 2) pixel coordinates of the projected means (pixel (i, j) centre = (i+.5, j+.5)).
    conics: (N, 3) inverse 2D covariance (a, b, c) = [[a, b], [b, c]], pixels^-2.
    depths: (N,) camera-frame z of the means (world units).
    radii: (N,) int32 pixel radius of the 3-sigma extent; 0 = culled (behind the near plane,
        degenerate covariance or off-screen). Not differentiable.
    opacities: (N,) and colors: (N, 3): the snapshot's, passed through.
    """

    means2d: torch.Tensor
    conics: torch.Tensor
    depths: torch.Tensor
    radii: torch.Tensor
    opacities: torch.Tensor
    colors: torch.Tensor


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """(N, 4) wxyz quaternions, any norm -> (N, 3, 3) rotation matrices; zero -> identity."""
    norm = quats.norm(dim=-1, keepdim=True)
    ok = norm > QUAT_NORM_MIN
    identity = torch.zeros_like(quats)
    identity[:, 0] = 1.0
    q = torch.where(ok, quats / torch.where(ok, norm, torch.ones_like(norm)), identity)
    w, x, y, z = q.unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, -1).reshape(-1, 3, 3)


def project_gaussians(snapshot: Snapshot, camera: Camera) -> Projection:
    """Project a snapshot's Gaussians into ``camera`` (computed in the snapshot's dtype/device).

    2D covariance = J W R S (J W R S)^T + LOWPASS_2D I, with W the world-to-camera rotation, R S
    the Gaussian's rotation and scales and J the perspective Jacobian at the mean (tangent
    clamped to the widened field of view, like 3DGS). Writing it as a Gram matrix keeps it
    positive semi-definite in floating point.
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
    cov = torch.stack([(t0 * t0).sum(-1), (t0 * t1).sum(-1), (t1 * t1).sum(-1)], -1)
    ca = cov[:, 0] + LOWPASS_2D
    cb = cov[:, 1]
    cc = cov[:, 2] + LOWPASS_2D
    det = ca * cc - cb * cb
    ok = in_front & (det > DET_MIN) & torch.isfinite(det)
    det_safe = torch.where(ok, det, torch.ones_like(det))
    conics = torch.stack([cc / det_safe, -cb / det_safe, ca / det_safe], -1)

    with torch.no_grad():
        mid = 0.5 * (ca + cc)
        lam_max = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.0))
        radius = torch.ceil(SIGMA_EXTENT * torch.sqrt(torch.clamp(lam_max, min=0.0)))
        mx, my = means2d[:, 0], means2d[:, 1]
        on_screen = (mx + radius > 0) & (mx - radius < W) & (my + radius > 0) & (my - radius < H)
        keep = ok & on_screen & torch.isfinite(radius)
        # int32 headroom only: binning clips the extent to the image, so any radius this large
        # already covers every pixel it can reach
        radii = torch.where(keep, torch.clamp(radius, max=RADIUS_MAX), torch.zeros_like(radius)).to(torch.int32)
    return Projection(means2d=means2d, conics=conics, depths=z, radii=radii,
                      opacities=snapshot.opacities, colors=snapshot.colors)
