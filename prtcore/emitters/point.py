"""Point lights (KHR_lights_punctual ``point``): intensity in cd, E = I·cosθ/r²·window(r)."""

from __future__ import annotations

import math

import numpy as np

from prtcore.core.geometry import directions_around
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.emitters.base import Emitter, color_intensity, register
from prtcore.emitters.compiled import KIND_POSITIONED, light_row


def range_window(light: Light, dist: np.ndarray) -> np.ndarray:
    """KHR range window ``saturate(1 − (r/range)⁴)²``; ones when range is None."""
    if light.range is None:
        return np.ones_like(dist)
    x = np.clip(1.0 - (dist / light.range) ** 4, 0.0, 1.0)
    return x * x


@register
class PointEmitter(Emitter):
    type = "point"
    gl_code = 0

    def cone(self, light: Light, to_light: np.ndarray) -> np.ndarray | None:
        """Angular attenuation (n,) for unit directions toward the light; None: isotropic."""
        return None

    def unshadowed(self, light, points, normals):
        points = np.asarray(points, dtype=np.float64)
        color = color_intensity(light)
        delta = np.asarray(light.position, dtype=np.float64) - points
        r2 = np.einsum("ij,ij->i", delta, delta)
        dist = np.sqrt(r2)
        w = np.divide(delta, dist[:, None], out=np.zeros_like(delta), where=dist[:, None] > 0)
        cos = np.clip(np.einsum("ij,ij->i", normals, w), 0.0, None)
        att = cos * range_window(light, dist)
        cone = self.cone(light, w)
        if cone is not None:
            att = att * cone
        att = np.divide(att, r2, out=np.zeros_like(att), where=r2 > 0)
        return att[:, None] * color, w, dist

    def kernel_row(self, light):
        return light_row(KIND_POSITIONED, light.position, color=color_intensity(light),
                         light_range=light.range)

    def visible(self, light: Light, tracer: RayTracer, points, normals, to_light):
        target = np.broadcast_to(np.asarray(light.position, dtype=np.float64),
                                 (len(points), 3))
        return tracer.visible(points, normals, target)

    def emission_cone(self, light: Light) -> float:
        """Cosine of the half-angle of the cone the light emits into (−1: all directions)."""
        return -1.0

    def emission_axis(self, light: Light) -> np.ndarray:
        return np.array([0.0, 0.0, 1.0])

    def sample_rays(self, light, rng, n, disk_centre, disk_radius):
        u = rng.random((n, 2))
        phi = 2.0 * math.pi * u[:, 1]
        origin = np.broadcast_to(np.asarray(light.position, np.float64), (n, 3)).copy()
        axis = np.broadcast_to(self.emission_axis(light), (n, 3)).copy()
        c = self.emission_cone(light)
        return origin, directions_around(axis, 1.0 - u[:, 0] * (1.0 - c), phi)

    def first_hit_density(self, light, points, face_normals, disk_radius):
        w = points - np.asarray(light.position, np.float64)
        r2 = np.einsum("ij,ij->i", w, w)
        r = np.sqrt(r2)
        cos = np.abs(np.einsum("ij,ij->i", face_normals, w))
        c = self.emission_cone(light)
        if c > -1.0:
            inside = w @ self.emission_axis(light) >= c * r
            pdf_dir = np.where(inside, 1.0 / (2.0 * math.pi * (1.0 - c)), 0.0)
        else:
            pdf_dir = np.full(len(points), 1.0 / (4.0 * math.pi))
        return np.divide(pdf_dir * cos, r2 * r, out=np.zeros_like(r), where=r > 0)
