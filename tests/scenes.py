"""Shared test data (issue 21): the tiny bake spec, point lights, quads and the inside of a
sphere. One copy here; test modules (and the service and stability suites) import it from
here rather than from each other. ``tests/conftest.py`` puts ``tests/`` on ``sys.path``.
"""

from __future__ import annotations

import copy

import numpy as np
import trimesh

from prtcore.core.scene import Light

#: A bake of about a second on the Cornell box (point lights across the room).
TINY_SPEC = {
    "atlas": {"resolution": 32, "padding": 2},
    "measurement_points": {"count": 32, "supersample": 2},
    "lights": {"count": 24, "holdout": 4, "families": [
        {"type": "point", "position": {"box": [[-0.8, 0.3, -0.8], [0.8, 1.9, 0.9]]},
         "intensity": {"uniform": [0.5, 3.0]}}]},
    "transport": {"gather_rays": 16, "max_bounces": 8},
    "fit": {"basis": 8},
    "output": {"dtype": "float"},
}


def tiny_spec(**sections) -> dict:
    """A deep copy of TINY_SPEC with top-level sections replaced."""
    spec = copy.deepcopy(TINY_SPEC)
    spec.update(copy.deepcopy(sections))
    return spec


def point_light(pos, intensity: float = 1.0, color=(1.0, 1.0, 1.0)) -> Light:
    return Light(type="point", color=np.asarray(color, float), intensity=float(intensity),
                 position=np.asarray(pos, float))


def quad(corners, subdiv: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """A planar quad from corners a, b, c, d (counter-clockwise seen from the front), split
    into subdiv × subdiv cells of two triangles: (vertices (v, 3), faces (f, 3))."""
    a, b, c, d = np.asarray(corners, float)
    k = subdiv + 1
    s, t = (g.ravel()[:, None] for g in np.meshgrid(np.linspace(0, 1, k),
                                                    np.linspace(0, 1, k), indexing="ij"))
    v = (1 - s) * (1 - t) * a + s * (1 - t) * b + s * t * c + (1 - s) * t * d
    i, j = (g.ravel() for g in np.meshgrid(np.arange(subdiv), np.arange(subdiv),
                                           indexing="ij"))
    v00, v10, v11, v01 = i * k + j, (i + 1) * k + j, (i + 1) * k + j + 1, i * k + j + 1
    return v, np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])


def quad_normal(corners) -> np.ndarray:
    """The unit front normal of the quad ``corners``."""
    a, b, _c, d = np.asarray(corners, float)
    n = np.cross(b - a, d - a)
    return n / np.linalg.norm(n)


def inside_sphere(subdivisions: int = 2, radius: float = 1.0
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An icosphere wound so that its inside is the front: (vertices, faces, radial inward
    unit normals)."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    v = np.asarray(m.vertices, float)
    return v, np.asarray(m.faces)[:, ::-1].copy(), -v / np.linalg.norm(v, axis=1,
                                                                        keepdims=True)


def bake_sh_prt_bundle(tmp_path, storage: str, *, bounce: bool = True,
                       specular: float = 0.0):
    """An sh_prt bundle (``storage`` "texture" or "vertex", 3 bands, 16 rays per sample;
    ``specular`` > 0: a glossy layer, exponent 8) of the project's floor-and-object scene at
    a 32² atlas, baked through the CLI."""
    import json

    from prtcore.cli import main
    from prtcore.scenes import floor_object

    asset = floor_object.write_floor_object(tmp_path / "fo.glb")
    spec = dict(floor_object.SPEC, atlas={"resolution": 32, "padding": 2},
                method={"name": "sh_prt"},
                sh_prt={"storage": storage, "bands": 3, "strata": 4, "bounce": bounce,
                        "specular": specular, "exponent": 8.0},
                output={"dtype": "float"})
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    out = tmp_path / f"b_{storage}"
    assert main(["bake", str(asset), "--spec", str(tmp_path / "spec.json"), "--out",
                 str(out), "-q"]) == 0
    return out
