"""Static Gaussians shared across the segments of a long capture.

A static rig films the same static world in every segment. With ``segments.share_static`` (off by
default) the first segment runs alone; its static Gaussians (``dynamic`` False) are exported into
``RUN/segments/shared_static/`` (``stage1.ply`` from its stage-1 model, ``final.ply`` from its
refined one) and every later segment trains on top of them, frozen (``SpacetimeGaussians.frozen``:
the trainer never moves, densifies or prunes them):

- stage 1 (and the matched control) start from the segment's own init with the shared stage-1
  static rows appended; the segment's own static points are kept only where the shared static
  does not already explain them (``uncovered``: static content the first segment never saw,
  e.g. floor a person stood on), its moving points all become its dynamic Gaussians;
- stage 2 swaps the frozen rows for the first segment's refined static rows (``final.ply``),
  so every report row of the stitched model uses static Gaussians of the same stage.

So the static world is identical on both sides of every segment boundary and is stored and
trained once. The learned restorer's leave-one-camera-out folds never use the shared rows: the
first segment saw every train camera, which would leak the held-back camera into its fold.

Limitation: content that is static during the first segment and moves later stays where the
first segment saw it (frozen rows are never pruned); its later motion is learned by dynamic
Gaussians on top of it. And the first segment's stage-1 outcome is carried into every segment:
on the whole Panoptic capture sharing gave +0.9 dB on one camera split and -0.25 dB on the other
(README "Long captures"), which is why it is opt-in.
"""
from __future__ import annotations

import hashlib
import logging
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians

log = logging.getLogger("fixer4d.pipeline")

SHARED_DIR = "shared_static"
STAGE1_FILE = "stage1.ply"
FINAL_FILE = "final.ply"
# A point is explained by the shared static in a camera where their render has accumulated at
# least this opacity at the point's pixel (half-transparent edges do not count as covered) ...
COVER_ALPHA = 0.5
# ... and the point does not lie in front of the rendered surface by more than this fraction of
# its depth (a new object in front of the wall is not the wall; 5% is a few plane-sweep depth
# steps at the rig's distances).
COVER_DEPTH_REL = 0.05
# Parameters a static row uses; every other one (time terms) is neutral for it.
_STATIC_PARAMS = ("means", "log_scales", "quats", "opacity_logits", "colors", "sh_rest")


def static_rows(model: SpacetimeGaussians) -> SpacetimeGaussians:
    """The static Gaussians of ``model`` (``dynamic`` False), flagged frozen."""
    keep = ~model.dynamic
    t = {k: v[keep].clone() for k, v in model.tensors().items()}
    t["frozen"] = torch.ones(int(keep.sum()), dtype=torch.bool)
    return SpacetimeGaussians.from_tensors(model.config, t, source="shared static rows")


def export_shared_static(segment_dir: Path, out_dir: Path) -> dict[str, int] | None:
    """The first segment's static rows -> ``out_dir``/{stage1,final}.ply (final only when that
    segment ran stage 2). Returns {"stage1": n, "final": m, "sh_degree": d}, or None when its
    model has no static Gaussians (model terms "all" make every Gaussian dynamic): nothing to share."""
    from fixer4d.model.io import load_ply, save_ply

    segment_dir, out_dir = Path(segment_dir), Path(out_dir)
    s1 = load_ply(segment_dir / "model_stage1.ply")
    shared = static_rows(s1)
    if shared.num_gaussians == 0:
        return None
    out_dir.mkdir(parents=True, exist_ok=True)
    save_ply(shared, out_dir / STAGE1_FILE)
    summary = {"stage1": shared.num_gaussians, "final": 0, "sh_degree": s1.config.sh_degree}
    final = segment_dir / "model_final.ply"
    if final.is_file():
        refined = static_rows(load_ply(final))
        save_ply(refined, out_dir / FINAL_FILE)
        summary["final"] = refined.num_gaussians
    return summary


def digest(shared_dir: str | Path) -> str:
    """A content hash of the shared files (part of the later segments' stage keys, so a changed
    first segment retrains them)."""
    h = hashlib.sha256()
    for name in (STAGE1_FILE, FINAL_FILE):
        p = Path(shared_dir) / name
        h.update(name.encode())
        h.update(p.read_bytes() if p.is_file() else b"-")
    return h.hexdigest()[:16]


