"""Building blocks of the scenes the project builds: planar quads, flat-faced boxes, and a
trimesh scene of named parts with factor-only Lambertian materials (no TEXCOORD_0: the
bake generates lightmap UVs). Written to .glb through trimesh's exporter with normals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from trimesh.visual.material import PBRMaterial


def quad(corners: np.ndarray, subdiv: int = 1) -> trimesh.Trimesh:
    """A planar quad from 4 corners (4, 3) in counter-clockwise order seen from the front
    (front normal (b − a) × (d − a)), split into subdiv × subdiv cells of two triangles."""
    a, b, c, d = np.asarray(corners, dtype=np.float64)
    n = subdiv + 1
    s, t = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    s, t = s.ravel()[:, None], t.ravel()[:, None]
    verts = (1 - s) * (1 - t) * a + s * (1 - t) * b + s * t * c + (1 - s) * t * d
    i, j = (g.ravel() for g in np.meshgrid(np.arange(subdiv), np.arange(subdiv),
                                           indexing="ij"))
    v00, v10, v11, v01 = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
    faces = np.stack([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)], 1)
    return trimesh.Trimesh(verts, faces.reshape(-1, 3), process=False)


def block(center, size, angle_deg: float = 0.0) -> trimesh.Trimesh:
    """A closed box of extents ``size`` (x, y, z) turned ``angle_deg`` about +y and moved to
    ``center``, with flat faces (no normal smoothing across its edges)."""
    box = trimesh.creation.box(extents=size)
    box.apply_transform(trimesh.transformations.rotation_matrix(np.radians(angle_deg),
                                                                [0, 1, 0]))
    box.apply_translation(center)
    box.unmerge_vertices()
    return box


def material_scene(parts: dict[str, trimesh.Trimesh],
                   albedo: dict[str, tuple[float, float, float]]) -> trimesh.Scene:
    """A scene with one node, mesh and material per part: base colour ``albedo[name]``
    (linear RGB), metallic 0, roughness 1."""
    scene = trimesh.Scene()
    for name, mesh in parts.items():
        mesh.visual = trimesh.visual.TextureVisuals(
            material=PBRMaterial(name=name, baseColorFactor=[*albedo[name], 1.0],
                                 metallicFactor=0.0, roughnessFactor=1.0))
        scene.add_geometry(mesh, geom_name=name, node_name=name)
    return scene


def write_glb(scene: trimesh.Scene, path: str | Path) -> Path:
    """Write ``scene`` as a .glb with normals; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(scene.export(file_type="glb", include_normals=True))
    return path
