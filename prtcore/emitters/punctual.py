"""Light evaluation: the one formula every stage uses, dispatched to each light's emitter.

Conventions (docs/bundle.md): KHR_lights_punctual; ``color`` linear RGB; ``intensity`` in cd
(point/spot) or lux (directional), used directly as radiometric units. Irradiance at a
surface point with unit normal n:

* point/spot: ``E = color · I · max(0, n·ω) / r² · spot(ω) · window(r)``, ω unit vector
  from the point to the light, r the distance;
* directional: ``E = color · I · max(0, n·(−d))``, d the direction light travels.

``spot`` and ``window`` are the KHR_lights_punctual reference formulas: the angular
attenuation ``saturate(cosθ·scale + offset)²`` with ``scale = 1/max(1e-3, cos(inner) −
cos(outer))``, ``offset = −cos(outer)·scale``, and the range window
``saturate(1 − (r/range)⁴)²`` (1 when range is None).
"""

from __future__ import annotations

import numpy as np

from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.emitters.base import emitter_for

# ---------------------------------------------------------------------------------------
# Evaluation


def unshadowed_irradiance(light: Light, points: np.ndarray, normals: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Irradiance without visibility.

    points, normals : (n, 3) float64. Returns ``E`` (n, 3) float64 RGB irradiance,
    ``to_light`` (n, 3) unit directions toward the light, and ``dist`` (n,) distances
    (inf for directional lights).
    """
    return emitter_for(light).unshadowed(light, points, normals)


def irradiance(light: Light, points: np.ndarray, normals: np.ndarray,
               tracer: RayTracer | None) -> np.ndarray:
    """Direct irradiance with shadows (occlusion rays) when ``tracer`` is given.

    points, normals : (n, 3) float64. Returns (n, 3) float64. Dispatched to the light's
    emitter (:meth:`prtcore.emitters.base.Emitter.irradiance`): for punctual lights only
    points that receive light at all are traced.
    """
    return emitter_for(light).irradiance(light, points, normals, tracer)
