"""The model terms: which optional terms of the spacetime model (motion, view dependence,
rotation velocity, temporal opacity, camera response) a scene and each Gaussian get, decided by
evidence and recorded.

``model_terms.mode = auto | all | static`` (ModelTermsConfig), with forced overrides (motion_degree,
sh_degree, rotation_velocity, temporal_opacity; None = decided):

- auto: from the decomposed init (fixer4d.init.decompose.DecomposedInit)
  * static vs dynamic per Gaussian: the static cloud is static (no time terms at all); a moving
    point becomes a time-local dynamic Gaussian unless its track shows no motion and a static
    point already covers it (background caught by the dilated mask: a duplicate).
  * motion polynomial degree 0..3: the smallest degree that fits MOTION_DEGREE_COVERAGE of the
    reliable seeded tracks (track fits within the init's pixel tolerance), at least 1 when there
    are dynamic Gaussians (the masks saw motion a short track may not resolve); 0 when static.
  * rotation velocity: on when at least ROTATION_MIN_SHARE of the tracked dynamic points turn
    by ROTATION_MIN_ANGLE within their temporal extent AND rotation explains at least
    ROTATION_MIN_GAIN of their neighbourhood's relative motion; only those are seeded with it.
  * SH degree: 1 when at least SH_MIN_SHARE of the static points that >= 2 views see have an
    exposure-corrected colour spread above SH_VIEW_STD (view-dependent residual), else 0.
    Never above 1: four views cannot constrain the 8 extra coefficients per channel of degree 2.
  * temporal opacity: on exactly when there are dynamic Gaussians (it only ever applies to them).
- every mode: camera response (an affine colour map per train camera, trained beside the
  Gaussians; fixer4d.model.camera_response) when the train cameras' colour gains, measured on
  the static points several of them see, differ beyond 2 % and beyond their noise.
- all: every term on every Gaussian (cubic motion, rotation velocity, temporal opacity, SH 1;
  the static cloud becomes clip-long dynamic Gaussians): the reference for speed and accuracy.
- static: no time terms at all, the static cloud only.

During stage 1 (``revise``) the decision is revised per Gaussian: fixer4d/model/term_revisions.py.

Decisions are deterministic (no randomness; ties broken by fixed order).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from fixer4d.errors import InputError
from fixer4d.geometry.subsample import subsample
from fixer4d.model.camera_response import decide as decide_camera_response
from fixer4d.model.initial_scales import initial_temporal_std, knn_scales
from fixer4d.model.spacetime import MAX_MOTION_DEGREE, ModelConfig, SpacetimeGaussians

MODES = ("auto", "all", "static")

# ---- thresholds (each with its reason) --------------------------------------------------------
# A scene with fewer dynamic points than this (after duplicates are dropped) is static: a
# handful of points is mask noise, not an object (one small object at the demo's density has
# hundreds of points per frame).
MIN_DYNAMIC_POINTS = 50
# A moving point whose track fits degree 0 (no motion within the init's pixel tolerance) and
# has a static point within this many voxel sizes is background caught by the dilated mask.
DUPLICATE_VOXELS = 2.0
# Voxel size of the fusion down-sampling relative to the scene scale (fixer4d.init.constants
# FUSION_VOXEL_REL, repeated here so the model does not import the init package's constants).
FUSION_VOXEL_REL = 0.002
# Share of the reliable tracks the chosen motion degree must fit: 90% lets a few badly tracked
# points (occlusion boundaries, flow errors) not raise the degree of the whole scene.
MOTION_DEGREE_COVERAGE = 0.9
# A track fit is reliable when its RMS reprojection residual is within this many pixels (the
# init's own degree-selection tolerance, fixer4d.init.decompose.MOTION_FIT_TOL_PX).
RELIABLE_FIT_PX = 1.0
# Rotation "pays" for a Gaussian that turns by >= 0.2 rad (11 degrees) within one temporal std:
# below that an anisotropic Gaussian's footprint changes by < 4% (1 - cos) and translation
# alone renders it; and when rotation explains >= half of its neighbourhood's relative motion.
ROTATION_MIN_ANGLE = 0.2
ROTATION_MIN_GAIN = 0.5
# The scene gets the omega Parameter when >= 10% of the tracked dynamic points rotate: one
# spinning object among several moving ones (the demo's cube) qualifies; noise does not.
ROTATION_MIN_SHARE = 0.10
# View-dependent colour: an exposure-corrected colour std across views (of images blurred by
# 2 px, fixer4d.init.decompose.EVIDENCE_BLUR_SIGMA) above 0.1 counts as view dependence: on the
# matte demo room (static_matte) 99% of the points stay under 0.058 and 0.1% exceed 0.1, while
# a highlight of strength >= 0.2 in one of four views alone gives a std >= 0.09 ...
SH_VIEW_STD = 0.1
# ... and SH degree 1 is used when >= 1% of the static points show it (10x the matte scene's
# share, so texture and sub-pixel misregistration never switch it on).
SH_MIN_SHARE = 0.01
# The largest SH degree four views support (degree 1: 3 extra coefficients per channel).
SH_MAX_SUPPORTED = 1
# Initial temporal std of the static cloud's Gaussians in mode "all": 1 clip (the model's
# SINGLE_TIME_TEMPORAL_STD), so they start visible over the whole clip.
ALL_MODE_STATIC_TEMPORAL_STD = 1.0
# Priority of dynamic points under the init point cap: they may take at most half of it (the
# static cloud needs the rest; the demo's moving points are ~25% of the raw points).
DYNAMIC_CAP_SHARE = 0.5


@dataclass
class ModelTermsConfig:
    """mode: auto | all | static. Forced overrides (None = decided by ``mode``): motion_degree
    0..3, sh_degree 0..3, rotation_velocity, temporal_opacity; camera_response (None = decided by
    the cameras' measured colour gains in every mode, fixer4d.model.camera_response). revise:
    demote/split during stage 1 (auto mode only)."""

    mode: str = "auto"
    motion_degree: int | None = None
    sh_degree: int | None = None
    rotation_velocity: bool | None = None
    temporal_opacity: bool | None = None
    camera_response: bool | None = None
    revise: bool = True

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise InputError(f"model_terms mode {self.mode!r}; choose one of {list(MODES)}")
        if self.motion_degree is not None and not 0 <= int(self.motion_degree) <= MAX_MOTION_DEGREE:
            raise InputError(f"model_terms motion_degree must be in 0..{MAX_MOTION_DEGREE} or None, got {self.motion_degree}")

    @property
    def forced(self) -> dict[str, Any]:
        return {k: v for k, v in (("motion_degree", self.motion_degree), ("sh_degree", self.sh_degree),
                                  ("rotation_velocity", self.rotation_velocity),
                                  ("temporal_opacity", self.temporal_opacity),
                                  ("camera_response", self.camera_response)) if v is not None}

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any] | str | None) -> "ModelTermsConfig":
        if d is None:
            return cls()
        if isinstance(d, str):
            return cls(mode=d)
        return cls(**d)


@dataclass
class TermsDecision:
    """The decided model terms of one scene.

    model_config: the scene's switches. dynamic_keep: (M,) which moving points become dynamic
    Gaussians. point_degree: (M,) per-point motion degree used for seeding (<= the scene's).
    rotates: (M,) points seeded with an angular velocity. static_dynamic: the static cloud's
    Gaussians are dynamic too (mode all). camera_response: train each train camera's colour
    response (fixer4d.model.camera_response). reasons: why, per switch. evidence: the numbers.
    """

    mode: str
    model_config: ModelConfig
    dynamic_keep: np.ndarray
    point_degree: np.ndarray
    rotates: np.ndarray
    static_dynamic: bool
    reasons: dict[str, str] = field(default_factory=dict)
    evidence: dict[str, Any] = field(default_factory=dict)
    forced: dict[str, Any] = field(default_factory=dict)
    camera_response: bool = False


def _lifetime(init) -> float:
    return initial_temporal_std(np.asarray(init.dyn_times)) if init.num_dynamic else 1.0


@dataclass
class _Switches:
    """The scene's switches and the per-point choices while ``decide_terms`` settles them."""

    motion: int
    rotation: bool
    temporal: bool
    sh: int
    keep: np.ndarray
    point_degree: np.ndarray
    rotates: np.ndarray
    static_dynamic: bool = False


def decide_terms(init, config: ModelTermsConfig | None = None) -> TermsDecision:
    """Decide the model terms of a scene from its DecomposedInit (module docstring). Deterministic."""
    config = config or ModelTermsConfig()
    M = init.num_dynamic
    ev: dict[str, Any] = {"static_points": init.num_static, "moving_points": M}
    reasons: dict[str, str] = {}
    sh = _sh_degree(init, ev, reasons)
    degree = np.asarray(init.dyn_degree, np.int64)
    keep, reliable = _dynamic_points(init, degree, ev)
    n_dyn = int(keep.sum())
    has_dynamic = n_dyn >= MIN_DYNAMIC_POINTS
    motion = _motion_degree(degree, reliable, n_dyn, has_dynamic, ev, reasons)
    point_degree = np.clip(degree, 0, motion)
    rotation, rotates = _rotation(init, keep, degree, has_dynamic and motion > 0, ev, reasons)
    reasons["temporal_opacity"] = (f"{n_dyn} time-local dynamic Gaussians" if has_dynamic else "no dynamic Gaussians")
    sw = _Switches(motion, rotation, has_dynamic, sh, keep, point_degree, rotates)
    _apply_mode(sw, config.mode, degree, M, reasons)
    forced = config.forced
    _apply_forced(sw, forced, reasons)
    if not sw.rotation:
        sw.rotates = np.zeros(M, bool)
    cfg = ModelConfig(motion_degree=sw.motion, rotation_velocity=sw.rotation, temporal_opacity=sw.temporal,
                      sh_degree=sw.sh)
    if not cfg.has_time_terms:
        sw.keep = np.zeros(M, bool)
        if M and config.mode != "static":
            reasons["dynamic"] = "the model has no time terms: moving points are left out (they would be ghosts)"
    response = _camera_response(init, config.camera_response, ev, reasons)
    return TermsDecision(mode=config.mode, model_config=cfg, dynamic_keep=sw.keep, point_degree=sw.point_degree,
                         rotates=sw.rotates & sw.keep, static_dynamic=sw.static_dynamic and cfg.has_time_terms,
                         reasons=reasons, evidence=ev, forced=forced, camera_response=response)


def _camera_response(init, forced: bool | None, ev: dict[str, Any], reasons: dict[str, str]) -> bool:
    """Per-camera colour response from the train views' measured gains (camera_response.decide)."""
    log_gain = np.asarray(init.view_log_gain, np.float64)
    ev["camera_gain"] = np.exp(log_gain).round(4).tolist()
    on, reasons["camera_response"] = decide_camera_response(log_gain, init.view_gain_stderr, forced)
    return on


def _sh_degree(init, ev: dict[str, Any], reasons: dict[str, str]) -> int:
    """SH degree from the static cloud's view-dependent residual (SH_VIEW_STD, SH_MIN_SHARE)."""
    std = np.asarray(init.static_view_std, np.float64)
    seen = np.isfinite(std)
    share_vd = float((std[seen] > SH_VIEW_STD).mean()) if seen.any() else 0.0
    ev["view_dependent_share"] = share_vd
    reasons["sh_degree"] = (f"{100 * share_vd:.1f}% of the static points seen by >= 2 views differ across views by "
                            f"more than {SH_VIEW_STD} (std, exposure-corrected); threshold {100 * SH_MIN_SHARE:.0f}%")
    return SH_MAX_SUPPORTED if share_vd >= SH_MIN_SHARE else 0


def _dynamic_points(init, degree: np.ndarray, ev: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(keep, reliable) (M,) bool: the moving points that become dynamic Gaussians (all but the
    still ones with a static point within DUPLICATE_VOXELS), and those of them with a reliable
    track fit (within RELIABLE_FIT_PX)."""
    M = init.num_dynamic
    fit = np.asarray(init.dyn_fit_px, np.float64)
    keep = np.ones(M, bool)
    if M and init.num_static:
        from scipy.spatial import cKDTree

        d, _ = cKDTree(init.static_points).query(init.dyn_points, k=1)
        still = degree == 0
        keep = ~(still & (d <= DUPLICATE_VOXELS * FUSION_VOXEL_REL * init.scene_scale))
    ev["duplicates_of_static"] = int(M - int(keep.sum()))
    reliable = keep & (degree >= 0) & (fit <= RELIABLE_FIT_PX)
    ev["reliable_tracks"] = int(reliable.sum())
    return keep, reliable


def _motion_degree(degree: np.ndarray, reliable: np.ndarray, n_dyn: int, has_dynamic: bool,
                   ev: dict[str, Any], reasons: dict[str, str]) -> int:
    """The scene's motion degree: the smallest that fits MOTION_DEGREE_COVERAGE of the reliable
    tracks, at least 1 with dynamic content, 0 without."""
    if not has_dynamic:
        reasons["motion_degree"] = f"{n_dyn} moving point(s) after dropping static duplicates (< {MIN_DYNAMIC_POINTS}): static scene"
        return 0
    if reliable.sum() == 0:
        reasons["motion_degree"] = "moving points but no reliable track: linear motion, learned from the images"
        return 1
    hist = np.bincount(degree[reliable], minlength=MAX_MOTION_DEGREE + 1)
    cum = np.cumsum(hist) / hist.sum()
    vote = int(np.argmax(cum >= MOTION_DEGREE_COVERAGE - 1e-12))
    ev["track_degree_histogram"] = hist.tolist()
    reasons["motion_degree"] = (f"degree {vote} fits {100 * cum[vote]:.0f}% of {int(reliable.sum())} reliable "
                                f"tracks (histogram deg 0..3: {hist.tolist()}; needed {100 * MOTION_DEGREE_COVERAGE:.0f}%)"
                                + ("; at least 1 because the moving masks show motion" if vote == 0 else ""))
    # the masks say these points move over the clip; a short track (a few frames) can be too
    # short to resolve slow motion, so a scene with dynamic content gets at least linear motion
    return max(vote, 1)


def _rotation(init, keep: np.ndarray, degree: np.ndarray, moving: bool, ev: dict[str, Any],
              reasons: dict[str, str]) -> tuple[bool, np.ndarray]:
    """(the scene gets omega, (M,) points seeded with it): ROTATION_MIN_ANGLE per temporal std,
    ROTATION_MIN_GAIN of the neighbourhood's motion, ROTATION_MIN_SHARE of the tracked points.
    moving: the scene has dynamic Gaussians with motion."""
    M = init.num_dynamic
    life = _lifetime(init)
    angle = np.linalg.norm(np.asarray(init.dyn_omega, np.float64), axis=1) * life if M else np.zeros(0)
    gain = np.asarray(getattr(init, "dyn_rot_gain", np.zeros(M)), np.float64)
    rotates = keep & (degree >= 1) & (angle >= ROTATION_MIN_ANGLE) & (gain >= ROTATION_MIN_GAIN)
    tracked = keep & (degree >= 1)
    rot_share = float(rotates.sum() / max(tracked.sum(), 1))
    ev["rotating_share"] = rot_share
    reasons["rotation_velocity"] = (f"{100 * rot_share:.1f}% of the moving tracked points turn by >= {ROTATION_MIN_ANGLE} rad "
                                    f"per temporal std ({life:.3f}) with rotation explaining >= {ROTATION_MIN_GAIN:.0%} of "
                                    f"their neighbourhood's motion; threshold {100 * ROTATION_MIN_SHARE:.0f}%")
    return bool(moving and rot_share >= ROTATION_MIN_SHARE), rotates


def _apply_mode(sw: _Switches, mode: str, degree: np.ndarray, M: int, reasons: dict[str, str]) -> None:
    """Mode "all": every term on every Gaussian; "static": no time terms; "auto": as decided.
    degree: (M,) the moving points' track degrees."""
    if mode == "all":
        sw.motion, sw.rotation, sw.temporal, sw.sh = MAX_MOTION_DEGREE, True, True, SH_MAX_SUPPORTED
        sw.keep = np.ones(M, bool)
        sw.point_degree = np.clip(degree, 0, sw.motion)
        sw.rotates = degree >= 1
        sw.static_dynamic = True
        for k in ("motion_degree", "rotation_velocity", "temporal_opacity", "sh_degree"):
            reasons[k] = "mode 'all': every term on every Gaussian"
    elif mode == "static":
        sw.motion, sw.rotation, sw.temporal = 0, False, False
        sw.keep = np.zeros(M, bool)
        for k in ("motion_degree", "rotation_velocity", "temporal_opacity"):
            reasons[k] = "mode 'static': no time terms; the static cloud only"


def _apply_forced(sw: _Switches, forced: dict[str, Any], reasons: dict[str, str]) -> None:
    """The config's forced switches win over every decision."""
    if "motion_degree" in forced:
        sw.motion = int(forced["motion_degree"])
        sw.point_degree = np.clip(sw.point_degree, 0, sw.motion)
    if "sh_degree" in forced:
        sw.sh = int(forced["sh_degree"])
    if "rotation_velocity" in forced:
        sw.rotation = bool(forced["rotation_velocity"])
    if "temporal_opacity" in forced:
        sw.temporal = bool(forced["temporal_opacity"])
    for k, v in forced.items():
        reasons[k] = f"forced to {v} by the config ({reasons.get(k, '')})"


def model_from_decomposed(init, decision: TermsDecision, *, opacity: float, max_points: int,
                          seed: int = 0, subsample_method: str = "random") -> SpacetimeGaussians:
    """Gaussians from a DecomposedInit and its TermsDecision.

    Static cloud -> static Gaussians (no time terms; clip-long dynamic ones in mode "all"),
    scales from 3-NN distances within the static cloud. Kept moving points -> dynamic Gaussians
    centred at their frame's time with the init spacing as temporal std, motion seeded with the
    track fit up to the point's degree, omega with the local rigid fit where it rotates; scales
    from 3-NN within their frame. At most ``max_points`` (moving points first, up to
    DYNAMIC_CAP_SHARE of the cap; ``subsample_method``: a uniform draw with ``seed`` or an even
    spread in space, moving points frame by frame, fixer4d.geometry.subsample).
    """
    rng = np.random.default_rng(seed)
    cfg = decision.model_config
    dyn_idx = np.nonzero(decision.dynamic_keep)[0]
    n_dyn_cap = int(max_points * DYNAMIC_CAP_SHARE) if init.num_static else max_points
    if dyn_idx.size > n_dyn_cap:
        dyn_idx = dyn_idx[subsample(np.asarray(init.dyn_points)[dyn_idx], n_dyn_cap, subsample_method, rng,
                                    groups=np.asarray(init.dyn_frames)[dyn_idx])]
    st_idx = np.arange(init.num_static)
    room = max_points - dyn_idx.size
    if st_idx.size > room:
        st_idx = subsample(np.asarray(init.static_points), max(room, 0), subsample_method, rng)
    s_pts = np.asarray(init.static_points, np.float64)[st_idx]
    d_pts = np.asarray(init.dyn_points, np.float64)[dyn_idx]
    s_scales = knn_scales(s_pts)
    d_scales = np.zeros(dyn_idx.size)
    frames = np.asarray(init.dyn_frames)[dyn_idx]
    for f in np.unique(frames):
        sel = frames == f
        d_scales[sel] = knn_scales(d_pts[sel]) if sel.sum() >= 2 else knn_scales(np.concatenate([d_pts[sel], s_pts]))[:sel.sum()]
    life = _lifetime(init)
    points = np.concatenate([s_pts, d_pts])
    if points.shape[0] == 0:
        raise InputError("the decomposed init has no points; check the masks and the depth range")
    colors = np.concatenate([np.asarray(init.static_colors, np.float64)[st_idx],
                             np.asarray(init.dyn_colors, np.float64)[dyn_idx]])
    times = np.concatenate([np.full(st_idx.size, 0.5), np.asarray(init.dyn_times, np.float64)[dyn_idx]])
    dynamic = np.concatenate([np.full(st_idx.size, decision.static_dynamic), np.ones(dyn_idx.size, bool)])
    model = SpacetimeGaussians.from_points(points, colors, times, cfg, opacity=opacity,
                                           scales=np.concatenate([s_scales, d_scales]), dynamic=dynamic, t_scale=life)
    n_s = st_idx.size
    with torch.no_grad():
        if cfg.temporal_opacity and n_s:
            model.t_log_scale[:n_s] = math.log(ALL_MODE_STATIC_TEMPORAL_STD)
        if cfg.motion_degree > 0 and dyn_idx.size:
            coeffs = np.asarray(init.dyn_coeffs, np.float64)[dyn_idx]  # (D, 3, 3) m1..m3
            deg = decision.point_degree[dyn_idx]
            k = np.arange(1, MAX_MOTION_DEGREE + 1)[None, :, None]
            coeffs = np.where(k <= deg[:, None, None], coeffs, 0.0)[:, : cfg.motion_degree]
            model.motion[n_s:] = torch.from_numpy(coeffs.reshape(dyn_idx.size, -1)).to(model.motion.dtype)
        if cfg.rotation_velocity and dyn_idx.size:
            w = np.asarray(init.dyn_omega, np.float64)[dyn_idx] * decision.rotates[dyn_idx, None]
            # q(t) = q + omega dt with q = identity: dq/dt = 0.5 (0, w) (x) q = (0, w / 2)
            om = np.concatenate([np.zeros((dyn_idx.size, 1)), 0.5 * w], 1)
            model.omega[n_s:] = torch.from_numpy(om).to(model.omega.dtype)
    return model


def terms_report(model: SpacetimeGaussians, decision: TermsDecision | None,
                 revisions: dict[str, int] | None = None) -> dict[str, Any]:
    """The ``model`` section of a run's report: Gaussians static/dynamic, the chosen degrees
    and switches, why, and the training revisions (demoted / split counts)."""
    cfg = model.config
    out: dict[str, Any] = {
        "gaussians": model.num_gaussians, "dynamic": model.num_dynamic,
        "static": model.num_gaussians - model.num_dynamic,
        "config": cfg.to_dict(),
        "parameters_per_gaussian": int(sum(int(np.prod(s)) if s else 1 for s in cfg.param_shapes().values())),
    }
    if model.num_frozen:  # another segment's static Gaussians, trained there
        out["frozen"] = model.num_frozen
    if decision is None:
        out.update(mode=None, reasons={"all": "per-frame clouds without decomposition: every Gaussian dynamic, "
                                              "the default terms"})
    else:
        out.update(mode=decision.mode, reasons=dict(decision.reasons), evidence=_jsonable(decision.evidence),
                   forced=dict(decision.forced),
                   init={"dynamic_gaussians": int(decision.dynamic_keep.sum()),
                         "rotating_gaussians": int(decision.rotates.sum()),
                         "point_degree_histogram": np.bincount(decision.point_degree[decision.dynamic_keep],
                                                               minlength=MAX_MOTION_DEGREE + 1).tolist()
                         if decision.dynamic_keep.any() else [0] * (MAX_MOTION_DEGREE + 1)})
    if revisions:
        out["revisions"] = dict(revisions)
    return out


def _jsonable(d: dict[str, Any]) -> dict[str, Any]:
    return {k: (v.tolist() if isinstance(v, np.ndarray) else float(v) if isinstance(v, np.floating)
                else int(v) if isinstance(v, np.integer) else v) for k, v in d.items()}
