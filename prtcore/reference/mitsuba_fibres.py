"""An independent check of light in hair by Mitsuba 3 (a dev dependency, imported here only):
the diffuse-fibre model on Mitsuba's own round ``linearcurve`` geometry, ``diffuse`` BSDF
and ``path`` integrator (``scalar_rgb``: the LLVM variants do not run on this machine's
LLVM).

Mitsuba has no bake. A strand texel's value — outgoing radiance averaged over azimuth and
the texel's arc interval — is estimated by rays that start just outside the fibre
(1.02 × its radius, at a uniform arc position and azimuth of the texel) and point at its
axis: for a Lambertian fibre the radiance the path integrator returns along such a ray is
the outgoing radiance ρ/π·E at the hit, whatever the direction. ``max_depth = 2`` gives the
direct part (camera → fibre → light); the indirect part is the full estimate minus the
direct one, both drawn with the same sampler seed per ray so that their first vertices
coincide. Estimates come as two independent halves (noise removal as in
:func:`prtcore.reference.fibres.noise_corrected_error`).

Shared with prtcore: the hair (polylines and radii), the lights' meaning (point: intensity
as radiant intensity, directional: illuminance as irradiance), the texels' arc intervals.
Not shared: geometry (round curves with round joints, not triangulated tubes), ray
tracing, sampling, shading normals.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from prtcore.core.scene import Light
from prtcore.receivers.strands import StrandSpace, axis_frame, interp_points

#: where the query rays start, in fibre radii from the axis
START_RADII = 1.02


def _write_curves(space: StrandSpace, path: Path) -> None:
    """Mitsuba's curve text format: ``x y z radius`` per control point, curves separated
    by an empty line."""
    h = space.hair
    with open(path, "w") as f:
        for s in range(h.strand_count):
            a, b = h.offsets[s], h.offsets[s + 1]
            for p, t in zip(h.points[a:b], h.thickness[a:b], strict=True):
                f.write(f"{float(p[0])!r} {float(p[1])!r} {float(p[2])!r} {float(t) / 2!r}\n")
            f.write("\n")


def _emitter(light: Light) -> dict:
    rgb = {"type": "rgb", "value": (np.asarray(light.color) * light.intensity).tolist()}
    if light.type == "point":
        return {"type": "point", "position": np.asarray(light.position).tolist(),
                "intensity": rgb}
    if light.type == "directional":
        return {"type": "directional", "direction": np.asarray(light.direction).tolist(),
                "irradiance": rgb}
    raise ValueError(f"mitsuba_fibre_indirect: {light.type!r} lights are not mapped")


def mitsuba_fibre_indirect(space: StrandSpace, lights: Sequence[Light], texels: np.ndarray,
                           samples: int, seed: int, max_depth: int = 64
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Indirect outgoing radiance of ``texels`` (n,) for each light, as two independent
    halves of ``samples`` // 2 rays each: (a, b), each (n, K, 3) float64. The hair must
    have one colour (one Mitsuba BSDF)."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    hair = space.hair
    color = hair.color[0]
    if not np.allclose(hair.color, color):
        raise ValueError("mitsuba_fibre_indirect: the hair must have one colour")
    texels = np.asarray(texels, dtype=np.int64)
    rng = np.random.default_rng(seed)
    half = samples // 2
    n = len(texels)
    strand = np.repeat(space.strand[texels], 2 * half)
    lo = np.repeat(space.arc[texels, 0], 2 * half)
    hi = np.repeat(space.arc[texels, 1], 2 * half)
    arc = lo + rng.random(len(strand)) * (hi - lo)
    axis, tangent, u = axis_frame(hair, strand, arc)
    phi = 2 * np.pi * rng.random(len(strand))
    normal = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * np.cross(tangent, u)
    radius = interp_points(hair, hair.thickness[:, None] / 2, strand, arc)[:, 0]
    origin = axis + (START_RADII * radius)[:, None] * normal
    out = np.zeros((n * 2 * half, len(lights), 3))
    with tempfile.TemporaryDirectory() as tmp:
        curves = Path(tmp) / "hair.txt"
        _write_curves(space, curves)
        bsdf = {"type": "diffuse", "reflectance": {"type": "rgb",
                                                   "value": np.clip(color, 0, 0.99).tolist()}}
        full_i = mi.load_dict({"type": "path", "max_depth": max_depth})
        direct_i = mi.load_dict({"type": "path", "max_depth": 2})
        sampler = mi.load_dict({"type": "independent"})
        for k, light in enumerate(lights):
            scene = mi.load_dict({"type": "scene", "hair": {"type": "linearcurve",
                                                            "filename": str(curves),
                                                            "bsdf": bsdf},
                                  "light": _emitter(light)})
            for i in range(len(origin)):
                ray = mi.Ray3f(mi.Point3f(*origin[i]), mi.Vector3f(*(-normal[i])))
                sampler.seed(int(seed) * 1_000_003 + i)
                full, _, _ = full_i.sample(scene, sampler, ray)
                sampler.seed(int(seed) * 1_000_003 + i)
                direct, _, _ = direct_i.sample(scene, sampler, ray)
                out[i, k] = np.array(full) - np.array(direct)
    out = out.reshape(n, 2, half, len(lights), 3)
    return out[:, 0].mean(axis=1), out[:, 1].mean(axis=1)
