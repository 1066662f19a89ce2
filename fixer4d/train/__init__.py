"""Floor 3: training. Stage 1 (STGS on the observed views) and stage 2 (restoration-guided
refinement) in ``trainer.py``, their configs in ``config.py``, losses in ``losses.py``."""
