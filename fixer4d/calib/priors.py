"""Focal priors of a self-calibration: what the user knows about each lens, with its uncertainty.

``--focal 466`` is a prior for every camera, ``--focal cam18=515`` for one (it wins over the one
for all), ``--focal 466:2%`` or ``--focal cam18=515:5`` give the standard deviation (percent or
pixels). A prior is one more residual of the bundle adjustment, weighed against the frames
(``fixer4d.calib.adjust``); the frames overrule a prior they contradict (``sfm``).
"""
from __future__ import annotations

from dataclasses import dataclass

from fixer4d.errors import InputError

# A focal given as a number without its uncertainty is taken as known to 1 %: a lens's focal
# from an earlier calibration or a data sheet at a fixed zoom (a board fit gets 0.1-0.2 %).
DEFAULT_PRIOR_SD_REL = 0.01
SYNTAX = "[CAM=]PX[:SD] (SD in pixels, or percent with %), e.g. --focal 466, --focal cam18=515:1%"


@dataclass(frozen=True)
class FocalPrior:
    """A focal length in pixels (at the videos' size) and its standard deviation in pixels."""

    focal_px: float
    sd_px: float

    def describe(self) -> str:
        return f"{self.focal_px:.1f} +- {self.sd_px:.1f} px"


def _prior(text: str, value: str, sd: str | None) -> FocalPrior:
    try:
        f = float(value)
        s = f * DEFAULT_PRIOR_SD_REL if sd is None else (
            f * float(sd[:-1]) / 100 if sd.endswith("%") else float(sd))
    except ValueError:
        raise InputError(f"--focal {text!r}: expected {SYNTAX}") from None
    if not (f > 0 and s > 0) or f == float("inf") or s == float("inf"):
        raise InputError(f"--focal {text!r}: the focal and its uncertainty must be positive pixels; {SYNTAX}")
    return FocalPrior(f, s)


def parse_focal_priors(items: list[str], names: list[str]) -> dict[str, FocalPrior]:
    """``--focal`` arguments -> {camera name: prior} for the cameras ``names`` that have one;
    InputError for a malformed item or a camera the capture lacks."""
    everyone: FocalPrior | None = None
    each: dict[str, FocalPrior] = {}
    for text in items:
        name, sep, rest = str(text).rpartition("=")
        value, _, sd = rest.partition(":")
        prior = _prior(text, value.strip(), sd.strip() or None)
        if not sep:
            everyone = prior
        elif name.strip() not in names:
            raise InputError(f"--focal {text}: no camera {name.strip()!r}; this capture's cameras: {names}")
        else:
            each[name.strip()] = prior
    return {n: each.get(n, everyone) for n in names if each.get(n, everyone) is not None}


# A prior differs from the frames' own estimate by more than this many standard deviations of
# the difference: they contradict each other (a correct prior does so once in ~370 cameras).
CONFLICT_SIGMAS = 3.0


def weigh_priors(obs, cams, names: list[str], priors: dict[str, FocalPrior], determined_rel: float):
    """Bundle adjustment of ``cams`` (``adjust.CameraState``) on ``obs`` with the priors the frames allow.

    The frames alone are fitted first. A prior that contradicts their estimate (beyond
    ``CONFLICT_SIGMAS``) is dropped when the frames determine that camera's focal (standard error
    at most ``determined_rel`` of it: the frames correct the prior) and kept otherwise (the gate
    then refuses the camera, naming both figures). Returns (the final ``adjust.Adjusted``, the
    frames-only one, {camera name: "none" | "agrees" | "overruled by the frames" | "contradicts the frames"}).
    """
    import numpy as np

    from fixer4d.calib.adjust import adjust

    free = adjust(obs, cams)
    verdicts = {}
    value = np.full(len(names), np.nan)
    sd = np.ones(len(names))
    for i, n in enumerate(names):
        p = priors.get(n)
        if p is None:
            verdicts[n] = "none"
            continue
        gap = abs(free.cameras.f[i] - p.focal_px) / np.hypot(free.focal_sd_px[i], p.sd_px)
        if gap <= CONFLICT_SIGMAS:
            verdicts[n] = "agrees"
        elif free.focal_sd_px[i] <= determined_rel * free.cameras.f[i]:
            verdicts[n] = "overruled by the frames"
            continue
        else:
            verdicts[n] = "contradicts the frames"
        value[i], sd[i] = p.focal_px, p.sd_px
    if not np.isfinite(value).any():
        return free, free, verdicts
    return adjust(obs, cams, value, sd, sigma_px=free.sigma_px), free, verdicts
