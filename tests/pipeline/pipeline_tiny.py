"""The tiny pipeline configuration shared by the pipeline tests."""
from __future__ import annotations

# The smallest run that still exercises every stage: 40 stage-1 iterations, one restoration round
# of 20 iterations, 3-frame trajectories at one restored timestamp, clouds from every 2nd frame.
TINY = {
    "training.iterations": 40, "stage2.rounds": 1, "stage2.refresh_every": 20,
    "trajectories.frames": 3, "trajectories.time_stride": 4, "init_frame_stride": 2, "eval.stride": 2,
    "init.mvs.planes": 24, "eval.examples": 1,
    # a tiny field trains in less time than a worker process takes to start (train.field_workers;
    # tests/train/test_field_workers.py runs them)
    "training.field_workers": 1,
}


def tiny_config(**overrides):
    from fixer4d.pipeline.config import resolve

    return resolve("tiny", overrides={**TINY, **overrides})


class HeldOutSpy:
    """A scene that records every read of a held-out camera's frame, mask or depth made outside
    the evaluation (``fixer4d/eval/evaluate.py`` on the call stack): held-out cameras are for
    evaluation only. ``violations`` lists (what, camera, the innermost fixer4d function)."""

    EVALUATION = ("fixer4d/eval/evaluate.py",)

    def __init__(self, scene) -> None:
        self._scene = scene
        self.violations: list[tuple[str, int, str]] = []
        self.evaluation_reads = 0

    def __getattr__(self, name):
        return getattr(self._scene, name)

    def _check(self, what: str, cam: int) -> None:
        import inspect

        if cam not in self._scene.test_ids:
            return
        stack = inspect.stack(context=0)
        if any(f.filename.replace("\\", "/").endswith(self.EVALUATION) for f in stack):
            self.evaluation_reads += 1
            return
        inner = next((f"{f.filename.split('fixer4d/')[-1]}:{f.function}" for f in stack[2:] if "/fixer4d/" in f.filename),
                     "?")
        self.violations.append((what, cam, inner))

    def frame(self, frame: int, cam: int):
        self._check("frame", cam)
        return self._scene.frame(frame, cam)

    def mask(self, frame: int, cam: int):
        self._check("mask", cam)
        return self._scene.mask(frame, cam)

    def depth(self, frame: int, cam: int):
        self._check("depth", cam)
        return self._scene.depth(frame, cam)


def run_spied(config, run_dir, stage_cache=None):
    """The whole pipeline of ``config`` into ``run_dir`` on a HeldOutSpy of its scene: (report, spy)."""
    from fixer4d.pipeline.run import open_context, run_stages

    ctx = open_context(config, run_dir, progress=False, stage_cache=stage_cache)
    spy = HeldOutSpy(ctx.scene)
    ctx.scene = spy
    ctx.scene_from_config = False  # a worker process would load the scene, not the spy
    return run_stages(ctx), spy
