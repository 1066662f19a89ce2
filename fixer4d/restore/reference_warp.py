"""ReferenceWarpRestorer: the built-in, CPU, deterministic reference-guided restorer.

For every novel frame of a clip (docs/design.md §11):

1. Geometry. The novel view's depth is the rendered depth where the render is opaque enough;
   elsewhere (holes) it is the references' model depth forward-splatted into the novel view
   (z-buffered), so a hole the model never filled still gets geometry from what the references
   see.
2. Warp. Every pixel is back-projected to a world point (pixel centre at (u + 0.5, v + 0.5)),
   projected into each source view (the two endpoint references, and the other real views of the
   timestamp when ``use_extra_views``) and the real image is sampled bilinearly. A point counts as
   visible in a source when its depth there lies within a relative tolerance of that source's own
   model depth (3x3 min..max range): the occlusion test.
3. Fuse the warps. Each source's weight = visibility x angular proximity of its ray to the novel
   ray through the point x photometric agreement (with the other warps' consensus and with the
   render's low frequencies, where the render exists).
4. Fuse with the render. The warp replaces the render by ``blend = ref confidence x
   max(hole, blur, base trust)``: hole = low alpha; blur = the local Laplacian energy of the
   render is below the warp's (the render lacks detail the real frames carry).
5. Temporal consistency. The ``blend`` weight of each frame is averaged with those of its
   neighbours along the trajectory, warped into it through its depth, so the
   choice between render and references does not flicker from frame to frame.
6. Inpaint what neither the render nor any source supports (push-pull pyramid fill).

The result carries a per-pixel confidence (how much real support a pixel has) and its per-frame
mean.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
import fixer4d.restore.constants as C
from fixer4d.restore.base import ProgressFn, RestoreRequest, RestoreResult

# Divisions by accumulated weights use this floor; weights are O(1) when anything is known.
_EPS = 1e-8


@dataclass
class ReferenceWarpConfig:
    """Settings of the reference-warp restorer (every field is documented in restore/constants.py)."""

    alpha_depth_min: float = C.ALPHA_DEPTH_MIN
    ref_alpha_min: float = C.REF_ALPHA_MIN
    occlusion_rel_tol: float = C.OCCLUSION_REL_TOL
    splat_crack_passes: int = C.SPLAT_CRACK_PASSES
    angle_sigma: float = C.ANGLE_SIGMA_RAD
    agreement_sigma: float = C.AGREEMENT_SIGMA
    lowpass_sigma: float = C.LOWPASS_SIGMA_PX
    detail_window_sigma: float = C.DETAIL_WINDOW_SIGMA_PX
    detail_energy_floor: float = C.DETAIL_ENERGY_FLOOR
    ref_base_trust: float = C.REF_BASE_TRUST
    hole_alpha_low: float = C.HOLE_ALPHA_LOW
    hole_alpha_high: float = C.HOLE_ALPHA_HIGH
    use_extra_views: bool = C.USE_EXTRA_VIEWS
    extra_view_weight: float = C.EXTRA_VIEW_WEIGHT
    inpaint_known_full: float = C.INPAINT_KNOWN_FULL
    temporal_radius: int = C.TEMPORAL_RADIUS
    temporal_neighbor_weight: float = C.TEMPORAL_NEIGHBOR_WEIGHT

    def __post_init__(self) -> None:
        if not 0.0 <= self.hole_alpha_low < self.hole_alpha_high <= 1.0:
            raise InputError(f"ReferenceWarpConfig: need 0 <= hole_alpha_low < hole_alpha_high <= 1, got "
                             f"{self.hole_alpha_low}, {self.hole_alpha_high}")
        for name in ("occlusion_rel_tol", "angle_sigma", "agreement_sigma", "lowpass_sigma",
                     "detail_window_sigma", "inpaint_known_full"):
            if not getattr(self, name) > 0:
                raise InputError(f"ReferenceWarpConfig: {name} must be > 0, got {getattr(self, name)}")
        if self.temporal_radius < 0 or self.splat_crack_passes < 0:
            raise InputError("ReferenceWarpConfig: temporal_radius and splat_crack_passes must be >= 0")


@dataclass
class _Source:
    """A real view used for warping, with what is precomputed once per clip."""

    camera: Camera
    image: np.ndarray      # (H_s, W_s, 3) float32
    depth_min: np.ndarray  # (H_s, W_s) float32, 3x3 min of valid model depth (inf where none)
    depth_max: np.ndarray  # (H_s, W_s) float32, 3x3 max of valid model depth (0 where none)
    points: np.ndarray     # (M, 3) world points of its valid depth pixels (for forward splatting)
    weight: float          # relative weight (1 for endpoint references)


@dataclass
class FrameWarp:
    """What the restorer computed for one novel frame (the learned restorer's inputs reuse it)."""

    depth: np.ndarray      # (H, W) float64 novel depth used for warping, 0 = unknown
    warp: np.ndarray       # (H, W, 3) fused warped colour
    blend: np.ndarray      # (H, W) weight of the warp against the render in [0, 1] (ref support x trust)
    blur: np.ndarray       # (H, W) how much blurrier the render is than the warp, [0, 1]
    hole: np.ndarray       # (H, W) 1 where the render is a hole
    # per source (the two endpoint references first, then the extra views): the source's image
    # warped into the frame (H, W, 3) and its visibility after the occlusion test (H, W) in {0, 1}
    colors: list[np.ndarray] = dataclasses.field(default_factory=list)
    visible: list[np.ndarray] = dataclasses.field(default_factory=list)


def sanitize_depth(depth: np.ndarray) -> np.ndarray:
    """Depth with every non-finite or non-positive value replaced by 0 (= unknown), float64."""
    d = np.asarray(depth, dtype=np.float64)
    return np.where(np.isfinite(d) & (d > C.MIN_VALID_DEPTH), d, 0.0)


def _transform(points: np.ndarray, M: np.ndarray) -> np.ndarray:
    """(..., 3) points -> M[:3, :3] p + M[:3, 3] with element-wise ops.

    A (N, 3) @ (3, 3) matmul goes through the multi-threaded BLAS, which is 10x slower than this
    on a busy 2-core machine; the restorer does dozens per frame.
    """
    x, y, z = points[..., 0:1], points[..., 1:2], points[..., 2:3]
    return x * M[:3, 0] + y * M[:3, 1] + z * M[:3, 2] + M[:3, 3]


def project(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``Camera.project`` for whole images of (..., 3) world points: uv (..., 2) continuous pixel
    coordinates (pixel centre at i + 0.5; NaN behind the camera) and z-depth (...).

    The restorer's own element-wise form (``_transform``), not a copy to merge: it avoids the BLAS
    matmul (10x slower on a busy 2-core machine) and rounds differently in the last bits, so the
    two cannot share one body without changing every restored frame's bits; tests check they
    agree to 1e-6 px (tests/restore/test_reference_warp.py)."""
    pc = _transform(points, camera.w2c)
    z = pc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (camera.fx * pc[..., 0] + camera.K[0, 1] * pc[..., 1]) / z + camera.cx
        v = camera.fy * pc[..., 1] / z + camera.cy
    uv = np.stack([u, v], axis=-1)
    uv[z <= 0] = np.nan
    return uv, z


def backproject(camera: Camera, depth: np.ndarray) -> np.ndarray:
    """(H, W) z-depth -> (H, W, 3) world points through pixel centres (``Camera.backproject_depth``)."""
    K = camera.K
    u = np.arange(camera.width, dtype=np.float64) + 0.5
    v = np.arange(camera.height, dtype=np.float64) + 0.5
    y = ((v - K[1, 2]) / K[1, 1])[:, None]
    x = (u[None, :] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    rays = np.stack(np.broadcast_arrays(x, y, np.ones_like(x)), axis=-1) * depth[..., None]
    return _transform(rays, camera.c2w)


def _remap(img: np.ndarray, uv: np.ndarray, interpolation: int) -> np.ndarray:
    """Sample ``img`` at continuous pixel coords uv (H, W, 2) (centre of pixel i at i + 0.5)."""
    # cv2.remap puts pixel centres at integers: shift by the half-pixel convention.
    mx = (uv[..., 0] - 0.5).astype(np.float32)
    my = (uv[..., 1] - 0.5).astype(np.float32)
    return cv2.remap(img, mx, my, interpolation, borderMode=cv2.BORDER_REPLICATE)


def _gauss(img: np.ndarray, sigma: float) -> np.ndarray:
    return cv2.GaussianBlur(img, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)


def _lowpass_masked(img: np.ndarray, mask: np.ndarray, sigma: float) -> np.ndarray:
    """Normalized convolution: the low-pass of ``img`` over pixels where ``mask`` (H, W) is set."""
    m = mask.astype(np.float32)
    num = _gauss(img * m[..., None], sigma)
    den = _gauss(m, sigma)
    return num / np.maximum(den, 1e-4)[..., None]


def _detail_energy(img: np.ndarray, sigma: float) -> np.ndarray:
    """(H, W) local energy of the Laplacian of the luminance: how much fine detail is there."""
    lum = img.mean(axis=2).astype(np.float32)
    lap = cv2.Laplacian(lum, cv2.CV_32F, ksize=1, borderType=cv2.BORDER_REFLECT)
    return _gauss(lap * lap, sigma)


def smooth_along_clip(cameras: list[Camera], depths: list[np.ndarray], maps: list[np.ndarray], radius: int,
                      neighbor_weight: float, rel_tol: float) -> list[np.ndarray]:
    """Temporal consistency along a clip: each frame's per-pixel maps (H, W, C) averaged with its
    ``radius`` neighbours' maps warped into it through its depth (H, W, 0 = unknown), a neighbour
    counting with ``neighbor_weight`` where it sees the same surface (depth within ``rel_tol``)."""
    F = len(maps)
    out = []
    for k in range(F):
        cam = cameras[k]
        H, W = cam.height, cam.width
        depth = np.asarray(depths[k], np.float64)
        points = backproject(cam, depth)
        num = maps[k].astype(np.float64).copy()
        den = np.ones((H, W, 1))
        for j in range(max(0, k - radius), min(F, k + radius + 1)):
            if j == k:
                continue
            uv, z = project(cameras[j], points)
            with np.errstate(invalid="ignore"):
                inside = (np.isfinite(uv).all(axis=2) & (uv[..., 0] >= 0) & (uv[..., 0] <= W)
                          & (uv[..., 1] >= 0) & (uv[..., 1] <= H) & (depth > 0))
            uv = np.where(inside[..., None], uv, 0.5)
            dj = _remap(np.asarray(depths[j], np.float32), uv, cv2.INTER_NEAREST)
            with np.errstate(invalid="ignore"):
                same = inside & (np.abs(z - dj) <= rel_tol * np.maximum(dj, C.MIN_VALID_DEPTH))
            wgt = (neighbor_weight * same)[..., None]
            warped = _remap(np.ascontiguousarray(maps[j], dtype=np.float32), uv, cv2.INTER_LINEAR)
            num += wgt * warped.reshape(H, W, -1)
            den += wgt
        out.append((num / den).astype(np.float32))
    return out


def push_pull_fill(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Fill (H, W, C) ``values`` where ``weights`` (H, W) in [0, 1] are small, from the known pixels.

    Gortler et al.'s push-pull: premultiplied values and weights are summed into a pyramid
    (weights clipped at 1 per level), then pulled back up, each level filling its missing part
    from the coarser one. Returns (H, W, C) float32; where nothing at all is known, zeros.
    """
    w = np.clip(weights.astype(np.float32), 0.0, 1.0)
    v = values.astype(np.float32) * w[..., None]
    pyramid = [(v, w)]
    while min(v.shape[:2]) > 1:
        H, W = v.shape[:2]
        Hp, Wp = H + H % 2, W + W % 2
        vp = np.pad(v, ((0, Hp - H), (0, Wp - W), (0, 0)))
        wp = np.pad(w, ((0, Hp - H), (0, Wp - W)))
        v = vp.reshape(Hp // 2, 2, Wp // 2, 2, -1).sum(axis=(1, 3))
        w = wp.reshape(Hp // 2, 2, Wp // 2, 2).sum(axis=(1, 3))
        scale = np.where(w > 1.0, 1.0 / np.maximum(w, _EPS), 1.0).astype(np.float32)
        v = v * scale[..., None]
        w = w * scale
        pyramid.append((v, w))
    v_up, w_up = pyramid[-1]
    for v_l, w_l in reversed(pyramid[:-1]):
        H, W = w_l.shape
        up_v = np.repeat(np.repeat(v_up, 2, axis=0), 2, axis=1)[:H, :W]
        up_w = np.repeat(np.repeat(w_up, 2, axis=0), 2, axis=1)[:H, :W]
        miss = (1.0 - w_l)
        v_up = v_l + miss[..., None] * up_v
        w_up = w_l + miss * up_w
    return (v_up / np.maximum(w_up, _EPS)[..., None]).astype(np.float32)


class ReferenceWarpRestorer:
    """Restore a rendered clip by warping the real reference frames into it (see module doc)."""

    name = "reference_warp"

    def __init__(self, config: ReferenceWarpConfig | None = None) -> None:
        self.config = config if config is not None else ReferenceWarpConfig()

    def settings(self) -> dict[str, Any]:
        return dataclasses.asdict(self.config)

    # ---- public ------------------------------------------------------------------------
    def restore(self, request: RestoreRequest, progress: ProgressFn | None = None) -> RestoreResult:
        """Restore every frame of ``request``; returns rgb (F, H, W, 3), confidence (F, H, W), (F,)."""
        return self.restore_detailed(request, progress)[0]

    def restore_detailed(self, request: RestoreRequest,
                         progress: ProgressFn | None = None) -> tuple[RestoreResult, list[FrameWarp]]:
        """``restore`` plus, per frame, the warps, visibilities and weights it used (``FrameWarp``;
        ``blend`` is the temporally smoothed one)."""
        cfg = self.config
        sources = self._sources(request)
        F = request.num_frames
        states: list[FrameWarp] = []
        for k in range(F):
            states.append(self._fuse_frame(request, k, sources))
            if progress is not None:
                progress(0.8 * (k + 1) / F)
        blends = [s.blend for s in states]
        if cfg.temporal_radius > 0 and F > 1:
            blends = self._temporal_smooth(request, states)
        rgb_out = np.empty_like(request.rgb)
        conf_out = np.empty(request.alpha.shape, dtype=np.float32)
        for k in range(F):
            rgb_out[k], conf_out[k] = self._composite(request.rgb[k], states[k], blends[k])
            if progress is not None:
                progress(0.8 + 0.2 * (k + 1) / F)
        frame_conf = conf_out.reshape(F, -1).mean(axis=1)
        for state, blend in zip(states, blends):
            state.blend = blend
        return RestoreResult(rgb_out, conf_out, frame_conf), states

    # ---- sources -----------------------------------------------------------------------
    def _sources(self, request: RestoreRequest) -> list[_Source]:
        cfg = self.config
        views: list[tuple[Camera, np.ndarray, np.ndarray, np.ndarray | None, float]] = [
            (cam, img, d, a, 1.0)
            for cam, img, d, a in zip(request.ref_cameras, request.ref_images, request.ref_depths, request.ref_alphas)
        ]
        if cfg.use_extra_views and request.num_extra:
            views += [(cam, img, d, None, cfg.extra_view_weight)
                      for cam, img, d in zip(request.extra_cameras, request.extra_images, request.extra_depths)]
        sources = []
        for cam, img, depth, alpha, weight in views:
            d = sanitize_depth(depth)
            valid = d > 0
            if alpha is not None:
                valid &= np.nan_to_num(alpha, nan=0.0) >= cfg.ref_alpha_min
            d32 = d.astype(np.float32)
            kernel = np.ones((3, 3), np.uint8)
            dmin = cv2.erode(np.where(valid, d32, np.float32(np.inf)), kernel, borderType=cv2.BORDER_REPLICATE)
            dmax = cv2.dilate(np.where(valid, d32, np.float32(0.0)), kernel, borderType=cv2.BORDER_REPLICATE)
            points = backproject(cam, np.where(valid, d, 0.0))[valid]
            image = np.clip(np.nan_to_num(img, nan=0.0), 0.0, 1.0).astype(np.float32)
            sources.append(_Source(cam, image, dmin, dmax, points, weight))
        return sources

    # ---- per frame ---------------------------------------------------------------------
    def _novel_depth(self, request: RestoreRequest, k: int, sources: list[_Source]) -> np.ndarray:
        """(H, W) float64 depth of novel frame k: rendered where opaque, splatted from sources elsewhere."""
        cfg = self.config
        cam = request.cameras[k]
        rendered = sanitize_depth(request.depth[k])
        opaque = (np.nan_to_num(request.alpha[k], nan=0.0) >= cfg.alpha_depth_min) & (rendered > 0)
        if opaque.all():
            return rendered
        # the endpoint references decide the depth of a hole; the extra views only fill what neither
        # endpoint sees (a far view's depth error would otherwise win the z-test: measured -1.8 dB)
        splat = self._splat(cam, sources[:2])
        if len(sources) > 2:
            splat = np.where(np.isinf(splat), self._splat(cam, sources[2:]), splat)
        splat = np.where(np.isfinite(splat), splat, 0.0).astype(np.float64)
        return np.where(opaque, rendered, splat)

    def _splat(self, cam: Camera, sources: list[_Source]) -> np.ndarray:
        """(H, W) float32 nearest depth of the sources' points seen from ``cam`` (inf where none),
        one-pixel cracks closed."""
        H, W = cam.height, cam.width
        splat = np.full(H * W, np.inf, dtype=np.float32)
        for src in sources:
            if len(src.points) == 0:
                continue
            uv, z = project(cam, src.points)
            with np.errstate(invalid="ignore"):
                ok = np.isfinite(uv).all(axis=1) & (z > C.MIN_VALID_DEPTH)
                ok &= (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
            idx = np.floor(uv[ok, 1]).astype(np.int64) * W + np.floor(uv[ok, 0]).astype(np.int64)
            zs = z[ok].astype(np.float32)
            order = np.argsort(-zs, kind="stable")  # farthest first, so the nearest write wins
            layer = np.full(H * W, np.inf, dtype=np.float32)
            layer[idx[order]] = zs[order]
            np.minimum(splat, layer, out=splat)
        splat = splat.reshape(H, W)
        kernel = np.ones((3, 3), np.uint8)
        for _ in range(self.config.splat_crack_passes):
            splat = np.where(np.isinf(splat), cv2.erode(splat, kernel, borderType=cv2.BORDER_REPLICATE), splat)
        return splat

    def _fuse_frame(self, request: RestoreRequest, k: int, sources: list[_Source]) -> FrameWarp:
        cfg = self.config
        cam = request.cameras[k]
        H, W = request.height, request.width
        render = np.clip(np.nan_to_num(request.rgb[k], nan=0.0), 0.0, 1.0)
        alpha = np.clip(np.nan_to_num(request.alpha[k], nan=0.0), 0.0, 1.0)
        depth = self._novel_depth(request, k, sources)
        has_depth = depth > 0
        points = backproject(cam, depth)
        to_novel = cam.center - points
        to_novel /= np.maximum(np.linalg.norm(to_novel, axis=2, keepdims=True), _EPS)

        colors, weights, visible = [], [], []
        for src in sources:
            uv, z = project(src.camera, points)
            with np.errstate(invalid="ignore"):
                inside = (np.isfinite(uv).all(axis=2) & (uv[..., 0] >= 0) & (uv[..., 0] <= src.camera.width)
                          & (uv[..., 1] >= 0) & (uv[..., 1] <= src.camera.height))
            uv = np.where(inside[..., None], uv, 0.5)
            dmin = _remap(src.depth_min, uv, cv2.INTER_NEAREST)
            dmax = _remap(src.depth_max, uv, cv2.INTER_NEAREST)
            with np.errstate(invalid="ignore"):
                vis = (inside & has_depth & (z >= dmin * (1.0 - cfg.occlusion_rel_tol))
                       & (z <= dmax * (1.0 + cfg.occlusion_rel_tol)))
            to_src = src.camera.center - points
            to_src /= np.maximum(np.linalg.norm(to_src, axis=2, keepdims=True), _EPS)
            cos = np.clip(np.sum(to_novel * to_src, axis=2), -1.0, 1.0)
            proximity = np.exp(-np.arccos(cos) / cfg.angle_sigma)
            colors.append(_remap(src.image, uv, cv2.INTER_LINEAR))
            visible.append(vis.astype(np.float32))
            weights.append((vis * proximity * src.weight).astype(np.float32))

        # agreement with the render's low frequencies (only where the render has content)
        render_lp = _lowpass_masked(render, alpha >= cfg.alpha_depth_min, cfg.lowpass_sigma)
        render_gate = np.clip((alpha - cfg.hole_alpha_low) / (cfg.hole_alpha_high - cfg.hole_alpha_low), 0.0, 1.0)
        agree_render = []
        for col, vis in zip(colors, visible):
            dev = np.abs(_lowpass_masked(col, vis > 0, cfg.lowpass_sigma) - render_lp).mean(axis=2)
            agree_render.append(1.0 - render_gate * (1.0 - np.exp(-(dev / cfg.agreement_sigma) ** 2)))
        # agreement with the consensus of the warps
        w_sum = np.sum(weights, axis=0)
        consensus = np.sum([w[..., None] * c for w, c in zip(weights, colors)], axis=0) / np.maximum(w_sum, _EPS)[..., None]
        final_w = []
        support = np.zeros((H, W), np.float32)
        for col, w, vis, ar in zip(colors, weights, visible, agree_render):
            dev = np.abs(col - consensus).mean(axis=2)
            agree = np.exp(-(dev / cfg.agreement_sigma) ** 2) * ar
            final_w.append(w * agree)
            support = np.maximum(support, vis * agree)
        fw_sum = np.sum(final_w, axis=0)
        warp = np.sum([w[..., None] * c for w, c in zip(final_w, colors)], axis=0) / np.maximum(fw_sum, _EPS)[..., None]
        ref_conf = np.where(fw_sum > _EPS, support, 0.0).astype(np.float32)

        hole = 1.0 - render_gate
        e_render = _detail_energy(render, cfg.detail_window_sigma)
        e_warp = _detail_energy(warp, cfg.detail_window_sigma)
        blur = np.clip(1.0 - (e_render + cfg.detail_energy_floor) / (e_warp + cfg.detail_energy_floor), 0.0, 1.0)
        trust = np.maximum(np.maximum(hole, blur), cfg.ref_base_trust)
        blend = (ref_conf * trust).astype(np.float32)
        return FrameWarp(depth, warp.astype(np.float32), blend, blur.astype(np.float32),
                         hole.astype(np.float32), [c.astype(np.float32) for c in colors], visible)

    # ---- temporal consistency ----------------------------------------------------------
    def _temporal_smooth(self, request: RestoreRequest, states: list[FrameWarp]) -> list[np.ndarray]:
        """Average each frame's blend weight with its neighbours' warped into it (H, W) per frame."""
        cfg = self.config
        maps = smooth_along_clip(request.cameras, [s.depth for s in states], [s.blend[..., None] for s in states],
                                 cfg.temporal_radius, cfg.temporal_neighbor_weight, cfg.occlusion_rel_tol)
        return [m[..., 0] for m in maps]

    # ---- compositing -------------------------------------------------------------------
    def _composite(self, render: np.ndarray, state: FrameWarp,
                   blend: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Blend render and warp, inpaint the unsupported rest; returns rgb (H, W, 3), confidence (H, W)."""
        cfg = self.config
        render = np.clip(np.nan_to_num(render, nan=0.0), 0.0, 1.0)
        w_render = (1.0 - state.hole) * (1.0 - blend)
        known = w_render + blend
        mixed = (w_render[..., None] * render + blend[..., None] * state.warp) / np.maximum(known, _EPS)[..., None]
        keep = np.clip(known / cfg.inpaint_known_full, 0.0, 1.0)
        if np.all(keep >= 1.0):
            out = mixed
        else:
            fill = push_pull_fill(mixed, keep)
            out = keep[..., None] * mixed + (1.0 - keep[..., None]) * fill
        # real support: the warp's share (already scaled by its reference confidence) plus the
        # render's share where it is opaque and as sharp as the references
        support = blend + w_render * (1.0 - state.blur)
        confidence = np.clip(keep * support, 0.0, 1.0)
        return np.clip(out, 0.0, 1.0).astype(np.float32), confidence.astype(np.float32)
