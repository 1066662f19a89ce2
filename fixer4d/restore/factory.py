"""``build_restorer``: the restorer a ``RestoreConfig`` selects (above config.py and every
restorer module, so none of them imports another through it)."""
from __future__ import annotations

from pathlib import Path

from fixer4d.errors import BackendUnavailable, InputError
from fixer4d.restore.cogvideo import CogVideoV2VRestorer
from fixer4d.restore.config import WEIGHTS_FILE, RestoreConfig


def build_restorer(config: RestoreConfig, weights_dir: str | Path | None = None):
    """The restorer ``config`` selects, wrapped in the Real-ESRGAN prior when
    ``config.sr_prior.enabled`` (``restore.sr_prior.SRPriorRestorer``). ``weights_dir``: the
    learned restorer's folder (RUN/restorer).

    learned without weights raises InputError saying how to train them; cogvideo on a machine
    without diffusers, its local weights or CUDA raises BackendUnavailable naming what is missing.
    """
    restorer = _restorer_of_kind(config, weights_dir)
    if config.sr_prior.enabled:
        from fixer4d.restore.sr_prior import SRPriorRestorer

        return SRPriorRestorer(restorer, config.sr_prior)
    return restorer


def _restorer_of_kind(config: RestoreConfig, weights_dir: str | Path | None):
    if config.kind == "warp":
        from fixer4d.restore.reference_warp import ReferenceWarpRestorer

        return ReferenceWarpRestorer(config.warp)
    if config.kind == "cogvideo":
        restorer = CogVideoV2VRestorer(config.cogvideo)
        reason = restorer.unavailable_reason()
        if reason is not None:
            raise BackendUnavailable(reason + "; use --restorer learned or --restorer warp on this machine")
        return restorer
    from fixer4d.restore.learned import LearnedRestorer

    if weights_dir is None or not (Path(weights_dir) / WEIGHTS_FILE).is_file():
        where = "no weights folder was given" if weights_dir is None else f"{Path(weights_dir) / WEIGHTS_FILE} is missing"
        raise InputError(f"learned restorer: {where}. Train it for the scene first: `fixer4d run SCENE --out RUN "
                         "--restorer learned` trains it into RUN/restorer (or call "
                         "fixer4d.train.restorer_pairs.train_scene_restorer), or use --restorer warp")
    return LearnedRestorer.load(weights_dir, config)
