"""Adaptive density control for spacetime Gaussians (3DGS clone/split/prune) and the Adam
state surgery that keeps the optimizer aligned with a model whose Gaussian count changes.

The model owns its Parameters (``model.prune(keep)`` / ``model.append(rows)`` replace them);
this module re-binds every Adam group to the new Parameter and carries its moments: survivors
keep theirs, new rows start at zero (as 3DGS does). Every size threshold is relative to the
scene extent or the image size, never an absolute scene-specific number.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

# The one torch quaternion->matrix (normalizes; zero -> identity); the name stays for callers.
from fixer4d.geometry.quaternion import to_matrix_torch as quat_to_matrix

# Adam per-parameter state entries that have one row per Gaussian.
_ROW_STATES = ("exp_avg", "exp_avg_sq", "max_exp_avg_sq")


def make_adam(param_groups: list[dict], eps: float, lr: float = 0.0) -> torch.optim.Adam:
    """The Adam every Gaussian model trains with: torch's fused kernel where every parameter is
    a floating CPU or CUDA tensor (one pass per tensor instead of ~10 foreach ops: 16.8 -> ~5 ms
    a step for 100k Gaussians on one CPU thread; same update rule, round-off differs), else the
    default implementation. The state layout is the same either way, so the surgery below and
    checkpoints do not care which."""
    params = [p for g in param_groups for p in g["params"]]
    fused = bool(params) and all(p.is_floating_point() and p.device.type in ("cpu", "cuda") for p in params)
    return torch.optim.Adam(param_groups, lr=lr, eps=eps, fused=fused or None)


@dataclass
class DensifyStats:
    """Per-Gaussian statistics accumulated between densification steps.

    grad_accum: (N,) sum over views of the view-space positional gradient norm (NDC units).
    denom: (N,) number of views in which the Gaussian was drawn (radii > 0).
    max_radii: (N,) largest screen radius seen, as a fraction of the image's larger side.
    """

    grad_accum: torch.Tensor
    denom: torch.Tensor
    max_radii: torch.Tensor

    @classmethod
    def zeros(cls, n: int, device: torch.device | str = "cpu") -> "DensifyStats":
        z = lambda: torch.zeros(n, dtype=torch.float32, device=device)  # noqa: E731
        return cls(z(), z(), z())

    def __len__(self) -> int:
        return int(self.grad_accum.shape[0])

    def to(self, device: torch.device | str) -> "DensifyStats":
        """These statistics on ``device``."""
        return DensifyStats(self.grad_accum.to(device), self.denom.to(device), self.max_radii.to(device))

    @torch.no_grad()
    def update(self, means2d_grad: torch.Tensor, radii: torch.Tensor, width: int, height: int) -> None:
        """Add one view: ``means2d_grad`` (N, 2) dL/d(pixel position), ``radii`` (N,) pixels.

        The pixel-space gradient is converted to NDC (x W/2, y H/2) so that the threshold does
        not depend on the image resolution (the convention of 3DGS's viewspace gradient).

        The rows not drawn are selected away rather than indexed out (``torch.where`` instead of
        a boolean mask), so nothing is read back to the host: on a GPU the step does not wait
        here. A drawn row gets the same sums as ``grad_accum[vis] += g[vis]``, bit for bit; an
        undrawn one adds an exact zero.
        """
        vis = radii.reshape(-1) > 0
        g = ndc_grad_norm(means2d_grad, width, height).to(self.grad_accum.dtype)
        self.grad_accum += torch.where(vis, g, 0.0)
        self.denom += vis.to(self.denom.dtype)
        r = radii.detach().to(self.max_radii.dtype) / float(max(width, height))
        self.max_radii.copy_(torch.where(vis, torch.maximum(self.max_radii, r), self.max_radii))

    def mean_grad(self) -> torch.Tensor:
        """(N,) average gradient norm over the views that drew each Gaussian (0 if none)."""
        return torch.where(self.denom > 0, self.grad_accum / self.denom.clamp_min(1.0), torch.zeros_like(self.grad_accum))

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {"grad_accum": self.grad_accum.clone(), "denom": self.denom.clone(), "max_radii": self.max_radii.clone()}

    @classmethod
    def from_state_dict(cls, d: dict[str, torch.Tensor]) -> "DensifyStats":
        return cls(d["grad_accum"].clone(), d["denom"].clone(), d["max_radii"].clone())


def ndc_grad_norm(means2d_grad: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """(N,) norm of a pixel-space gradient (N, 2) in NDC units (x W/2, y H/2), so that the
    densification threshold does not depend on the image resolution."""
    g = means2d_grad.detach()
    return torch.stack([g[:, 0] * (width * 0.5), g[:, 1] * (height * 0.5)], -1).norm(dim=-1)


# ---- optimizer surgery -------------------------------------------------------------------

def _rebind(model: torch.nn.Module, optimizer: torch.optim.Optimizer,
            transform: Callable[[str, torch.Tensor], torch.Tensor]) -> None:
    """Point each named Adam group at the model's current Parameter of that name and map its
    per-row moments through ``transform(name, moment)``."""
    params = dict(model.named_parameters())
    for group in optimizer.param_groups:
        name = group["name"]
        old = group["params"][0]
        new = params[name]
        state = optimizer.state.pop(old, None)
        group["params"][0] = new
        if state:
            for key in _ROW_STATES:
                if key in state:
                    state[key] = transform(name, state[key]).contiguous()
            optimizer.state[new] = state


def prune_gaussians(model: torch.nn.Module, optimizer: torch.optim.Optimizer | None, keep: torch.Tensor) -> None:
    """Keep the Gaussians where ``keep`` (N,) bool is True, in the model and in Adam's moments."""
    keep = keep.to(torch.bool)
    model.prune(keep)
    if optimizer is not None:
        _rebind(model, optimizer, lambda _n, m: m[keep])


def append_gaussians(model: torch.nn.Module, optimizer: torch.optim.Optimizer | None,
                     rows: dict[str, torch.Tensor]) -> None:
    """Append new Gaussians (``rows``: parameter name -> (M, ...) values, plus ``dynamic`` when
    the model has that buffer); their Adam moments start at zero."""
    n_new = int(next(iter(rows.values())).shape[0])
    model.append(rows)
    if optimizer is not None:
        _rebind(model, optimizer,
                lambda _n, m: torch.cat([m, m.new_zeros((n_new, *m.shape[1:]))], 0))


@torch.no_grad()
def reset_parameter(model: torch.nn.Module, optimizer: torch.optim.Optimizer | None, name: str,
                    value: torch.Tensor) -> None:
    """Overwrite parameter ``name`` in place and zero its Adam moments (the 3DGS opacity reset)."""
    param = dict(model.named_parameters())[name]
    param.copy_(value)
    if optimizer is not None and param in optimizer.state:
        for key in _ROW_STATES:
            if key in optimizer.state[param]:
                optimizer.state[param][key].zero_()


# ---- densify and prune -------------------------------------------------------------------

def _rows(model: torch.nn.Module, index: torch.Tensor) -> dict[str, torch.Tensor]:
    """Copies of every per-Gaussian parameter (and the ``dynamic`` buffer) at ``index``."""
    rows = {name: p.detach()[index].clone() for name, p in model.named_parameters()}
    dyn = getattr(model, "dynamic", None)
    if isinstance(dyn, torch.Tensor):
        rows["dynamic"] = dyn[index].clone()
    return rows


def _frozen(model: torch.nn.Module) -> torch.Tensor:
    """(N,) bool rows density control must leave alone (all False for a model without the buffer)."""
    frozen = getattr(model, "frozen", None)
    if isinstance(frozen, torch.Tensor):
        return frozen
    return torch.zeros(model.num_gaussians, dtype=torch.bool, device=model.means.device)


def _budgeted(candidates: torch.Tensor, cost: torch.Tensor, priority: torch.Tensor, budget: int) -> torch.Tensor:
    """Restrict a (N,) bool candidate mask to the highest-priority ones whose summed cost fits
    ``budget`` (the Gaussian cap)."""
    idx = torch.nonzero(candidates).reshape(-1)
    if idx.numel() == 0 or int(cost[idx].sum()) <= budget:
        return candidates
    order = idx[torch.argsort(priority[idx], descending=True, stable=True)]
    fits = torch.cumsum(cost[order], 0) <= max(budget, 0)
    out = torch.zeros_like(candidates)
    out[order[fits]] = True
    return out


@torch.no_grad()
def densify_and_prune(model: torch.nn.Module, optimizer: torch.optim.Optimizer | None, stats: DensifyStats, *,
                      extent: float, grad_threshold: float, percent_dense: float, max_gaussians: int,
                      prune_opacity: float, prune_world_scale: float | None, prune_screen_fraction: float | None,
                      generator: torch.Generator, split_children: int = 2,
                      split_scale_divisor: float = 1.6) -> dict[str, int]:
    """One 3DGS densification step on ``model`` (and ``optimizer``), then pruning.

    Gaussians whose mean view-space gradient (``stats``) reaches ``grad_threshold`` are cloned
    when small (max scale <= ``percent_dense`` x extent) or split when large: ``split_children``
    children drawn from the parent Gaussian, scales divided by ``split_scale_divisor``, the parent
    removed. New Gaussians stop at ``max_gaussians`` (highest gradients first). Then Gaussians
    with base opacity below ``prune_opacity``, (when set) a world max scale above
    ``prune_world_scale`` x extent, or (when set) a screen radius above ``prune_screen_fraction``
    of the image are removed; 3DGS applies the two size tests only after the first opacity reset,
    when the init's large Gaussians have had time to shrink. Frozen rows (``model.frozen``) are
    never cloned, split or pruned. Returns counts: cloned, split, pruned, total. ``stats`` must be reset by
    the caller (its length no longer matches).
    """
    n = model.num_gaussians
    grads = stats.mean_grad()
    scales = torch.exp(model.log_scales.detach())
    max_scale = scales.max(dim=1).values
    movable = ~_frozen(model)
    hot = (grads >= grad_threshold) & movable
    small = max_scale <= percent_dense * extent
    clone = hot & small
    split = hot & ~small
    cost = torch.where(split, float(split_children - 1), 1.0).to(torch.float64)
    budget = int(max_gaussians) - n
    chosen = _budgeted(clone | split, cost, grads, budget)
    clone &= chosen
    split &= chosen

    new_rows: list[dict[str, torch.Tensor]] = []
    if bool(clone.any()):
        new_rows.append(_rows(model, clone))
    n_split = int(split.sum())
    if n_split:
        idx = torch.nonzero(split).reshape(-1).repeat(split_children)
        children = _rows(model, idx)
        std = scales[idx]
        # drawn on the generator's device (the trainer's is on the CPU) so that a CUDA run splits
        # with the same offsets as a CPU run of the same seed
        device = std.device if generator is None else generator.device
        local = torch.randn(std.shape, generator=generator, dtype=std.dtype, device=device).to(std.device) * std
        rot = quat_to_matrix(model.quats.detach()[idx])
        children["means"] = children["means"] + torch.einsum("nij,nj->ni", rot, local)
        children["log_scales"] = torch.log(std / split_scale_divisor)
        new_rows.append(children)
    n_added = 0
    if new_rows:
        merged = {k: torch.cat([r[k] for r in new_rows], 0) for k in new_rows[0]}
        n_added = int(next(iter(merged.values())).shape[0])
        append_gaussians(model, optimizer, merged)

    pad = lambda t: torch.cat([t, t.new_zeros(n_added)])  # noqa: E731 (new Gaussians: no history)
    drop = torch.cat([split, torch.zeros(n_added, dtype=torch.bool, device=split.device)])
    opacity = torch.sigmoid(model.opacity_logits.detach())
    drop |= opacity < prune_opacity
    if prune_world_scale is not None:
        drop |= torch.exp(model.log_scales.detach()).max(dim=1).values > prune_world_scale * extent
    if prune_screen_fraction is not None:
        drop |= pad(stats.max_radii) > prune_screen_fraction
    drop &= ~_frozen(model)
    if bool(drop.all()):
        # Never prune to an empty model: keep the most opaque Gaussian so training can go on.
        drop[torch.argmax(opacity)] = False
    if bool(drop.any()):
        prune_gaussians(model, optimizer, ~drop)
    return {"cloned": int(clone.sum()), "split": n_split, "pruned": int(drop.sum()) - n_split,
            "total": model.num_gaussians}
