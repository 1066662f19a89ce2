"""Stage 1 (STGS on the observed views) and stage 2 (restoration-guided refinement).

    model = model_from_clouds(clouds, scene, Stage1Config())
    trainer = Trainer(model, scene, Stage1Config(), run_dir="runs/demo")
    trainer.train()                      # or trainer.step() in a loop, e.g. from a viewer thread
    trainer.snapshot(t)                  # a detached Snapshot, safe to read between steps

Stage 2 is the same trainer with a ``Stage2Config``, a restoration cache and (optionally) a
refresh callback: L = mean over the observed views of L_STG + lambda_gen * mean over the cached
pseudo-views of the confidence-weighted L1(render, restored frame), each pseudo-view rendered at
its clip's time; a clip's frames at the train cameras themselves (alpha = 0 and 1) are skipped.

Everything random draws from the trainer's own generators (numpy for frames/views/pseudo
batches, a torch.Generator for split sampling) whose states live in the checkpoints, so a run
killed and resumed from its last checkpoint reproduces the uninterrupted run exactly.
"""
from __future__ import annotations

import logging
import math
import re
import threading
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any, Callable, Protocol, Sequence

import numpy as np
import torch

from fixer4d.atomic import atomic_path
from fixer4d.errors import InputError, NumericalError
from fixer4d.geometry.camera import Camera, rig_extent
from fixer4d.model.densify import DensifyStats, densify_and_prune, make_adam, reset_parameter
from fixer4d.model.effects import EffectsConfig, EffectsDecision, TemporalStats, revise_effects
from fixer4d.model.snapshot import Snapshot
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians, knn_scales
from fixer4d.render.api import RenderOutput, render
from fixer4d.render.constants import ALPHA_MIN
from fixer4d.render.views import model_render_fn
from fixer4d.scene.base import MultiViewVideo
from fixer4d.train.config import Stage1Config, Stage2Config
from fixer4d.train.losses import masked_l1, psnr_torch, stg_loss
from fixer4d.train.schedule import exponential_lr

log = logging.getLogger("fixer4d.train")

# Version of the checkpoint layout (the keys of Trainer.state_dict()), bumped when they change meaning.
# Checkpoints hold tensors, numbers, strings and containers only, so that they load with
# torch.load(weights_only=True).
CHECKPOINT_FORMAT = 1
_CKPT_NAME = re.compile(r"^stage(\d)_(\d{7})\.pt$")
# The temporary that fixer4d.atomic.atomic_path writes a checkpoint to before the rename.
_CKPT_TEMP = re.compile(r"^\.stage(\d)_\d{7}\.pt\..+$")
# 3DGS's scene radius is 1.1 x the largest camera distance from the rig centre.
EXTENT_MARGIN = 1.1
# Floor of the extent (a single point seen by coincident cameras).
_DEGENERATE_RIG = 1e-6
# Percentile of point distances from the cloud median used as the cloud's radius (robust to
# the stray far points MVS and SfM leave).
_CLOUD_RADIUS_PERCENTILE = 90.0
# Fewer points than this cannot give a 3-NN scale; such an init is topped up with random points.
MIN_INIT_POINTS = 4
# Random points used when an init is degenerate (empty or < MIN_INIT_POINTS points): enough to
# cover a small scene coarsely; densification refines from there.
FALLBACK_POINTS = 2000
# Colour of fallback points: mid grey, the least-biased guess.
FALLBACK_COLOR = 0.5
# Adam epsilon of 3DGS: position gradients are tiny and the default 1e-8 would damp them.
ADAM_EPS = 1e-15


class PseudoEntry(Protocol):
    """What stage 2 reads from a restoration cache entry (fixer4d.restore.cache.CacheEntry)."""

    key: str
    cameras: list[Camera]
    time: float

    def rgb(self) -> np.ndarray: ...

    def confidence(self) -> np.ndarray: ...

    def unobserved(self) -> np.ndarray | None: ...


class PseudoCache(Protocol):
    def entries(self, round: int | None = None) -> list[PseudoEntry]: ...

    def latest_round(self) -> int | None: ...


RefreshFn = Callable[[SpacetimeGaussians, int], None]


# ---- initialization ------------------------------------------------------------------------

