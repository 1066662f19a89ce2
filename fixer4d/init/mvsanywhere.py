"""MVSAnywhere (Izquierdo et al., CVPR 2025) behind the DepthEstimator protocol.

The ``mvsanywhere`` package, its weights and its CUDA device are optional: importing this module
never imports the package; building an ``MVSAnywhereEstimator`` checks them all and raises
BackendUnavailable naming every missing piece (no fallback).

How ``estimate`` calls the library (``DepthModel.forward`` with the batch layout of the package's
own datasets and of its rmvd wrapper), per key view r of V views, the other V - 1 as sources:
  images    each view area-resampled to image_width x image_height, RGB in [0, 1] then ImageNet-
            normalized (mean/std below), float32 (3, h, w); batched as ``image_b3hw`` (1, 3, h, w)
            for the key view and (1, V - 1, 3, h, w) for the sources;
  K         the intrinsics of that resized image with rows 0-1 scaled by the model's
            ``matching_scale`` (the cost volume's resolution), as 4x4 ``K_matching_b44`` with its
            inverse; (1, 4, 4) key, (1, V - 1, 4, 4) sources;
  poses     ``world_T_cam_b44`` = the camera's c2w (OpenCV axes, scene units) and
            ``cam_T_world_b44`` its inverse (world-to-camera);
  ranges    ``min_depth`` / ``max_depth`` (1,) from ``depth_ranges``. The library's forward
            replaces them with its own estimate from the camera baselines (``estimate_depth_range``
            defaults to True) and refines that once (``num_refinement_steps=1``), so they are hints.
The output ``depth_pred_s0_b1hw`` (1, 1, h', w') is z-depth in scene units (the model is scale-
agnostic: its depth range comes from the baselines, in scene units) at the model's prediction
scale of the network input; it becomes a DepthResult at h' x w' with the camera resized to it,
depth 0 / invalid where it is not finite and > 0, confidence 1 where valid.
"""
from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from fixer4d.errors import BackendUnavailable
from fixer4d.geometry.camera import Camera
from fixer4d.init.depth_estimator import DepthResult, check_views

MVSANYWHERE_WEIGHTS_ENV = "FIXER4D_MVSANYWHERE_WEIGHTS"
MVSANYWHERE_CONFIG_ENV = "FIXER4D_MVSANYWHERE_CONFIG"
# ImageNet statistics: the package's datasets normalize [0, 1] RGB with them (imagenet_normalize).
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


@dataclass
class MVSAnywhereConfig:
    """weights_path: local checkpoint (e.g. mvsanywhere_hero.ckpt), default from the
    FIXER4D_MVSANYWHERE_WEIGHTS environment variable. config_file: the model YAML of the
    mvsanywhere repository (configs/models/mvsanywhere_model.yaml), default from
    FIXER4D_MVSANYWHERE_CONFIG. device: torch device. image_width/height: network input size
    (the package's defaults)."""

    weights_path: str | None = None
    config_file: str | None = None
    device: str = "cuda"
    image_width: int = 512
    image_height: int = 384


def _missing(weights: str | None, cfg_file: str | None, device: str) -> list[str]:
    """What MVSAnywhere lacks here, one phrase each ([] when it can run)."""
    missing = []
    try:
        importlib.import_module("mvsanywhere")
    except ImportError:
        missing.append("the `mvsanywhere` Python package (pip install it from github.com/nianticlabs/mvsanywhere)")
    if not weights:
        missing.append(f"a weights path (MVSAnywhereConfig.weights_path or ${MVSANYWHERE_WEIGHTS_ENV})")
    elif not os.path.isfile(weights):
        missing.append(f"the weights file {weights} (it does not exist)")
    if not cfg_file:
        missing.append(f"the model config YAML (MVSAnywhereConfig.config_file or ${MVSANYWHERE_CONFIG_ENV})")
    elif not os.path.isfile(cfg_file):
        missing.append(f"the model config {cfg_file} (it does not exist)")
    if str(device).startswith("cuda") and not torch.cuda.is_available():
        missing.append(f"a CUDA device for device={device!r} (torch.cuda.is_available() is False)")
    return missing


