"""The emitter interface: what every kind of light provides, and the registry.

An emitter is stateless: it evaluates a :class:`prtcore.core.scene.Light` of its ``type``.
Each member is a module of this package that defines a subclass and registers it with
:func:`register`; ``prtcore.emitters`` imports the members (one line each). The transport,
the path tracer, the runtime and the GL renderer never branch on a light's type: they ask
:func:`emitter_for`.

A new kind of light (an environment map, SH lighting) is a new module here.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from prtcore.core.raytrace import RayTracer
from prtcore.core.registry import Registry
from prtcore.core.scene import Light


class Emitter:
    """One kind of light. Arrays are float64 unless stated.

    type : the light-file / glTF type name; gl_code : its code in the GLSL light table;
    positioned / directed / coned / ranged : which Light fields the kind uses (the
    light-file contract requires position when positioned and direction when directed).
    """

    type: ClassVar[str]
    gl_code: ClassVar[int]
    positioned: ClassVar[bool] = True
    directed: ClassVar[bool] = False
    coned: ClassVar[bool] = False
    ranged: ClassVar[bool] = True

    def unshadowed(self, light: Light, points: np.ndarray, normals: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Irradiance without visibility at points (n, 3) with unit normals (n, 3).

        Returns E (n, 3) RGB, unit directions toward the light (n, 3), distances (n,)
        (inf for lights at infinity)."""
        raise NotImplementedError

    def irradiance(self, light: Light, points: np.ndarray, normals: np.ndarray,
                   tracer: RayTracer | None) -> np.ndarray:
        """Direct irradiance (n, 3) at points (n, 3) with unit shading normals (n, 3),
        shadowed when ``tracer`` is given. Lights with one direction per point (the
        punctual kinds): :meth:`unshadowed` times one :meth:`visible` ray from the points
        the light reaches; an emitter that integrates over directions (an environment)
        overrides this."""
        e, w, _ = self.unshadowed(light, points, normals)
        if tracer is None:
            return e
        lit = np.flatnonzero(e[:, 0] + e[:, 1] + e[:, 2] > 0)  # e ≥ 0: any channel lit
        if len(lit):
            vis = self.visible(light, tracer, points[lit], normals[lit], w[lit])
            e[lit[~vis]] = 0.0
        return e

    def visible(self, light: Light, tracer: RayTracer, points: np.ndarray,
                normals: np.ndarray, to_light: np.ndarray) -> np.ndarray:
        """(n,) bool: an occlusion ray from each point reaches the light."""
        raise NotImplementedError

    def kernel_row(self, light: Light) -> np.ndarray | None:
        """The light's constants for the compiled evaluation (:mod:`prtcore.emitters.
        compiled`, :func:`~prtcore.emitters.compiled.light_row`), or None: evaluate with
        :meth:`irradiance` (the default, for kinds the kernels do not know)."""
        return None

    def sample_rays(self, light: Light, rng: np.random.Generator, n: int,
                    disk_centre: np.ndarray, disk_radius: float
                    ) -> tuple[np.ndarray, np.ndarray]:
        """n rays leaving the light (for the path tracer's light strategy): origins (n, 3),
        unit directions (n, 3). Lights at infinity start on a disk of ``disk_radius``
        around ``disk_centre`` that covers the scene."""
        raise NotImplementedError

    def first_hit_density(self, light: Light, points: np.ndarray, face_normals: np.ndarray,
                          disk_radius: float) -> np.ndarray:
        """(n,) area density of :meth:`sample_rays`' first hits at surface points the light
        reaches unoccluded."""
        raise NotImplementedError


def color_intensity(light: Light) -> np.ndarray:
    """(3,) float64 ``color × intensity`` of a light."""
    return np.asarray(light.color, dtype=np.float64) * float(light.intensity)


def light_axis(light: Light) -> np.ndarray:
    """(3,) float64 unit vector of ``light.direction`` (the way light travels)."""
    d = np.asarray(light.direction, dtype=np.float64)
    return d / np.linalg.norm(d)


_REGISTRY: Registry[Emitter] = Registry("emitter for light type", "type")

#: class decorator: make a class the emitter of lights of its ``type``
register = _REGISTRY.register


def emitter_for(light_or_type: Light | str) -> Emitter:
    """The emitter of a light (or of a type name). KeyError names the known types."""
    return _REGISTRY.get(light_or_type if isinstance(light_or_type, str) else light_or_type.type)


def types() -> tuple[str, ...]:
    """Registered light types, in registration order."""
    return _REGISTRY.names()
