"""Directional lights (KHR_lights_punctual ``directional``): illuminance in lux along
``direction`` (the way light travels), E = I·max(0, n·(−d)); no position, no range."""

from __future__ import annotations

import math

import numpy as np

from prtcore.core.geometry import orthonormal_frame
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.emitters.base import Emitter, color_intensity, light_axis, register
from prtcore.emitters.compiled import KIND_DIRECTIONAL, light_row


@register
class DirectionalEmitter(Emitter):
    type = "directional"
    gl_code = 2
    positioned = False
    directed = True
    ranged = False

    def unshadowed(self, light, points, normals):
        points = np.asarray(points, dtype=np.float64)
        color = color_intensity(light)
        w = np.broadcast_to(self.toward(light), points.shape).copy()
        cos = np.einsum("ij,ij->i", normals, w)
        e = np.clip(cos, 0.0, None)[:, None] * color
        return e, w, np.full(len(points), np.inf)

    @staticmethod
    def toward(light: Light) -> np.ndarray:
        """(3,) float64 unit direction toward the light (against ``direction``)."""
        d = np.asarray(light.direction, dtype=np.float64)
        return -d / np.linalg.norm(d)

    def kernel_row(self, light):
        return light_row(KIND_DIRECTIONAL, axis=self.toward(light),
                         color=color_intensity(light))

    def visible(self, light: Light, tracer: RayTracer, points, normals, to_light):
        return tracer.unoccluded_towards(points, normals, to_light)

    def sample_rays(self, light, rng, n, disk_centre, disk_radius):
        u = rng.random((n, 2))
        phi = 2.0 * math.pi * u[:, 1]
        axis = np.broadcast_to(light_axis(light), (n, 3))
        t, s = orthonormal_frame(np.ascontiguousarray(axis))
        r = disk_radius * np.sqrt(u[:, 0])
        origin = (disk_centre - 2.0 * disk_radius * axis
                  + (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * s)
        return origin, axis.copy()

    def first_hit_density(self, light, points, face_normals, disk_radius):
        cos = np.abs(face_normals @ light_axis(light))
        return cos / (math.pi * disk_radius**2)
