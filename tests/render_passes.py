"""``prtcore render`` of a bundle in its three passes (full, direct only, indirect only),
for the tests that check a kind of bundle renders and that the passes add up."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from prtcore.cli import main
from prtcore.io.imageio import read_image

PASSES = (("full", []), ("direct", ["--no-indirect"]), ("indirect", ["--indirect-only"]))


def render_passes(bundle: Path, light: Path, camera: dict, tmp: Path) -> dict[str, np.ndarray]:
    """pass name → the (H, W, 4) linear EXR ``prtcore render`` wrote (exit 0 asserted);
    ``camera`` is a camera file's contents (docs/lights.md)."""
    cam = tmp / "camera.json"
    cam.write_text(json.dumps(camera))
    images = {}
    for name, flags in PASSES:
        path = tmp / f"{name}.exr"
        assert main(["render", str(bundle), "--light", str(light), "--camera", str(cam),
                     "--out", str(path), *flags]) == 0
        images[name] = read_image(path)
    return images
