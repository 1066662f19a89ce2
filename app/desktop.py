"""Opening a file or folder with the desktop's default application, and what to say when the
machine has none (a server, a container, Xvfb): where the file is, with its path copied."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Callable


def desktop_opener() -> str | None:
    """The command that opens a file with its default application here ("xdg-open", "open"),
    or None when it is not installed (Windows: os.startfile, named "startfile")."""
    if sys.platform.startswith("win"):
        return "startfile"
    exe = "open" if sys.platform == "darwin" else "xdg-open"
    return exe if shutil.which(exe) else None


def open_with_desktop(path: str | Path, copy: Callable[[str], None], what: str = "file") -> str:
    """Open ``path`` with the desktop's default application. Without an opener (or when it
    fails to start) the path goes to the clipboard through ``copy(text)`` and the returned line
    says where the ``what`` is; else it says which program was asked. Never raises OSError."""
    opener = desktop_opener()
    try:
        if opener == "startfile":
            os.startfile(str(path))  # noqa: S606 (a local file the viewer wrote)
            return f"opened {path}"
        if opener is not None:
            subprocess.Popen([opener, str(path)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            return f"asked {opener} to open {path}"
        why = "no desktop opener (xdg-open) on this machine"
    except OSError as exc:
        why = f"{opener} could not start ({exc.strerror or exc})"
    copy(str(path))
    return f"{why}: the {what} is {path} (path copied to the clipboard)"
