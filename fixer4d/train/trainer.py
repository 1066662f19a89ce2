"""The training loop of stage 1 (STGS on the observed views) and stage 2 (restoration-guided refinement).

    model = model_from_clouds(clouds, scene, TrainingConfig())   # fixer4d.train.model_init
    trainer = Trainer(model, scene, TrainingConfig(), run_dir="runs/demo")
    trainer.train()                      # or trainer.step() in a loop, e.g. from a viewer thread
    trainer.snapshot(t)                  # a detached Snapshot, safe to read between steps

Stage 2 is the same trainer with a ``Stage2Config``, a restoration cache and (optionally) a
refresh callback: L = mean over the observed views of L_STG + lambda_gen * mean over the cached
pseudo-views of the confidence-weighted L1(render, restored frame) (fixer4d.train.pseudo_targets).
What differs between the stages (length, position learning rate, densification window, opacity
resets, pseudo-views, refreshes) is the trainer's ``StageSchedule`` (fixer4d.train.schedule).

Everything random draws from the trainer's own generators (numpy for frames/views/pseudo
batches, a torch.Generator for split sampling) whose states live in the checkpoints
(fixer4d.train.checkpoints), so a run killed and resumed from its last checkpoint reproduces the
uninterrupted run exactly.

A step reads nothing back to the host (on a GPU each read waits for the device, and the host
could not queue the next step's kernels meanwhile): the loss, the PSNR and the model's
finiteness of CHECK_EVERY steps come back in one read, which reports a non-finite loss naming
its step. With gsplat (the CUDA path) the scene's train frames, the moving-pixel weights and the
camera matrices are copied to the device once, and the views of a step are rendered in one call
(``render.api.render_batch``); the CPU kernels render view by view (``render.api.render``) with
the host-side checks of every call, which cost nothing there.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from fixer4d.errors import InputError, NumericalError
from fixer4d.geometry.camera import Camera
from fixer4d.model.camera_response import RESPONSE_LR, RESPONSE_REG, CameraResponse
from fixer4d.model.densify import DensifyStats, densify_and_prune, make_adam, reset_parameter
from fixer4d.model.term_revisions import TemporalStats, revise_terms
from fixer4d.model.terms import ModelTermsConfig
from fixer4d.model.snapshot import Snapshot
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians
from fixer4d.psnr import psnr_from_mse
from fixer4d.render.api import RenderOutput, render, render_batch, resolve_backend
from fixer4d.render.constants import ALPHA_MIN
from fixer4d.render.views import model_render_fn
from fixer4d.scene.base import MultiViewVideo
from fixer4d.threads import digit_threads
from fixer4d.train.background import resolve_background
from fixer4d.train.checkpoints import (CHECKPOINT_FORMAT, check_resumable, list_checkpoints, read_checkpoint,
                                       remove_partial_checkpoints, training_settings, write_checkpoint)
from fixer4d.train.config import TrainingConfig, Stage2Config
from fixer4d.train.depth_prior import DepthTargets, NovelDepthViews, depth_loss
from fixer4d.train.device import training_device
from fixer4d.train.losses import masked_l1, masked_l1_device, mean_squared_error, stg_loss, stg_loss_device
from fixer4d.train.model_init import scene_extent
from fixer4d.train.opacity_decay import OpacityDecay
from fixer4d.train.pseudo_targets import PseudoCache, PseudoTargets, RefreshFn
from fixer4d.train.scale_ratio import scale_ratio_penalty
from fixer4d.train.schedule import StageSchedule

log = logging.getLogger("fixer4d.train")

# Adam epsilon of 3DGS: position gradients are tiny and the default 1e-8 would damp them.
ADAM_EPS = 1e-15
# Seconds of each part of a step, reported by ``Trainer.step``.
TIMING_KEYS = ("t_at", "t_render", "t_loss", "t_backward", "t_optim", "t_densify", "t_refresh")
# Steps between two reads of the scalars of the steps in between (loss, PSNR) and of the model's
# finiteness: every read waits for a GPU, so a step reads nothing and CHECK_EVERY steps come back
# in one read. 10 = the progress bar's refresh; a diverged run trains on for at most 9 steps
# before it is reported (and a checkpoint reads first, so none is written from it).
CHECK_EVERY = 10
# Pseudo-view cameras whose gsplat matrices stay on the device: a stage-2 round's trajectories
# hold a few dozen cameras (trajectories.frames per pair), so a round's are all kept.
CAMERA_CACHE = 256
# The novel depth views' random stream beside the seed (any constant other streams do not use).
NOVEL_DEPTH_STREAM = 7
# A rendered view of a step: its render, camera and ``_drawn`` radii (densification statistics).
RenderedView = tuple[RenderOutput, Camera, torch.Tensor]


def _drawn(snap: Snapshot, out: RenderOutput) -> torch.Tensor:
    """(N,) radii of the Gaussians the renderer really drew: on screen (radii > 0) AND opacity
    at the render's time >= ALPHA_MIN (the renderers skip fainter ones). A time-local Gaussian
    far from its time is on screen but invisible; counting such views in the densification
    statistics would average its gradient over times it does not exist (it would never be
    densified, however badly it fits its own frames)."""
    return torch.where(snap.opacities.detach() >= ALPHA_MIN, out.radii, torch.zeros_like(out.radii))


def _decayed(base: torch.Tensor | None) -> dict[str, torch.Tensor]:
    """``model.at``'s keyword for a step's decayed base opacities (none without the decay, so a
    model that only takes (t, camera_center) still trains)."""
    return {} if base is None else {"base_opacities": base}


class Trainer:
    """Optimizes a SpacetimeGaussians model on a scene (stage 1, or stage 2 with ``stage2``).

    model: the model to train (replaced on ``load_checkpoint``; read ``trainer.model``).
    scene: the multi-view video; its ``train_ids`` are the observed views.
    config: TrainingConfig (learning rates, densification, backend, seed; also used in stage 2).
    run_dir: where checkpoints go (RUN/checkpoints/stage{1,2}_STEP.pt); None = no checkpoints.
    stage2: a Stage2Config to run stage 2 (then ``cache`` is required).
    cache: the restoration cache (``entries(round)``, ``latest_round()``).
    refresh_cache: ``refresh_cache(model, round)`` re-renders and restores the trajectories into
      cache round ``round`` with the current model; None = use the cache as it is.
    terms: the model-terms config whose auto decisions stage 1 revises (None: no revisions).
    camera_response: a CameraResponse over the train views, trained with the model: each train
      view's render passes through it before its loss (None: the cameras agree on colour).
    depth_init: the init (DecomposedInit or frame clouds) whose points hold the train views'
      rendered depth in stage 1 when ``config.depth_prior`` is on (``train.depth_prior``).

    ``step()`` runs one iteration and returns scalars; ``train(n)`` runs up to ``n`` more (default:
    to the end) with a progress bar and checkpoints; ``stop()`` ends ``train`` after the current
    step; ``snapshot(t)`` reads the model at time t between steps (thread-safe). ``schedule`` is
    the stage's StageSchedule; ``pseudo`` stage 2's PseudoTargets (None in stage 1).
    """

    def __init__(self, model: SpacetimeGaussians, scene: MultiViewVideo, config: TrainingConfig, *,
                 run_dir: str | Path | None = None, stage2: Stage2Config | None = None,
                 cache: PseudoCache | None = None, refresh_cache: RefreshFn | None = None,
                 terms: ModelTermsConfig | None = None, camera_response: CameraResponse | None = None,
                 depth_init: Any = None) -> None:
        if len(scene.train_ids) < 1:
            raise InputError(f"{scene.name}: no train cameras to optimize on")
        if stage2 is not None and cache is None:
            raise InputError("stage 2 needs a restoration cache (RUN/cache); run the pipeline or `fixer4d run` first")
        if model.num_gaussians == 0:
            raise InputError("the model has no Gaussians; initialize it with model_from_clouds")
        # the model moves to the training device (in place: nn.Module.to); a stage takes it back with host_model()
        self.device = training_device(config.device, config.backend)
        self.model = model.check("initial model").to(self.device)
        self.scene = scene
        self.config = config
        self.stage2 = stage2
        self.schedule = StageSchedule.stage1(config) if stage2 is None else StageSchedule.stage2(config, stage2)
        # stage 2's restored frames (None in stage 1)
        self.pseudo = (None if stage2 is None else
                       PseudoTargets(stage2, cache, refresh_cache, scene.train_cameras, device=self.device))
        self.run_dir = Path(run_dir) if run_dir is not None else None
        self.stage = self.schedule.stage
        # what the progress bar calls this training (e.g. one of stage 1's fields)
        self.label = f"stage {self.stage}"
        self.train_ids = list(scene.train_ids)
        self.extent = scene_extent(scene.train_cameras, model.means)
        self.background = torch.tensor(resolve_background(config.background, scene), dtype=torch.float32,
                                       device=self.device)
        seed = self.schedule.seed
        self._seed = int(seed)
        self._frame_pass: tuple[int, np.ndarray] | None = None  # (pass index, frame order) of "shuffled"
        self.rng = np.random.default_rng(seed)
        self.generator = torch.Generator().manual_seed(seed)
        # No process-wide torch.use_deterministic_algorithms: the step's index_add / index_copy /
        # index_fill write each row once, so their results do not depend on the order of CUDA's
        # atomics; gsplat's backward adds with atomics whatever torch is told.
        self.step_count = 0
        self.optimizer = self._make_optimizer()
        # the learned opacity decay in place of the resets (stage 1 with training.opacity_decay)
        self.decay = (None if self.schedule.decay_from is None else
                      OpacityDecay(config.opacity_decay, self.device, seed))
        # per-train-camera colour response (None: the cameras agree on colour)
        self.response = None if camera_response is None else camera_response.to(self.device)
        # the init's points as depth targets of the train views (stage 1 with training.depth_prior)
        prior = config.depth_prior if stage2 is None and depth_init is not None else None
        self.depth_targets = (DepthTargets(depth_init, scene.train_cameras, prior, self._moving_mask, self.device)
                              if prior is not None and prior.weight > 0 else None)
        self.novel_depth = (NovelDepthViews(depth_init, scene.train_cameras, prior, self.device)
                            if prior is not None and prior.novel_weight > 0 else None)
        # the novel cameras' own draws: the train views' and frames' draws stay those of the seed
        self.novel_rng = np.random.default_rng([seed, NOVEL_DEPTH_STREAM])
        self.response_optimizer = (None if camera_response is None else
                                   torch.optim.Adam(camera_response.parameters(), lr=RESPONSE_LR))
        self.stats = DensifyStats.zeros(model.num_gaussians, self.device)
        # model terms revised on the density schedule (auto mode, stage 1): demote / split
        self.revise = (self.schedule.revises_terms and terms is not None and terms.mode == "auto"
                       and terms.revise)
        self.temporal_stats = TemporalStats.zeros(model.num_gaussians if self.revise else 0, device=self.device)
        self.revisions: dict[str, int] = {"demoted": 0, "split_dynamic": 0}
        self.history: list[dict[str, float]] = []
        self.train_seconds = 0.0  # wall time spent in train(), summed over resumed sessions
        self._moving_packed: np.ndarray | None = None  # (V, T, H, ceil(W/8)) train-view moving masks, bit-packed
        # the CUDA path: train frames, camera matrices and pixel weights on the device (_DeviceFrames)
        self._frames = (_DeviceFrames(scene, self.train_ids, self.device)
                        if resolve_backend(config.backend, self.device) == "gsplat" else None)
        # (host scalars, device values) of the steps not read back yet (_read_back)
        self._pending: list[tuple[dict[str, float], torch.Tensor]] = []
        self._last: dict[str, float] = {}
        self._lock = threading.RLock()
        self._stop = threading.Event()

    # -- configuration ------------------------------------------------------------------------
    @property
    def total_iterations(self) -> int:
        return self.schedule.iterations

    @property
    def round(self) -> int:
        """Stage 2: index of the cache round in use (-1 = none loaded yet, and always in stage 1)."""
        return -1 if self.pseudo is None else self.pseudo.round

    def learning_rates(self, step: int) -> dict[str, float]:
        """Per-parameter learning rates at ``step`` (positions and motion decay; the rest are constant)."""
        c = self.config
        pos = self.schedule.position_lr(step)
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

    # -- one iteration ------------------------------------------------------------------------
    def step(self) -> dict[str, float]:
        """One optimization step. Returns loss, loss_stg, loss_gen (stage 2), psnr (train views),
        num_gaussians, step, lr_means and the seconds spent in each part (t_at, t_render, t_loss,
        t_backward, t_optim, t_densify, t_refresh); reads them back at once (``train`` reads
        every CHECK_EVERY steps)."""
        with self._lock:
            self._step()
            return self._read_back()

    def _step(self) -> None:
        """One step, on ``DIGIT_TORCH_THREADS`` torch threads whatever the caller's count
        (fixer4d/threads.py: its digits then do not depend on the core count); its scalars wait on
        the device in ``_pending`` until ``_read_back``."""
        with digit_threads():
            self._take_step()

    def _take_step(self) -> None:
        timing = dict.fromkeys(TIMING_KEYS, 0.0)
        if self.pseudo is not None:
            tic = time.perf_counter()
            self.pseudo.update(self.model, self.schedule.refresh_round(self.step_count))
            timing["t_refresh"] = time.perf_counter() - tic
        self._set_learning_rates()
        frame = self._next_frame()
        k = min(self.config.views_per_step, len(self.train_ids))
        views = self.rng.choice(len(self.train_ids), size=k, replace=False)
        t = self.scene.time(frame)
        outputs: list[RenderedView] = []
        decaying = self.decay is not None and self.schedule.decays(self.step_count)
        base = (self.decay.opacities(self.model, t, [self.scene.cameras[self.train_ids[int(v)]] for v in views],
                                     self.extent) if decaying else None)
        loss_stg, mses = self._observed_loss(frame, t, views, outputs, timing, base)

        # L = mean_v L_STG(view v) + lambda_gen * mean_p L1(pseudo p): both per-view means, as the
        # paper states it. The gradient taken is that of V x L: Adam is invariant to the overall
        # scale, and each observed view keeps the gradient of its own loss, on which the
        # densification threshold (3DGS: one view per step) is calibrated.
        n_views = max(len(views), 1)
        loss_stg = loss_stg / n_views
        if self.novel_depth is not None and self.step_count % self.config.depth_prior.novel_every == 0:
            loss_stg = loss_stg + self._novel_depth_term(base, timing)
        if self.response is not None:
            loss_stg = loss_stg + RESPONSE_REG * self.response.regularizer()
        if self.config.scale_ratio_weight > 0.0:
            loss_stg = loss_stg + self.config.scale_ratio_weight * scale_ratio_penalty(
                self.model.log_scales, self.config.scale_ratio_max, self.config.scale_ratio_against)
        loss_gen = torch.zeros((), device=self.device)
        pseudo_outputs: list[RenderedView] = []
        evidence = [] if self._gathers_evidence() else None
        if self.pseudo is not None and self.schedule.draws_pseudo_views:
            loss_gen = self.pseudo.loss(self.model, self.rng,
                                        lambda snap, cam: self._render_view(snap, cam, pseudo_outputs, timing), timing,
                                        evidence=evidence, l1=masked_l1 if self._frames is None else masked_l1_device)
            loss = loss_stg + self.schedule.lambda_gen * loss_gen
        else:
            loss = loss_stg
        grads = self._evidence_grads(pseudo_outputs, evidence, n_views, timing) if evidence else []
        self._backward(loss * n_views, timing)
        if self.schedule.densify_stats == "all":
            outputs = outputs + pseudo_outputs
        self._gather_stats(outputs, grads, t, timing)

        tic = time.perf_counter()
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        if self.response_optimizer is not None:
            self.response_optimizer.step()
            self.response_optimizer.zero_grad(set_to_none=True)
        if decaying:
            self.decay.step()
        timing["t_optim"] = time.perf_counter() - tic
        self.step_count += 1

        tic = time.perf_counter()
        counts = self._density_control()
        timing["t_densify"] += time.perf_counter() - tic

        rec = {"step": float(self.step_count), "num_gaussians": float(self.model.num_gaussians),
               "lr_means": self.optimizer.param_groups[0]["lr"], **timing,
               **{f"densify_{k}": float(v) for k, v in counts.items()}}
        scalars = torch.stack([x.detach().to(torch.float64) for x in (loss, loss_stg, loss_gen)])
        self._pending.append((rec, torch.cat([scalars, mses])))

    def _read_back(self) -> dict[str, float]:
        """Read the scalars of the steps not read yet, and whether every Parameter is finite, in
        one transfer; add the steps to ``history`` and return the newest one's record (with loss,
        loss_stg, loss_gen and psnr). NumericalError naming the first step whose loss is not
        finite (its state went on for the steps since; resume from the last checkpoint), or the
        Parameter that is not."""
        if not self._pending:
            return dict(self._last)
        pending, self._pending = self._pending, []
        finite = torch.stack([torch.isfinite(p).all() for p in self.model.parameters()]).all()
        values = torch.cat([v for _, v in pending] + [finite.to(torch.float64).reshape(1)]).tolist()
        at = 0
        for rec, v in pending:
            loss, loss_stg, loss_gen, *mses = values[at:at + v.numel()]
            at += v.numel()
            if not math.isfinite(loss):
                raise NumericalError(f"stage {self.stage} step {int(rec['step'])}: the loss is {loss}; "
                                     "lower the learning rates or resume from the last checkpoint")
            rec.update(loss=loss, loss_stg=loss_stg, loss_gen=loss_gen,
                       psnr=float(np.mean([psnr_from_mse(m) for m in mses])))
            self.history.append({k: rec[k] for k in ("step", "loss", "psnr", "num_gaussians")})
        if not values[-1]:
            self.model.check(f"stage {self.stage} step {self.step_count}")
        self._last = pending[-1][0]
        return dict(self._last)

    def _observed_loss(self, frame: int, t: float, views: np.ndarray, outputs: list[RenderedView],
                       timing: dict[str, float], base: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Sum over the train views ``views`` (indices into train_ids) at ``frame`` (time ``t``) of
        L_STG, and (V,) each view's mean squared error (float64); the renders go to ``outputs``.
        base: (N,) the step's decayed base opacities (None: sigmoid of the logits)."""
        shared = self.model.config.sh_degree == 0  # colours do not depend on the camera
        if shared and self._frames is not None and self._frames.batches:
            return self._observed_loss_batched(frame, t, views, outputs, timing, base)
        loss_stg = torch.zeros((), device=self.device)
        mses = []
        snap = None
        for v in views:
            cam_id = self.train_ids[int(v)]
            cam = self.scene.cameras[cam_id]
            tic = time.perf_counter()
            if snap is None or not shared:
                snap = self.model.at(t, camera_center=None if shared else cam.center, **_decayed(base))
            timing["t_at"] += time.perf_counter() - tic
            out = self._render_view(snap, cam, outputs, timing, view=int(v))
            tic = time.perf_counter()
            recorded = out.rgb if self.response is None else self.response.apply(out.rgb, int(v))
            if self._frames is None:
                target = torch.from_numpy(np.ascontiguousarray(self.scene.frame(frame, cam_id)))
                loss_stg = loss_stg + stg_loss(recorded, target, self._pixel_weight(int(v), frame))
            else:
                target = self._frames.target(int(v), frame)
                loss_stg = loss_stg + stg_loss_device(recorded, target, self._pixel_weight(int(v), frame))
            if (term := self._depth_term(out, int(v), frame)) is not None:
                loss_stg = loss_stg + term
            mses.append(mean_squared_error(recorded, target))
            timing["t_loss"] += time.perf_counter() - tic
        return loss_stg, torch.stack(mses)

    def _observed_loss_batched(self, frame: int, t: float, views: np.ndarray, outputs: list[RenderedView],
                               timing: dict[str, float], base: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        """``_observed_loss`` on the CUDA path with view-independent colours: one snapshot, the
        views rendered in one gsplat call, one loss over the (V, H, W, 3) batch (V x its mean
        is the per-view sum)."""
        tic = time.perf_counter()
        snap = self.model.at(t, **_decayed(base))
        timing["t_at"] += time.perf_counter() - tic
        index = [int(v) for v in views]
        tic = time.perf_counter()
        cams = [self.scene.cameras[self.train_ids[v]] for v in index]
        rendered = render_batch(snap, cams, self.background, matrices=self._frames.matrices(index))
        timing["t_render"] += time.perf_counter() - tic
        outputs.extend((out, cam, _drawn(snap, out)) for out, cam in zip(rendered, cams))
        tic = time.perf_counter()
        recorded = torch.stack([out.rgb if self.response is None else self.response.apply(out.rgb, v)
                                for out, v in zip(rendered, index)])
        target = torch.stack([self._frames.target(v, frame) for v in index])
        weights = [self._pixel_weight(v, frame) for v in index]
        weight = None if weights[0] is None else torch.stack(weights)
        loss_stg = len(index) * stg_loss_device(recorded, target, weight)
        for out, v in zip(rendered, index):
            if (term := self._depth_term(out, v, frame)) is not None:
                loss_stg = loss_stg + term
        mses = (recorded.detach().double() - target.double()).pow(2).mean(dim=(1, 2, 3))
        timing["t_loss"] += time.perf_counter() - tic
        return loss_stg, mses

    def _backward(self, loss: torch.Tensor, timing: dict[str, float]) -> None:
        """Backpropagate ``loss`` and hold the frozen rows (a non-finite loss is reported when
        the step's scalars are read back, ``_read_back``)."""
        tic = time.perf_counter()
        loss.backward()
        self._hold_frozen_rows()
        timing["t_backward"] = time.perf_counter() - tic

    def _gathers_evidence(self) -> bool:
        """Whether this step's pseudo-views add their unobserved-pixel gradients to the
        densification statistics (``densify_stats = "evidence"`` while the schedule densifies)."""
        return (self.pseudo is not None and self.schedule.draws_pseudo_views and self.schedule.densify_stats == "evidence"
                and self.schedule.gathers_stats(self.step_count))

    def _evidence_grads(self, pseudo_outputs: list[RenderedView], evidence: list[torch.Tensor], n_views: int,
                        timing: dict[str, float]) -> list[tuple[torch.Tensor, Camera, torch.Tensor]]:
        """Per pseudo-view: the screen-space gradient of its loss term restricted to the pixels no
        train camera explains, at the scale the full loss gives its render (``n_views x lambda_gen``),
        with its camera and drawn mask. Taken before the step's backward (which frees the graph)."""
        tic = time.perf_counter()
        grads = []
        for (out, cam, drawn), term in zip(pseudo_outputs, evidence):
            if not out.means2d.requires_grad:
                continue
            (g,) = torch.autograd.grad(term * (n_views * self.schedule.lambda_gen), out.means2d, retain_graph=True,
                                       allow_unused=True)
            if g is not None:
                grads.append((g, cam, drawn))
        timing["t_densify"] += time.perf_counter() - tic
        return grads

    def _gather_stats(self, outputs: list[RenderedView], grads: list[tuple[torch.Tensor, Camera, torch.Tensor]],
                      t: float, timing: dict[str, float]) -> None:
        """Add the screen-space gradients of this step's renders ``outputs`` (at time ``t``), and
        the precomputed ``grads`` (gradient, camera, drawn), to the densification (and
        term-revision) statistics while the schedule densifies."""
        tic = time.perf_counter()
        if self.schedule.gathers_stats(self.step_count):
            views = [(out.means2d.grad, cam, drawn) for out, cam, drawn in outputs] + list(grads)
            for grad, cam, drawn in views:
                if grad is not None:
                    self.stats.update(grad, drawn, cam.width, cam.height)
                    if self.revise:
                        self.temporal_stats.update(grad, drawn, cam.width, cam.height, t)
        timing["t_densify"] += time.perf_counter() - tic

    def _next_frame(self) -> int:
        """The frame of this step (``TrainingConfig.frame_order``)."""
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
        frozen = self.model.frozen_index()
        if frozen.numel() == 0:
            return
        for p in self.model.parameters():
            if p.grad is not None:
                p.grad.index_fill_(0, frozen, 0.0)

    def _pixel_weight(self, view: int, frame: int) -> torch.Tensor | None:
        """(H, W) weight of the observed loss at train view ``view`` (index into train_ids) and
        ``frame``: 1 + ``moving_loss_weight`` on the pixels of that camera's own moving-content
        mask (fixer4d.init.masks, from its own video; no other camera), 1 elsewhere; None when
        the weight is 0. The masks of every frame are estimated once, on first use."""
        w = float(self.config.moving_loss_weight)
        if w <= 0.0:
            return None
        if self._frames is not None and self._frames.weights is not None:
            return self._frames.weights[view][frame]
        if self._frames is not None:
            self._moving_masks()
            self._frames.cache_weights(self._moving_packed, w)
            return self._frames.weights[view][frame]
        return torch.from_numpy(1.0 + w * self._moving_mask(view, frame).astype(np.float32))

    def _moving_masks(self) -> np.ndarray:
        """(V, T, H, ceil(W/8)) the train views' moving-content masks, bit-packed (estimated on
        first use)."""
        if self._moving_packed is None:
            from fixer4d.init.masks import moving_masks_for_scene

            masks = moving_masks_for_scene(self.scene, self.train_ids, list(range(self.scene.num_frames)))
            self._moving_packed = np.packbits(masks, axis=-1)
        return self._moving_packed

    def _moving_mask(self, view: int, frame: int) -> np.ndarray:
        """(H, W) bool moving-content mask of train view ``view`` at ``frame``."""
        width = self.scene.cameras[self.train_ids[view]].width
        return np.unpackbits(self._moving_masks()[view, frame], axis=-1, count=width).astype(bool)

    def _novel_depth_term(self, base: torch.Tensor | None, timing: dict[str, float]) -> torch.Tensor:
        """weight x L_depth of one novel camera's render at an init frame (``NovelDepthViews``); its
        render enters no densification statistic (no image was seen there)."""
        drawn = self.novel_depth.draw(self.novel_rng)
        if drawn is None:
            return torch.zeros((), device=self.device)
        cam, frame, target = drawn
        snap = self.model.at(self.scene.time(frame), **_decayed(base))
        out = self._render_view(snap, cam, [], timing)
        return self.config.depth_prior.novel_weight * depth_loss(out.depth, target)

    def _depth_term(self, out: RenderOutput, view: int, frame: int) -> torch.Tensor | None:
        """weight x L_depth of train view ``view``'s render at ``frame`` (``train.depth_prior``);
        None without depth targets or without a target there."""
        if self.depth_targets is None:
            return None
        target = self.depth_targets.target(view, frame)
        return None if target is None else self.config.depth_prior.weight * depth_loss(out.depth, target)

    def _render_view(self, snap: Snapshot, cam: Camera, outputs: list[RenderedView],
                     timing: dict[str, float], view: int | None = None) -> RenderOutput:
        """Render ``snap`` at ``cam`` (train view ``view``, or None) (seconds into
        ``timing["t_render"]``) and record the view in ``outputs`` for the densification statistics."""
        tic = time.perf_counter()
        if self._frames is None:
            out = render(snap, cam, background=self.background, backend=self.config.backend)
        else:
            matrices = self._frames.matrices([view]) if view is not None else self._frames.camera(cam)
            (out,) = render_batch(snap, [cam], self.background, matrices=matrices)
        timing["t_render"] += time.perf_counter() - tic
        outputs.append((out, cam, _drawn(snap, out)))
        return out

    @torch.no_grad()
    def _density_control(self) -> dict[str, int]:
        """Densify/prune and reset opacities (unless they decay) on the schedule (``step_count`` is 1-based here, as 3DGS)."""
        cfg = self.config
        s = self.step_count
        counts: dict[str, int] = {}
        if self.schedule.densifies(s, cfg.densify_every):
            # the size prunes (off by default) apply after the first opacity reset, as in 3DGS;
            # stage 2 never resets and so never applies them (its pseudo-views are less
            # trustworthy than the real views that shaped the model)
            size_prunes = self.schedule.size_prunes_apply(s)
            if self.revise:
                counts.update(self._revise_terms())
            counts.update(densify_and_prune(
                self.model, self.optimizer, self.stats, extent=self.extent,
                grad_threshold=cfg.densify_grad_threshold, percent_dense=cfg.percent_dense,
                max_gaussians=cfg.max_gaussians, prune_opacity=cfg.prune_opacity,
                prune_world_scale=cfg.prune_world_scale if size_prunes else None,
                prune_screen_fraction=cfg.prune_screen_fraction if size_prunes else None,
                generator=self.generator, split_children=cfg.split_children,
                split_scale_divisor=cfg.split_scale_divisor))
            self.stats = DensifyStats.zeros(self.model.num_gaussians, self.model.means.device)
            if self.revise:
                self.temporal_stats = TemporalStats.zeros(self.model.num_gaussians, device=self.model.means.device)
        if self.schedule.resets_opacity(s):
            cap = math.log(cfg.opacity_reset_value / (1.0 - cfg.opacity_reset_value))
            logits = self.model.opacity_logits
            reset_parameter(self.model, self.optimizer, "opacity_logits",
                            torch.where(self.model.frozen, logits, logits.clamp(max=cap)))
            counts["opacity_reset"] = 1
        return counts

    def _revise_terms(self) -> dict[str, int]:
        """Demote / split model terms (``fixer4d.model.term_revisions.revise_terms``); the split rows get
        empty densification statistics. Returns the counts of this round."""
        cfg = self.config
        rev = revise_terms(self.model, self.optimizer, self.temporal_stats,
                           grad_threshold=cfg.densify_grad_threshold, max_gaussians=cfg.max_gaussians)
        for k, v in rev.items():
            self.revisions[k] += v
        if rev["split_dynamic"]:  # the new rows have no statistics yet
            self.stats = DensifyStats(*(torch.cat([x, x.new_zeros(rev["split_dynamic"])])
                                        for x in (self.stats.grad_accum, self.stats.denom, self.stats.max_radii)))
        return dict(rev)

    # -- loops and reading --------------------------------------------------------------------
    def stop(self) -> None:
        """Ask ``train`` to return after the current step (thread-safe)."""
        self._stop.set()

    @property
    def done(self) -> bool:
        return self.step_count >= self.total_iterations

    def train(self, n: int | None = None, progress: bool | None = None,
              on_step: Callable[[int], None] | None = None) -> dict[str, float]:
        """Run up to ``n`` more steps (default: until ``total_iterations``), checkpointing every
        ``checkpoint_every`` steps and at the end. ``on_step(step_count)`` after every step (a
        worker process's progress, ``train.field_workers``). Returns the last step's scalars plus
        seconds."""
        self._stop.clear()
        end = self.total_iterations if n is None else min(self.step_count + int(n), self.total_iterations)
        show = self.config.progress if progress is None else progress
        from tqdm import tqdm

        bar = tqdm(total=self.total_iterations, initial=self.step_count, disable=not show,
                   desc=self.label, unit="it", dynamic_ncols=True)
        rec: dict[str, float] = {}
        tic = last = time.perf_counter()
        try:
            while self.step_count < end and not self._stop.is_set():
                with self._lock:
                    self._step()
                now = time.perf_counter()
                self.train_seconds += now - last  # before a checkpoint, so that it records it
                last = now
                bar.update(1)
                if on_step is not None:
                    on_step(self.step_count)
                if self.step_count % CHECK_EVERY == 0 or self.step_count == end:
                    with self._lock:
                        rec = self._read_back()
                    bar.set_postfix(loss=f"{rec['loss']:.4f}", psnr=f"{rec['psnr']:.2f}",
                                    n=int(rec["num_gaussians"]), refresh=False)
                if self.run_dir is not None and self.step_count % self.config.checkpoint_every == 0:
                    self.save_checkpoint()
        finally:
            bar.close()
        with self._lock:
            rec = self._read_back() if self._pending else rec
        if self.run_dir is not None and rec and self.step_count % self.config.checkpoint_every != 0:
            self.save_checkpoint()
        rec = dict(rec)
        rec["seconds"] = time.perf_counter() - tic
        return rec

    def snapshot(self, t: float, camera_center: np.ndarray | None = None) -> Snapshot:
        """The model at time t, detached (safe to hand to another thread)."""
        with self._lock, torch.no_grad():
            return self.model.at(float(t), camera_center).detach()

    def host_model(self) -> SpacetimeGaussians:
        """The model moved to host memory (in place), what a stage hands on once training is over:
        PLYs, later stages, the viewer and the restoration renders read host tensors."""
        with self._lock:
            return self.model.cpu()

    def render_fn(self) -> Callable[[Camera, float], np.ndarray]:
        """``fn(camera, t) -> (H, W, 3) float32`` rendering the current model (for evaluation);
        each render takes its snapshot under the trainer's lock."""
        return model_render_fn(_Snapshots(self), self.config.backend, self.background)

    # -- checkpoints (fixer4d.train.checkpoints) ----------------------------------------------
    list_checkpoints = staticmethod(list_checkpoints)

    def state_dict(self) -> dict[str, Any]:
        """Everything a resumed run needs; reads the pending steps back first (``_read_back``:
        no checkpoint of a diverged model)."""
        with self._lock:
            self._read_back()
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
                **training_settings(self.config, self.stage2),
                "history": list(self.history),
                "train_seconds": self.train_seconds,
                **({} if self.response is None else {
                    "camera_response": {k: v.detach().clone() for k, v in self.response.state_dict().items()},
                    "camera_response_optimizer": self.response_optimizer.state_dict()}),
                **({} if self.decay is None else {"opacity_decay": self.decay.state_dict()}),
                **({} if self.novel_depth is None else {"novel_depth_rng": self.novel_rng.bit_generator.state}),
            }

    def load_state_dict(self, state: dict[str, Any], source: str = "checkpoint") -> None:
        """Restore a ``state_dict()`` (model, optimizer, statistics, RNG states, step)."""
        check_resumable(state, self.stage, training_settings(self.config, self.stage2), source)
        with self._lock:
            model = SpacetimeGaussians.from_state_dict(state["model"], ModelConfig.from_dict(state["model_config"]))
            self.model = model.to(self.model.means.device)
            self.step_count = int(state["step"])
            self.extent = float(state["extent"])
            self.optimizer = self._make_optimizer()
            self.optimizer.load_state_dict(state["optimizer"])
            self.stats = DensifyStats.from_state_dict(state["stats"]).to(self.device)
            if "temporal_stats" in state:
                self.temporal_stats = TemporalStats.from_state_dict(state["temporal_stats"]).to(self.device)
                self.revisions = dict(state.get("revisions", self.revisions))
            self._pending, self._last = [], {}
            self.rng.bit_generator.state = state["numpy_rng"]
            self.generator.set_state(state["torch_generator"])
            self.history = list(state.get("history", []))
            self.train_seconds = float(state.get("train_seconds", 0.0))
            if self.response is not None and "camera_response" in state:
                self.response.load_state_dict(state["camera_response"])
                self.response_optimizer.load_state_dict(state["camera_response_optimizer"])
            if self.decay is not None:
                self.decay.load_state_dict(state["opacity_decay"])
            if self.novel_depth is not None:
                self.novel_rng.bit_generator.state = state["novel_depth_rng"]
            if self.pseudo is not None:
                self.pseudo.forget(int(state["round"]))

    def save_checkpoint(self) -> Path:
        """Write RUN/checkpoints/stage{S}_{STEP}.pt atomically; keep the newest ``keep_checkpoints``."""
        if self.run_dir is None:
            raise InputError("save_checkpoint: this trainer has no run_dir")
        return write_checkpoint(self.state_dict(), self.run_dir, self.stage, self.step_count,
                                self.config.keep_checkpoints)

    def load_checkpoint(self, path: str | Path) -> None:
        """Load ``path`` with ``torch.load(weights_only=True)``: only tensors and plain containers
        are rebuilt, so a checkpoint that carries pickled code or objects is refused, never run."""
        self.load_state_dict(read_checkpoint(path), source=str(path))

    def resume(self) -> bool:
        """Load the newest checkpoint of this stage from ``run_dir`` if there is one (after deleting
        the partial ones a killed save left)."""
        if self.run_dir is None:
            return False
        remove_partial_checkpoints(self.run_dir, self.stage)
        found = list_checkpoints(self.run_dir, self.stage)
        if not found:
            return False
        self.load_checkpoint(found[-1])
        log.info("resumed stage %d from %s (step %d)", self.stage, found[-1], self.step_count)
        return True


