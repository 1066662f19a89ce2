"""The viewer's notifications area: errors and messages from panels, menus and background work.

Every message also goes to the ``fixer4d.view`` logger, so a viewer started without a terminal
still leaves a trace in its log file (``app.main`` configures one next to the session). No GL
and no imgui here: the panels' guard (``app.panels._layout.panel``) and the workers call
``Notifications.error`` / ``info``; the viewer draws the list.
"""
from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass

LOG = logging.getLogger("fixer4d.view")
# Messages kept for the notifications window (older ones are still in the log).
MAX_MESSAGES = 200


@dataclass(frozen=True)
class Message:
    """One notification: ``level`` "error" | "info", ``source`` the panel or job that said it,
    ``when`` seconds since the epoch."""

    level: str
    source: str
    text: str
    when: float


class Notifications:
    """A bounded, thread-safe list of messages, newest last; ``serial`` counts every message ever
    added (the UI opens the window when an error arrives)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: deque[Message] = deque(maxlen=MAX_MESSAGES)
        self.serial = 0
        self.errors = 0

    def add(self, level: str, source: str, text: str) -> Message:
        msg = Message(level, source, str(text), time.time())
        with self._lock:
            self._items.append(msg)
            self.serial += 1
            self.errors += level == "error"
        (LOG.error if level == "error" else LOG.info)("%s: %s", source, text)
        return msg

    def error(self, source: str, exc: BaseException | str) -> Message:
        """Record an exception (``Type: message``) or an error text from ``source``."""
        text = exc if isinstance(exc, str) else f"{type(exc).__name__}: {exc}"
        if not isinstance(exc, str):
            LOG.debug("%s: traceback", source, exc_info=exc)
        return self.add("error", source, text)

    def info(self, source: str, text: str) -> Message:
        return self.add("info", source, text)

    def items(self) -> list[Message]:
        with self._lock:
            return list(self._items)

    def last_error(self) -> Message | None:
        with self._lock:
            return next((m for m in reversed(self._items) if m.level == "error"), None)

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
