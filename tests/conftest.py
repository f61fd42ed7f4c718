"""Shared test fixtures (keep small)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
if str(TESTS) not in sys.path:  # helpers such as hostile_assets.py import as top-level modules
    sys.path.insert(0, str(TESTS))


@pytest.fixture(scope="session")
def shared_assets() -> Path:
    """``../shared/assets`` next to the repository: public sample models, never copied in.

    Missing folder is a failure, not a skip: CI always provides it.
    """
    path = TESTS.parents[1] / "shared" / "assets"
    assert path.is_dir(), f"shared test assets missing: {path}"
    return path


@pytest.fixture(scope="module")
def gl_ctx():
    """A headless EGL context for one test module (made current again before release:
    CLI tests in the module create and release contexts of their own)."""
    from prtcore.runtime.glcontext import create_context, make_current

    ctx = create_context()
    yield ctx
    make_current(ctx)
    ctx.release()