class _DeviceFrames:
    """The CUDA path's copies on the training device, made once: every train view's frames
    ((T, H, W, 3) float32 per view; the demo's 4 views x 30 frames at 200x150 are 43 MB, the
    Panoptic split's at 640x360 330 MB), its camera matrices for gsplat and, once the moving
    masks are estimated, its pixel weights ((T, H, W) per view)."""

    def __init__(self, scene: MultiViewVideo, train_ids: list, device: torch.device) -> None:
        frames = [np.stack([scene.frame(f, c) for f in range(scene.num_frames)]) for c in train_ids]
        self.frames = [torch.from_numpy(np.ascontiguousarray(f, dtype=np.float32)).to(device) for f in frames]
        if not all(bool(torch.isfinite(f).all()) for f in self.frames):
            raise NumericalError(f"{scene.name}: a train frame has NaN/inf pixels; the scene's images are corrupt")
        from fixer4d.render.gsplat_backend import camera_matrices

        cameras = [scene.cameras[c] for c in train_ids]
        self.viewmats, self.Ks = camera_matrices(cameras, device)
        self.batches = len({(c.width, c.height) for c in cameras}) == 1  # gsplat batches one image size
        self.weights: list[torch.Tensor] | None = None
        self.device = device
        self._cameras: OrderedDict[int, tuple[Camera, tuple[torch.Tensor, torch.Tensor]]] = OrderedDict()

    def target(self, view: int, frame: int) -> torch.Tensor:
        return self.frames[view][frame]

    def matrices(self, views: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
        """(viewmats (C, 4, 4), Ks (C, 3, 3)) of train views ``views``, gathered on the device."""
        return torch.stack([self.viewmats[v] for v in views]), torch.stack([self.Ks[v] for v in views])

    def camera(self, cam: Camera) -> tuple[torch.Tensor, torch.Tensor]:
        """(viewmats (1, 4, 4), Ks (1, 3, 3)) of a camera that is no train view (stage 2's
        pseudo-views), copied over on its first render and kept for the last CAMERA_CACHE ones."""
        hit = self._cameras.get(id(cam))
        if hit is not None and hit[0] is cam:
            self._cameras.move_to_end(id(cam))
            return hit[1]
        from fixer4d.render.gsplat_backend import camera_matrices

        matrices = camera_matrices([cam], self.device)
        self._cameras[id(cam)] = (cam, matrices)  # the camera is kept, so its id is not reused meanwhile
        while len(self._cameras) > CAMERA_CACHE:
            self._cameras.popitem(last=False)
        return matrices

    def cache_weights(self, packed: np.ndarray, w: float) -> None:
        """The pixel weights 1 + ``w`` x mask of every view and frame from the bit-packed moving
        masks (V, T, H, ceil(W/8)), as ``Trainer._pixel_weight`` computes one of them."""
        self.weights = []
        for view, frames in enumerate(self.frames):
            m = np.unpackbits(packed[view], axis=-1, count=frames.shape[2]).astype(np.float32)
            self.weights.append(torch.from_numpy(1.0 + w * m).to(self.device))


class _Snapshots:
    """A trainer seen as a model: ``at(t, camera_center)`` is its locked, detached snapshot."""

    def __init__(self, trainer: Trainer) -> None:
        self.at = lambda t, camera_center=None: trainer.snapshot(t, camera_center)
