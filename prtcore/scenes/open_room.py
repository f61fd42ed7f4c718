"""An open L-shaped room with a pillar and a low wall, built by the project (issue 13).

The scene the Cornell box is not: light leaves it (no ceiling, the end of one leg open),
an L corner hides one leg from the other, and two occluders cast shadows that the
measurement points must see to predict the bounce.

Plan (metres, y up): the floor is an L made of leg A, x ∈ [0, 4], z ∈ [0, 2], and leg B,
x ∈ [0, 2], z ∈ [2, 4]. Walls 2.5 m high run along the L's outline, single-sided facing
inward, except at z = 4 (the end of leg B is open); there is no ceiling. A square pillar
(0.3 m, full height) stands in leg A near the corner; a low wall (0.8 m high, 0.15 m thick)
crosses most of leg A at x = 3. Pillar and low wall are closed boxes with flat faces.

Materials: factor-only Lambertian (``metallicFactor`` 0, ``roughnessFactor`` 1, no
TEXCOORD_0), albedos from dark to bright and coloured, so each channel has its own bounce.
The glb is written through trimesh's exporter with normals, like
:mod:`prtcore.scenes.cornell`; the bake generates lightmap UVs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from prtcore.scenes.parts import block, material_scene, quad, write_glb

HEIGHT = 2.5

#: albedo per part (linear RGB)
ALBEDO = {
    "floor": (0.55, 0.45, 0.35),       # warm wood
    "wall_south": (0.75, 0.75, 0.72),  # z = 0, off-white
    "wall_east": (0.70, 0.25, 0.20),   # x = 4, brick red
    "wall_north_a": (0.20, 0.45, 0.65),  # z = 2 for x ∈ [2, 4], blue
    "wall_inner_b": (0.80, 0.72, 0.30),  # x = 2 for z ∈ [2, 4], ochre
    "wall_west": (0.35, 0.60, 0.30),   # x = 0, green
    "pillar": (0.85, 0.85, 0.85),
    "low_wall": (0.12, 0.12, 0.14),    # nearly black: a dark occluder
}

#: The pillar's footprint: (x, z) of two opposite corners.
PILLAR = ((0.85, 0.85), (1.15, 1.15))


def light_families(pillar_clearance: float = 0.05) -> list[dict]:
    """Point lights filling the room's air: 0.3 m clear of the walls, from just above the
    low wall to 0.3 m below the walls' top, and ``pillar_clearance`` metres clear of the
    pillar (leg A as four boxes around the pillar's column, plus leg B; each weighted by
    its floor area). Lights a few centimetres from the pillar are the hard case: a hot
    spot on a small occluder that few blue-noise points see. Lights inside the pillar are
    left out: they light only the floor buried under it, where measurement points can
    sit (points are placed on buried surfaces too)."""
    y0, y1 = 0.9, 2.2
    (px0, pz0), (px1, pz1) = PILLAR
    c = pillar_clearance
    px0, pz0, px1, pz1 = px0 - c, pz0 - c, px1 + c, pz1 + c

    def box(x0, z0, x1, z1) -> dict:
        return {"type": "point", "weight": (x1 - x0) * (z1 - z0),
                "position": {"box": [[x0, y0, z0], [x1, y1, z1]]},
                "intensity": {"uniform": [0.5, 3.0]}, "color": "white"}

    return [
        box(0.3, 0.3, 3.7, pz0),    # leg A, south of the pillar
        box(0.3, pz1, 3.7, 1.7),    # leg A, north of the pillar
        box(0.3, pz0, px0, pz1),    # leg A, west of the pillar
        box(px1, pz0, 3.7, pz1),    # leg A, east of the pillar
        box(0.3, 2.0, 1.7, 3.7),    # leg B
    ]


#: The room's light family (:func:`light_families` with the default clearance).
LIGHT_FAMILIES = light_families()

#: A bake spec naming the room's light family (sizes small enough for tests to override).
SPEC = {
    "atlas": {"resolution": 128, "padding": 2},
    "measurement_points": {"count": 256, "supersample": 4, "seed": 1},
    "lights": {"count": 128, "holdout": 16, "seed": 2, "families": LIGHT_FAMILIES},
    "transport": {"gather_rays": 64, "max_bounces": 16, "tolerance": 0.001},
    "fit": {"basis": 16, "ridge": "auto", "channels": "mono"},
}


def _wall(x0, z0, x1, z1, subdiv: int) -> trimesh.Trimesh:
    """A vertical wall from (x0, z0) to (x1, z1), 0 ≤ y ≤ HEIGHT, whose front faces
    the direction (−(z1 − z0), 0, x1 − x0)."""
    P = np.array
    return quad(P([[x0, 0, z0], [x1, 0, z1], [x1, HEIGHT, z1], [x0, HEIGHT, z0]], float),
                 subdiv)


def open_room(subdiv: int = 2) -> trimesh.Scene:
    """The room as a trimesh scene with one PBR material per part."""
    P = np.array
    floor_a = quad(P([[0, 0, 2], [4, 0, 2], [4, 0, 0], [0, 0, 0]], float), subdiv)
    floor_b = quad(P([[0, 0, 4], [2, 0, 4], [2, 0, 2], [0, 0, 2]], float), subdiv)
    floor = trimesh.util.concatenate([floor_a, floor_b])
    parts = {
        "floor": floor,
        # the outline; each wall's front faces the room
        "wall_south": _wall(0, 0, 4, 0, subdiv),      # faces +z
        "wall_east": _wall(4, 0, 4, 2, subdiv),       # faces −x
        "wall_north_a": _wall(4, 2, 2, 2, subdiv),    # faces −z
        "wall_inner_b": _wall(2, 2, 2, 4, subdiv),    # faces −x
        "wall_west": _wall(0, 4, 0, 0, subdiv),       # faces +x
        "pillar": block([(PILLAR[0][0] + PILLAR[1][0]) / 2, HEIGHT / 2,
                          (PILLAR[0][1] + PILLAR[1][1]) / 2],
                         [PILLAR[1][0] - PILLAR[0][0], HEIGHT, PILLAR[1][1] - PILLAR[0][1]],
                         0.0),
        "low_wall": block([3.0, 0.4, 1.0], [0.15, 0.8, 1.4], 0.0),
    }
    return material_scene(parts, ALBEDO)


def write_open_room(path: str | Path, subdiv: int = 2) -> Path:
    """Write the open room as a .glb; returns the path."""
    return write_glb(open_room(subdiv), path)
