"""Hair as a :class:`~prtcore.core.scene.Scene` of fibre tubes, for the stages that take a
scene: the measurement points on the hull of the hair volume (paper 4.1, placement
``"hull"`` of :func:`prtcore.intake.points.place_measurement_points`) and the light
families' bounds."""

from __future__ import annotations

import numpy as np

from prtcore.core.fibres import DEFAULT_SIDES, fibre_tubes
from prtcore.core.hair import Hair
from prtcore.core.scene import Material, Scene


def hair_scene(hair: Hair, sides: int = DEFAULT_SIDES) -> Scene:
    """The fibre tubes as a scene: radial vertex normals, one material whose base colour
    is the hair's mean colour (hull points take their albedo from it)."""
    mesh = fibre_tubes(hair, sides, pieces=1)  # a vertex per point and side
    axis = np.repeat(hair.points, sides, axis=0)
    n = mesh.positions - axis
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    f = len(mesh.faces)
    color = hair.color.mean(axis=0)
    return Scene(source=hair.name, positions=mesh.positions, normals=n,
                 uv0=np.zeros((len(n), 2)), uv1=None, faces=mesh.faces,
                 face_material=np.zeros(f, dtype=np.int32),
                 face_instance=np.zeros(f, dtype=np.int32),
                 materials=(Material(name="hair", base_color_factor=np.array(
                     [*color, 1.0])),))


def with_hair(scene: Scene, hair: Hair, sides: int = DEFAULT_SIDES) -> Scene:
    """A mesh and the fibre tubes of ``hair`` as one scene, the mesh's triangles first
    (indices [0, F), as :func:`prtcore.transport.fibre.hair_tracer` orders them), the
    tubes' with one more material (the hair's mean colour): what a hair + mesh bake places
    its hull measurement points on and what its runtime traces shadow rays against."""
    tubes = hair_scene(hair, sides)
    nv, m = len(scene.positions), len(scene.materials)
    has = scene.has_uv0 if scene.has_uv0 is not None else np.ones(nv, dtype=bool)
    return scene.replace(
        positions=np.concatenate([scene.positions, tubes.positions]),
        normals=np.concatenate([scene.normals, tubes.normals]),
        uv0=np.concatenate([scene.uv0, tubes.uv0]),
        uv1=None if scene.uv1 is None else np.concatenate([scene.uv1, tubes.uv0]),
        faces=np.concatenate([scene.faces, tubes.faces + nv]),
        face_material=np.concatenate([scene.face_material, tubes.face_material + m]),
        face_instance=np.concatenate([scene.face_instance,
                                      np.full(tubes.triangle_count, -1, np.int32)]),
        materials=(*scene.materials, *tubes.materials),
        has_uv0=np.concatenate([has, np.zeros(len(tubes.positions), dtype=bool)]),
        source=f"{scene.source} + {hair.name}")
