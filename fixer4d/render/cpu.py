"""The fast CPU rasterizer: the torch side of the numba kernels (fixer4d/render/cpu_kernels.py).

A Projection's splats become float32 records; visible splats are depth-sorted once (stable) and
binned to tiles; tiles are ordered by work and dealt evenly to the threads (static schedule); the
kernels composite front to back and, in the backward, walk back to the per-splat gradients,
which the torch autograd Function (_RasterizeCPU) hands back as dL/d(means2d, conics, opacities,
colours, depths).

Memory is the image, the splat records and the flat tile lists. Chain rule from the 2D splats
to means/quats/scales is torch autograd through fixer4d/render/project.py.
"""
from __future__ import annotations

import numpy as np
import torch

from fixer4d.jit import NUMBA_ERROR, numba, torch_threads_kept
import fixer4d.render.constants as C
import fixer4d.render.cpu_kernels as kernels
from fixer4d.render.project import Projection

# numba is a core dependency, but "auto" must still work (via the oracle) without it
_IMPORT_ERROR = None if NUMBA_ERROR is None else f"{NUMBA_ERROR}; install numba or use backend='reference'"


def unavailable_reason() -> str | None:
    """None when the numba kernels can run, else why not."""
    return _IMPORT_ERROR


def _tile_orders(offsets: np.ndarray, n_threads: int) -> tuple[np.ndarray, np.ndarray]:
    """(by_work, dealt): tiles by decreasing work (list length, stable), and the same dealt
    round-robin into n_threads contiguous blocks. prange's static schedule gives thread c the
    c-th contiguous block of ``dealt`` (the forward), the backward's chunk c takes
    by_work[c::n_threads]: either way every thread gets an equal share of heavy and light
    tiles, without the per-tile dispatch cost of a dynamic schedule (measured 3x slower)."""
    by_work = np.argsort(-np.diff(offsets), kind="stable").astype(np.int64)
    dealt = np.concatenate([by_work[c::n_threads] for c in range(n_threads)])
    return by_work, dealt


def _as_np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to(torch.float32).cpu().numpy())


def _records(means2d, conics, opacities, colors, depths) -> np.ndarray:
    """(N, R_N) float32 splat records (columns ``cpu_kernels.R_*``); binning fills R_LEV and the rows."""
    rec = torch.zeros(means2d.shape[0], kernels.R_N, dtype=torch.float32)
    rec[:, kernels.R_MX:kernels.R_MY + 1] = means2d.detach()
    rec[:, kernels.R_A:kernels.R_Q + 1] = conics.detach()
    rec[:, kernels.R_O] = opacities.detach()
    rec[:, kernels.R_CR:kernels.R_CB + 1] = colors.detach()
    rec[:, kernels.R_Z] = depths.detach()
    return rec.numpy()


class _RasterizeCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, depths, radii, width, height):
        rec = _records(means2d, conics, opacities, colors, depths)
        radii_np = radii.detach().cpu().numpy().astype(np.int64)
        op, z = rec[:, kernels.R_O], rec[:, kernels.R_Z]
        # alpha <= opacity, so a splat below ALPHA_MIN opacity never blends: not binned
        visible = np.nonzero((radii_np > 0) & (op >= kernels.ALPHA_MIN32))[0]
        order = visible[np.argsort(z[visible], kind="stable")].astype(np.int64)
        color = np.empty((height, width, 3), np.float32)
        trans = np.empty((height, width), np.float32)
        depth = np.empty((height, width), np.float32)
        count = np.empty((height, width), np.int32)
        with torch_threads_kept():
            n_threads = numba.get_num_threads()
            offsets, ids = kernels.bin_tiles(rec, radii_np, order, width, height, C.TILE, n_threads)
            by_work, dealt = _tile_orders(offsets, n_threads)
            frags = kernels.composite_forward(rec, offsets, ids, dealt, width, height, color, trans, depth, count)
        ctx.arrays = (rec, offsets, ids, by_work, trans, count)
        ctx.size = (width, height)
        n_frag = torch.tensor(int(frags.sum()), dtype=torch.int64)
        ctx.mark_non_differentiable(n_frag)
        dev = means2d.device
        return (torch.from_numpy(color).to(dev), torch.from_numpy(trans).to(dev),
                torch.from_numpy(depth).to(dev), n_frag)

    @staticmethod
    def backward(ctx, g_color, g_trans, g_depth, _g_frag):
        rec, offsets, ids, by_work, trans, count = ctx.arrays
        width, height = ctx.size

        def grad_np(g, shape):
            return np.zeros(shape, np.float32) if g is None else _as_np(g)

        with torch_threads_kept():
            sums = kernels.composite_backward(rec, offsets, ids, by_work, width, height, trans, count,
                                              grad_np(g_color, (height, width, 3)), grad_np(g_trans, (height, width)),
                                              grad_np(g_depth, (height, width)), numba.get_num_threads()).sum(0)
        g = torch.from_numpy(sums.astype(np.float32))
        k = kernels
        return (g[:, k.G_MX:k.G_MY + 1], g[:, k.G_A:k.G_C + 1], g[:, k.G_O], g[:, k.G_R:k.G_BL + 1], g[:, k.G_Z],
                None, None, None)


def rasterize_cpu(proj: Projection, width: int, height: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, int]:
    """Same contract as ``rasterize_reference``, float32: (color_acc (H, W, 3), transmittance
    (H, W), depth_acc (H, W), n_fragments); differentiable through the hand-written backward."""
    if _IMPORT_ERROR is not None:
        from fixer4d.errors import BackendUnavailable

        raise BackendUnavailable(_IMPORT_ERROR)
    f32 = torch.float32
    color, trans, depth, n_frag = _RasterizeCPU.apply(
        proj.means2d.to(f32), proj.conic_ldl.to(f32), proj.opacities.to(f32), proj.colors.to(f32),
        proj.depths.to(f32), proj.radii, int(width), int(height))
    return color, trans, depth, int(n_frag)
