"""Reading the project's JSON input files (spec, light and camera files): one rule for
the two ways it fails, each reported by the caller's own error type."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any


def read_json(path: str | Path, fail: Callable[[str], Exception]) -> Any:
    """The decoded JSON of ``path``. An unreadable file or invalid JSON raises
    ``fail(what)`` — "cannot read: <reason>" or "not valid JSON at line L column C: <msg>"."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as e:
        raise fail(f"cannot read: {e.strerror}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise fail(f"not valid JSON at line {e.lineno} column {e.colno}: {e.msg}") from None
