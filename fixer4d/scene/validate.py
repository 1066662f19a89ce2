"""A fast pre-flight check of a scene's input files, run before any training starts.

A video can have a readable header (so the scene opens and reports its size and length) and
still fail to decode its frames; a Panoptic image can exist and be truncated. Training would
then stop minutes in, at the first frame it needs. ``validate_scene`` decodes the first and
last frame of the range for every camera now and raises one InputError naming the file and the
frame. Synthetic scenes are ray-cast, not read, and have nothing to decode. ``check_split``
(every scene; its id part, ``check_ids``, already when a scene opens) catches what would otherwise fail late or mislead: a camera listed twice or as
both train and held-out, cameras of different sizes, images too small to evaluate.
"""
from __future__ import annotations

from fixer4d.errors import InputError
from fixer4d.scene.base import MultiViewVideo

# The evaluation's SSIM window (fixer4d.eval.metrics.SSIM_WIN_SIZE): smaller images cannot be
# scored, which a run would find only after training.
MIN_IMAGE_SIDE = 7


def check_ids(scene: MultiViewVideo) -> None:
    """Every camera in the split once, none both train and held-out (``load_scene`` runs it on
    every scene it opens: an overlap would score a trained camera as held-out)."""
    names = [c.name for c in scene.cameras]
    for what, ids in (("train", scene.train_ids), ("held-out", scene.test_ids)):
        twice = sorted({names[i] for i in ids if list(ids).count(i) > 1})
        if twice:
            raise InputError(f"{scene.name}: {what} camera(s) {twice} listed twice; list each camera once")
    both = sorted(names[i] for i in set(scene.train_ids) & set(scene.test_ids))
    if both:
        raise InputError(f"{scene.name}: camera(s) {both} are both train and held-out; a held-out camera must not be "
                         "trained on")


def check_split(scene: MultiViewVideo) -> None:
    """The camera split and sizes a run can use (``check_ids``, one size, at least the SSIM window);
    InputError naming the cameras otherwise."""
    check_ids(scene)
    used = [scene.cameras[i] for i in list(scene.train_ids) + list(scene.test_ids)]
    sizes = {(c.width, c.height) for c in used}
    if len(sizes) > 1:
        ref = used[0]
        odd = sorted(f"{c.name} ({c.width}x{c.height})" for c in used if (c.width, c.height) != (ref.width, ref.height))
        raise InputError(f"{scene.name}: cameras of different sizes: {odd} against {ref.name} ({ref.width}x{ref.height}); "
                         "resize the videos to one size first")
    small = [c for c in used if min(c.width, c.height) < MIN_IMAGE_SIDE]
    if small:
        c = small[0]
        raise InputError(f"{scene.name}: images of {c.name} are {c.width}x{c.height} at this scale; the evaluation needs "
                         f"at least {MIN_IMAGE_SIDE}x{MIN_IMAGE_SIDE} pixels: use a larger --scale")


def validate_scene(scene: MultiViewVideo) -> None:
    """``check_split``, then decode frames 0 and num_frames - 1 of every camera (train and held-out).

    Raises InputError from the scene's reader naming the file and the frame (e.g. "cam01.mp4:
    cannot decode frame 19 ..."). Costs two decodes per camera (a seek to the last frame
    decodes at most one group of pictures); the frames stay in the scene's frame cache.
    """
    from fixer4d.scene.synthetic import SyntheticScene

    check_split(scene)
    if isinstance(scene, SyntheticScene):
        return
    last = scene.num_frames - 1
    for cam in range(len(scene.cameras)):
        for frame in dict.fromkeys((0, last)):
            scene.frame(frame, cam)
