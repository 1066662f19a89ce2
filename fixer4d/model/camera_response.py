"""Per-train-camera colour response: the model term for "the cameras do not agree on colour".

Real rigs expose and white-balance each camera on its own; the same surface then has another
colour in every train view, and a model that must reproduce all four splits the difference with
view-dependent colour, floaters and blur. The response maps the model's render into what camera
``v`` records, per channel ``c``::

    observed[v, c] = exp(a[v, c] - mean_v a[:, c]) * render[c] + (b[v, c] - mean_v b[:, c])

The means are subtracted, so the responses of the rig average to the identity: the model keeps
the rig's mean colour (what a held-out camera of the same rig is closest to on average) and no
camera is singled out as the reference. Renders at other cameras (held-out, pseudo-views, the
viewer, exports) are the model's own colours, without any response.

On or off is an evidence decision (``decide``), like the other model terms (fixer4d.model.terms):
per-view gains measured on static points that several train views see (``view_gains``) must
differ from one another beyond what the measurement's own noise explains.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import torch

# A camera's gain counts as different when it is this far from the rig's (log units, ~2 %): a 2 %
# gain error on a mid-grey pixel is a 0.01 intensity error (about 40 dB on its own), below what a
# response could win back; identical synthetic cameras measure under 0.3 %.
MIN_LOG_GAIN = 0.02
# ... and when it lies this many standard errors from the rig's (the standard error of a median
# ratio over the co-visible points, from their spread): noise alone exceeds 4 sigma rarely.
MIN_SIGMAS = 4.0
# Co-visible points a view needs before its gain is measured at all.
MIN_POINTS = 50
# Colours darker than this (in [0, 1]) are left out of the ratios: there a ratio is mostly noise.
MIN_COLOR = 0.05
# Adam step of the log gains and biases: 1e-3 per step moves a gain by up to ~0.1 % per step, so a
# 1500-step stage 1 can reach any real rig's 5-20 % differences while the Gaussians' colours
# (lr 2.5e-3) still lead early on.
RESPONSE_LR = 1e-3
# Weight of the pull toward the identity (mean square of the centred log gains and biases) in the
# per-view loss: with typical L1 losses of 0.02-0.1 it only decides what the images leave free.
RESPONSE_REG = 0.1


def view_gains(colors: np.ndarray, visible: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-view, per-channel log gain relative to the rig, from static points seen by >= 2 views.

    colors: (V, N, 3) the colour each view records for each point (any value where not visible);
    visible: (V, N) bool. For every point seen by >= 2 views, each seeing view's log colour minus
    the mean log colour of the views that see it; a view's log gain is the median of these over
    its points, centred over the views. Returns (log_gain (V, 3), stderr (V, 3), points (V,)):
    stderr from the median absolute deviation (1.253 x 1.4826 MAD / sqrt(n)); views with fewer than
    MIN_POINTS points get gain 0 and stderr inf.
    """
    colors = np.asarray(colors, np.float64)
    visible = np.asarray(visible, bool)
    V = colors.shape[0]
    bright = visible[..., None] & (colors >= MIN_COLOR)                       # (V, N, 3)
    logc = np.log(np.maximum(colors, MIN_COLOR))
    n = bright.sum(0)                                                         # (N, 3)
    mean = np.where(n > 0, (logc * bright).sum(0) / np.maximum(n, 1), 0.0)
    gain = np.zeros((V, 3))
    stderr = np.full((V, 3), np.inf)
    points = np.zeros(V, np.int64)
    for v in range(V):
        for c in range(3):
            use = bright[v, :, c] & (n[:, c] >= 2)
            if use.sum() < MIN_POINTS:
                continue
            d = logc[v, use, c] - mean[use, c]
            gain[v, c] = np.median(d)
            mad = np.median(np.abs(d - gain[v, c]))
            stderr[v, c] = 1.253 * 1.4826 * mad / np.sqrt(use.sum())
        points[v] = int((visible[v] & (visible.sum(0) >= 2)).sum())
    measured = np.isfinite(stderr)
    for c in range(3):
        if measured[:, c].any():
            gain[measured[:, c], c] -= gain[measured[:, c], c].mean()
    return gain, stderr, points


