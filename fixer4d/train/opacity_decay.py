"""Learned opacity decay: how stage 1 shapes the model, in place of opacity resets (4C4D's idea,
CVPR 2026; ``training.opacity_decay.enabled=false`` gives the reset back).

With four cameras a Gaussian can explain the train views from a wrong depth: nothing in the
photometric loss pulls it out once its opacity is high, and the opacity reset of 3DGS (every
opacity clamped to 0.01 once, at a quarter of stage 1) gives all of them the same second chance at
once. Here every step multiplies the opacity of each Gaussian the step's views see by a factor in
[``f_min``, ``f_max``] (just below 1) and writes the result back into the opacity logits: a
Gaussian that the loss does not keep pushing up fades by itself and is pruned at
``TrainingConfig.prune_opacity``, while one that the views need is restored by its gradient every
step. The factor comes from a small network on the Gaussian's own state, trained with the model:

    x = [2 sigmoid(o) - 1, standardized (x, y, z, t_center), standardized (log-scales, t_log_scale)]
    f = f_min + (f_max - f_min) * sigmoid(MLP(x))        (N,), one hidden layer with dropout
    opacity used by the step's renders = sigmoid(o) * f   (for the decayed rows)

The render loss reaches the network through f and the opacities through the product, so the
network learns which kinds of Gaussian (faint / opaque, large / small, far / near, short- /
long-lived) should decay more slowly. Its inputs are detached: the decay must not move positions or
scales. The network's initialization and dropout draw from generators seeded by the training's
seed (the dropout's is checkpointed), so a resumed run reproduces the uninterrupted one.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch
from torch import nn

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.model.densify import make_adam

# Inputs of the decay network: opacity, (x, y, z, t_center), (3 log-scales, t_log_scale).
NUM_FEATURES = 9
# Standardization's floor: a feature constant over the model (a static model's t) becomes 0.
_STD_EPS = 1e-6
# A Gaussian counts as seen by a view when its centre projects in front of the camera and inside
# the image grown by this fraction of its size on each side (its footprint reaches in).
VIEW_MARGIN = 0.1
# Nearest depth (x scene extent) at which a centre counts as in front of a camera.
NEAR_FRACTION = 1e-3
# A time-local Gaussian counts as present at the step's time where its temporal factor
# exp(-(dt / s_t)^2) is above this (4C4D's threshold on the marginal in time).
TIME_PRESENT = 0.05
# Opacities written back stay this far inside (0, 1), so that their logits stay finite.
_OPACITY_CLAMP = 1e-6


@dataclass
class OpacityDecayConfig:
    """``training.opacity_decay``: the learned decay of visible opacities (module docstring).

    enabled: decay instead of opacity resets in stage 1 (stage 2 and the matched control never
      decay: they continue a shaped model, as they never reset either). On by default: over five
      seeds it raised Full on both real splits' validation cameras (docs/decisions/opacity-decay.md).
    f_min / f_max: range of the per-step factor: 4C4D's [0.996, 0.998] (per render there). A
      visible Gaussian's logit then falls by about (1 - f) / (1 - opacity) a step, which Adam's
      opacity steps (lr 0.05) hold up to an opacity of about 0.94 where the views need it. A
      wider range, [0.990, 0.998] (an unsupported Gaussian at 0.5 fades under the prune
      threshold within the densification window), lost 0.17 dB more on demo_val
      (docs/decisions/opacity-decay.md).
    start: first step (0-based) that decays; None = the stage's first densification
      (``densify_from``), 4C4D's start (densify_from_iter 500).
    until_fraction: no step from this fraction of stage 1 on decays (1.0: every step to the end,
      as 4C4D; 0.5: only while the default schedule densifies and prunes, so the opacities the
      decay held down recover in the second half).
    hidden / dropout: the network's hidden width and dropout rate (4C4D's 32 and 0.1).
    lr / weight_decay: Adam settings of the network (4C4D's 1e-5 and 1e-4: the factor only needs
      to move within a range of 0.004, so it learns slowly and stays close to its middle).
    """

    enabled: bool = True
    f_min: float = 0.996
    f_max: float = 0.998
    start: int | None = None
    until_fraction: float = 1.0
    hidden: int = 32
    dropout: float = 0.1
    lr: float = 1e-5
    weight_decay: float = 1e-4

    def __post_init__(self) -> None:
        if not 0.0 < self.f_min <= self.f_max <= 1.0:
            raise InputError(f"opacity_decay: need 0 < f_min <= f_max <= 1, got f_min={self.f_min}, f_max={self.f_max}")
        if self.start is not None and self.start < 0:
            raise InputError(f"opacity_decay.start must be >= 0 or null, got {self.start}")
        if not 0.0 < self.until_fraction <= 1.0:
            raise InputError(f"opacity_decay.until_fraction must be in (0, 1], got {self.until_fraction}")
        if self.hidden < 1 or not 0.0 <= self.dropout < 1.0:
            raise InputError("opacity_decay: hidden must be >= 1 and dropout in [0, 1)")
        if not self.lr > 0 or self.weight_decay < 0:
            raise InputError("opacity_decay: lr must be > 0 and weight_decay >= 0")


class DecayNetwork(nn.Module):
    """(N, NUM_FEATURES) standardized features -> (N,) decay factor in [f_min, f_max]."""

    def __init__(self, config: OpacityDecayConfig, seed: int) -> None:
        super().__init__()
        self.f_min, self.f_max, self.dropout = float(config.f_min), float(config.f_max), float(config.dropout)
        self.hidden = nn.Linear(NUM_FEATURES, config.hidden)
        self.out = nn.Linear(config.hidden, 1)
        # torch's default initialization (uniform within 1/sqrt(fan_in)), drawn from the training's
        # seed instead of the global generator: the same seed gives the same network
        generator = torch.Generator().manual_seed(int(seed))
        with torch.no_grad():
            for layer in (self.hidden, self.out):
                bound = 1.0 / layer.in_features ** 0.5
                for p in (layer.weight, layer.bias):
                    p.copy_(torch.rand(p.shape, generator=generator) * (2 * bound) - bound)

    def forward(self, features: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        h = torch.relu(self.hidden(features))
        if self.training and self.dropout > 0:
            # dropout from the given (checkpointed) generator, not torch's global one
            keep = torch.rand(h.shape, generator=generator, device=h.device) >= self.dropout
            h = h * keep / (1.0 - self.dropout)
        return self.f_min + (self.f_max - self.f_min) * torch.sigmoid(self.out(h)).squeeze(-1)


def decay_features(model, opacities: torch.Tensor) -> torch.Tensor:
    """(N, NUM_FEATURES) detached inputs of the decay network for ``model`` (a SpacetimeGaussians)
    whose base opacities are ``opacities`` (N,): opacity mapped to [-1, 1], then the centres
    (x, y, z, t_center) and the log-scales (3 spatial, temporal) each standardized over the
    model (zero where the model has no time terms)."""
    n = model.num_gaussians
    zeros = torch.zeros(n, device=model.means.device)
    t = model.t_center.detach() if hasattr(model, "t_center") else zeros
    s_t = model.t_log_scale.detach() if hasattr(model, "t_log_scale") else zeros
    position = torch.cat([model.means.detach(), t.reshape(n, 1)], dim=1)
    scale = torch.cat([model.log_scales.detach(), s_t.reshape(n, 1)], dim=1)
    parts = [opacities.detach().reshape(n, 1) * 2.0 - 1.0]
    for block in (position, scale):
        std, mean = torch.std_mean(block, dim=0, unbiased=False, keepdim=True)
        parts.append((block - mean) / (std + _STD_EPS))
    return torch.cat(parts, dim=1)


def camera_tensors(cam: Camera, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """(w2c (4, 4), K (3, 3)) float32 of ``cam`` on ``device``."""
    return (torch.tensor(cam.w2c, dtype=torch.float32, device=device),
            torch.tensor(cam.K, dtype=torch.float32, device=device))


def seen_by(means: torch.Tensor, cameras: Sequence[Camera], extent: float,
            matrices: Sequence[tuple[torch.Tensor, torch.Tensor]] | None = None) -> torch.Tensor:
    """(N,) bool: the centres ``means`` (N, 3) that project in front of at least one of
    ``cameras`` and inside its image grown by VIEW_MARGIN. matrices: each camera's
    ``camera_tensors`` on the means' device (default: made here)."""
    seen = torch.zeros(means.shape[0], dtype=torch.bool, device=means.device)
    for i, cam in enumerate(cameras):
        w2c, K = camera_tensors(cam, means.device) if matrices is None else matrices[i]
        pc = means @ w2c[:3, :3].T + w2c[:3, 3]
        z = pc[:, 2]
        front = z > NEAR_FRACTION * extent
        uv = (pc @ K.T)[:, :2] / z.clamp(min=NEAR_FRACTION * extent).unsqueeze(-1)
        mu, mv = VIEW_MARGIN * cam.width, VIEW_MARGIN * cam.height
        inside = (uv[:, 0] > -mu) & (uv[:, 0] < cam.width + mu) & (uv[:, 1] > -mv) & (uv[:, 1] < cam.height + mv)
        seen |= front & inside
    return seen