def model_from_clouds(clouds: Sequence[Any], scene: MultiViewVideo, config: Stage1Config,
                      model_config: ModelConfig | None = None) -> SpacetimeGaussians:
    """Spacetime Gaussians from per-frame clouds (fixer4d.init.cloud.FrameCloud: frame, time,
    points (N,3), colors (N,3)).

    Each point becomes a Gaussian with time centre = its frame's time, isotropic scale = the RMS
    distance to its 3 nearest neighbours *within its frame* (points of different frames
    coincide on static content and would give degenerate scales), opacity ``config.init_opacity``.
    At most ``config.init_max_points`` points are kept (seeded uniform subsample). An empty or
    nearly empty init (< MIN_INIT_POINTS points) is topped up with FALLBACK_POINTS random points
    inside the scene bounds (logged); without known bounds it raises InputError.
    """
    pts_l, col_l, t_l, fid_l = [], [], [], []
    for i, c in enumerate(clouds):
        p = np.asarray(c.points, dtype=np.float64).reshape(-1, 3)
        ok = np.all(np.isfinite(p), axis=1)
        pts_l.append(p[ok])
        col_l.append(np.clip(np.asarray(c.colors, dtype=np.float64).reshape(-1, 3)[ok], 0.0, 1.0))
        t_l.append(np.full(int(ok.sum()), float(c.time)))
        fid_l.append(np.full(int(ok.sum()), i))
    points = np.concatenate(pts_l) if pts_l else np.zeros((0, 3))
    colors = np.concatenate(col_l) if col_l else np.zeros((0, 3))
    times = np.concatenate(t_l) if t_l else np.zeros(0)
    group = np.concatenate(fid_l) if fid_l else np.zeros(0, np.int64)
    rng = np.random.default_rng(config.seed)

    if points.shape[0] > config.init_max_points:
        keep = np.sort(rng.choice(points.shape[0], size=config.init_max_points, replace=False))
        points, colors, times, group = points[keep], colors[keep], times[keep], group[keep]

    scales = np.zeros(points.shape[0])
    for g in np.unique(group):
        sel = group == g
        scales[sel] = knn_scales(points[sel]) if sel.sum() >= 2 else np.nan
    if points.shape[0] < MIN_INIT_POINTS:
        fb_points, fb_times = _fallback_points(scene, rng)
        log.warning("init has %d point(s) (< %d): adding %d random points inside the scene bounds; "
                    "the reconstruction will rely on densification", points.shape[0], MIN_INIT_POINTS, len(fb_points))
        points = np.concatenate([points, fb_points])
        colors = np.concatenate([colors, np.full_like(fb_points, FALLBACK_COLOR)])
        times = np.concatenate([times, fb_times])
        # every scale is recomputed over the whole set: a lone point has no neighbour in its frame
        scales = knn_scales(points)
    return SpacetimeGaussians.from_points(points, colors, times, model_config,
                                          opacity=config.init_opacity, scales=scales)


