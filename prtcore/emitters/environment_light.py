"""Environment lights for the data-driven bake (``"type": "environment"``): distant
radiance from every direction, so the direct irradiance at a point is the hemisphere
integral ``E(x) = ∫ L(ω) V(x, ω) max(0, n·ω) dω`` instead of one shadow ray.

Which environment (:attr:`prtcore.core.scene.Light.environment`):

* ``"sky"`` — the analytic sky of :func:`prtcore.emitters.environment.sky_environment`
  about the sun direction ``−direction`` (a family of them is the spec's "sky with a
  random sun": the sun's glow, its direction drawn like a directional light's);
* ``"ambient"`` — uniform radiance from every direction (an ambient term; the direction
  is ignored): with a directional family beside it, the spec's "random directional lights
  plus an ambient term" — the transfer is linear, so the engine adds the two lights'
  direct light at the measurement points (docs/lights.md);
* a file — an equirect map (:func:`~prtcore.emitters.environment.load_environment`) turned
  about +y by the azimuth of ``−direction`` (φ = atan2(t_x, −t_z), t = −direction: φ = 0
  for t toward −z), so a family of them is the "rotated environment".

Radiance is scaled by ``color · intensity``.

Estimator: ``E ≈ π/S Σ_k L(ω_k) V(x, ω_k)`` over S = :data:`STRATA`² stratified
cosine-distributed directions about the shading normal (importance sampling of the cosine
term), drawn from the fixed seed :data:`DIRECTION_SEED`. The directions depend only on the
points and normals, never on the light, so every light of a family shares them and their
visibility: it is traced once per point set and cached (:data:`CACHE_BYTES`), and each
further light costs S radiance lookups per point. Because the same directions serve every
light, the estimate is a fixed linear functional of the radiance — its error is the same
quadrature error for every member of the family (what the data-driven fit sees is
consistent), about 1/S^¾ relative for smooth skies (stratification); a sharp sun is not
importance-sampled and is noisier. Ray origins and the below-the-surface rule are the
punctual lights' (:meth:`prtcore.core.raytrace.RayTracer.unoccluded_towards`).
"""

from __future__ import annotations

import hashlib
import math
import threading
from functools import lru_cache

import numpy as np

from prtcore.core.errors import PrtError
from prtcore.core.geometry import stratified_cosine_directions
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.emitters.base import Emitter, register
from prtcore.emitters.environment import (
    Environment,
    constant_environment,
    load_environment,
    rotation_about_y,
    sky_environment,
)

#: S = STRATA² directions per point
STRATA = 8
#: the seed of the shared direction sets
DIRECTION_SEED = 17
#: the analytic sky's map height (pixels; width twice that)
SKY_HEIGHT = 64
#: the ambient term's (uniform) map height
AMBIENT_HEIGHT = 8
#: visibility cached across lights, at most this many bytes in all (then traced per light)
CACHE_BYTES = 1 << 28


def to_light_axis(light: Light) -> np.ndarray:
    """(3,) unit −direction: toward the sun (sky) or the map's turning reference."""
    d = -np.asarray(light.direction, np.float64)
    return d / np.linalg.norm(d)


@lru_cache(maxsize=4)
def _map(path: str) -> Environment:
    return load_environment(path)


def environment_of(light: Light) -> Environment:
    """The light's environment (world space, unscaled)."""
    if light.environment == "ambient":
        return constant_environment(np.ones(3), AMBIENT_HEIGHT)
    t = to_light_axis(light)
    if light.environment in ("", "sky"):
        return sky_environment(t, SKY_HEIGHT)
    phi = math.degrees(math.atan2(t[0], -t[2]))
    return _map(light.environment).rotated(rotation_about_y(phi))


def environment_radiance(light: Light, directions: np.ndarray) -> np.ndarray:
    """(n, 3) radiance of the light arriving from unit ``directions`` (n, 3)."""
    scale = np.asarray(light.color, np.float64) * float(light.intensity)
    return environment_of(light).radiance(directions) * scale


class _Directions:
    """The shared direction sets and their visibility, per point set (thread-safe)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._store: dict[tuple, tuple[np.ndarray, np.ndarray | None]] = {}
        self._bytes = 0

    def get(self, points: np.ndarray, normals: np.ndarray, tracer: RayTracer | None
            ) -> tuple[np.ndarray, np.ndarray | None]:
        """Directions (n, S, 3) float64 and visibility (n, S) bool (None without tracer)."""
        h = hashlib.blake2b(np.ascontiguousarray(points, np.float64).tobytes(), digest_size=16)
        h.update(np.ascontiguousarray(normals, np.float64).tobytes())
        key = (h.hexdigest(), None if tracer is None else id(tracer))
        with self._lock:
            hit = self._store.get(key)
        if hit is not None:
            return hit
        rng = np.random.default_rng(DIRECTION_SEED)
        d = stratified_cosine_directions(np.asarray(normals, np.float64), STRATA, rng)
        vis = None
        if tracer is not None:
            n, s = d.shape[:2]
            vis = tracer.unoccluded_towards(np.repeat(points, s, axis=0),
                                            np.repeat(normals, s, axis=0),
                                            d.reshape(-1, 3)).reshape(n, s)
        size = d.nbytes + (0 if vis is None else vis.nbytes)
        with self._lock:
            if self._bytes + size <= CACHE_BYTES:
                self._store[key] = (d, vis)
                self._bytes += size
        return d, vis


@register
class EnvironmentEmitter(Emitter):
    type = "environment"
    gl_code = -1  # not in the GL light table: the GL renderers do not draw environments
    positioned = False
    directed = True
    ranged = False

    def __init__(self):
        self._directions = _Directions()

    def directions(self, points: np.ndarray, normals: np.ndarray, tracer: RayTracer | None
                   ) -> tuple[np.ndarray, np.ndarray | None]:
        """The estimator's S cosine directions about each normal, (n, S, 3) float64, and
        their visibility from each point, (n, S) bool (None without ``tracer``): the same
        for every environment light (see the module docstring). For receivers that weight
        each direction (the Chiang fibre's directional albedo)."""
        return self._directions.get(np.asarray(points, np.float64),
                                    np.asarray(normals, np.float64), tracer)

    def irradiance(self, light, points, normals, tracer):
        points = np.asarray(points, np.float64)
        normals = np.asarray(normals, np.float64)
        if not len(points):
            return np.zeros((0, 3))
        d, vis = self._directions.get(points, normals, tracer)
        n, s = d.shape[:2]
        rad = environment_radiance(light, d.reshape(-1, 3)).reshape(n, s, 3)
        if vis is not None:
            rad = rad * vis[:, :, None]
        return math.pi / s * rad.sum(axis=1)

    def unshadowed(self, light, points, normals):
        e = self.irradiance(light, points, normals, None)
        return e, np.array(normals, np.float64, copy=True), np.full(len(points), np.inf)

    def visible(self, light, tracer, points, normals, to_light):
        raise PrtError("an environment light has no single direction to test; use "
                       "EnvironmentEmitter.irradiance")

    def sample_rays(self, light, rng, n, disk_centre, disk_radius):
        raise PrtError("environment lights are not traced from the light by the "
                       "point-light path tracer (use prtcore.reference.environment)")

    def first_hit_density(self, light, points, face_normals, disk_radius):
        raise PrtError("environment lights are not traced from the light by the "
                       "point-light path tracer (use prtcore.reference.environment)")