def present_at(model, t: float) -> torch.Tensor:
    """(N,) bool: the Gaussians present at clip time ``t``: every static row, and the dynamic rows
    whose temporal opacity factor is above TIME_PRESENT (all of them without that term)."""
    present = torch.ones(model.num_gaussians, dtype=torch.bool, device=model.means.device)
    if not (model.config.temporal_opacity and hasattr(model, "t_log_scale")):
        return present
    from fixer4d.model.spacetime import T_LOG_SCALE_MIN

    with torch.no_grad():
        dt = (t - model.t_center) * torch.exp(-model.t_log_scale.clamp(min=T_LOG_SCALE_MIN))
        alive = torch.exp(-dt * dt) > TIME_PRESENT
    return torch.where(model.dynamic, alive, present)


class OpacityDecay:
    """The decay of one training: its network (initialized from ``seed``), the network's
    optimizer, and the step that decays.

    ``opacities(model, t, cameras, extent)`` returns the (N,) base opacities the step's renders
    use (with gradient to the logits and the network) and writes the decayed values into
    ``model.opacity_logits`` for the rows seen at time ``t`` by ``cameras`` (frozen rows
    excepted); ``step()`` after the model's optimizer step; ``state_dict`` / ``load_state_dict``
    for checkpoints. Nothing is read back to the host: the cameras' matrices are copied to the
    device once and the dropout draws on the device.
    """

    def __init__(self, config: OpacityDecayConfig, device: torch.device, seed: int = 0) -> None:
        self.config = config
        self.device = torch.device(device)
        self.network = DecayNetwork(config, seed).to(self.device)
        # fused Adam (model.densify.make_adam) reads nothing back per step; 4C4D's eps
        self.optimizer = make_adam([{"params": list(self.network.parameters()), "weight_decay": config.weight_decay}],
                                   eps=1e-15, lr=config.lr)
        self.generator = torch.Generator(device=self.device).manual_seed(int(seed))
        self._matrices: dict[int, tuple[Camera, tuple[torch.Tensor, torch.Tensor]]] = {}

    def _camera(self, cam: Camera) -> tuple[torch.Tensor, torch.Tensor]:
        hit = self._matrices.get(id(cam))
        if hit is None or hit[0] is not cam:  # the camera is kept, so its id is not reused meanwhile
            hit = self._matrices[id(cam)] = (cam, camera_tensors(cam, self.device))
        return hit[1]

    def opacities(self, model, t: float, cameras: Sequence[Camera], extent: float) -> torch.Tensor:
        base = torch.sigmoid(model.opacity_logits)
        seen = seen_by(model.means.detach(), cameras, extent, [self._camera(c) for c in cameras])
        rows = seen & present_at(model, t) & ~model.frozen
        factor = self.network(decay_features(model, base), self.generator)
        decayed = torch.where(rows, base * factor, base)
        with torch.no_grad():
            kept = decayed.detach().clamp(_OPACITY_CLAMP, 1.0 - _OPACITY_CLAMP)
            model.opacity_logits.data.copy_(torch.where(rows, torch.logit(kept), model.opacity_logits.data))
        return decayed

    def step(self) -> None:
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)

    def state_dict(self) -> dict:
        return {"network": {k: v.detach().clone() for k, v in self.network.state_dict().items()},
                "optimizer": self.optimizer.state_dict(), "generator": self.generator.get_state()}

    def load_state_dict(self, state: dict) -> None:
        self.network.load_state_dict(state["network"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.generator.set_state(state["generator"])
