"""Revisions of the model terms during stage 1 (``ModelTermsConfig.revise``; the decision itself:
fixer4d/model/terms.py).

A dynamic Gaussian whose motion over the clip stays within DEMOTE_MOTION_SCALES of its own size
and whose temporal opacity varies by less than DEMOTE_OPACITY_VARIATION is demoted to static; a
static Gaussian whose view-space gradient is concentrated in one time bin (TemporalStats;
PROMOTE_*) is split: a time-local dynamic copy is added at that bin (the static one keeps the
other times). Deterministic (ties broken by fixed order).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from fixer4d.model.densify import ndc_grad_norm
from fixer4d.model.spacetime import SpacetimeGaussians

# Time bins of the per-Gaussian gradient statistics: 4 bins of a clip resolve "only while the
# ball passes" from "always", and each bin still gets ~1/4 of the steps.
TEMPORAL_BINS = 4
# Demotion: motion over the whole clip within 0.5 of the Gaussian's largest std, and temporal
# opacity varying by < 10% over the clip: it renders the same as a static Gaussian.
DEMOTE_MOTION_SCALES = 0.5
DEMOTE_OPACITY_VARIATION = 0.1
# Split (promotion): a static Gaussian whose mean gradient in its hottest time bin is >= 2x the
# densification threshold and >= 3x its mean over the other bins keeps a residual that one
# static position cannot remove. Each bin needs >= 3 views' statistics to be trusted.
PROMOTE_GRAD_FACTOR = 2.0
PROMOTE_CONCENTRATION = 3.0
PROMOTE_MIN_VIEWS = 3


@dataclass
class TemporalStats:
    """Per-Gaussian view-space gradient statistics per time bin (between two density steps).

    grad: (N, B) summed NDC gradient norms; count: (N, B) views that drew the Gaussian.
    """

    grad: torch.Tensor
    count: torch.Tensor

    @classmethod
    def zeros(cls, n: int, bins: int = TEMPORAL_BINS, device: torch.device | str = "cpu") -> "TemporalStats":
        return cls(torch.zeros(n, bins, device=device), torch.zeros(n, bins, device=device))

    def __len__(self) -> int:
        return int(self.grad.shape[0])

    def to(self, device: torch.device | str) -> "TemporalStats":
        """These statistics on ``device``."""
        return TemporalStats(self.grad.to(device), self.count.to(device))

    @torch.no_grad()
    def update(self, means2d_grad: torch.Tensor, radii: torch.Tensor, width: int, height: int, t: float) -> None:
        """Add one view rendered at clip time t (same conventions as DensifyStats.update, and as
        it without reading a value back)."""
        vis = radii.reshape(-1) > 0
        b = min(int(float(t) * self.grad.shape[1]), self.grad.shape[1] - 1)
        g = ndc_grad_norm(means2d_grad, width, height).to(self.grad.dtype)
        self.grad[:, b] += torch.where(vis, g, 0.0)
        self.count[:, b] += vis.to(self.count.dtype)

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {"grad": self.grad.clone(), "count": self.count.clone()}

    @classmethod
    def from_state_dict(cls, d: dict[str, torch.Tensor]) -> "TemporalStats":
        return cls(d["grad"].clone(), d["count"].clone())


@torch.no_grad()
def demote_candidates(model: SpacetimeGaussians) -> torch.Tensor:
    """(N,) bool: dynamic Gaussians that render like static ones over the clip t in [0, 1]."""
    cfg = model.config
    dyn = model.dynamic.clone()
    if not cfg.has_time_terms or not bool(dyn.any()):
        return torch.zeros_like(dyn)
    tc = model.t_center.detach()
    far = torch.maximum(tc.abs(), (1.0 - tc).abs())  # largest |dt| within the clip
    ok = dyn.clone()
    if cfg.temporal_opacity:
        s = torch.exp(model.t_log_scale.detach())
        ok &= (1.0 - torch.exp(-(far / s) ** 2)) < DEMOTE_OPACITY_VARIATION
    if cfg.motion_degree > 0:
        coeff = model.motion.detach().view(-1, cfg.motion_degree, 3)
        disp = torch.zeros(model.num_gaussians, dtype=coeff.dtype, device=coeff.device)
        for dt_sign in (-1.0, 1.0):
            dt = (far * dt_sign).unsqueeze(-1)
            acc = sum(coeff[:, k] * dt ** (k + 1) for k in range(cfg.motion_degree))
            disp = torch.maximum(disp, acc.norm(dim=-1))
        size = torch.exp(model.log_scales.detach()).max(dim=1).values
        ok &= disp <= DEMOTE_MOTION_SCALES * size
    if cfg.rotation_velocity:
        qn = model.quats.detach().norm(dim=-1).clamp_min(1e-12)
        ok &= (model.omega.detach().norm(dim=-1) * far / qn) < DEMOTE_MOTION_SCALES * 0.5
    return ok


@torch.no_grad()
def promote_candidates(model: SpacetimeGaussians, stats: TemporalStats, grad_threshold: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(N,) bool static Gaussians whose gradient is concentrated in one time bin, and (N,) that bin."""
    mean = torch.where(stats.count >= PROMOTE_MIN_VIEWS, stats.grad / stats.count.clamp_min(1.0),
                       torch.zeros_like(stats.grad))
    hot, b = mean.max(dim=1)
    bins = mean.shape[1]
    others = (mean.sum(dim=1) - hot) / max(bins - 1, 1)
    cand = (~model.dynamic) & (hot >= PROMOTE_GRAD_FACTOR * grad_threshold) & (hot >= PROMOTE_CONCENTRATION * others)
    return cand, b


