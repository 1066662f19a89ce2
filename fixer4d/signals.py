"""SIGTERM as an exception: a killed run unwinds like an interrupted one.

Without this, SIGTERM ends the process at once, and once pycolmap is imported (its glog
installs a failure-signal handler for SIGTERM on import) it also prints a C++ stack trace
that reads like a crash. ``install_sigterm`` (called by the CLI) makes SIGTERM raise
``fixer4d.errors.Terminated`` in the main thread; ``reassert_python_handlers`` puts Python's
handlers back after a native library replaced them.
"""
from __future__ import annotations

import signal
import threading

from fixer4d.errors import Terminated

# glog's InstallFailureSignalHandler takes these; only SIGTERM is a request to stop (the
# others are real faults, where a native stack trace is what a developer wants).
_STOP_SIGNALS = (signal.SIGTERM,)


def _raise_terminated(signum, frame) -> None:
    raise Terminated(f"signal {signal.Signals(signum).name}")


def install_sigterm() -> bool:
    """SIGTERM -> ``Terminated`` in the main thread; False (nothing done) in any other thread,
    where Python cannot set handlers."""
    if threading.current_thread() is not threading.main_thread():
        return False
    signal.signal(signal.SIGTERM, _raise_terminated)
    return True


def reassert_python_handlers() -> None:
    """Re-install Python's own handler for each stop signal (a native library may have replaced
    it at the C level while Python still reports its own); main thread only, else a no-op."""
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in _STOP_SIGNALS:
        handler = signal.getsignal(sig)
        if handler is not None:  # None: set outside Python, nothing of ours to restore
            signal.signal(sig, handler)


def interrupt_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or ``Terminated`` that ``exc`` wraps, if any. A signal handler that raises while
    a numba kernel runs (the kernel calls back into Python between its parallel chunks) surfaces
    as numba's ``SystemError("... returned a result with an exception set")`` with the
    interrupt as its context."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None
