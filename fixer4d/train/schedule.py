"""Learning-rate schedules (pure functions of the step, so a resumed run gets the same rates)."""
from __future__ import annotations

import math


def exponential_lr(step: int, lr_init: float, lr_final: float, max_steps: int) -> float:
    """Log-linear interpolation from ``lr_init`` at step 0 to ``lr_final`` at ``max_steps``.

    The position schedule of 3DGS/STGS: the learning rate decays by a constant factor per step;
    steps beyond ``max_steps`` keep ``lr_final``. A zero rate at either end gives 0 throughout
    (a frozen parameter).
    """
    if lr_init <= 0.0 or lr_final <= 0.0:
        return 0.0
    if max_steps <= 0:
        return float(lr_final)
    s = min(max(step / float(max_steps), 0.0), 1.0)
    return float(math.exp((1.0 - s) * math.log(lr_init) + s * math.log(lr_final)))