class MVSAnywhereEstimator:
    """Adapter around the ``mvsanywhere`` package: each view is the key view, the others its
    sources (module docstring). No fallback: a missing package, weights file, config or CUDA
    device raises BackendUnavailable."""

    name = "mvsanywhere"

    def __init__(self, config: MVSAnywhereConfig | None = None) -> None:
        self.config = config or MVSAnywhereConfig()
        weights = self.config.weights_path or os.environ.get(MVSANYWHERE_WEIGHTS_ENV)
        cfg_file = self.config.config_file or os.environ.get(MVSANYWHERE_CONFIG_ENV)
        missing = _missing(weights, cfg_file, self.config.device)
        if missing:
            raise BackendUnavailable("MVSAnywhere is unavailable; missing: " + "; ".join(missing)
                                     + ". Use the built-in plane sweep (--estimator planesweep) instead.")
        self.weights = weights
        self.config_file = cfg_file
        self._model = None

    def _load(self):
        """The model in eval mode on the configured device (loaded once), and its matching scale."""
        if self._model is None:
            from mvsanywhere import options
            from mvsanywhere.utils.model_utils import get_model_class, load_model_inference

            handler = options.OptionsHandler()
            handler.parse_and_merge_options(config_filepaths=self.config_file, ignore_cl_args=True)
            opts = handler.options
            opts.load_weights_from_checkpoint = self.weights
            model = load_model_inference(opts, get_model_class(opts))
            self._model = model.to(self.config.device).eval()
            self._matching_scale = float(opts.matching_scale)
        return self._model

    def _network_inputs(self, images: Sequence[np.ndarray], cameras: Sequence[Camera], dev: torch.device
                        ) -> tuple[list[torch.Tensor], list[torch.Tensor], list[torch.Tensor]]:
        """Per view: the normalized network image (3, h, w), K_matching (4, 4) and c2w (4, 4),
        float32 on ``dev`` (module docstring)."""
        import cv2

        cfg = self.config
        mean = torch.tensor(IMAGENET_MEAN, device=dev)[:, None, None]
        std = torch.tensor(IMAGENET_STD, device=dev)[:, None, None]
        tens, Ks, c2ws = [], [], []
        for img, cam in zip(images, cameras):
            small = cv2.resize(np.asarray(img, np.float32), (cfg.image_width, cfg.image_height),
                               interpolation=cv2.INTER_AREA)
            tens.append((torch.from_numpy(small).permute(2, 0, 1).to(dev) - mean) / std)
            K = np.eye(4)
            K[:3, :3] = cam.resized(cfg.image_width, cfg.image_height).K
            K[:2] *= self._matching_scale
            Ks.append(torch.from_numpy(K).float().to(dev))
            c2ws.append(torch.tensor(cam.c2w).float().to(dev))
        return tens, Ks, c2ws

    def estimate(self, images: Sequence[np.ndarray], cameras: Sequence[Camera],
                 depth_ranges: Sequence[tuple[float, float]] | None = None) -> list[DepthResult]:
        """One DepthResult per view at the model's output resolution (module docstring).
        images: V (H, W, 3) float32 RGB in [0, 1]; cameras: the V posed cameras (scene units);
        depth_ranges: optional per-view (near, far) z-depths, hints to the model."""
        views = check_views(images, cameras)
        model = self._load()
        dev = torch.device(self.config.device)
        tens, Ks, c2ws = self._network_inputs(images, cameras, dev)

        def pack(ids, batch_dims):
            img = torch.stack([tens[i] for i in ids])
            K = torch.stack([Ks[i] for i in ids])
            pose = torch.stack([c2ws[i] for i in ids])
            d = {"image_b3hw": img, "world_T_cam_b44": pose, "cam_T_world_b44": torch.linalg.inv(pose),
                 "K_matching_b44": K, "invK_matching_b44": torch.linalg.inv(K)}
            return {key: val.unsqueeze(0) if batch_dims else val for key, val in d.items()}

        results = []
        with torch.inference_mode():
            for r in range(views):
                src = [s for s in range(views) if s != r]
                cur = pack([r], False)
                if depth_ranges is not None:
                    cur["min_depth"] = torch.tensor([depth_ranges[r][0]], device=dev)
                    cur["max_depth"] = torch.tensor([depth_ranges[r][1]], device=dev)
                out = model(phase="test", cur_data=cur, src_data=pack(src, True),
                            unbatched_matching_encoder_forward=True, return_mask=True, num_refinement_steps=1)
                results.append(_depth_result(out["depth_pred_s0_b1hw"], cameras[r]))
        return results


def _depth_result(pred_b1hw: torch.Tensor, camera: Camera) -> DepthResult:
    """The model's (1, 1, h', w') depth of one key view -> DepthResult at h' x w' (``camera``
    resized to it): float32 depth, 0 where not finite or <= 0; confidence 1 where valid."""
    pred = pred_b1hw[0, 0].float().cpu().numpy()
    cam = camera.resized(pred.shape[1], pred.shape[0])
    valid = np.isfinite(pred) & (pred > 0)
    return DepthResult(np.where(valid, pred, 0).astype(np.float32), valid, valid.astype(np.float32), cam)