def _fallback_points(scene: MultiViewVideo, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    bounds = scene.bounds()
    if bounds is None:
        raise InputError(f"{scene.name}: the init point clouds are empty and the scene has no known bounds to "
                         "place random points in; re-run `fixer4d init` with the other method (--init mvs|sparse) "
                         "or check the cameras")
    lo = np.asarray(bounds.bbox_min, np.float64)
    hi = np.asarray(bounds.bbox_max, np.float64)
    pts = lo + rng.random((FALLBACK_POINTS, 3)) * (hi - lo)
    frames = rng.integers(0, scene.num_frames, FALLBACK_POINTS)
    return pts, frames / float(scene.num_frames)


def model_from_init(init: Any, scene: MultiViewVideo, config: Stage1Config,
                    effects: EffectsConfig | None = None) -> tuple[SpacetimeGaussians, EffectsDecision | None]:
    """The model of an init and the effect decision behind it.

    init: a DecomposedInit (fixer4d.init.decompose) -> effects decided by evidence
    (fixer4d.model.effects.decide_effects; ``effects`` picks auto | all | static and forced
    switches), or per-frame clouds -> ``model_from_clouds`` with the default effects on every
    Gaussian (decision None; e.g. the sparse baseline). A decomposed init with fewer than
    MIN_INIT_POINTS points takes the per-frame path too (random points, decision None).
    """
    from fixer4d.model.effects import decide_effects, model_from_decomposed

    if isinstance(init, (list, tuple)):
        return model_from_clouds(init, scene, config), None
    if init.num_static + init.num_dynamic < MIN_INIT_POINTS:
        # nothing to decide effects from (e.g. a textureless capture): the per-frame path, whose
        # degenerate init is topped up with random points like any other
        log.warning("the decomposed init has %d point(s): training from random points with every effect on",
                    init.num_static + init.num_dynamic)
        return model_from_clouds(init.frame_clouds(), scene, config), None
    decision = decide_effects(init, effects)
    model = model_from_decomposed(init, decision, opacity=config.init_opacity, max_points=config.init_max_points,
                                  seed=config.seed)
    return model, decision


def scene_extent(cameras: Sequence[Camera], means: torch.Tensor) -> float:
    """The length every size threshold and the position learning rate scale with:
    EXTENT_MARGIN x the larger of the rig radius (3DGS's camera extent) and the init cloud's
    radius. The cloud term matters for narrow, forward-facing rigs (cameras 1 m apart filming a
    scene 4 m away), where the rig alone would call every background Gaussian "too large"."""
    r = rig_extent(list(cameras))
    pts = means.detach().cpu().double().numpy()
    if pts.shape[0]:
        r = max(r, float(np.percentile(np.linalg.norm(pts - np.median(pts, 0), axis=1), _CLOUD_RADIUS_PERCENTILE)))
    return EXTENT_MARGIN * max(r, _DEGENERATE_RIG)


def _drawn(snap: Snapshot, out: RenderOutput) -> torch.Tensor:
    """(N,) radii of the Gaussians the renderer really drew: on screen (radii > 0) AND opacity
    at the render's time >= ALPHA_MIN (the renderers skip fainter ones). A time-local Gaussian
    far from its time is on screen but invisible; counting such views in the densification
    statistics would average its gradient over times it does not exist (it would never be
    densified, however badly it fits its own frames)."""
    return torch.where(snap.opacities.detach() >= ALPHA_MIN, out.radii, torch.zeros_like(out.radii))


# ---- the trainer ---------------------------------------------------------------------------

class Trainer:
    """Optimizes a SpacetimeGaussians model on a scene (stage 1, or stage 2 with ``stage2``).

    model: the model to train (replaced on ``load_checkpoint``; read ``trainer.model``).
    scene: the multi-view video; its ``train_ids`` are the observed views.
    config: Stage1Config (learning rates, densification, backend, seed; also used in stage 2).
    run_dir: where checkpoints go (RUN/checkpoints/stage{1,2}_STEP.pt); None = no checkpoints.
    stage2: a Stage2Config to run stage 2 (then ``cache`` is required).
    cache: the restoration cache (``entries(round)``, ``latest_round()``).
    refresh_cache: ``refresh_cache(model, round)`` re-renders and restores the trajectories into
      cache round ``round`` with the current model; None = use the cache as it is.

    ``step()`` runs one iteration and returns scalars; ``train(n)`` runs up to ``n`` more (default:
    to the end) with a progress bar and checkpoints; ``stop()`` ends ``train`` after the current
    step; ``snapshot(t)`` reads the model at time t between steps (thread-safe).
    """

    def __init__(self, model: SpacetimeGaussians, scene: MultiViewVideo, config: Stage1Config, *,
                 run_dir: str | Path | None = None, stage2: Stage2Config | None = None,
                 cache: PseudoCache | None = None, refresh_cache: RefreshFn | None = None,
                 effects: EffectsConfig | None = None) -> None:
        if len(scene.train_ids) < 1:
            raise InputError(f"{scene.name}: no train cameras to optimize on")
        if stage2 is not None and cache is None:
            raise InputError("stage 2 needs a restoration cache (RUN/cache); run the pipeline or `fixer4d run` first")
        if model.num_gaussians == 0:
            raise InputError("the model has no Gaussians; initialize it with model_from_clouds")
        self.model = model.check("initial model")
        self.scene = scene
        self.config = config
        self.stage2 = stage2
        self.cache = cache
        self.refresh_cache = refresh_cache
        self.run_dir = Path(run_dir) if run_dir is not None else None
        self.stage = 2 if stage2 is not None else 1
        self.train_ids = list(scene.train_ids)
        self.extent = scene_extent(scene.train_cameras, model.means)
        self.background = torch.tensor(config.background, dtype=torch.float32)
        seed = config.seed if stage2 is None else stage2.seed
        self._seed = int(seed)
        self._frame_pass: tuple[int, np.ndarray] | None = None  # (pass index, frame order) of "shuffled"
        self.rng = np.random.default_rng(seed)
        self.generator = torch.Generator().manual_seed(seed)
        if model.means.device.type == "cuda":
            # CUDA scatter kernels are nondeterministic by default; CPU ones are deterministic.
            torch.use_deterministic_algorithms(True, warn_only=True)
        self.step_count = 0
        self.round = -1  # stage 2: index of the cache round in use (-1 = none loaded yet)
        self.optimizer = self._make_optimizer()
        self.stats = DensifyStats.zeros(model.num_gaussians, model.means.device)
        # effects revised during stage 1 (auto mode): demote / split on the density schedule
        self.revise = stage2 is None and effects is not None and effects.mode == "auto" and effects.revise
        self.temporal_stats = TemporalStats.zeros(model.num_gaussians if self.revise else 0, device=model.means.device)
        self.revisions: dict[str, int] = {"demoted": 0, "split_dynamic": 0}
        self.history: list[dict[str, float]] = []
        self.train_seconds = 0.0  # wall time spent in train(), summed over resumed sessions
        self._entries: list[PseudoEntry] = []
        self._entry_offsets = np.zeros(1, np.int64)
        self._entry_frames: list[np.ndarray] = []  # per entry: the clip frames used as pseudo-views
        self._clips: OrderedDict[str, tuple[torch.Tensor, torch.Tensor]] = OrderedDict()
        self._moving_packed: np.ndarray | None = None  # (V, T, H, ceil(W/8)) train-view moving masks, bit-packed
        self._lock = threading.RLock()
        self._stop = threading.Event()

    # -- configuration ------------------------------------------------------------------------
    @property
    def total_iterations(self) -> int:
        return self.stage2.total_iterations if self.stage2 is not None else self.config.iterations

    def learning_rates(self, step: int) -> dict[str, float]:
        """Per-parameter learning rates at ``step`` (positions and motion decay; the rest are constant)."""
        c = self.config
        if self.stage2 is None:
            pos = exponential_lr(step, c.lr_means_init, c.lr_means_final, c.iterations)
        else:
            pos = exponential_lr(step, self.stage2.lr_means_init, self.stage2.lr_means_final, self.total_iterations)
        pos *= self.extent
        return {"means": pos, "motion": pos * c.lr_motion_factor, "log_scales": c.lr_scales, "quats": c.lr_quats,
                "opacity_logits": c.lr_opacity, "colors": c.lr_colors, "sh_rest": c.lr_sh_rest,
                "t_center": c.lr_t_center, "t_log_scale": c.lr_t_log_scale, "omega": c.lr_omega}

    def _make_optimizer(self) -> torch.optim.Adam:
        return make_adam(self.model.param_groups(self.learning_rates(self.step_count)), eps=ADAM_EPS)

    def _set_learning_rates(self) -> None:
        lrs = self.learning_rates(self.step_count)
        for group in self.optimizer.param_groups:
            group["lr"] = lrs[group["name"]]

    def _densify_window(self) -> tuple[int, int]:
        """[from, until) steps of this stage during which densification statistics are gathered."""
        if self.stage2 is None:
            return self.config.densify_from, self.config.densify_until
        until = int(self.stage2.densify_until_fraction * self.total_iterations)
        return min(self.config.densify_every, until), until

    # -- one iteration ------------------------------------------------------------------------
    def step(self) -> dict[str, float]:
        """One optimization step. Returns loss, loss_stg, loss_gen (stage 2), psnr (train views),
        num_gaussians, step, lr_means and the seconds spent in each part (t_at, t_render, t_loss,
        t_backward, t_optim, t_densify, t_refresh)."""
        with self._lock:
            return self._step()

    def _step(self) -> dict[str, float]:
        cfg = self.config
        timing = dict.fromkeys(("t_at", "t_render", "t_loss", "t_backward", "t_optim", "t_densify", "t_refresh"), 0.0)
        if self.stage2 is not None:
            tic = time.perf_counter()
            self._maybe_refresh()
            timing["t_refresh"] = time.perf_counter() - tic
        self._set_learning_rates()
        frame = self._next_frame()
        k = min(cfg.views_per_step, len(self.train_ids))
        views = self.rng.choice(len(self.train_ids), size=k, replace=False)
        t = self.scene.time(frame)
        shared = self.model.config.sh_degree == 0  # colours do not depend on the camera

        outputs: list[tuple[RenderOutput, Camera, torch.Tensor]] = []
        loss_stg = torch.zeros(())
        psnrs = []
        snap = None
        for v in views:
            cam_id = self.train_ids[int(v)]
            cam = self.scene.cameras[cam_id]
            tic = time.perf_counter()
            if snap is None or not shared:
                snap = self.model.at(t, camera_center=None if shared else cam.center)
            timing["t_at"] += time.perf_counter() - tic
            out, dt = self._render(snap, cam)
            timing["t_render"] += dt
            tic = time.perf_counter()
            target = torch.from_numpy(np.ascontiguousarray(self.scene.frame(frame, cam_id)))
            loss_stg = loss_stg + stg_loss(out.rgb, target, self._pixel_weight(int(v), frame))
            psnrs.append(psnr_torch(out.rgb, target))
            timing["t_loss"] += time.perf_counter() - tic
            outputs.append((out, cam, _drawn(snap, out)))

        # L = mean_v L_STG(view v) + lambda_gen * mean_p L1(pseudo p): both per-view means, as the
        # paper states it. The gradient taken is that of V x L: Adam is invariant to the overall
        # scale, and each observed view keeps the gradient of its own loss, on which the
        # densification threshold (3DGS: one view per step) is calibrated.
        n_views = max(len(views), 1)
        loss_stg = loss_stg / n_views
        loss_gen = torch.zeros(())
        if self.stage2 is not None and self.stage2.lambda_gen > 0 and self.stage2.batch_pseudo > 0:
            loss_gen = self._pseudo_loss(outputs, timing)
            loss = loss_stg + self.stage2.lambda_gen * loss_gen
        else:
            loss = loss_stg
        if not bool(torch.isfinite(loss)):
            raise NumericalError(f"stage {self.stage} step {self.step_count}: the loss is {float(loss)}; "
                                 "lower the learning rates or resume from the last checkpoint")
        tic = time.perf_counter()
        (loss * n_views).backward()
        self._hold_frozen_rows()
        timing["t_backward"] = time.perf_counter() - tic

        tic = time.perf_counter()
        d_from, d_until = self._densify_window()
        if self.step_count < d_until:
            for out, cam, drawn in outputs:
                if out.means2d.grad is not None:
                    self.stats.update(out.means2d.grad, drawn, cam.width, cam.height)
                    if self.revise:
                        self.temporal_stats.update(out.means2d.grad, drawn, cam.width, cam.height, t)
        timing["t_densify"] = time.perf_counter() - tic

        tic = time.perf_counter()
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        timing["t_optim"] = time.perf_counter() - tic
        self.step_count += 1

        tic = time.perf_counter()
        counts = self._density_control(d_from, d_until)
        timing["t_densify"] += time.perf_counter() - tic
        self.model.check(f"stage {self.stage} step {self.step_count}")

        rec = {"step": float(self.step_count), "loss": float(loss.detach()), "loss_stg": float(loss_stg.detach()),
               "loss_gen": float(loss_gen.detach()), "psnr": float(np.mean(psnrs)),
               "num_gaussians": float(self.model.num_gaussians),
               "lr_means": self.optimizer.param_groups[0]["lr"], **timing,
               **{f"densify_{k}": float(v) for k, v in counts.items()}}
        self.history.append({k: rec[k] for k in ("step", "loss", "psnr", "num_gaussians")})
        return rec

    def _next_frame(self) -> int:
        """The frame of this step (``Stage1Config.frame_order``)."""
        T = self.scene.num_frames
        if self.config.frame_order == "shuffled":
            rounds, k = divmod(self.step_count, T)
            if self._frame_pass is None or self._frame_pass[0] != rounds:
                order = np.random.default_rng([self._seed, self.stage, rounds]).permutation(T)
                self._frame_pass = (rounds, order)
            return int(self._frame_pass[1][k])
        return int(self.rng.integers(0, T))

    def _hold_frozen_rows(self) -> None:
        """Zero the gradients of the frozen rows: Adam's moments of a row whose gradient is always
        zero stay zero, so its update is exactly zero and the row keeps its value bit for bit."""
        frozen = self.model.frozen
        if not bool(frozen.any()):
            return
        for p in self.model.parameters():
            if p.grad is not None:
                p.grad[frozen] = 0.0

    def _pixel_weight(self, view: int, frame: int) -> torch.Tensor | None:
        """(H, W) weight of the observed loss at train view ``view`` (index into train_ids) and
        ``frame``: 1 + ``moving_loss_weight`` on the pixels of that camera's own moving-content
        mask (fixer4d.init.masks, from its own video; no other camera), 1 elsewhere; None when
        the weight is 0. The masks of every frame are estimated once, on first use."""
        w = float(self.config.moving_loss_weight)
        if w <= 0.0:
            return None
        if self._moving_packed is None:
            from fixer4d.init.masks import moving_masks_for_scene

            masks = moving_masks_for_scene(self.scene, self.train_ids, list(range(self.scene.num_frames)))
            self._moving_packed = np.packbits(masks, axis=-1)
        width = self.scene.cameras[self.train_ids[view]].width
        m = np.unpackbits(self._moving_packed[view, frame], axis=-1, count=width).astype(np.float32)
        return torch.from_numpy(1.0 + w * m)

    def _render(self, snap: Snapshot, cam: Camera) -> tuple[RenderOutput, float]:
        tic = time.perf_counter()
        out = render(snap, cam, background=self.background, backend=self.config.backend)
        return out, time.perf_counter() - tic

    @torch.no_grad()
    def _density_control(self, d_from: int, d_until: int) -> dict[str, int]:
        """Densify/prune and reset opacities on the schedule (``step_count`` is 1-based here, as 3DGS)."""
        cfg = self.config
        s = self.step_count
        counts: dict[str, int] = {}
        if d_from < s < d_until and s % cfg.densify_every == 0:
            # the size prunes (off by default) apply only after the first opacity reset, as in
            # 3DGS; stage 2 never applies them (its pseudo-views are less trustworthy than the
            # real views that shaped the model).
            first_reset_done = self.stage2 is None and s > cfg.opacity_reset_every
            if self.revise:
                rev = revise_effects(self.model, self.optimizer, self.temporal_stats,
                                     grad_threshold=cfg.densify_grad_threshold, max_gaussians=cfg.max_gaussians)
                for k, v in rev.items():
                    self.revisions[k] += v
                    counts[k] = v
                if rev["split_dynamic"]:  # the new rows have no statistics yet
                    self.stats = DensifyStats(*(torch.cat([x, x.new_zeros(rev["split_dynamic"])])
                                                for x in (self.stats.grad_accum, self.stats.denom, self.stats.max_radii)))
            counts.update(densify_and_prune(
                self.model, self.optimizer, self.stats, extent=self.extent,
                grad_threshold=cfg.densify_grad_threshold, percent_dense=cfg.percent_dense,
                max_gaussians=cfg.max_gaussians, prune_opacity=cfg.prune_opacity,
                prune_world_scale=cfg.prune_world_scale if first_reset_done else None,
                prune_screen_fraction=cfg.prune_screen_fraction if first_reset_done else None,
                generator=self.generator, split_children=cfg.split_children,
                split_scale_divisor=cfg.split_scale_divisor))
            self.stats = DensifyStats.zeros(self.model.num_gaussians, self.model.means.device)
            if self.revise:
                self.temporal_stats = TemporalStats.zeros(self.model.num_gaussians, device=self.model.means.device)
        if self.stage2 is None and s < d_until and s % cfg.opacity_reset_every == 0:
            cap = math.log(cfg.opacity_reset_value / (1.0 - cfg.opacity_reset_value))
            logits = self.model.opacity_logits
            reset_parameter(self.model, self.optimizer, "opacity_logits",
                            torch.where(self.model.frozen, logits, logits.clamp(max=cap)))
            counts["opacity_reset"] = 1
        return counts

    # -- stage 2: pseudo-views ----------------------------------------------------------------
    def _maybe_refresh(self) -> None:
        """At step 0 and every refresh_every steps (until ``rounds`` rounds), refresh the cache with
        the current model and load that round's entries; after a resume, reload the round in use."""
        s2 = self.stage2
        assert s2 is not None and self.cache is not None
        due = self.step_count % s2.refresh_every == 0 and self.step_count // s2.refresh_every < s2.rounds
        if due:
            r = self.step_count // s2.refresh_every
            if self.refresh_cache is not None:
                with torch.no_grad():
                    self.refresh_cache(self.model, r)
                self._load_round(r)
            elif self.round < 0:
                self._load_round(self.cache.latest_round())
        elif not self._entries:
            self._load_round(self.round if self.round >= 0 else self.cache.latest_round())

    def _load_round(self, r: int | None) -> None:
        """Load round ``r``'s entries; only their novel frames are pseudo-views (a trajectory's
        endpoints at alpha = 0 and 1 are the train cameras themselves, supervised by real frames)."""
        from fixer4d.geometry.trajectory import novel_frame_mask

        train_cams = self.scene.train_cameras
        entries, frames = [], []
        for e in ([] if r is None else self.cache.entries(r)):
            novel = np.flatnonzero(novel_frame_mask(e.cameras, train_cams)) if len(e.cameras) else []
            if len(novel):
                entries.append(e)
                frames.append(novel.astype(np.int64))
        if not entries:
            raise InputError(f"stage 2: the restoration cache has no entries with novel views for round {r}; run "
                             "the restore step (`fixer4d run`, or a refresh callback) before refining")
        self.round = int(r)
        self._entries = entries
        self._entry_frames = frames
        self._entry_offsets = np.concatenate([[0], np.cumsum([len(f) for f in frames])]).astype(np.int64)
        self._clips.clear()

    def _clip(self, entry: PseudoEntry) -> tuple[torch.Tensor, torch.Tensor]:
        """(F,H,W,3) restored frames and (F,H,W) per-pixel weight of an entry's pseudo-loss,
        decoded on first use and kept in a small LRU (``max_cached_clips``)."""
        key = entry.key
        if key in self._clips:
            self._clips.move_to_end(key)
            return self._clips[key]
        rgb = torch.from_numpy(np.ascontiguousarray(entry.rgb(), dtype=np.float32))
        conf = torch.from_numpy(np.ascontiguousarray(self._pseudo_weight(entry), dtype=np.float32))
        self._clips[key] = (rgb, conf)
        assert self.stage2 is not None
        while len(self._clips) > max(self.stage2.max_cached_clips, 1):
            self._clips.popitem(last=False)
        return rgb, conf

    def _pseudo_weight(self, entry: PseudoEntry) -> np.ndarray:
        """(F, H, W) weight of the pseudo L1 (``Stage2Config``): the restorer's confidence (when
        ``confidence_weighting``) times, with ``pseudo_mask = "unobserved"``, observed_weight +
        (1 - observed_weight) x how unobserved the pixel is by the train cameras."""
        s2 = self.stage2
        assert s2 is not None
        weight = entry.confidence() if s2.confidence_weighting else None
        if s2.pseudo_mask == "unobserved":
            hidden = entry.unobserved()
            if hidden is None:
                raise InputError(f"cache entry {entry.key} has no unobserved-pixel map (written with "
                                 "stage2.pseudo_mask=all); refresh the cache or set stage2.pseudo_mask=all")
            mask = s2.observed_weight + (1.0 - s2.observed_weight) * hidden
            weight = mask if weight is None else weight * mask
        if weight is None:
            weight = np.ones_like(entry.confidence())
        return weight

    def _pseudo_loss(self, outputs: list[tuple[RenderOutput, Camera, torch.Tensor]], timing: dict[str, float]) -> torch.Tensor:
        """Mean over ``batch_pseudo`` cached novel frames of the (confidence-weighted) L1 between the
        model rendered at the frame's camera *and its clip's time* and the restored frame."""
        s2 = self.stage2
        assert s2 is not None
        total = int(self._entry_offsets[-1])
        picks = self.rng.integers(0, total, size=s2.batch_pseudo)
        loss = torch.zeros(())
        for flat in picks:
            e_idx = int(np.searchsorted(self._entry_offsets, flat, side="right") - 1)
            entry = self._entries[e_idx]
            f = int(self._entry_frames[e_idx][int(flat - self._entry_offsets[e_idx])])
            cam = entry.cameras[f]
            tic = time.perf_counter()
            snap = self.model.at(float(entry.time), camera_center=cam.center)
            timing["t_at"] += time.perf_counter() - tic
            out, dt = self._render(snap, cam)
            timing["t_render"] += dt
            tic = time.perf_counter()
            rgb, conf = self._clip(entry)
            target = rgb[f]
            if tuple(target.shape[:2]) != (cam.height, cam.width):
                raise InputError(f"cache entry {entry.key}: frame {f} is {tuple(target.shape[:2])} but its camera is "
                                 f"{cam.height}x{cam.width}; the cache is stale, refresh it")
            weight = conf[f] if s2.confidence_weighting or s2.pseudo_mask != "all" else None
            loss = loss + masked_l1(out.rgb, target, weight)
            timing["t_loss"] += time.perf_counter() - tic
            outputs.append((out, cam, _drawn(snap, out)))
        return loss / max(len(picks), 1)

    # -- loops and reading --------------------------------------------------------------------
    def stop(self) -> None:
        """Ask ``train`` to return after the current step (thread-safe)."""
        self._stop.set()

    @property
    def done(self) -> bool:
        return self.step_count >= self.total_iterations

    def train(self, n: int | None = None, progress: bool | None = None) -> dict[str, float]:
        """Run up to ``n`` more steps (default: until ``total_iterations``), checkpointing every
        ``checkpoint_every`` steps and at the end. Returns the last step's scalars plus seconds."""
        self._stop.clear()
        end = self.total_iterations if n is None else min(self.step_count + int(n), self.total_iterations)
        show = self.config.progress if progress is None else progress
        from tqdm import tqdm

        bar = tqdm(total=self.total_iterations, initial=self.step_count, disable=not show,
                   desc=f"stage {self.stage}", unit="it", dynamic_ncols=True)
        rec: dict[str, float] = {}
        tic = last = time.perf_counter()
        try:
            while self.step_count < end and not self._stop.is_set():
                rec = self.step()
                now = time.perf_counter()
                self.train_seconds += now - last  # before a checkpoint, so that it records it
                last = now
                bar.update(1)
                if self.step_count % 10 == 0 or self.step_count == end:
                    bar.set_postfix(loss=f"{rec['loss']:.4f}", psnr=f"{rec['psnr']:.2f}",
                                    n=int(rec["num_gaussians"]), refresh=False)
                if self.run_dir is not None and self.step_count % self.config.checkpoint_every == 0:
                    self.save_checkpoint()
        finally:
            bar.close()
        if self.run_dir is not None and rec and self.step_count % self.config.checkpoint_every != 0:
            self.save_checkpoint()
        rec = dict(rec)
        rec["seconds"] = time.perf_counter() - tic
        return rec

    def snapshot(self, t: float, camera_center: np.ndarray | None = None) -> Snapshot:
        """The model at time t, detached (safe to hand to another thread)."""
        with self._lock, torch.no_grad():
            return self.model.at(float(t), camera_center).detach()

    def render_fn(self) -> Callable[[Camera, float], np.ndarray]:
        """``fn(camera, t) -> (H, W, 3) float32`` rendering the current model (for evaluation);
        each render takes its snapshot under the trainer's lock."""
        return model_render_fn(_Snapshots(self), self.config.backend, self.background)

    # -- checkpoints --------------------------------------------------------------------------
    @property
    def checkpoint_dir(self) -> Path | None:
        return None if self.run_dir is None else self.run_dir / "checkpoints"

    def state_dict(self) -> dict[str, Any]:
        with self._lock:
            return {
                "format": CHECKPOINT_FORMAT, "stage": self.stage, "step": self.step_count, "round": self.round,
                "extent": self.extent,
                "model_config": self.model.config.to_dict(),
                "model": {k: v.detach().clone() for k, v in self.model.state_dict().items()},
                "optimizer": self.optimizer.state_dict(),
                "stats": self.stats.state_dict(),
                "temporal_stats": self.temporal_stats.state_dict(), "revisions": dict(self.revisions),
                "numpy_rng": self.rng.bit_generator.state,
                "torch_generator": self.generator.get_state(),
                "config": _comparable(self.config.to_dict()),
                "stage2": None if self.stage2 is None else self.stage2.to_dict(),
                "history": list(self.history),
                "train_seconds": self.train_seconds,
            }

    def load_state_dict(self, state: dict[str, Any], source: str = "checkpoint") -> None:
        """Restore a ``state_dict()`` (model, optimizer, statistics, RNG states, step)."""
        fmt = state.get("format")
        if fmt != CHECKPOINT_FORMAT:
            raise InputError(f"{source}: checkpoint format {fmt!r}, but this fixer4d reads format "
                             f"{CHECKPOINT_FORMAT}; delete RUN/checkpoints to retrain this stage, or use the "
                             "fixer4d version that wrote it")
        if state.get("stage") != self.stage:
            raise InputError(f"{source}: a stage-{state.get('stage')} checkpoint where stage {self.stage} was "
                             "expected; delete it or train into a new run folder")
        mine = (_comparable(self.config.to_dict()), None if self.stage2 is None else self.stage2.to_dict())
        if (state["config"], state["stage2"]) != mine:
            raise InputError(f"{source}: written with another training config; resume with the same options, "
                             "or delete RUN/checkpoints to start over")
        with self._lock:
            model = SpacetimeGaussians.from_state_dict(state["model"], ModelConfig.from_dict(state["model_config"]))
            self.model = model.to(self.model.means.device)
            self.step_count = int(state["step"])
            self.round = int(state["round"])
            self.extent = float(state["extent"])
            self.optimizer = self._make_optimizer()
            self.optimizer.load_state_dict(state["optimizer"])
            self.stats = DensifyStats.from_state_dict(state["stats"])
            if "temporal_stats" in state:
                self.temporal_stats = TemporalStats.from_state_dict(state["temporal_stats"])
                self.revisions = dict(state.get("revisions", self.revisions))
            self.rng.bit_generator.state = state["numpy_rng"]
            self.generator.set_state(state["torch_generator"])
            self.history = list(state.get("history", []))
            self.train_seconds = float(state.get("train_seconds", 0.0))
            self._entries = []
            self._clips.clear()

    def save_checkpoint(self) -> Path:
        """Write RUN/checkpoints/stage{S}_{STEP}.pt atomically; keep the newest ``keep_checkpoints``."""
        if self.checkpoint_dir is None:
            raise InputError("save_checkpoint: this trainer has no run_dir")
        path = self.checkpoint_dir / f"stage{self.stage}_{self.step_count:07d}.pt"
        state = self.state_dict()
        with atomic_path(path) as tmp:
            torch.save(state, tmp)
        for old in self.list_checkpoints(self.run_dir, self.stage)[:-max(self.config.keep_checkpoints, 1)]:
            old.unlink(missing_ok=True)
        return path

    @staticmethod
    def list_checkpoints(run_dir: str | Path, stage: int) -> list[Path]:
        """Complete checkpoints of ``stage`` in RUN/checkpoints, oldest first."""
        d = Path(run_dir) / "checkpoints"
        if not d.is_dir():
            return []
        found = [(int(m.group(2)), p) for p in d.iterdir()
                 if (m := _CKPT_NAME.match(p.name)) and int(m.group(1)) == stage]
        return [p for _, p in sorted(found)]

    def load_checkpoint(self, path: str | Path) -> None:
        """Load ``path`` with ``torch.load(weights_only=True)``: only tensors and plain containers
        are rebuilt, so a checkpoint that carries pickled code or objects is refused, never run."""
        self.load_state_dict(read_checkpoint(path), source=str(path))

    def _remove_partial_checkpoints(self) -> int:
        """Delete this stage's checkpoint temporaries (``.stage{S}_{STEP}.pt.*``) that a process
        killed inside ``save_checkpoint`` left; the complete checkpoints are never touched."""
        d = self.checkpoint_dir
        if d is None or not d.is_dir():
            return 0
        partial = [p for p in d.iterdir() if (m := _CKPT_TEMP.match(p.name)) and int(m.group(1)) == self.stage]
        for p in partial:
            p.unlink(missing_ok=True)
        return len(partial)

    def resume(self) -> bool:
        """Load the newest checkpoint of this stage from ``run_dir`` if there is one."""
        if self.run_dir is None:
            return False
        self._remove_partial_checkpoints()
        found = self.list_checkpoints(self.run_dir, self.stage)
        if not found:
            return False
        self.load_checkpoint(found[-1])
        log.info("resumed stage %d from %s (step %d)", self.stage, found[-1], self.step_count)
        return True


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The state dict stored in checkpoint ``path``, read without unpickling code.

    ``torch.load(weights_only=True)`` rebuilds tensors, numbers, strings and containers only; a
    file whose pickle names any other global (a ``__reduce__`` payload, a pickled class) is
    refused with an InputError before anything in it runs. Truncated or foreign files get an
    InputError naming the file and the fix.
    """
    import pickle

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such checkpoint; list RUN/checkpoints or start the stage over")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        # torch wraps the unpickler's complaint in a long advisory; keep its "WeightsUnpickler error"
        detail = str(exc).partition("WeightsUnpickler error:")[2].partition("Check the documentation")[0]
        detail = " ".join(detail.split()) or type(exc).__name__
        if "Unsupported global" in detail:  # a global other than tensors/containers: code or an object
            name = detail.partition("GLOBAL ")[2].partition(" ")[0] or "?"
            raise InputError(f"{path}: refused to load: the checkpoint contains pickled code or objects ({name}), "
                             "not only tensors; fixer4d never executes a checkpoint; delete it (fixer4d did not "
                             "write it) to resume from an older one") from None
        raise InputError(f"{path}: unreadable checkpoint ({detail[:200]}); delete it to resume from an older "
                         "one") from None
    except Exception as exc:  # a truncated or foreign file: say which and what to do
        raise InputError(f"{path}: unreadable checkpoint ({type(exc).__name__}: {str(exc)[:200]}); delete it to "
                         "resume from an older one") from None
    if not isinstance(state, dict):
        raise InputError(f"{path}: not a fixer4d checkpoint (holds a {type(state).__name__}, not a state dict); "
                         "delete it to resume from an older one")
    return state


def _comparable(cfg: dict[str, Any]) -> dict[str, Any]:
    """A stage config without the fields that do not change the result (progress display,
    checkpoint cadence)."""
    return {k: v for k, v in cfg.items() if k not in ("progress", "checkpoint_every", "keep_checkpoints")}


class _Snapshots:
    """A trainer seen as a model: ``at(t, camera_center)`` is its locked, detached snapshot."""

    def __init__(self, trainer: Trainer) -> None:
        self.at = lambda t, camera_center=None: trainer.snapshot(t, camera_center)
