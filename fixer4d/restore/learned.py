"""LearnedRestorer: a small per-scene CNN that blends the render with the warped references.

The geometric ``ReferenceWarpRestorer`` runs first (one warping implementation): it gives, per
novel frame, the two endpoint references warped through the render's depth with their
occlusion-tested visibility, the fused warp of every real view, its hole / blur / blend maps and
its own restored frame. From those ``frame_features`` builds a (FEATURE_CHANNELS, H, W) input:

    0:3   render            3:6   reference 0 warped (colour-corrected onto the render)
    6:9   reference 1 warped 9:12  fused warp of all real views
    12:15 warp restorer output
    15 alpha  16 log depth / median depth (0 = unknown)  17, 18 visibility of references 0, 1
    19 warp blend  20 hole  21 blur  22 warp restorer confidence

``RestorerNet`` (a 3-level U-Net, ~150 k parameters at width 24) outputs per pixel softmax blend
weights over the five colour candidates (render, ref 0, ref 1, fused warp, warp output; a
reference that does not see the pixel is excluded), a residual bounded by ``residual_bound``
(tanh) and a confidence (sigmoid) trained to predict exp(-error / LEARNED_CONF_ERROR_SCALE).
restored = sum_i w_i candidate_i + residual. Along a clip, the blend weights and the confidence
are averaged with the neighbouring frames' (warped through the depth, ``smooth_along_clip``).

Training (``train_network``) is plain torch on the CPU: L1 + 0.2 D-SSIM + 0.1 confidence BCE on
random crops, Adam, fixed seed and thread count (deterministic). The pairs come from the scene
itself (``fixer4d.train.restorer_pairs``). Weights are saved as an npz of plain arrays.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from fixer4d.atomic import atomic_path, write_json
from fixer4d.errors import InputError
import fixer4d.restore.constants as C
from fixer4d.restore.base import ProgressFn, RestoreRequest, RestoreResult
from fixer4d.restore.config import META_FILE, WEIGHTS_FILE, LearnedRestorerConfig, RestoreConfig
from fixer4d.restore.reference_warp import FrameWarp, ReferenceWarpRestorer, sanitize_depth, smooth_along_clip
from fixer4d.threads import torch_threads

FORMAT = 1
FEATURE_CHANNELS = 23
CANDIDATES = ("render", "ref0", "ref1", "fused_warp", "warp_output")
# channel slices of the colour candidates inside the features, in CANDIDATES order
_CAND_SLICES = [(0, 3), (3, 6), (6, 9), (9, 12), (12, 15)]
_VIS0, _VIS1 = 17, 18
# Depth feature: log(depth / median) clipped to +-this (an order of magnitude either way).
_LOG_DEPTH_CLIP = 2.3
# A masked-out candidate's logit: exp(-1e4) underflows to exactly 0 in float32.
_MASKED_LOGIT = -1e4


# ---- features ------------------------------------------------------------------------------

def color_correct(warped: np.ndarray, visible: np.ndarray, render: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """(H, W, 3) ``warped`` with a per-channel gain and bias fitted onto ``render`` over pixels the
    warp sees and the render covers (alpha >= COLOR_FIT_ALPHA_MIN); bounded so that a wrong
    render cannot recolour a real image; unchanged with too few matched pixels."""
    sel = (visible > 0.5) & (alpha >= C.COLOR_FIT_ALPHA_MIN)
    if int(sel.sum()) < C.COLOR_FIT_MIN_PIXELS:
        return warped
    out = np.empty_like(warped)
    for ch in range(3):
        x = warped[..., ch][sel].astype(np.float64)
        y = render[..., ch][sel].astype(np.float64)
        var = x.var()
        gain = float(np.clip(((x - x.mean()) * (y - y.mean())).mean() / var if var > 1e-8 else 1.0,
                             *C.COLOR_GAIN_RANGE))
        bias = float(np.clip(y.mean() - gain * x.mean(), -C.COLOR_BIAS_MAX, C.COLOR_BIAS_MAX))
        out[..., ch] = warped[..., ch] * gain + bias
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def frame_features(request: RestoreRequest, k: int, fw: FrameWarp, warp_rgb: np.ndarray,
                   warp_conf: np.ndarray) -> np.ndarray:
    """(FEATURE_CHANNELS, H, W) float32 input of frame k (see module doc for the channels).

    fw: the warp restorer's ``FrameWarp`` of frame k; warp_rgb (H, W, 3) / warp_conf (H, W): its
    restored frame and confidence.
    """
    render = np.clip(np.nan_to_num(request.rgb[k], nan=0.0), 0.0, 1.0).astype(np.float32)
    alpha = np.clip(np.nan_to_num(request.alpha[k], nan=0.0), 0.0, 1.0).astype(np.float32)
    depth = sanitize_depth(request.depth[k])
    valid = depth > 0
    logd = np.zeros(depth.shape, np.float32)
    if valid.any():
        logd[valid] = np.clip(np.log(depth[valid] / np.median(depth[valid])), -_LOG_DEPTH_CLIP, _LOG_DEPTH_CLIP)
    refs = []
    for r in range(2):
        col, vis = fw.colors[r], fw.visible[r]
        refs.append((color_correct(col, vis, render, alpha) * vis[..., None], vis.astype(np.float32)))
    chans = [render, refs[0][0], refs[1][0], fw.warp, warp_rgb,
             alpha[..., None], logd[..., None], refs[0][1][..., None], refs[1][1][..., None],
             fw.blend[..., None], fw.hole[..., None], fw.blur[..., None], warp_conf[..., None]]
    feats = np.concatenate([np.asarray(c, np.float32) for c in chans], axis=2)
    assert feats.shape[2] == FEATURE_CHANNELS
    return np.ascontiguousarray(feats.transpose(2, 0, 1))


def request_features(request: RestoreRequest, warp: ReferenceWarpRestorer) -> tuple[list[np.ndarray], list[FrameWarp]]:
    """Per frame of ``request``: its features (C, H, W) and the warp restorer's ``FrameWarp``."""
    result, fws = warp.restore_detailed(request)
    feats = [frame_features(request, k, fws[k], result.rgb[k], result.confidence[k]) for k in range(request.num_frames)]
    return feats, fws


