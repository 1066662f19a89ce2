"""The tiny pipeline configuration shared by the pipeline tests."""
from __future__ import annotations

# The smallest run that still exercises every stage: 40 stage-1 iterations, one restoration round
# of 20 iterations, 3-frame trajectories at one restored timestamp, clouds from every 2nd frame.
TINY = {
    "stage1.iterations": 40, "stage2.rounds": 1, "stage2.refresh_every": 20,
    "trajectories.frames": 3, "trajectories.time_stride": 4, "init_frame_stride": 2, "eval.stride": 2,
    "init.mvs.planes": 24, "eval.examples": 1,
}


def tiny_config(**overrides):
    from fixer4d.pipeline.config import resolve

    return resolve("tiny", overrides={**TINY, **overrides})
