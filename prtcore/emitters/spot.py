"""Spot lights (KHR_lights_punctual ``spot``): a point light times the KHR angular
attenuation ``saturate(cosθ·scale + offset)²``, ``scale = 1/max(1e-3, cos(inner) −
cos(outer))``, ``offset = −cos(outer)·scale``."""

from __future__ import annotations

import math

import numpy as np

from prtcore.core.scene import Light
from prtcore.emitters.base import color_intensity, emitter_for, light_axis, register
from prtcore.emitters.compiled import KIND_POSITIONED, light_row
from prtcore.emitters.point import PointEmitter


def cone_coefficients(light: Light) -> tuple[float, float]:
    """The KHR angular attenuation's ``scale`` and ``offset`` of a spot light."""
    ci, co = math.cos(light.inner_cone_angle), math.cos(light.outer_cone_angle)
    scale = 1.0 / max(1e-3, ci - co)
    return scale, -co * scale


def spot_factor(light: Light, cos_angle: np.ndarray) -> np.ndarray:
    """KHR angular attenuation. cos_angle : (n,) cosine between the spot axis and the
    direction from the light to the point. Returns (n,) float64; ones for a light
    without a cone."""
    if not emitter_for(light).coned:
        return np.ones_like(cos_angle)
    scale, offset = cone_coefficients(light)
    a = np.clip(cos_angle * scale + offset, 0.0, 1.0)
    return a * a


@register
class SpotEmitter(PointEmitter):
    type = "spot"
    gl_code = 1
    directed = True
    coned = True

    def cone(self, light, to_light):
        return spot_factor(light, -(to_light @ light_axis(light)))

    def kernel_row(self, light):
        return light_row(KIND_POSITIONED, light.position, light_axis(light),
                         color_intensity(light), light.range, cone_coefficients(light))

    def emission_cone(self, light):
        return math.cos(light.outer_cone_angle)

    def emission_axis(self, light):
        return light_axis(light)
