"""The checks both hair readers make: file size against the limit before reading, and
arrays refused at their first non-finite (or out-of-range) element, naming file and field."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from prtcore.core.errors import AssetError, LimitExceeded
from prtcore.core.limits import IntakeLimits


def checked_size(path: str | Path, limits: IntakeLimits) -> tuple[str, int]:
    """(file name as a string, size in bytes); LimitExceeded beyond ``max_file_bytes``."""
    file = str(path)
    size = os.stat(file).st_size
    if size > limits.max_file_bytes:
        raise LimitExceeded(file, "", f"file is {size} bytes",
                            limit=f"max_file_bytes={limits.max_file_bytes}")
    return file, size


def refuse_bad(file: str, field: str, values: np.ndarray, *, positive: bool = False,
               nonnegative: bool = False) -> None:
    """AssetError naming ``field[i]``, the first row of ``values`` (n, …) that is not
    finite, or (when asked) not positive / negative."""
    flat = values.reshape(len(values), -1)
    bad = ~np.isfinite(flat).all(axis=1)
    what = "is not finite (NaN or infinite)"
    if not bad.any() and positive:
        bad, what = (flat <= 0).any(axis=1), "is not positive"
    if not bad.any() and nonnegative:
        bad, what = (flat < 0).any(axis=1), "is negative"
    if bad.any():
        i = int(np.argmax(bad))
        raise AssetError(file, f"{field}[{i}]", f"{what} ({', '.join(map(str, flat[i]))}); "
                         f"{int(bad.sum())} such entries")
