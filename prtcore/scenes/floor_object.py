"""The comparison scene the project builds (issue 17; the paper's Fig. 12 setting): a
poorly tessellated floor — one quad, two triangles — and an object standing on it, lit
by a directional light.

What it shows: per-vertex PRT stores transfer only at the floor's four corners, far
from the object, so the object's shadow on the floor cannot appear; transfer textures
store it per texel. Band-limited SH lighting blurs the directional light, so light
leaks into the shadow behind the object; data-driven PRT trained on directional lights
has neither problem.

Layout (metres, y up): a floor 4 m × 4 m at y = 0 facing up (two triangles); a block
0.8 m × 1.0 m × 0.8 m standing on it at the origin, turned 20° about y; both Lambertian
(no TEXCOORD_0; the bake generates lightmap UVs). Light: a directional light from
elevation ELEVATION_DEG, and a family of directional lights around it for the
data-driven bake.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import trimesh

from prtcore.core.scene import Light
from prtcore.scenes.parts import block, material_scene, quad, write_glb

ALBEDO = {"floor": (0.7, 0.7, 0.7), "object": (0.75, 0.45, 0.25)}
FLOOR_HALF = 2.0
OBJECT_SIZE = (0.8, 1.0, 0.8)
#: the held-out light's elevation and azimuth (degrees), shadow cast toward +z
ELEVATION_DEG = 40.0
AZIMUTH_DEG = 0.0

#: Directional lights from the upper hemisphere above 15°, aimed at the object (the
#: family the data-driven bake is trained on and the comparison's held-out lights come
#: from).
LIGHT_FAMILIES = [
    {"type": "directional", "weight": 1.0,
     "position": {"box": [[-6.0, 1.6, -6.0], [6.0, 6.0, 6.0]]},
     "aim": {"target": [0.0, 0.0, 0.0], "jitter": 0.0},
     "intensity": {"uniform": [1.0, 3.0]}, "color": "white"},
]

#: A bake spec for the scene (sizes small enough to run in minutes on two cores).
SPEC = {
    "atlas": {"resolution": 128, "padding": 2},
    "measurement_points": {"count": 256, "supersample": 4, "seed": 1},
    "lights": {"count": 96, "holdout": 8, "seed": 2, "families": LIGHT_FAMILIES},
    "transport": {"gather_rays": 64, "max_bounces": 8},
    "fit": {"basis": 16},
}


def floor_and_object() -> trimesh.Scene:
    """The floor (two triangles) and the block as a trimesh scene."""
    g = FLOOR_HALF
    floor = quad(np.array([[-g, 0, g], [g, 0, g], [g, 0, -g], [-g, 0, -g]], float), 1)
    obj = block([0.0, OBJECT_SIZE[1] / 2, 0.0], list(OBJECT_SIZE), 20.0)
    return material_scene({"floor": floor, "object": obj}, ALBEDO)


def write_floor_object(path: str | Path) -> Path:
    """Write the scene as a .glb; returns the path."""
    return write_glb(floor_and_object(), path)


def key_light(intensity: float = 2.0) -> Light:
    """The directional light of the comparison (travelling down and toward +z)."""
    el, az = math.radians(ELEVATION_DEG), math.radians(AZIMUTH_DEG)
    to_light = np.array([math.cos(el) * math.sin(az), math.sin(el),
                         -math.cos(el) * math.cos(az)])
    return Light(type="directional", color=np.ones(3), intensity=float(intensity),
                 direction=-to_light, name="key")
