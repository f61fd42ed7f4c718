"""An exterior scene built by the project (issue 13): a small house on a ground plane,
lit from around.

What the closed rooms are not: almost all light leaves the scene, the indirect light is
the bounce between the ground and the house's walls and the shadowed side of the roof,
and the lights come from every azimuth.

Layout (metres, y up, the house centred on the origin): a ground quad 8 m × 8 m at y = 0
facing up; the house body 3 m (x) × 2 m (y) × 2.4 m (z); a gable roof, a closed
triangular prism sitting on the body with its ridge along x at y = 3.1 (no overhang, so
no thin two-sided sheet); a chimney block through the roof's south slope; and a low
garden wall (0.6 m high, turned 30°) south-east of the house that shadows the ground and
faces the house's wall. Every part is a closed solid with flat faces, except the ground,
which is single-sided facing up.

Materials: factor-only Lambertian (``metallicFactor`` 0, ``roughnessFactor`` 1, no
TEXCOORD_0) with varied albedos. Written through trimesh's exporter with normals.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from prtcore.scenes.parts import block, material_scene, quad, write_glb

#: albedo per part (linear RGB)
ALBEDO = {
    "ground": (0.30, 0.42, 0.18),      # grass
    "body": (0.80, 0.76, 0.66),        # plaster
    "roof": (0.45, 0.12, 0.08),        # tiles
    "chimney": (0.55, 0.30, 0.25),     # brick
    "garden_wall": (0.60, 0.60, 0.62),  # stone
}

BODY = (3.0, 2.0, 2.4)      # x, y, z extents
RIDGE_HEIGHT = 1.1          # roof height above the body
GROUND_HALF = 4.0

#: Light families around the house, half and half: a sun (directional) from any azimuth,
#: from grazing (≈ 2°) to nearly overhead, aimed at the house's middle, and point lights
#: (lamps) in a slab above the ridge and the chimney, reaching past the house on every
#: side (a box cannot wrap around the house at wall height without entering it).
LIGHT_FAMILIES = [
    {"type": "directional", "weight": 1.0,
     "position": {"box": [[-8.0, 1.5, -8.0], [8.0, 8.0, 8.0]]},
     "aim": {"target": [0.0, 1.0, 0.0], "jitter": 0.1},
     "intensity": {"uniform": [1.0, 5.0]}, "color": "white"},
    {"type": "point", "weight": 1.0,
     "position": {"box": [[-4.0, 3.6, -4.0], [4.0, 5.0, 4.0]]},
     "intensity": {"uniform": [5.0, 30.0]}, "color": "white"},
]

#: A bake spec naming the exterior's light families (sizes small enough for tests to
#: override).
SPEC = {
    "atlas": {"resolution": 128, "padding": 2},
    "measurement_points": {"count": 256, "supersample": 4, "seed": 1},
    "lights": {"count": 128, "holdout": 16, "seed": 2, "families": LIGHT_FAMILIES},
    "transport": {"gather_rays": 64, "max_bounces": 16, "tolerance": 0.001},
    "fit": {"basis": 16, "ridge": "auto", "channels": "mono"},
}


def _prism_roof() -> trimesh.Trimesh:
    """A closed triangular prism on top of the body, ridge along x, flat faces."""
    hx, hz = BODY[0] / 2, BODY[2] / 2
    y0, y1 = BODY[1], BODY[1] + RIDGE_HEIGHT
    v = np.array([[-hx, y0, -hz], [-hx, y0, hz], [-hx, y1, 0.0],
                  [hx, y0, -hz], [hx, y0, hz], [hx, y1, 0.0]], float)
    f = np.array([[0, 1, 2], [3, 5, 4],              # gables (−x, +x)
                  [1, 4, 5], [1, 5, 2],              # south slope (+z)
                  [0, 2, 5], [0, 5, 3],              # north slope (−z)
                  [0, 3, 4], [0, 4, 1]])             # bottom (−y)
    m = trimesh.Trimesh(v, f, process=False)
    m.fix_normals()  # outward winding
    m.unmerge_vertices()
    return m


def house(subdiv: int = 4) -> trimesh.Scene:
    """The house, the garden wall and the ground as a trimesh scene."""
    g = GROUND_HALF
    ground = quad(np.array([[-g, 0, g], [g, 0, g], [g, 0, -g], [-g, 0, -g]], float), subdiv)
    # chimney on the south slope, its foot buried in the roof
    slope_y = BODY[1] + RIDGE_HEIGHT * (1 - 0.6 / (BODY[2] / 2))
    parts = {
        "ground": ground,
        "body": block([0.0, BODY[1] / 2, 0.0], list(BODY), 0.0),
        "roof": _prism_roof(),
        "chimney": block([0.8, slope_y + 0.25, 0.6], [0.35, 1.0, 0.35], 0.0),
        "garden_wall": block([2.6, 0.3, 2.4], [2.0, 0.6, 0.25], -30.0),
    }
    return material_scene(parts, ALBEDO)


def write_exterior(path: str | Path, subdiv: int = 4) -> Path:
    """Write the house scene as a .glb; returns the path."""
    return write_glb(house(subdiv), path)
