"""Write any MultiViewVideo to disk in the Neural3DV layout (what `fixer4d make-scene` does).

Output folder: camXX.mp4 (H.264, one per camera, XX = camera index), poses_bounds.npy (LLFF),
depth/camXX.npz (ground-truth z-depth float32 (T, H, W), inf where nothing is hit; only when
the scene has depth) and scene.json (split, fps, box, provenance). The folder appears whole or
not at all (written to a temporary sibling, then renamed).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm import tqdm

from fixer4d.atomic import atomic_dir, atomic_path, write_json
from fixer4d.errors import InputError
from fixer4d.geometry.llff import cameras_to_llff
from fixer4d.scene.base import MultiViewVideo
from fixer4d.scene.video import VIDEO_CRF, write_video

SCENE_JSON_VERSION = 1


def export_n3dv(scene: MultiViewVideo, out_dir: str | Path, *, crf: int = VIDEO_CRF, progress: bool = True) -> Path:
    """Write ``scene`` to ``out_dir`` in the Neural3DV layout; returns the folder.

    Camera XX is ``scene.cameras[XX]``, so the written scene.json train/test ids equal the
    scene's indices. An existing ``out_dir`` is replaced only once the new one is complete.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: exists and is not a folder; choose another --out")
    n_cams, T = len(scene.cameras), scene.num_frames
    b = scene.bounds()
    if b is None:
        raise InputError(f"{scene.name}: scene bounds are unknown, so poses_bounds.npy cannot be written")
    names = [f"cam{i:02d}" for i in range(n_cams)]
    with atomic_dir(out_dir) as tmp:
        bar = tqdm(total=n_cams * T, desc=f"make-scene {scene.name}", unit="frame", disable=not progress)
        for i in range(n_cams):
            depths = []

            def frames(cam=i, depths=depths):
                for f in range(T):
                    rgb = scene.frame(f, cam)
                    if scene.has_depth:
                        depths.append(scene.depth(f, cam).astype(np.float32))
                    bar.update(1)
                    yield rgb

            write_video(tmp / f"{names[i]}.mp4", frames(), scene.fps, crf=crf)
            if scene.has_depth:
                with atomic_path(tmp / "depth" / f"{names[i]}.npz") as p:
                    np.savez_compressed(p, depth=np.stack(depths))
        bar.close()
        cams = [c.with_pose(c.c2w, names[i]) for i, c in enumerate(scene.cameras)]
        with atomic_path(tmp / "poses_bounds.npy") as p:
            np.save(p, cameras_to_llff(cams, np.array([b.near, b.far])))
        meta = {
            "format": "fixer4d-n3dv",
            "version": SCENE_JSON_VERSION,
            "name": scene.name,
            "fps": scene.fps,
            "num_frames": T,
            "width": scene.cameras[0].width,
            "height": scene.cameras[0].height,
            "pose_cameras": list(range(n_cams)),
            "train_ids": list(scene.train_ids),
            "test_ids": list(scene.test_ids),
            "near": b.near,
            "far": b.far,
            "bbox_min": np.asarray(b.bbox_min).tolist(),
            "bbox_max": np.asarray(b.bbox_max).tolist(),
        }
        if scene.has_depth:
            meta["depth"] = "depth"
        spec = getattr(scene, "spec", None)
        if spec is not None:
            meta["source"] = str(getattr(scene, "source", ""))
            meta["spec"] = spec
            meta["supersample"] = getattr(scene, "supersample", None)
        write_json(tmp / "scene.json", meta)
    return out_dir
