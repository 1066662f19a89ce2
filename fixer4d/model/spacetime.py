"""Spacetime Gaussians, STGS "lite" parameterization with switchable model terms (docs/design.md §9).

At time t, with dt = t - t_center (per Gaussian):

    mu(t)      = mu + m1 dt + m2 dt^2 + m3 dt^3          (up to ``motion_degree``)
    q(t)       = q + omega dt                            (``rotation_velocity``; renderers normalize)
    opacity(t) = sigmoid(o) * exp(-(dt / exp(s_t))^2)    (``temporal_opacity``)
    scale      = exp(log_scales)                         (time-independent)
    colour     = max(0.5 + SH(dir) . coeffs, 0)          (degree 0 = RGB, no view dependence; sh.py)

A term that is switched off in the ``ModelConfig`` has no Parameter at all, so the optimizer
and ``at(t)`` pay nothing for it. Per Gaussian, the bool buffer ``dynamic`` marks which
Gaussians use the time terms: ``at(t)`` evaluates them only on the dynamic index set and
scatters the results, so its cost grows with the dynamic count, not the total.

q(t) is returned un-normalized, as in STGS: the Snapshot contract says renderers normalize, so
normalize(q + omega dt) and q + omega dt are the same rotation, and a static Gaussian's
quaternion passes through untouched.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from fixer4d.errors import InputError, NumericalError
from fixer4d.model.initial_scales import point_scales, point_temporal_std
from fixer4d.model.sh import MAX_SH_DEGREE, rgb_to_sh_dc, sh_colors
from fixer4d.model.snapshot import Snapshot

# Largest |coordinate|, time or colour from_points accepts: the model is float32 (max 3.4e38);
# 1e30 leaves room for the products the renderer and the optimizer form from them.
FLOAT32_SAFE_LIMIT = 1e30

# Largest |t| at(t) accepts: clip times are in [0, 1); viewers and exports may extrapolate,
# and up to a million clip lengths out dt^3 = 1e18 keeps the float32 cubic motion of
# unit-order coefficients and its gradient finite; beyond, positions head for overflow.
TIME_LIMIT = 1e6

MAX_MOTION_DEGREE = 3  # cubic motion, as in STGS lite

# exp(-s_t) overflows float32 for s_t < -88 and then 0 * inf poisons the gradient. A temporal
# std of exp(-20) ~ 2e-9 is six orders of magnitude below one frame of a 1000-frame clip, so no
# useful Gaussian lives there; clamping s_t below it only keeps values and gradients finite.
T_LOG_SCALE_MIN = -20.0

# Order of the Parameters (also the order of param_names() and of saved files).
_ALL_PARAMS = ("means", "log_scales", "quats", "opacity_logits", "colors", "sh_rest",
               "t_center", "t_log_scale", "motion", "omega")


@dataclass
class ModelConfig:
    """Which optional terms a model has (one per scene; docs/design.md §9).

    motion_degree: 0..3, polynomial degree of the mean's motion (0 = no motion Parameter).
    rotation_velocity: angular velocity omega (q + omega dt).
    temporal_opacity: Gaussian RBF in time on the opacity (needs t_log_scale).
    sh_degree: 0..3; 0 = plain RGB, no view dependence (no sh_rest Parameter).
    """

    motion_degree: int = 3
    rotation_velocity: bool = True
    temporal_opacity: bool = True
    sh_degree: int = 0

    def __post_init__(self) -> None:
        if not (0 <= int(self.motion_degree) <= MAX_MOTION_DEGREE):
            raise InputError(f"ModelConfig.motion_degree must be in 0..{MAX_MOTION_DEGREE}, got {self.motion_degree}")
        if not (0 <= int(self.sh_degree) <= MAX_SH_DEGREE):
            raise InputError(f"ModelConfig.sh_degree must be in 0..{MAX_SH_DEGREE}, got {self.sh_degree}")
        self.motion_degree = int(self.motion_degree)
        self.sh_degree = int(self.sh_degree)
        self.rotation_velocity = bool(self.rotation_velocity)
        self.temporal_opacity = bool(self.temporal_opacity)

    @property
    def has_time_terms(self) -> bool:
        """True when at(t) depends on t at all."""
        return self.motion_degree > 0 or self.rotation_velocity or self.temporal_opacity

    @property
    def num_sh_rest(self) -> int:
        """Number of non-DC SH coefficients per channel: (d + 1)^2 - 1."""
        return (self.sh_degree + 1) ** 2 - 1

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ModelConfig":
        known = {k: d[k] for k in ("motion_degree", "rotation_velocity", "temporal_opacity", "sh_degree") if k in d}
        return cls(**known)

    def param_shapes(self) -> dict[str, tuple[int, ...]]:
        """Per-Gaussian trailing shape of every Parameter this config has, in canonical order."""
        shapes: dict[str, tuple[int, ...]] = {
            "means": (3,), "log_scales": (3,), "quats": (4,), "opacity_logits": (), "colors": (3,),
        }
        if self.sh_degree > 0:
            shapes["sh_rest"] = (self.num_sh_rest, 3)
        if self.has_time_terms:
            shapes["t_center"] = ()
        if self.temporal_opacity:
            shapes["t_log_scale"] = ()
        if self.motion_degree > 0:
            shapes["motion"] = (3 * self.motion_degree,)
        if self.rotation_velocity:
            shapes["omega"] = (4,)
        return {k: shapes[k] for k in _ALL_PARAMS if k in shapes}


class SpacetimeGaussians(nn.Module):
    """N spacetime Gaussians (see the module docstring for the equations).

    Parameters (only those the config enables exist): means (N,3), log_scales (N,3),
    quats (N,4) wxyz, opacity_logits (N,), colors (N,3) SH DC (RGB = 0.5 + C0*colors),
    sh_rest (N,(d+1)^2-1,3), t_center (N,) in clip time, t_log_scale (N,) log temporal std,
    motion (N, 3*motion_degree) = m1, m2, m3 as consecutive xyz triples (N,9 at degree 3),
    omega (N,4). Buffers: dynamic (N,) bool; frozen (N,) bool, rows the trainer never changes
    (another segment's static Gaussians, ``fixer4d.pipeline.shared_static``).
    """

    def __init__(self, config: ModelConfig | None = None, num_gaussians: int = 0,
                 dtype: torch.dtype = torch.float32, device: torch.device | str | None = None) -> None:
        super().__init__()
        self.config = ModelConfig() if config is None else config
        n = int(num_gaussians)
        for name, shape in self.config.param_shapes().items():
            init = torch.zeros((n, *shape), dtype=dtype, device=device)
            if name == "quats":
                init[:, 0] = 1.0
            self.register_parameter(name, nn.Parameter(init))
        self.register_buffer("dynamic", torch.ones(n, dtype=torch.bool, device=device))
        self.register_buffer("frozen", torch.zeros(n, dtype=torch.bool, device=device))
        self._index_cache: dict[str, tuple[Any, torch.Tensor]] = {}

    # ---- construction -----------------------------------------------------------------
    @classmethod
    def from_points(cls, points: np.ndarray, colors: np.ndarray, times: np.ndarray,
                    config: ModelConfig | None = None, *, opacity: float = 0.1,
                    scales: np.ndarray | None = None, dynamic: np.ndarray | None = None,
                    t_scale: float | None = None) -> "SpacetimeGaussians":
        """Gaussians centred on points (N,3) with colours (N,3) in [0,1] born at times (N,).

        Identity rotation, zero motion/omega, t_center = the point's time, opacity ``opacity``.
        scales: (N,) isotropic or (N,3) std devs; default from 3-NN distances
        (``initial_scales.knn_scales``).
        t_scale: initial temporal std (clip time units); default from the times' spacing
        (``initial_scales.initial_temporal_std``).
        dynamic: (N,) bool; default all dynamic.
        """
        config = ModelConfig() if config is None else config
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        n = pts.shape[0]
        cols = np.asarray(colors, dtype=np.float64).reshape(-1, 3)
        tms = np.asarray(times, dtype=np.float64).reshape(-1)
        if cols.shape[0] != n or tms.shape[0] != n:
            raise InputError(f"from_points: {n} points but {cols.shape[0]} colours and {tms.shape[0]} times; "
                             "pass one colour and one time per point")
        for label, arr in (("points", pts), ("colors", cols), ("times", tms)):
            if not np.all(np.isfinite(arr)):
                raise InputError(f"from_points: non-finite values in {label}; filter the point cloud first")
            if arr.size and float(np.max(np.abs(arr))) > FLOAT32_SAFE_LIMIT:
                raise InputError(f"from_points: {label} reach {float(np.max(np.abs(arr))):.3g}, beyond what the "
                                 f"float32 model holds (|value| <= {FLOAT32_SAFE_LIMIT:g}); rescale the scene")
        if not (0.0 < opacity < 1.0):
            raise InputError(f"from_points: opacity must be in (0, 1), got {opacity}")
        sc = point_scales(pts, scales)
        std_t = point_temporal_std(tms, t_scale)
        model = cls(config, n)
        with torch.no_grad():
            model.means.copy_(torch.from_numpy(pts))
            model.log_scales.copy_(torch.from_numpy(np.log(sc)))
            model.opacity_logits.fill_(math.log(opacity / (1.0 - opacity)))
            model.colors.copy_(torch.from_numpy(rgb_to_sh_dc(np.clip(cols, 0.0, 1.0))))
            if "t_center" in model.param_names():
                model.t_center.copy_(torch.from_numpy(tms))
            if "t_log_scale" in model.param_names():
                model.t_log_scale.fill_(math.log(std_t))
        if dynamic is not None:
            model.set_dynamic(torch.as_tensor(np.asarray(dynamic, dtype=bool)))
        return model

    @classmethod
    def from_tensors(cls, config: ModelConfig, tensors: dict[str, torch.Tensor | np.ndarray],
                     source: str = "tensors") -> "SpacetimeGaussians":
        """Build a model from named arrays (every Parameter of ``config`` + optional ``dynamic``
        and ``frozen``).

        Validates shapes and finiteness; ``source`` names the origin (a file) in error messages.
        """
        shapes = config.param_shapes()
        missing = [k for k in shapes if k not in tensors]
        if missing:
            raise InputError(f"{source}: missing model fields {missing} for config {config.to_dict()}")
        n = int(np.asarray(tensors["means"]).shape[0])
        model = cls(config, 0)
        for name, shape in shapes.items():
            src = tensors[name]
            t = src if torch.is_tensor(src) else torch.from_numpy(np.array(src, copy=True, order="C"))
            if tuple(t.shape) != (n, *shape):
                raise InputError(f"{source}: field {name!r} has shape {tuple(t.shape)}, expected {(n, *shape)}")
            if not t.is_floating_point():
                t = t.float()
            if not bool(torch.isfinite(t).all()):
                bad = int((~torch.isfinite(t.reshape(n, -1))).any(1).sum()) if n else 0
                raise NumericalError(f"{source}: field {name!r} has non-finite values in {bad} of {n} Gaussians; "
                                     "the file is corrupt or the model diverged; re-export it from a good checkpoint")
            setattr(model, name, nn.Parameter(t.detach().clone()))
        dyn = tensors.get("dynamic")
        dyn_t = (torch.ones(n, dtype=torch.bool) if dyn is None
                 else torch.as_tensor(np.array(dyn, copy=True, order="C") if not torch.is_tensor(dyn) else dyn).to(torch.bool))
        if tuple(dyn_t.shape) != (n,):
            raise InputError(f"{source}: field 'dynamic' has shape {tuple(dyn_t.shape)}, expected {(n,)}")
        model.dynamic = dyn_t.to(model.means.device)
        model.frozen = _row_mask(tensors.get("frozen"), n, f"{source}: field 'frozen'").to(model.means.device)
        return model

    @classmethod
    def from_state_dict(cls, state: dict[str, torch.Tensor], config: ModelConfig) -> "SpacetimeGaussians":
        """Inverse of ``state_dict()`` for any N (nn.Module.load_state_dict needs matching N)."""
        return cls.from_tensors(config, dict(state), source="state_dict")

    # ---- bookkeeping ------------------------------------------------------------------
    @property
    def num_gaussians(self) -> int:
        return int(self.means.shape[0])

    def __len__(self) -> int:
        return self.num_gaussians

    @property
    def num_dynamic(self) -> int:
        return int(self._dynamic_index().numel())

    @property
    def num_frozen(self) -> int:
        return int(self.frozen.sum())

    def param_names(self) -> list[str]:
        """Names of the Parameters this model has, in canonical order."""
        return list(self.config.param_shapes())

    def tensors(self) -> dict[str, torch.Tensor]:
        """Every Parameter (detached) plus the ``dynamic`` and ``frozen`` buffers, by name."""
        out = {name: getattr(self, name).detach() for name in self.param_names()}
        out["dynamic"] = self.dynamic
        out["frozen"] = self.frozen
        return out

    def param_groups(self, lr: dict[str, float]) -> list[dict[str, Any]]:
        """One optimizer group per Parameter: {"params": [p], "lr": lr[name], "name": name}.

        ``lr`` may name Parameters this model lacks (e.g. "motion" for a static config); every
        Parameter the model has must have a rate.
        """
        missing = [k for k in self.param_names() if k not in lr]
        if missing:
            raise InputError(f"param_groups: no learning rate for {missing}; add them to the lr dict")
        return [{"params": [getattr(self, k)], "lr": float(lr[k]), "name": k} for k in self.param_names()]

    def set_dynamic(self, mask: torch.Tensor) -> None:
        """Replace the per-Gaussian dynamic mask (N,) bool."""
        mask = torch.as_tensor(mask).to(device=self.means.device, dtype=torch.bool)
        if tuple(mask.shape) != (self.num_gaussians,):
            raise InputError(f"dynamic mask has shape {tuple(mask.shape)}, expected ({self.num_gaussians},)")
        self.dynamic = mask.clone()

    def prune(self, keep: torch.Tensor) -> None:
        """Keep only the Gaussians where ``keep`` (N,) bool is True; Parameters are replaced."""
        keep = torch.as_tensor(keep).to(device=self.means.device)
        if keep.dtype != torch.bool or tuple(keep.shape) != (self.num_gaussians,):
            raise InputError(f"prune: keep must be a bool tensor of shape ({self.num_gaussians},), "
                             f"got {keep.dtype} {tuple(keep.shape)}")
        for name in self.param_names():
            setattr(self, name, nn.Parameter(getattr(self, name).detach()[keep].clone()))
        self.dynamic = self.dynamic[keep].clone()
        self.frozen = self.frozen[keep].clone()

    def set_frozen(self, mask: torch.Tensor) -> None:
        """Replace the per-Gaussian frozen mask (N,) bool (rows the trainer leaves untouched)."""
        self.frozen = _row_mask(mask, self.num_gaussians, "frozen mask").to(self.means.device)

    def append(self, params: dict[str, torch.Tensor]) -> None:
        """Append M Gaussians given as {name: (M, ...)} for every Parameter (+ optional
        ``dynamic`` (M,) bool, default True, and ``frozen`` (M,) bool, default False); Parameters
        are replaced."""
        missing = [k for k in self.param_names() if k not in params]
        if missing:
            raise InputError(f"append: missing fields {missing}")
        m = int(params["means"].shape[0])
        shapes = self.config.param_shapes()
        new: dict[str, torch.Tensor] = {}
        for name in self.param_names():
            old = getattr(self, name)
            t = torch.as_tensor(params[name]).to(device=old.device, dtype=old.dtype)
            if tuple(t.shape) != (m, *shapes[name]):
                raise InputError(f"append: {name!r} has shape {tuple(t.shape)}, expected {(m, *shapes[name])}")
            new[name] = torch.cat([old.detach(), t.detach()])
        dyn = params.get("dynamic")
        dyn_t = (torch.ones(m, dtype=torch.bool) if dyn is None else torch.as_tensor(dyn).to(torch.bool))
        if tuple(dyn_t.shape) != (m,):
            raise InputError(f"append: 'dynamic' has shape {tuple(dyn_t.shape)}, expected ({m},)")
        for name, t in new.items():
            setattr(self, name, nn.Parameter(t))
        self.dynamic = torch.cat([self.dynamic, dyn_t.to(self.dynamic.device)])
        frozen = _row_mask(params.get("frozen"), m, "append: 'frozen'")
        self.frozen = torch.cat([self.frozen, frozen.to(self.frozen.device)])

    def check(self, source: str = "model") -> "SpacetimeGaussians":
        """Raise NumericalError naming ``source`` and the field if any Parameter is non-finite."""
        for name in self.param_names():
            p = getattr(self, name)
            if not bool(torch.isfinite(p).all()):
                raise NumericalError(f"{source}: Parameter {name!r} has non-finite values; "
                                     "lower the learning rate or restart from the last good checkpoint")
        return self

    def _dynamic_index(self) -> torch.Tensor:
        """(D,) int64 indices of the dynamic Gaussians, cached until ``dynamic`` changes."""
        return self._row_index("dynamic")

    def frozen_index(self) -> torch.Tensor:
        """(F,) int64 indices of the frozen Gaussians, cached until ``frozen`` changes: a trainer
        reads it every step, and ``nonzero`` waits for a GPU, so it runs once per change."""
        return self._row_index("frozen")

    def _row_index(self, buffer: str) -> torch.Tensor:
        """``nonzero`` of the bool buffer ``buffer``, cached until it changes (keyed on the tensor's
        identity and in-place version counter)."""
        d = getattr(self, buffer)
        key = (id(d), d._version, d.data_ptr(), d.device, d.shape[0])
        cached = self._index_cache.get(buffer)
        if cached is None or cached[0] != key:
            cached = self._index_cache[buffer] = (key, torch.nonzero(d, as_tuple=False).reshape(-1))
        return cached[1]

    # ---- evaluation -------------------------------------------------------------------
    def at(self, t: float | torch.Tensor, camera_center: np.ndarray | None = None, *,
           base_opacities: torch.Tensor | None = None) -> Snapshot:
        """The differentiable static Snapshot at clip time t.

        camera_center: (3,) world position used for view-dependent colour (sh_degree > 0); when
        None, or sh_degree == 0, colours are the view-independent DC term.
        base_opacities: (N,) opacities before the time terms, in place of sigmoid(o) (a training
        step's decayed opacities, ``train.opacity_decay``).
        Static Gaussians (``dynamic`` False) and a config without time terms skip every time
        term: their means/quats are the Parameters themselves and their opacity is sigmoid(o).
        """
        t = _checked_time(t)
        if camera_center is not None:
            camera_center = _checked_center(camera_center)
        means, quats = self.means, self.quats
        opacities = torch.sigmoid(self.opacity_logits) if base_opacities is None else base_opacities
        if self.config.has_time_terms:
            idx = self._dynamic_index()
            if idx.numel() > 0:
                means, quats, opacities = self._apply_time(t, idx, means, quats, opacities)
        scales = torch.exp(self.log_scales)
        colors = self._colors(means, camera_center)
        return Snapshot(means=means, quats=quats, scales=scales, opacities=opacities, colors=colors)

    def _apply_time(self, t: float | torch.Tensor, idx: torch.Tensor, means: torch.Tensor,
                    quats: torch.Tensor, opacities: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Evaluate the time terms on the dynamic rows ``idx`` and scatter them back.

        Means and quaternions get their offsets with an out-of-place index_add, whose gradient
        with respect to the full tensor is the incoming gradient itself (no copy, no masking),
        so the backward pass does no per-Gaussian work for static rows beyond the dense
        gradients of the time Parameters.
        """
        cfg = self.config
        everyone = idx.numel() == self.num_gaussians

        def rows(x: torch.Tensor) -> torch.Tensor:
            return x if everyone else x.index_select(0, idx)

        def add(full: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
            return full + offset if everyone else full.index_add(0, idx, offset)

        dt = (t - rows(self.t_center)).unsqueeze(-1)  # (D, 1)
        if cfg.motion_degree > 0:
            coeff = rows(self.motion).view(-1, cfg.motion_degree, 3)
            acc = coeff[:, -1]
            for k in range(cfg.motion_degree - 2, -1, -1):  # Horner: ((m3 dt + m2) dt + m1) dt
                acc = acc * dt + coeff[:, k]
            means = add(means, acc * dt)
        if cfg.rotation_velocity:
            quats = add(quats, rows(self.omega) * dt)
        if cfg.temporal_opacity:
            inv_std = torch.exp(-rows(self.t_log_scale).clamp(min=T_LOG_SCALE_MIN))
            x = dt.squeeze(-1) * inv_std
            rbf = torch.exp(-x * x)
            opacities = opacities * rbf if everyone else opacities.index_copy(0, idx, rows(opacities) * rbf)
        return means, quats, opacities

    def _colors(self, means: torch.Tensor, camera_center: np.ndarray | None) -> torch.Tensor:
        rest = self.sh_rest if self.config.sh_degree > 0 else None
        return sh_colors(self.colors, rest, self.config.sh_degree, means, camera_center)

    @torch.no_grad()
    def snapshot(self, t: float, camera_center: np.ndarray | None = None) -> Snapshot:
        """``at(t)`` without autograd history (for viewers, exports, evaluation)."""
        return self.at(t, camera_center).detach()

    def extra_repr(self) -> str:
        return f"n={self.num_gaussians}, dynamic={self.num_dynamic}, config={json.dumps(self.config.to_dict())}"


def _checked_time(t: Any) -> float | torch.Tensor:
    """``t`` itself when it is a finite clip time (a real number or a one-element tensor);
    InputError naming t otherwise (an infinite t would give NaN positions, not a model error)."""
    if torch.is_tensor(t):
        if t.numel() != 1 or t.dtype.is_complex:
            raise InputError(f"at(t): t must be one real clip time, got a tensor of shape {tuple(t.shape)}")
        value = float(t.detach().reshape(-1)[0])
    else:
        try:
            value = float(t)
        except (TypeError, ValueError):
            raise InputError(f"at(t): t must be a real clip time (0 <= t < 1 within the clip), got {t!r}") from None
    if not abs(value) <= TIME_LIMIT:
        raise InputError(f"at(t): t must be a finite clip time (0 <= t < 1 within the clip, |t| <= {TIME_LIMIT:g}), "
                         f"got {value}")
    return t


def _checked_center(center: Any) -> np.ndarray:
    """(3,) finite float64 camera centre; InputError otherwise."""
    try:
        c = np.asarray(center, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"at(t): camera_center must be 3 numbers, got {center!r}") from None
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise InputError(f"at(t): camera_center must be 3 finite numbers, got {c.tolist()}")
    return c


def _row_mask(mask: Any, n: int, what: str) -> torch.Tensor:
    """(n,) bool tensor from a mask (tensor, array, or None -> all False)."""
    if mask is None:
        return torch.zeros(n, dtype=torch.bool)
    t = mask if torch.is_tensor(mask) else torch.as_tensor(np.array(mask, copy=True, order="C"))
    t = t.to(torch.bool)
    if tuple(t.shape) != (n,):
        raise InputError(f"{what} has shape {tuple(t.shape)}, expected ({n},)")
    return t.clone()