# ---- the network ---------------------------------------------------------------------------

def _block(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride=stride, padding=1, padding_mode="replicate"),
                         nn.LeakyReLU(0.1),
                         nn.Conv2d(cout, cout, 3, padding=1, padding_mode="replicate"), nn.LeakyReLU(0.1))


class RestorerNet(nn.Module):
    """(B, FEATURE_CHANNELS, H, W) -> logits (B, 5, H, W), residual (B, 3, H, W) in +-bound,
    confidence logits (B, 1, H, W). Any H, W (decoder upsamples to the skip's size)."""

    def __init__(self, width: int = C.LEARNED_WIDTH, residual_bound: float = C.LEARNED_RESIDUAL_BOUND) -> None:
        super().__init__()
        w = int(width)
        self.residual_bound = float(residual_bound)
        self.enc1 = _block(FEATURE_CHANNELS, w)
        self.enc2 = _block(w, 2 * w, stride=2)
        self.enc3 = _block(2 * w, 2 * w, stride=2)
        self.dec2 = nn.Sequential(nn.Conv2d(4 * w, 2 * w, 3, padding=1, padding_mode="replicate"), nn.LeakyReLU(0.1))
        self.dec1 = nn.Sequential(nn.Conv2d(3 * w, w, 3, padding=1, padding_mode="replicate"), nn.LeakyReLU(0.1))
        self.head = nn.Conv2d(w, len(CANDIDATES) + 4, 1)
        with torch.no_grad():  # start as the warp restorer: its output candidate wins, no residual
            self.head.weight.zero_()
            self.head.bias.zero_()
            self.head.bias[len(CANDIDATES) - 1] = C.LEARNED_INIT_WARP_LOGIT

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        e1 = self.enc1(x)
        e2 = self.enc2(e1)
        e3 = self.enc3(e2)
        d2 = self.dec2(torch.cat([F.interpolate(e3, size=e2.shape[-2:], mode="bilinear", align_corners=False), e2], 1))
        d1 = self.dec1(torch.cat([F.interpolate(d2, size=e1.shape[-2:], mode="bilinear", align_corners=False), e1], 1))
        out = self.head(d1)
        n = len(CANDIDATES)
        return out[:, :n], self.residual_bound * torch.tanh(out[:, n:n + 3]), out[:, n + 3:n + 4]

    def num_parameters(self) -> int:
        return int(sum(p.numel() for p in self.parameters()))


