"""Headless Chromium for the viewer tests (tests/test_viewer.py,
tests/service/test_service_viewer.py): Debian's Chromium (scripts/browser.sh installs it)
driven by the pinned Playwright; WebGL2 through SwiftShader, asked for explicitly. A missing
browser is a failure naming the install command, never a skip."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from scenes import tiny_spec

from prtcore import pipeline
from prtcore.core.spec import parse_spec

CORNELL = Path(__file__).resolve().parents[1] / "examples" / "cornell_box.glb"

#: WebGL2 without a GPU: SwiftShader.
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
#: How long a page may take to load a bundle (SwiftShader on 2 busy cores).
LOAD_TIMEOUT_MS = 60_000


def chromium() -> str:
    """The Chromium binary: PRT_CHROMIUM, else `chromium` on PATH."""
    path = os.environ.get("PRT_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
    assert os.access(path, os.X_OK), (
        f"Chromium not found at {path}: install it with `bash scripts/browser.sh` (the README's "
        "test command does)")
    return path


def launch(playwright):
    """A headless Chromium of `playwright` (sync API) with WebGL2."""
    return playwright.chromium.launch(executable_path=chromium(), args=CHROMIUM_ARGS)


def wait_ready(page) -> None:
    """Wait until the viewer page is ready or has said why not; fail on the latter."""
    page.wait_for_function("window.prt && (window.prt.ready || window.prt.error)",
                           timeout=LOAD_TIMEOUT_MS)
    assert page.evaluate("prt.error") is None, page.evaluate("prt.error")


def viewer_bundle(out: Path) -> Path:
    """The bundle the viewer tests load: the Cornell box, small (32×32 atlas, 32 points, 8
    basis elements), with a half-float basis (the browser's texture format)."""
    return pipeline.bake(CORNELL, parse_spec(tiny_spec(output={"dtype": "half"})), out,
                         quiet=True)
