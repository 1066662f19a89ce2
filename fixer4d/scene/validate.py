"""A fast pre-flight check of a scene's input files, run before any training starts.

A video can have a readable header (so the scene opens and reports its size and length) and
still fail to decode its frames; a Panoptic image can exist and be truncated. Training would
then stop minutes in, at the first frame it needs. ``validate_scene`` decodes the first and
last frame of the range for every camera now and raises one InputError naming the file and the
frame. Synthetic scenes are ray-cast, not read, and have nothing to check.
"""
from __future__ import annotations

from fixer4d.scene.base import MultiViewVideo


def validate_scene(scene: MultiViewVideo) -> None:
    """Decode frames 0 and num_frames - 1 of every camera (train and held-out) of ``scene``.

    Raises InputError from the scene's reader naming the file and the frame (e.g. "cam01.mp4:
    cannot decode frame 19 ..."). Costs two decodes per camera (a seek to the last frame
    decodes at most one group of pictures); the frames stay in the scene's frame cache.
    """
    from fixer4d.scene.synthetic import SyntheticScene

    if isinstance(scene, SyntheticScene):
        return
    last = scene.num_frames - 1
    for cam in range(len(scene.cameras)):
        for frame in dict.fromkeys((0, last)):
            scene.frame(frame, cam)
