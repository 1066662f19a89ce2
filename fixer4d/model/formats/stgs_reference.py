"""PLYs written by the reference implementation, SpacetimeGaussians' lite model (STGS, Li et al. 2024).

Its ``save_ply`` writes one ``vertex`` element of float32 properties:

    x y z  trbf_center trbf_scale  nx ny nz  motion_0..8  f_dc_0..2  opacity  scale_0..2
    rot_0..3  omega_0..3

and its lite renderer evaluates, at STGS time t (frame / clip length, as fixer4d's clip time):

    dt       = t - trbf_center
    position = xyz + motion_0..2 dt + motion_3..5 dt^2 + motion_6..8 dt^3
    rotation = normalize(rot + omega dt)                  (w x y z)
    opacity  = sigmoid(opacity) exp(-(dt / exp(trbf_scale))^2)
    scale    = exp(scale)
    colour   = f_dc_0..2 as RGB, passed to the rasterizer as is (no SH, no activation)

That is fixer4d's lite parameterization term for term (``fixer4d.model.spacetime``) except the
colour, which fixer4d stores as an SH DC coefficient: RGB c becomes (c - 0.5) / C0. fixer4d
clamps a colour below 0 to 0; STGS does not, so only negative RGB values (not produced by
training towards images in [0, 1]) render differently. Every Gaussian is dynamic.

Fields the file lacks get fixer4d's neutral defaults: no motion_* fields -> no motion, no
omega_* -> no angular velocity, no trbf_scale -> constant opacity, no trbf_center -> t_center 0.
STGS's full model stores 9 feature channels (f_dc_0..8) decoded by an MLP saved beside the PLY;
fixer4d cannot render those and refuses the file.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fixer4d.errors import InputError
from fixer4d.model.sh import rgb_to_sh_dc
from fixer4d.model.spacetime import MAX_MOTION_DEGREE, ModelConfig, SpacetimeGaussians

# The fields whose presence marks an STGS (spacetime) PLY rather than a static 3DGS one.
TIME_FIELDS = ("trbf_center", "trbf_scale", *[f"motion_{i}" for i in range(3 * MAX_MOTION_DEGREE)],
               *[f"omega_{i}" for i in range(4)])
REQUIRED_FIELDS = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
                   "rot_0", "rot_1", "rot_2", "rot_3")
# f_dc channels of STGS's full model (features for its colour MLP), never a lite file's RGB.
FULL_MODEL_FEATURE = "f_dc_3"


def is_reference(names: set[str]) -> bool:
    """True when the property names carry any STGS time field."""
    return any(f in names for f in TIME_FIELDS)


def config_for(names: set[str]) -> ModelConfig:
    """The model terms an STGS PLY's fields carry (absent fields: the term is off)."""
    motion_degree = max((d for d in range(1, MAX_MOTION_DEGREE + 1)
                         if all(f"motion_{i}" in names for i in range(3 * d))), default=0)
    return ModelConfig(motion_degree=motion_degree, rotation_velocity=all(f"omega_{i}" in names for i in range(4)),
                       temporal_opacity="trbf_scale" in names, sh_degree=0)


def read_reference(vertex: np.ndarray, path: Path) -> SpacetimeGaussians:
    """A fixer4d model from the ``vertex`` rows of an STGS lite PLY (see the module docstring)."""
    names = set(vertex.dtype.names or ())
    if FULL_MODEL_FEATURE in names:
        n_feat = len([f for f in names if f.startswith("f_dc_")])
        raise InputError(f"{path}: {n_feat} f_dc feature channels: an STGS full-model PLY, whose colours come from "
                         "its MLP; fixer4d reads STGS lite PLYs (f_dc_0..2 = RGB), train the lite model instead")
    missing = [f for f in REQUIRED_FIELDS if f not in names]
    if missing:
        raise InputError(f"{path}: STGS PLY without {missing} (found fields: {sorted(names)}); "
                         "not a SpacetimeGaussians lite model")
    cfg = config_for(names)

    def col(f: str) -> np.ndarray:
        return np.asarray(vertex[f], dtype=np.float32)

    def stack(fields: list[str]) -> np.ndarray:
        return np.stack([col(f) for f in fields], axis=1)

    n = len(vertex)
    rgb = stack(["f_dc_0", "f_dc_1", "f_dc_2"]).astype(np.float64)
    tensors: dict[str, np.ndarray] = {
        "means": stack(["x", "y", "z"]), "log_scales": stack([f"scale_{i}" for i in range(3)]),
        "quats": stack([f"rot_{i}" for i in range(4)]), "opacity_logits": col("opacity"),
        "colors": rgb_to_sh_dc(rgb).astype(np.float32), "dynamic": np.ones(n, dtype=bool),
    }
    if cfg.has_time_terms:
        tensors["t_center"] = col("trbf_center") if "trbf_center" in names else np.zeros(n, np.float32)
    if cfg.temporal_opacity:
        tensors["t_log_scale"] = col("trbf_scale")
    if cfg.motion_degree:
        tensors["motion"] = stack([f"motion_{i}" for i in range(3 * cfg.motion_degree)])
    if cfg.rotation_velocity:
        tensors["omega"] = stack([f"omega_{i}" for i in range(4)])
    return SpacetimeGaussians.from_tensors(cfg, tensors, source=str(path))