@torch.no_grad()
def revise_terms(model: SpacetimeGaussians, optimizer, stats: TemporalStats, *, grad_threshold: float,
                 max_gaussians: int) -> dict[str, int]:
    """One revision step (module docstring): demote, then split hot static Gaussians into a
    time-local dynamic copy (within the ``max_gaussians`` budget, hottest first). Needs a model
    with temporal opacity to split; returns {"demoted": n, "split_dynamic": m}."""
    from fixer4d.model.densify import append_gaussians

    counts = {"demoted": 0, "split_dynamic": 0}
    cfg = model.config
    if not cfg.has_time_terms:
        return counts
    demote = demote_candidates(model) & ~model.frozen
    if bool(demote.any()):
        model.set_dynamic(model.dynamic & ~demote)
        counts["demoted"] = int(demote.sum())
    if not cfg.temporal_opacity or len(stats) != model.num_gaussians:
        return counts
    cand, b = promote_candidates(model, stats, grad_threshold)
    idx = torch.nonzero(cand).reshape(-1)
    budget = int(max_gaussians) - model.num_gaussians
    if idx.numel() == 0 or budget <= 0:
        return counts
    if idx.numel() > budget:
        hot = (stats.grad / stats.count.clamp_min(1.0)).max(dim=1).values[idx]
        idx = idx[torch.argsort(hot, descending=True, stable=True)[:budget]]
        idx = torch.sort(idx).values
    bins = stats.grad.shape[1]
    rows = {name: p.detach()[idx].clone() for name, p in model.named_parameters()}
    rows["t_center"] = (b[idx].to(rows["t_center"].dtype) + 0.5) / bins
    rows["t_log_scale"] = torch.full_like(rows["t_log_scale"], math.log(1.0 / bins))
    if "motion" in rows:
        rows["motion"].zero_()
    if "omega" in rows:
        rows["omega"].zero_()
    rows["dynamic"] = torch.ones(idx.numel(), dtype=torch.bool)
    append_gaussians(model, optimizer, rows)
    counts["split_dynamic"] = int(idx.numel())
    return counts