def blend_weights(feats: torch.Tensor, logits: torch.Tensor) -> torch.Tensor:
    """(B, 5, H, W) softmax weights over the candidates, a reference excluded where it is not visible."""
    vis0, vis1 = feats[:, _VIS0:_VIS0 + 1], feats[:, _VIS1:_VIS1 + 1]
    ones = torch.ones_like(vis0)
    avail = torch.cat([ones, vis0, vis1, ones, ones], 1) > 0.5
    return torch.softmax(torch.where(avail, logits, torch.full_like(logits, _MASKED_LOGIT)), dim=1)


def compose(feats: torch.Tensor, weights: torch.Tensor, residual: torch.Tensor) -> torch.Tensor:
    """(B, 3, H, W) restored colour: sum_i weights_i x candidate_i + residual, clamped to [0, 1]."""
    out = residual
    for i, (a, b) in enumerate(_CAND_SLICES):
        out = out + weights[:, i:i + 1] * feats[:, a:b]
    return out.clamp(0.0, 1.0)


def _ssim(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean SSIM of (B, 3, H, W) images in [0, 1] (11x11 Gaussian window, sigma 1.5, valid part)."""
    g = torch.exp(-((torch.arange(11, dtype=a.dtype) - 5.0) ** 2) / (2 * 1.5 ** 2))
    g = g / g.sum()
    win = (g[:, None] * g[None, :]).expand(3, 1, 11, 11).contiguous()

    def filt(x: torch.Tensor) -> torch.Tensor:
        return F.conv2d(x, win, groups=3)

    mu_a, mu_b = filt(a), filt(b)
    var_a = filt(a * a) - mu_a ** 2
    var_b = filt(b * b) - mu_b ** 2
    cov = filt(a * b) - mu_a * mu_b
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    s = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2))
    return s.mean()


def restorer_loss(net: RestorerNet, feats: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(loss, restored (B, 3, H, W)) for a batch: L1 + LEARNED_SSIM_WEIGHT x D-SSIM + the
    confidence head's BCE against exp(-|restored - target| / LEARNED_CONF_ERROR_SCALE)."""
    logits, residual, conf_logit = net(feats)
    out = compose(feats, blend_weights(feats, logits), residual)
    l1 = (out - target).abs().mean()
    loss = l1
    if min(out.shape[-2:]) >= 11:
        loss = loss + C.LEARNED_SSIM_WEIGHT * (1.0 - _ssim(out, target)) / 2.0
    err = (out.detach() - target).abs().mean(1, keepdim=True)
    conf_target = torch.exp(-err / C.LEARNED_CONF_ERROR_SCALE)
    loss = loss + C.LEARNED_CONF_WEIGHT * F.binary_cross_entropy_with_logits(conf_logit, conf_target)
    return loss, out


def train_network(samples: Sequence[tuple[np.ndarray, np.ndarray]], config: LearnedRestorerConfig,
                  progress: Callable[[int, float], None] | None = None) -> tuple[RestorerNet, dict[str, Any]]:
    """Train a RestorerNet on ``samples`` = [(features (C, H, W), target (H, W, 3))].

    ``config.steps`` Adam steps on ``config.batch`` random crops of ``config.crop`` pixels (or the
    smallest sample's size), learning rate cosine-decayed from ``config.lr``; numpy and torch seeded
    from ``config.seed`` and ``config.threads`` torch threads, so the same samples give the same
    weights. progress(step, loss) is called every step. Returns (net, stats: steps, cpu_seconds,
    wall_seconds, final_loss, parameters).
    """
    if not samples:
        raise InputError("train_network: no training pairs; the pair builder produced none")
    for feats, target in samples:
        if feats.shape[0] != FEATURE_CHANNELS or feats.shape[1:] != target.shape[:2]:
            raise InputError(f"train_network: a sample has features {feats.shape} and target {target.shape}; "
                             f"expected ({FEATURE_CHANNELS}, H, W) and (H, W, 3)")
    rng = np.random.default_rng(config.seed)
    crop = int(min(config.crop, min(min(f.shape[1:]) for f, _ in samples)))
    data = [(torch.from_numpy(np.ascontiguousarray(f, np.float32)),
             torch.from_numpy(np.ascontiguousarray(t.transpose(2, 0, 1), np.float32))) for f, t in samples]
    cpu0, wall0 = time.process_time(), time.perf_counter()
    with torch_threads(config.threads):
        torch.manual_seed(config.seed)
        net = RestorerNet(config.width, config.residual_bound)
        opt = torch.optim.Adam(net.parameters(), lr=config.lr)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(config.steps, 1), eta_min=config.lr * 0.05)
        loss_v = float("nan")
        for step in range(config.steps):
            xs, ys = [], []
            for _ in range(config.batch):
                f, t = data[int(rng.integers(len(data)))]
                y0 = int(rng.integers(0, f.shape[1] - crop + 1))
                x0 = int(rng.integers(0, f.shape[2] - crop + 1))
                xs.append(f[:, y0:y0 + crop, x0:x0 + crop])
                ys.append(t[:, y0:y0 + crop, x0:x0 + crop])
                if rng.random() < 0.5:  # horizontal flip: the blend rules do not depend on the side
                    xs[-1], ys[-1] = xs[-1].flip(-1), ys[-1].flip(-1)
            loss, _ = restorer_loss(net, torch.stack(xs), torch.stack(ys))
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            loss_v = float(loss.detach())
            if progress is not None:
                progress(step + 1, loss_v)
    net.eval()
    stats = {"steps": int(config.steps), "cpu_seconds": time.process_time() - cpu0,
             "wall_seconds": time.perf_counter() - wall0, "final_loss": loss_v, "parameters": net.num_parameters()}
    return net, stats


