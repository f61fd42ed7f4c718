"""A plant of leaf cards on a floor (issue 18: a mesh with high-frequency visibility, as
the thesis' plant scenes): ``LEAVES`` thin elongated two-sided quads (front and back
1 mm apart, so each side has its own front face) around a vertical stem, at seeded
heights, azimuths and tilts, over a 3 m floor. Their shadows on the floor and on each
other are the sharp, many-edged visibility a smooth network finds hardest.

Layout (metres, y up): floor at y = 0 (two triangles), stem a thin box 1.2 m tall at the
origin, leaves 0.45 m × 0.12 m starting at the stem; all Lambertian (green leaves, grey
floor, brown stem).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import trimesh

from prtcore.scenes.parts import block, material_scene, quad, write_glb

ALBEDO = {"floor": (0.7, 0.7, 0.7), "stem": (0.35, 0.25, 0.15), "leaves": (0.25, 0.55, 0.2)}
LEAVES = 36
LEAF_SIZE = (0.45, 0.12)
FLOOR_HALF = 1.5
SEED = 7

#: A bake spec for the scene (learnt_sh: many small UV charts, so a 256² atlas)
SPEC = {"atlas": {"resolution": 256, "padding": 2}}


def leaf(base: np.ndarray, azimuth: float, tilt: float) -> trimesh.Trimesh:
    """A two-sided leaf card from ``base`` outward along ``azimuth`` (radians about +y),
    raised by ``tilt`` (radians) above the horizontal."""
    length, width = LEAF_SIZE
    out = np.array([math.cos(azimuth) * math.cos(tilt), math.sin(tilt),
                    math.sin(azimuth) * math.cos(tilt)])
    side = np.array([-math.sin(azimuth), 0.0, math.cos(azimuth)]) * width / 2
    a, b = base - side, base + side
    c, d = b + length * out, a + length * out
    normal = np.cross(b - a, d - a)
    normal /= np.linalg.norm(normal)
    front = quad(np.array([a, b, c, d]) + 0.0005 * normal, 2)
    back = quad(np.array([a, d, c, b]) - 0.0005 * normal, 2)
    return trimesh.util.concatenate([front, back])


def plant() -> trimesh.Scene:
    """The floor, the stem and the leaves as a trimesh scene (seeded by :data:`SEED`)."""
    rng = np.random.default_rng(SEED)
    g = FLOOR_HALF
    floor = quad(np.array([[-g, 0, g], [g, 0, g], [g, 0, -g], [-g, 0, -g]], float), 1)
    stem = block([0.0, 0.6, 0.0], [0.04, 1.2, 0.04])
    heights = np.sort(rng.uniform(0.25, 1.15, LEAVES))
    leaves = [leaf(np.array([0.0, h, 0.0]), rng.uniform(0, 2 * math.pi),
                   rng.uniform(-0.35, 0.6)) for h in heights]
    return material_scene({"floor": floor, "stem": stem,
                           "leaves": trimesh.util.concatenate(leaves)}, ALBEDO)


def write_plant(path: str | Path) -> Path:
    """Write the scene as a .glb; returns the path."""
    return write_glb(plant(), path)
