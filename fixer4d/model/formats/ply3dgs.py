"""The INRIA 3DGS PLY of static Gaussians: one frame of a spacetime model out, a 3DGS file in.

Layout (binary little-endian, one ``vertex`` element, float32 properties in this order, the
order 3DGS writes and every splat viewer reads):

    x y z  nx ny nz  f_dc_0..2  f_rest_0..3K-1  opacity  scale_0..2  rot_0..3

    position      x y z (world units)
    nx ny nz      zeros (3DGS writes zeros; no reader uses them)
    f_dc, f_rest  SH coefficients; colour = max(0.5 + C0 f_dc + sum_k Y_k(dir) f_rest_k, 0),
                  f_rest channel-major: f_rest_{c*K + k} is coefficient k of channel c,
                  K = (degree + 1)^2 - 1 (0, 3, 8 or 15)
    opacity       logit: alpha = sigmoid(opacity)
    scale_i       log standard deviation along local axis i
    rot_0..3      quaternion w x y z (readers normalize)

This is fixer4d's own colour and activation model, so a static frame is lossless: a frame
written at time t renders as ``model.at(t)`` does (``frame_rows``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from fixer4d.atomic import atomic_path
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians

HEAD_FIELDS = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
TAIL_FIELDS = ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
# SH degree from the number of f_rest fields (3 channels x ((d+1)^2 - 1)).
SH_DEGREE_OF_REST = {0: 0, 9: 1, 24: 2, 45: 3}


def field_names(num_sh_rest: int) -> list[str]:
    """The property names of a 3DGS PLY with ``num_sh_rest`` non-DC coefficients per channel."""
    return HEAD_FIELDS + [f"f_rest_{i}" for i in range(3 * num_sh_rest)] + TAIL_FIELDS


def _logit_at_most(p: np.ndarray, logit_bound: np.ndarray) -> np.ndarray:
    """logit(p) in float64, capped at ``logit_bound``: p = sigmoid(o) * rbf with rbf <= 1, so its
    logit is at most o; the cap also returns o itself where float32 rounded p up to sigmoid(o)."""
    p64 = p.astype(np.float64)
    with np.errstate(divide="ignore"):
        logit = np.log(p64) - np.log1p(-p64)
    return np.minimum(logit, logit_bound)


@torch.no_grad()
def frame_rows(model: SpacetimeGaussians, t: float, min_opacity: float) -> np.ndarray:
    """The Gaussians of ``model`` at clip time ``t`` as 3DGS PLY rows (structured float32 array).

    Static rows pass through bit for bit; dynamic rows get their position, rotation and opacity
    at ``t`` (temporal opacity folded into the opacity logit). Rows whose opacity at ``t`` is below
    ``min_opacity`` are dropped: with the rasterizers' smallest blended alpha (1/255) as the
    threshold they could not change a pixel. Work and memory are O(N) for one frame.
    """
    snap = model.snapshot(t)
    p = snap.opacities.cpu().numpy()
    keep = np.flatnonzero(p >= min_opacity) if min_opacity > 0 else np.flatnonzero(p > 0)
    k = model.config.num_sh_rest
    rows = np.zeros(keep.size, dtype=[(f, "<f4") for f in field_names(k)])
    means = snap.means.cpu().numpy()[keep]
    rows["x"], rows["y"], rows["z"] = means[:, 0], means[:, 1], means[:, 2]
    dc = model.colors.detach().cpu().numpy()[keep]
    for c in range(3):
        rows[f"f_dc_{c}"] = dc[:, c]
    if k:
        rest = model.sh_rest.detach().cpu().numpy()[keep].transpose(0, 2, 1).reshape(keep.size, 3 * k)
        for i in range(3 * k):
            rows[f"f_rest_{i}"] = rest[:, i]
    logits = model.opacity_logits.detach().cpu().numpy()[keep]
    faded = model.dynamic.cpu().numpy()[keep] & model.config.temporal_opacity
    rows["opacity"] = np.where(faded, _logit_at_most(p[keep], logits.astype(np.float64)), logits)
    log_scales = model.log_scales.detach().cpu().numpy()[keep]
    quats = snap.quats.cpu().numpy()[keep]
    for i in range(3):
        rows[f"scale_{i}"] = log_scales[:, i]
    for i in range(4):
        rows[f"rot_{i}"] = quats[:, i]
    return rows


def write_rows(rows: np.ndarray, path: str | Path) -> Path:
    """Write 3DGS rows (``frame_rows``) to ``path`` as a binary little-endian PLY, atomically."""
    from plyfile import PlyData, PlyElement

    ply = PlyData([PlyElement.describe(rows, "vertex")], text=False, byte_order="<")
    with atomic_path(path) as tmp:
        ply.write(str(tmp))
    return Path(path)


def write_frame(model: SpacetimeGaussians, t: float, path: str | Path, min_opacity: float) -> int:
    """Write ``model`` at time ``t`` as a 3DGS PLY; returns the number of Gaussians written."""
    rows = frame_rows(model, t, min_opacity)
    write_rows(rows, path)
    return int(rows.shape[0])


def is_3dgs(names: set[str]) -> bool:
    """True when the property names hold a static 3DGS model (and no spacetime fields)."""
    return set(field_names(0)) - {"nx", "ny", "nz"} <= names


def read_3dgs(vertex: np.ndarray, path: Path) -> SpacetimeGaussians:
    """A static model (no time terms) from the ``vertex`` rows of a 3DGS PLY."""
    from fixer4d.errors import InputError

    names = set(vertex.dtype.names or ())
    n_rest = len([f for f in names if f.startswith("f_rest_")])
    degree = SH_DEGREE_OF_REST.get(n_rest)
    if degree is None:
        raise InputError(f"{path}: {n_rest} f_rest fields is not 3*((d+1)^2-1) for an SH degree d <= 3")
    cfg = ModelConfig(motion_degree=0, rotation_velocity=False, temporal_opacity=False, sh_degree=degree)
    missing = [f for f in field_names(cfg.num_sh_rest) if f not in names and f not in ("nx", "ny", "nz")]
    if missing:
        raise InputError(f"{path}: missing 3DGS PLY fields {missing}")

    def stack(fields: list[str]) -> np.ndarray:
        return np.stack([np.asarray(vertex[f], dtype=np.float32) for f in fields], axis=1)

    n, k = len(vertex), cfg.num_sh_rest
    tensors = {"means": stack(["x", "y", "z"]), "log_scales": stack([f"scale_{i}" for i in range(3)]),
               "quats": stack([f"rot_{i}" for i in range(4)]),
               "opacity_logits": np.asarray(vertex["opacity"], dtype=np.float32),
               "colors": stack(["f_dc_0", "f_dc_1", "f_dc_2"])}
    if k:
        tensors["sh_rest"] = stack([f"f_rest_{i}" for i in range(3 * k)]).reshape(n, 3, k).transpose(0, 2, 1).copy()
    for flag in ("dynamic", "frozen"):
        if flag in names:
            tensors[flag] = np.asarray(vertex[flag]) != 0
    return SpacetimeGaussians.from_tensors(cfg, tensors, source=str(path))