@torch.no_grad()
def apply_network(net: RestorerNet, feats: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One frame's features (C, H, W) -> blend weights (5, H, W), residual (3, H, W), confidence (H, W)."""
    x = torch.from_numpy(np.ascontiguousarray(feats, np.float32))[None]
    logits, residual, conf_logit = net(x)
    w = blend_weights(x, logits)
    return w[0].numpy(), residual[0].numpy(), torch.sigmoid(conf_logit)[0, 0].numpy()


def restore_features(net: RestorerNet, feats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One frame (no temporal smoothing): features (C, H, W) -> restored (H, W, 3), confidence (H, W)."""
    w, res, conf = apply_network(net, feats)
    out = compose(torch.from_numpy(feats)[None], torch.from_numpy(w)[None], torch.from_numpy(res)[None])
    return out[0].numpy().transpose(1, 2, 0), conf


# ---- the restorer --------------------------------------------------------------------------

class LearnedRestorer:
    """The per-scene learned restorer (see module doc). Build it with ``LearnedRestorer.load`` or
    ``build_restorer``; ``settings()`` names the weights by their SHA-1."""

    name = "learned"

    def __init__(self, net: RestorerNet, config: RestoreConfig, meta: dict[str, Any] | None = None) -> None:
        self.net = net.eval()
        self.config = config
        self.warp = ReferenceWarpRestorer(config.warp)
        self.meta = dict(meta or {})

    def settings(self) -> dict[str, Any]:
        return {"warp": dataclasses.asdict(self.config.warp), "learned": dataclasses.asdict(self.config.learned),
                "weights_sha1": self.meta.get("weights_sha1")}

    def restore(self, request: RestoreRequest, progress: ProgressFn | None = None) -> RestoreResult:
        """Restore every frame: rgb (F, H, W, 3), confidence (F, H, W), frame_confidence (F,)."""
        lc = self.config.learned
        feats, fws = request_features(request, self.warp)
        Fn = request.num_frames
        maps, residuals = [], []
        for k in range(Fn):
            w, res, conf = apply_network(self.net, feats[k])
            maps.append(np.concatenate([w.transpose(1, 2, 0), conf[..., None]], axis=2))
            residuals.append(res)
            if progress is not None:
                progress(0.9 * (k + 1) / Fn)
        if Fn > 1 and lc.temporal_radius > 0:
            maps = smooth_along_clip(request.cameras, [fw.depth for fw in fws], maps, lc.temporal_radius,
                                     lc.temporal_neighbor_weight, self.config.warp.occlusion_rel_tol)
        rgb = np.empty_like(request.rgb)
        confidence = np.empty(request.alpha.shape, np.float32)
        n = len(CANDIDATES)
        for k in range(Fn):
            x = torch.from_numpy(feats[k])[None]
            w = torch.from_numpy(np.ascontiguousarray(maps[k][..., :n].transpose(2, 0, 1)))[None]
            # a neighbour may bring weight to a reference this frame does not see: re-mask, renormalize
            vis = torch.cat([torch.ones_like(x[:, :1]), x[:, _VIS0:_VIS0 + 1], x[:, _VIS1:_VIS1 + 1],
                             torch.ones_like(x[:, :2])], 1)
            w = w * (vis > 0.5)
            w = w / w.sum(1, keepdim=True).clamp_min(1e-8)
            rgb[k] = compose(x, w, torch.from_numpy(residuals[k])[None])[0].numpy().transpose(1, 2, 0)
            confidence[k] = np.clip(maps[k][..., n], 0.0, 1.0)
        if progress is not None:
            progress(1.0)
        return RestoreResult(rgb, confidence, confidence.reshape(Fn, -1).mean(axis=1))

    # ---- files -------------------------------------------------------------------------
    def save(self, weights_dir: str | Path, extra: dict[str, Any] | None = None) -> Path:
        """Write WEIGHTS_FILE (npz of plain float32 arrays) and META_FILE atomically into ``weights_dir``."""
        weights_dir = Path(weights_dir)
        weights_dir.mkdir(parents=True, exist_ok=True)
        arrays = {k: v.detach().cpu().numpy().astype(np.float32) for k, v in self.net.state_dict().items()}
        with atomic_path(weights_dir / WEIGHTS_FILE, suffix=".npz") as tmp:
            np.savez(tmp, **arrays)
        digest = hashlib.sha1((weights_dir / WEIGHTS_FILE).read_bytes()).hexdigest()
        self.meta = {"format": FORMAT, "candidates": list(CANDIDATES), "feature_channels": FEATURE_CHANNELS,
                     "width": self.config.learned.width, "residual_bound": self.config.learned.residual_bound,
                     "parameters": self.net.num_parameters(), "weights_sha1": digest,
                     "training_key": self.config.learned.training_key(), **(extra or {})}
        write_json(weights_dir / META_FILE, self.meta)
        return weights_dir / WEIGHTS_FILE

    @classmethod
    def load(cls, weights_dir: str | Path, config: RestoreConfig) -> "LearnedRestorer":
        """Load the weights in ``weights_dir`` (written by ``save``) for ``config``."""
        weights_dir = Path(weights_dir)
        try:
            meta = json.loads((weights_dir / META_FILE).read_text())
            with np.load(weights_dir / WEIGHTS_FILE, allow_pickle=False) as data:
                state = {k: torch.from_numpy(np.array(data[k])) for k in data.files}
        except (OSError, ValueError) as exc:
            raise InputError(f"{weights_dir}: unreadable learned-restorer weights ({exc}); delete the folder so "
                             "that they are trained again") from exc
        if meta.get("format") != FORMAT or meta.get("feature_channels") != FEATURE_CHANNELS:
            raise InputError(f"{weights_dir}: learned-restorer weights of another format; delete the folder so "
                             "that they are trained again")
        net = RestorerNet(int(meta["width"]), float(meta["residual_bound"]))
        try:
            net.load_state_dict(state)
        except RuntimeError as exc:
            raise InputError(f"{weights_dir}: the weights do not fit the network ({exc}); delete the folder") from exc
        return cls(net, config, meta)
