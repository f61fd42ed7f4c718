"""Golden-image comparison shared by the GL runtime's and the viewer's tests
(tests/test_render.py, tests/test_viewer.py) and scripts/regen_goldens.py.

A golden test passes when at most GOLDEN_OUTLIERS of the pixels differ from
``tests/goldens/<name>.png`` by more than GOLDEN_TOLERANCE (8-bit levels, any channel).
A failure writes ``tests/_failures/<name>_{output,golden,diff}.png``. The check always
compares; ``PRT_GOLDEN_RENDERS=DIR`` (scripts/regen_goldens.py) only adds a copy of each
output there.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from prtcore.io.imageio import read_image, write_png

GOLDENS = Path(__file__).resolve().parent / "goldens"
FAILURES = Path(__file__).resolve().parent / "_failures"

#: Per-pixel tolerance of a golden comparison, in 8-bit levels (any channel).
GOLDEN_TOLERANCE = 8
#: Fraction of pixels allowed beyond the tolerance.
GOLDEN_OUTLIERS = 0.01


def compare_to_golden(out: np.ndarray, golden: np.ndarray, tolerance: int = GOLDEN_TOLERANCE,
                      outliers: float = GOLDEN_OUTLIERS
                      ) -> tuple[bool, str, np.ndarray | None]:
    """(passed, message, amplified difference image or None)."""
    if out.shape != golden.shape:
        return False, f"shape {out.shape} ≠ golden {golden.shape}", None
    d = np.abs(out.astype(np.int16) - golden.astype(np.int16)).max(axis=2)
    frac = float((d > tolerance).mean())
    diff = np.clip(d * 8, 0, 255).astype(np.uint8)[:, :, None].repeat(3, axis=2)
    return frac <= outliers, (f"{frac:.2%} of pixels differ by more than "
                              f"{tolerance}/255 (allowed {outliers:.0%}); "
                              f"max {int(d.max())}"), diff


def check_golden(name: str, rgb8: np.ndarray, goldens: Path = GOLDENS,
                 tolerance: int = GOLDEN_TOLERANCE, outliers: float = GOLDEN_OUTLIERS) -> None:
    """Compare (h, w, 3) uint8 with tests/goldens/<name>.png (see the module docstring)."""
    assert rgb8.dtype == np.uint8 and max(rgb8.shape[:2]) <= 256
    if renders := os.environ.get("PRT_GOLDEN_RENDERS"):
        Path(renders).mkdir(parents=True, exist_ok=True)
        write_png(Path(renders) / f"{name}.png", rgb8)
    path = goldens / f"{name}.png"
    assert path.is_file(), f"{path} missing: create it with scripts/regen_goldens.py"
    golden = np.round(read_image(path)[:, :, :3] * 255).astype(np.uint8)
    ok, message, diff = compare_to_golden(rgb8, golden, tolerance, outliers)
    if not ok:
        FAILURES.mkdir(exist_ok=True)
        write_png(FAILURES / f"{name}_output.png", rgb8)
        write_png(FAILURES / f"{name}_golden.png", golden)
        if diff is not None:
            write_png(FAILURES / f"{name}_diff.png", diff)
        pytest.fail(f"{name}: {message} (images in {FAILURES})")
