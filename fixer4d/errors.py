"""Errors that reach users. Every message names the offending file or value and the fix."""


class Fixer4DError(Exception):
    """Base class for every error fixer4d raises on purpose."""


class InputError(Fixer4DError, ValueError):
    """Bad user input: a missing/corrupt file, mismatched cameras, NaN values, an unknown layout."""


class NumericalError(Fixer4DError, FloatingPointError):
    """Non-finite values where finite ones are required (e.g. NaN Gaussian parameters)."""


class BackendUnavailable(Fixer4DError, RuntimeError):
    """An optional backend (gsplat, diffusers, MVSAnywhere, LPIPS weights) is not installed or lacks weights."""


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a scheduler's time limit), raised in the main thread like Ctrl-C's
    KeyboardInterrupt so that every ``finally`` and atomic write unwinds the same way
    (``fixer4d.signals``); a KeyboardInterrupt so that ``except Exception`` never swallows it."""