def load_shared(shared_dir: str | Path, stage: str) -> SpacetimeGaussians:
    """The shared static rows for ``stage`` ("stage1" | "final"; final falls back to stage1)."""
    from fixer4d.model.io import load_ply

    d = Path(shared_dir)
    path = d / (FINAL_FILE if stage == "final" and (d / FINAL_FILE).is_file() else STAGE1_FILE)
    if not path.is_file():
        raise InputError(f"{path}: the first segment's shared static Gaussians are missing; rerun the "
                         "segmented run (it exports them after the first segment) or set segments.share_static=false")
    return load_ply(path)


def rows_in(shared: SpacetimeGaussians, config: ModelConfig) -> dict[str, torch.Tensor]:
    """The shared rows as ``append`` rows of a model with ``config``: their static parameters
    as they are, time terms neutral (a static row never evaluates them), dynamic False, frozen."""
    if shared.config.sh_degree != config.sh_degree:
        raise InputError(f"shared static rows have SH degree {shared.config.sh_degree}, the segment's model "
                         f"{config.sh_degree}; the segments must use the first segment's SH degree")
    n = shared.num_gaussians
    src = shared.tensors()
    rows: dict[str, torch.Tensor] = {}
    for name, shape in config.param_shapes().items():
        rows[name] = (src[name].clone() if name in _STATIC_PARAMS
                      else torch.zeros((n, *shape), dtype=shared.means.dtype))
    rows["dynamic"] = torch.zeros(n, dtype=torch.bool)
    rows["frozen"] = torch.ones(n, dtype=torch.bool)
    return rows


@torch.no_grad()
def uncovered(shared: SpacetimeGaussians, points: np.ndarray, cameras: Sequence[Camera],
              backend: str = "auto") -> np.ndarray:
    """(N,) bool: points (N, 3) that the shared static does not explain in at least one camera
    that sees them (their pixel's accumulated opacity < COVER_ALPHA, or the point lies in front
    of the rendered depth by more than COVER_DEPTH_REL). A point no camera sees counts as
    explained (no evidence for new content)."""
    from fixer4d.render.api import render

    pts = np.asarray(points, np.float64).reshape(-1, 3)
    new = np.zeros(pts.shape[0], bool)
    if pts.shape[0] == 0 or shared.num_gaussians == 0:
        return ~new
    for cam in cameras:
        out = render(shared.snapshot(0.5, camera_center=cam.center), cam, backend=backend)
        alpha = out.alpha.detach().cpu().numpy()
        depth = out.depth.detach().cpu().numpy()
        uv, z = cam.project(pts)
        ok = (z > 0) & np.all(np.isfinite(uv), axis=1)
        ij = np.floor(np.nan_to_num(uv)).astype(np.int64)
        ok &= (ij[:, 0] >= 0) & (ij[:, 0] < cam.width) & (ij[:, 1] >= 0) & (ij[:, 1] < cam.height)
        a = np.zeros(pts.shape[0])
        d = np.zeros(pts.shape[0])
        a[ok] = alpha[ij[ok, 1], ij[ok, 0]]
        d[ok] = depth[ij[ok, 1], ij[ok, 0]]
        new |= ok & ((a < COVER_ALPHA) | (z < (1.0 - COVER_DEPTH_REL) * d))
    return new


def add_shared_static(model: SpacetimeGaussians, shared: SpacetimeGaussians, cameras: Sequence[Camera],
                      backend: str = "auto") -> dict[str, int]:
    """In place: drop ``model``'s own static rows that ``shared`` explains in the ``cameras``
    (``uncovered``), then append the shared rows frozen. Returns the counts for the report."""
    own_static = ~model.dynamic & ~model.frozen
    idx = torch.nonzero(own_static).reshape(-1)
    new = uncovered(shared, model.means.detach()[idx].cpu().numpy(), cameras, backend)
    keep = torch.ones(model.num_gaussians, dtype=torch.bool)
    keep[idx[torch.from_numpy(~new)]] = False
    model.prune(keep)
    model.append(rows_in(shared, model.config))
    counts = {"shared_static": shared.num_gaussians, "own_static_kept": int(new.sum()),
              "own_static_dropped": int((~new).sum())}
    log.info("shared static: %(shared_static)d frozen rows; own static points kept %(own_static_kept)d, "
             "dropped %(own_static_dropped)d (explained by the shared rows)", counts)
    return counts


def swap_shared_static(model: SpacetimeGaussians, shared: SpacetimeGaussians) -> SpacetimeGaussians:
    """A copy of ``model`` with its frozen rows replaced by ``shared`` (the refined static rows
    stage 2 trains beside)."""
    import copy

    out = copy.deepcopy(model)
    out.prune(~out.frozen)
    out.append(rows_in(shared, out.config))
    return out
