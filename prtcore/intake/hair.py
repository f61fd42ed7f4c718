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
    mesh = fibre_tubes(hair, sides)
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
