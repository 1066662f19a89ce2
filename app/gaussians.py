"""Raw spacetime-Gaussian parameters as numpy arrays: what the GL renderer uploads and what the
editor selects, deletes and saves.

The field names and meanings follow ``fixer4d.model.spacetime.SpacetimeGaussians`` (docs/design.md
§9): at time t with dt = t - t_center,
  mean(t)    = means + m1*dt + m2*dt^2 + m3*dt^3
  quat(t)    = normalize(quats + omega*dt)
  opacity(t) = sigmoid(opacity_logits) * exp(-(dt / exp(t_log_scale))^2)
  rgb        = max(0.5 + C0 * colors, 0)
Static Gaussians (dynamic == False) skip every time term.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from fixer4d.errors import InputError
from fixer4d.model.sh import SH_C0
from fixer4d.model.spacetime import T_LOG_SCALE_MIN

# Opacity clamp when converting a snapshot's opacities back to logits: keeps logit(x) finite.
_OPACITY_EPS = 1e-6
# A model without temporal opacity has no t_log_scale: exp(-(dt/exp(30))^2) == 1 in float32 for
# every dt in [-1, 1], i.e. no temporal fading.
NO_TEMPORAL_LOG_SCALE = 30.0
# Smallest scale (std dev) accepted when converting a snapshot's scales back to log-scales.
_SCALE_EPS = 1e-12


@dataclass
class GaussianArrays:
    """Spacetime Gaussian parameters, float32 numpy, one row per Gaussian.

    means (N,3) world units; log_scales (N,3) log std devs; quats (N,4) wxyz (any norm);
    opacity_logits (N,); colors (N,3) SH DC coefficients; t_center (N,) in clip time [0,1);
    t_log_scale (N,) log temporal std; motion (N,9) = m1, m2, m3 as xyz triples; omega (N,4)
    quaternion velocity; dynamic (N,) bool; sh_rest (N,K,3) higher SH bands (K may be 0; the
    GL shader evaluates them up to the degree K implies); model_config: the ModelConfig as a dict.
    """

    means: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    opacity_logits: np.ndarray
    colors: np.ndarray
    t_center: np.ndarray
    t_log_scale: np.ndarray
    motion: np.ndarray
    omega: np.ndarray
    dynamic: np.ndarray
    sh_rest: np.ndarray | None = None
    model_config: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = int(np.asarray(self.means).reshape(-1, 3).shape[0])
        shapes = {"means": (n, 3), "log_scales": (n, 3), "quats": (n, 4), "opacity_logits": (n,),
                  "colors": (n, 3), "t_center": (n,), "t_log_scale": (n,), "motion": (n, 9),
                  "omega": (n, 4), "dynamic": (n,)}
        for name, shape in shapes.items():
            dtype = bool if name == "dynamic" else np.float32
            arr = np.ascontiguousarray(np.asarray(getattr(self, name), dtype=dtype).reshape(shape))
            if dtype is np.float32 and not np.all(np.isfinite(arr)):
                raise InputError(f"Gaussian parameter {name!r} has non-finite values; re-export the model")
            setattr(self, name, arr)
        rest = np.zeros((n, 0, 3), np.float32) if self.sh_rest is None else self.sh_rest
        self.sh_rest = np.ascontiguousarray(np.asarray(rest, np.float32).reshape(n, -1, 3))

    @property
    def n(self) -> int:
        return int(self.means.shape[0])

    # ---- constructors ---------------------------------------------------------------------
    @classmethod
    def from_model(cls, model: Any) -> "GaussianArrays":
        """Copy the raw parameters of a ``SpacetimeGaussians`` (any device) to numpy.

        Model terms the model's config switches off have no Parameter; they are filled with their
        neutral values (zero motion/omega, a temporal scale so wide that the temporal factor is
        1) so that the GL shader agrees with ``model.at``.
        """
        names = set(model.param_names())
        n = model.num_gaussians

        def get(name: str, shape: tuple[int, ...], fill: float = 0.0) -> np.ndarray:
            if name not in names:
                return np.full((n, *shape), fill, np.float32)
            return getattr(model, name).detach().float().cpu().numpy().reshape(n, *shape)

        motion = np.zeros((n, 9), np.float32)
        if "motion" in names:
            m = get("motion", (-1,))
            motion[:, : m.shape[1]] = m
        t_log_scale = get("t_log_scale", (), NO_TEMPORAL_LOG_SCALE)
        sh_rest = get("sh_rest", (-1, 3)) if "sh_rest" in names else np.zeros((n, 0, 3), np.float32)
        return cls(means=get("means", (3,)), log_scales=get("log_scales", (3,)), quats=get("quats", (4,)),
                   opacity_logits=get("opacity_logits", ()), colors=get("colors", (3,)),
                   t_center=get("t_center", ()), t_log_scale=t_log_scale, motion=motion,
                   omega=get("omega", (4,)), dynamic=model.dynamic.detach().cpu().numpy().astype(bool),
                   sh_rest=sh_rest, model_config=model.config.to_dict())

    def to_model(self) -> Any:
        """A ``SpacetimeGaussians`` with this set's parameters and its original config
        (round-trips ``from_model`` exactly for the Parameters the config has)."""
        from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians  # torch: only when saving

        config = ModelConfig.from_dict(self.model_config)
        full = {"means": self.means, "log_scales": self.log_scales, "quats": self.quats,
                "opacity_logits": self.opacity_logits, "colors": self.colors, "sh_rest": self.sh_rest,
                "t_center": self.t_center, "t_log_scale": self.t_log_scale,
                "motion": self.motion[:, : 3 * config.motion_degree], "omega": self.omega}
        tensors = {k: full[k] for k in config.param_shapes()}
        tensors["dynamic"] = self.dynamic
        return SpacetimeGaussians.from_tensors(config, tensors, source="viewer edit")

    @classmethod
    def from_snapshot(cls, snapshot: Any) -> "GaussianArrays":
        """A static set from a ``fixer4d.model.snapshot.Snapshot`` (means, quats, scales,
        opacities, colors as RGB in [0,1]); every Gaussian is marked static."""
        def arr(x: Any) -> np.ndarray:
            return x.detach().float().cpu().numpy() if hasattr(x, "detach") else np.asarray(x, np.float32)

        means = arr(snapshot.means)
        n = means.shape[0]
        op = np.clip(arr(snapshot.opacities).reshape(n), _OPACITY_EPS, 1.0 - _OPACITY_EPS)
        return cls(means=means, log_scales=np.log(np.maximum(arr(snapshot.scales), _SCALE_EPS)),
                   quats=arr(snapshot.quats), opacity_logits=np.log(op / (1.0 - op)),
                   colors=(arr(snapshot.colors) - 0.5) / SH_C0, t_center=np.zeros(n), t_log_scale=np.zeros(n),
                   motion=np.zeros((n, 9)), omega=np.zeros((n, 4)), dynamic=np.zeros(n, bool),
                   model_config={"motion_degree": 0, "rotation_velocity": False, "temporal_opacity": False,
                                 "sh_degree": 0})

    @staticmethod
    def array_fields() -> list[str]:
        return [f.name for f in fields(GaussianArrays) if f.name != "model_config"]

    # ---- editing ----------------------------------------------------------------------------
    def subset(self, keep: np.ndarray) -> "GaussianArrays":
        """The Gaussians where ``keep`` (bool (N,) or an index array) selects."""
        keep = np.asarray(keep)
        return replace(self, **{name: getattr(self, name)[keep] for name in self.array_fields()})

    @staticmethod
    def concatenate(parts: list["GaussianArrays"]) -> "GaussianArrays":
        arrays = {name: np.concatenate([getattr(p, name) for p in parts]) for name in GaussianArrays.array_fields()}
        return GaussianArrays(**arrays, model_config=dict(parts[0].model_config))

    # ---- evaluation at a time (CPU side: sorting, selection, heatmaps) ------------------------
    def _dt(self, t: float) -> np.ndarray:
        return np.where(self.dynamic, np.float32(t) - self.t_center, np.float32(0.0)).astype(np.float32)

    def means_at(self, t: float) -> np.ndarray:
        """(N,3) float32 centres at time t."""
        dt = self._dt(t)[:, None]
        m = self.motion
        return self.means + dt * (m[:, 0:3] + dt * (m[:, 3:6] + dt * m[:, 6:9]))

    def temporal_opacity(self, t: float) -> np.ndarray:
        """(N,) the temporal factor exp(-(dt/exp(t_log_scale))^2), 1 for static Gaussians."""
        dt = self._dt(t)
        return np.exp(-np.square(dt * np.exp(-np.maximum(self.t_log_scale, T_LOG_SCALE_MIN)))).astype(np.float32)

    def opacity_at(self, t: float) -> np.ndarray:
        """(N,) sigmoid(opacity_logits) times the temporal factor."""
        return (1.0 / (1.0 + np.exp(-self.opacity_logits)) * self.temporal_opacity(t)).astype(np.float32)

    def speed_at(self, t: float) -> np.ndarray:
        """(N,) |d mean / dt| (world units per clip time), 0 for static Gaussians."""
        dt = self._dt(t)[:, None]
        m = self.motion
        v = m[:, 0:3] + 2.0 * dt * m[:, 3:6] + 3.0 * dt * dt * m[:, 6:9]
        return np.where(self.dynamic, np.linalg.norm(v, axis=1), 0.0).astype(np.float32)

    def rgb(self) -> np.ndarray:
        """(N,3) colours in [0, inf) from the DC coefficients."""
        return np.maximum(0.5 + SH_C0 * self.colors, 0.0)

    def equals(self, other: "GaussianArrays") -> bool:
        return self.n == other.n and all(np.array_equal(getattr(self, name), getattr(other, name))
                                         for name in self.array_fields())