def decide(log_gain: np.ndarray, stderr: np.ndarray, forced: bool | None = None) -> tuple[bool, str]:
    """(on, reason): on when some view's gain differs from the rig's by >= MIN_LOG_GAIN and by
    >= MIN_SIGMAS standard errors; ``forced`` True/False overrides the evidence."""
    g, s = np.asarray(log_gain, np.float64), np.asarray(stderr, np.float64)
    if g.size == 0:
        return bool(forced), "no per-camera colour measurement (an init without a static cloud)"
    spread = np.abs(g)
    beyond = (spread >= MIN_LOG_GAIN) & (spread >= MIN_SIGMAS * s)
    worst = float(spread[np.isfinite(s)].max()) if np.isfinite(s).any() else 0.0
    figures = (f"largest per-camera gain difference {100 * (np.exp(worst) - 1):.1f}% "
               f"({int(beyond.any(1).sum())} of {g.shape[0]} cameras beyond {100 * MIN_LOG_GAIN:.0f}% and "
               f"{MIN_SIGMAS:g} standard errors)")
    if forced is not None:
        return bool(forced), f"forced {'on' if forced else 'off'}; {figures}"
    return bool(beyond.any()), figures


class CameraResponse(torch.nn.Module):
    """Affine colour response per train view (module docstring). ``apply(rgb, view)`` maps an
    (H, W, 3) render of train view ``view`` (its index in the scene's train list)."""

    def __init__(self, num_views: int) -> None:
        super().__init__()
        self.log_gain = torch.nn.Parameter(torch.zeros(num_views, 3))
        self.bias = torch.nn.Parameter(torch.zeros(num_views, 3))

    def gains_biases(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(V, 3) gains and (V, 3) biases with the rig's mean response the identity."""
        a = self.log_gain - self.log_gain.mean(0, keepdim=True)
        b = self.bias - self.bias.mean(0, keepdim=True)
        return torch.exp(a), b

    def apply(self, rgb: torch.Tensor, view: int) -> torch.Tensor:
        gain, bias = self.gains_biases()
        return rgb * gain[view] + bias[view]

    def regularizer(self) -> torch.Tensor:
        """Mean square of the centred log gains and biases."""
        a = self.log_gain - self.log_gain.mean(0, keepdim=True)
        b = self.bias - self.bias.mean(0, keepdim=True)
        return (a.square().mean() + b.square().mean()) / 2

    def summary(self) -> list[dict[str, Any]]:
        """Per view: gain and bias per channel (for report.json)."""
        with torch.no_grad():
            gain, bias = self.gains_biases()
        return [{"gain": [round(float(x), 5) for x in gain[v]], "bias": [round(float(x), 5) for x in bias[v]]}
                for v in range(gain.shape[0])]

    def to_json(self) -> dict[str, Any]:
        """The raw parameters (round-trips through ``from_json``) and the per-view summary."""
        return {"log_gain": self.log_gain.detach().tolist(), "bias": self.bias.detach().tolist(),
                "views": self.summary()}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> "CameraResponse":
        log_gain = torch.tensor(data["log_gain"], dtype=torch.float32)
        resp = cls(log_gain.shape[0])
        with torch.no_grad():
            resp.log_gain.copy_(log_gain)
            resp.bias.copy_(torch.tensor(data["bias"], dtype=torch.float32))
        return resp


def train_view_render_fn(render_fn, response: CameraResponse, train_cameras: list) -> Any:
    """``render_fn(camera, t) -> (H, W, 3)`` for scoring the fit to the train views: a train camera
    (``train_cameras``, in the response's view order; matched by name) comes out through its
    trained response, clipped to [0, 1] as the camera records it; any other camera as
    ``render_fn`` renders it."""
    index = {c.name: k for k, c in enumerate(train_cameras)}
    with torch.no_grad():
        gains, biases = (x.cpu().numpy() for x in response.gains_biases())

    def fn(camera, t: float) -> np.ndarray:
        rgb = render_fn(camera, t)
        k = index.get(camera.name)
        return rgb if k is None else np.clip(rgb * gains[k] + biases[k], 0.0, 1.0).astype(np.float32)

    return fn
