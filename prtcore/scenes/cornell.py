"""The Cornell box built by the project: the bundled example and the analytic-ish test scene.

A 2 m room (x, z ∈ [−1, 1], y ∈ [0, 2]) open toward +z, walls single-sided facing inward,
with the classic red (left, −x) and green (right, +x) walls and two white blocks. Written
as a plain glTF binary through trimesh's exporter (factor-only materials, no TEXCOORD_1:
the bake generates lightmap UVs).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from prtcore.scenes.parts import block, material_scene, quad, write_glb

WHITE = (0.73, 0.73, 0.73)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.09)

#: The example bake spec shipped with the box: lights inside the room.
EXAMPLE_SPEC = {
    # Point lights anywhere in the upper half of the room, clear of the walls, ceiling and
    # the tall block (top at y = 1.2): a light 10 cm from a wall makes a hot spot whose
    # bounce is not low-rank, and the spec of a bake should draw lights the engine will
    # actually use. Lights of other families are checked with `prtcore report --light`.
    "atlas": {"resolution": 256, "padding": 4},
    "measurement_points": {"count": 256, "supersample": 8, "seed": 1},
    "lights": {
        "count": 128, "holdout": 16, "seed": 2,
        "families": [
            {"type": "point", "weight": 1.0,
             "position": {"box": [[-0.6, 1.3, -0.6], [0.6, 1.7, 0.6]]},
             "intensity": {"uniform": [0.5, 3.0]},
             "color": "white"},
        ],
    },
    "transport": {"gather_rays": 128, "max_bounces": 16, "tolerance": 0.001},
    "fit": {"basis": 16, "ridge": "auto", "channels": "mono"},
}


def cornell_box(subdiv: int = 1) -> trimesh.Scene:
    """The room and blocks as a trimesh scene with one PBR material per part."""
    P = np.array
    parts = {
        # floor (y=0) facing +y
        "floor": (quad(P([[-1, 0, 1], [1, 0, 1], [1, 0, -1], [-1, 0, -1]], float), subdiv),
                  WHITE),
        # ceiling (y=2) facing −y
        "ceiling": (quad(P([[-1, 2, -1], [1, 2, -1], [1, 2, 1], [-1, 2, 1]], float), subdiv),
                    WHITE),
        # back wall (z=−1) facing +z
        "back": (quad(P([[-1, 0, -1], [1, 0, -1], [1, 2, -1], [-1, 2, -1]], float), subdiv),
                 WHITE),
        # left wall (x=−1) facing +x, red
        "left": (quad(P([[-1, 0, 1], [-1, 0, -1], [-1, 2, -1], [-1, 2, 1]], float), subdiv),
                 RED),
        # right wall (x=+1) facing −x, green
        "right": (quad(P([[1, 0, -1], [1, 0, 1], [1, 2, 1], [1, 2, -1]], float), subdiv),
                  GREEN),
        "tall_block": (block([-0.33, 0.6, -0.3], [0.6, 1.2, 0.6], 18.0), WHITE),
        "short_block": (block([0.35, 0.3, 0.35], [0.6, 0.6, 0.6], -17.0), WHITE),
    }
    return material_scene({k: m for k, (m, _) in parts.items()},
                          {k: c for k, (_, c) in parts.items()})


def write_cornell_box(path: str | Path, subdiv: int = 1) -> Path:
    """Write the Cornell box as a .glb; returns the path."""
    return write_glb(cornell_box(subdiv), path)
