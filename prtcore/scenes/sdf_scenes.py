"""The SDF test scenes the project builds (issue 18, thesis ch. 4: its SDF scenes include
a bunny and an old car): analytic primitives joined by a smooth union, written as
``*.sdf.json`` files (:mod:`prtcore.io.sdf`).

* :data:`BUNNY` — a bunny-like blob: an ellipsoid body, a round head, two capsule ears
  (deep concave creases where they meet the head) and a tail; 1.6 m tall.
* :data:`OLD_CAR` — an old-car-like shape: a long rounded body, a cabin on top, four
  tori as wheels under the body (self-shadowed wheel wells) and round headlights.
"""

from __future__ import annotations

import json
from pathlib import Path

#: Bake specs for the scenes: their marching-cubes meshes have many small UV charts
#: (docs/learnt_sh.md "SDF scenes"); the bunny's fit a 256² atlas at padding 2, the old
#: car's 1762 do not (384² do)
BUNNY_SPEC = {"atlas": {"resolution": 256, "padding": 2}}
OLD_CAR_SPEC = {"atlas": {"resolution": 384, "padding": 2}}

BUNNY = {
    "primitives": [
        {"type": "ellipsoid", "centre": [0.0, 0.45, 0.0], "radii": [0.55, 0.45, 0.4]},
        {"type": "sphere", "centre": [0.5, 0.85, 0.0], "radius": 0.28},
        {"type": "capsule", "a": [0.5, 1.05, 0.1], "b": [0.42, 1.55, 0.2], "radius": 0.07},
        {"type": "capsule", "a": [0.5, 1.05, -0.1], "b": [0.42, 1.55, -0.2], "radius": 0.07},
        {"type": "sphere", "centre": [-0.56, 0.5, 0.0], "radius": 0.12},
        {"type": "ellipsoid", "centre": [0.3, 0.08, 0.2], "radii": [0.25, 0.08, 0.1]},
        {"type": "ellipsoid", "centre": [0.3, 0.08, -0.2], "radii": [0.25, 0.08, 0.1]},
    ],
    "smooth": 0.1,
    "albedo": [0.75, 0.7, 0.62],
    "resolution": 96,
}

OLD_CAR = {
    "primitives": [
        {"type": "box", "centre": [0.0, 0.55, 0.0], "half_size": [1.2, 0.22, 0.5],
         "rounding": 0.12},
        {"type": "box", "centre": [-0.15, 0.95, 0.0], "half_size": [0.55, 0.25, 0.45],
         "rounding": 0.1},
        {"type": "torus", "centre": [0.8, 0.3, 0.52], "major": 0.18, "minor": 0.1,
         "axis": "z"},
        {"type": "torus", "centre": [0.8, 0.3, -0.52], "major": 0.18, "minor": 0.1,
         "axis": "z"},
        {"type": "torus", "centre": [-0.8, 0.3, 0.52], "major": 0.18, "minor": 0.1,
         "axis": "z"},
        {"type": "torus", "centre": [-0.8, 0.3, -0.52], "major": 0.18, "minor": 0.1,
         "axis": "z"},
        {"type": "sphere", "centre": [1.2, 0.62, 0.32], "radius": 0.09},
        {"type": "sphere", "centre": [1.2, 0.62, -0.32], "radius": 0.09},
    ],
    "smooth": 0.05,
    "albedo": [0.55, 0.12, 0.1],
    "resolution": 128,
}


def write_sdf(path: Path, data: dict) -> Path:
    """Write an SDF scene file (``*.sdf.json``; :func:`prtcore.io.sdf.load_sdf` reads
    and checks it)."""
    Path(path).write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    return Path(path)


def write_bunny(path: Path) -> Path:
    """The bunny-like blob as an SDF scene file."""
    return write_sdf(path, BUNNY)


def write_old_car(path: Path) -> Path:
    """The old-car-like shape as an SDF scene file."""
    return write_sdf(path, OLD_CAR)
