"""JSON files a user wrote or a run saved, read with one error line naming the file and the fix."""
from __future__ import annotations

import json
from pathlib import Path

from fixer4d.errors import InputError


def read_json_object(path: Path, label: str, fix: str) -> dict:
    """A JSON file whose top level is an object; InputError naming ``label`` and ``fix`` when it
    is not valid JSON or not an object (the caller checks that the file exists)."""
    try:
        data = json.loads(Path(path).read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{label}: not valid JSON ({exc}); {fix}") from None
    if not isinstance(data, dict):
        raise InputError(f"{label}: the top level must be a JSON object; {fix}")
    return data
