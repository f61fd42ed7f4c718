"""Independent Monte Carlo reference for light in hair with the Chiang et al. 2016 fibre
(``hair.fibre = "chiang"``): the ground truth :mod:`prtcore.transport.fibre_chiang` is
checked against.

It shares the hair, the strand texels, the fibre tubes (as occlusion proxies), the ray
tracer, the light evaluation and :func:`prtcore.core.bcsdf.scattering`, but none of the
fast path's shortcuts: no directional-albedo table, no texel → texel operator, no
isotropic outgoing radiance at the fibre hit (every hit is shaded with the BCSDF toward
the direction the path came from), no iteration to a fixed point.

A texel stores ``L̄ = (1/π²) ∫ L_o(ωo) cos θo dωo`` averaged over its arc interval
(:mod:`prtcore.core.bcsdf`). Estimator: a point uniform over the texel's arc, a view
direction ωo with density cos θo / π² (a cosine direction about a uniformly random radial
normal), then ``L_o(ωo)`` at that fibre as at any path vertex. At a vertex on a fibre of
tangent t, seen from ωo, with an impact offset h uniform in [−1, 1]:

* next-event estimation, ``β · S(ωo, ωl, h) · E⊥_l · V`` per light, E⊥ the light's
  irradiance on a plane facing it and V its visibility from a point of the fibre's lit
  half (an azimuth ψ from the side facing the light with density cos ψ / 2, which is the
  fast path's cosine-weighted visibility over the fibre surface, in expectation) — counted
  from the second vertex on (the texel's own direct light is not indirect);
* continuation along ωi drawn by :func:`prtcore.core.bcsdf.sample_scattering` (pbrt's
  importance sampling of the lobes), ``β ← β · S/pdf``, from the tube's circumscribed
  cylinder on the side facing ωi; the next hit's ωo is −ωi.

σ_a along the fibre is interpolated between the hair's points. Russian roulette after
``rr_depth`` vertices, as :mod:`prtcore.reference.fibres`; a miss or a mesh hit ends the
path (the mesh only occludes). Two independent halves, for the noise to be removed.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from prtcore.core.bcsdf import ChiangParams, sample_scattering, scattering
from prtcore.core.fibres import FibreMesh, facing, fibre_at_hits, outside_offset
from prtcore.core.geometry import orthonormal_frame
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.emitters.environment_light import environment_radiance
from prtcore.emitters.punctual import irradiance, unshadowed_irradiance
from prtcore.receivers.strands import StrandSpace, axis_frame, interp_points
from prtcore.reference.fibres import cosine_about, roulette, two_halves

#: the fibre's outgoing radiance at a hit, by name (:func:`chiang_reference`): the
#: azimuthal orders its projection keeps (None: the BCSDF's own, toward the path)
EXITANCE_ORDERS = {"exact": None, "isotropic": 0, "linear": 1, "quadratic": 2,
                   "second_order": 3, "longitudinal_4": 5, "longitudinal_6": 7}


def projection_kernel(tangent: np.ndarray, w: np.ndarray, target: np.ndarray,
                      orders: int) -> np.ndarray:
    """(n,) reproducing kernel ``k(w, target)`` of the weighted projection (weight
    cos θ / π² over the sphere) onto {1} (orders 0), {1, sin θ, cos θ cos φ, cos θ sin φ}
    (1) and also cos² θ (cos 2φ, sin 2φ) (2), in the frames of ``tangent`` (n, 3): for
    w drawn with that density, ``E[k(w, target) f(w)]`` is the projection of f evaluated at
    ``target``. Orders 5 and 7 (``longitudinal_4``, ``longitudinal_6``, diagnostics the
    transport does not carry) add U_3 … U_{orders−1} of sin θ (:func:`chebyshev_u`).
    Duals: 1, 4 sin θ, 8/3 cos θ (cos φ, sin φ), 16/5 cos² θ (cos 2φ, sin 2φ)."""
    k = np.ones(len(w))
    if orders >= 1:
        s1 = np.einsum("ij,ij->i", w, tangent)
        s2 = np.einsum("ij,ij->i", target, tangent)
        perp = np.einsum("ij,ij->i", w, target) - s1 * s2  # cos θ cos θ* cos(φ − φ*)
        k += 4 * s1 * s2 + 8 / 3 * perp
        if orders >= 2:
            k += 16 / 5 * (2 * perp ** 2 - (1 - s1 ** 2) * (1 - s2 ** 2))
        if orders >= 3:  # the rest of second order: (sin² θ − 1/4) and sin θ · ω⊥
            k += 16 * (s1 ** 2 - 0.25) * (s2 ** 2 - 0.25) + 16 * s1 * s2 * perp
        for n in range(3, orders):  # longitudinal_*: U_3 … U_{orders−1} of sin θ alone
            k += chebyshev_u(n, s1) * chebyshev_u(n, s2)
    return k


def chebyshev_u(n: int, x: np.ndarray) -> np.ndarray:
    """(m,) U_n(x), the Chebyshev polynomial of the second kind: with x = sin θ these are
    orthonormal under the weight cos θ / π² over the sphere (U_0 = 1, U_1 = 2 sin θ,
    U_2 = 4 (sin² θ − 1/4): the longitudinal terms of the exitance's orders)."""
    a, b = np.ones_like(x), 2 * x
    if n == 0:
        return a
    for _ in range(n - 1):
        a, b = b, 2 * x * b - a
    return b


def random_radial(tangent: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) unit radial directions of uniformly random azimuth about ``tangent``."""
    u, v = orthonormal_frame(tangent)
    phi = 2 * np.pi * rng.random(len(tangent))
    return np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v


def _lit_side(tangent: np.ndarray, toward: np.ndarray, rng: np.random.Generator
              ) -> np.ndarray:
    """Radial unit directions on the half of the fibre facing ``toward``, at azimuth ψ from
    its middle with density cos ψ / 2."""
    n = facing(tangent, toward)
    b = np.cross(tangent, n)
    psi = np.arcsin(2 * rng.random(len(n)) - 1)
    return np.cos(psi)[:, None] * n + np.sin(psi)[:, None] * b


def fibre_nee(lights: Sequence[Light], tracer: RayTracer, params: ChiangParams,
              beta: np.ndarray, centre: np.ndarray, tangent: np.ndarray, radius: np.ndarray,
              wo: np.ndarray, sigma: np.ndarray, h: np.ndarray,
              rng: np.random.Generator | None) -> np.ndarray:
    """Next-event estimation at m fibre vertices (the module docstring's first bullet):
    ``β · S(ωo, ωl, h) · E⊥_l · V`` per light, (m, K, 3); for an environment light one
    direction ωi drawn by :func:`~prtcore.core.bcsdf.sample_scattering`, ``β · (S/pdf) ·
    L(ωi) · V(ωi)``. beta, sigma (m, 3); centre, tangent, wo (m, 3); radius, h (m,).
    ``rng`` None (a camera's drawing): V of a punctual light from the point of the fibre
    that faces the light, not from a random point of its lit half (an environment's
    direction is then drawn from a fixed seed)."""
    out = np.zeros((len(centre), len(lights), 3))
    for li, light in enumerate(lights):
        if light.type == "environment":  # one direction from the BCSDF's own sampling
            wi, w = sample_scattering(tangent, wo, h, params,
                                      np.random.default_rng(0) if rng is None else rng, sigma)
            seen = ~tracer.occluded(centre + radius[:, None] * facing(tangent, wi), wi,
                                    tracer.tfar)
            out[:, li] = beta * w * environment_radiance(light, wi) * seen[:, None]
            continue
        _, to_light, _ = unshadowed_irradiance(light, centre, np.tile(
            [0.0, 0.0, 1.0], (len(centre), 1)))
        side = facing(tangent, to_light) if rng is None else _lit_side(tangent, to_light, rng)
        p = centre + radius[:, None] * side
        e = irradiance(light, p, to_light, tracer)  # E⊥ · V: the normal faces the light
        s = scattering(tangent, wo, to_light, h, params, sigma)
        out[:, li] = beta * s * e
    return out


def fibre_starts(space: StrandSpace, off: np.ndarray, sigma_points: np.ndarray,
                 texels: np.ndarray, rng: np.random.Generator) -> tuple:
    """Where paths from strand ``texels`` (n,) start: a point uniform over each texel's arc
    on the axis, its tangent, the outside radius (``off`` (p,) per hair point), σ_a
    (``sigma_points`` (p, 3)) and a view direction ωo with density cos θo / π² over the
    sphere. Returns (centre, tangent, radius, sigma, wo)."""
    hair = space.hair
    strand = space.strand[texels]
    arc = space.arc[texels, 0] + rng.random(len(texels)) * (space.arc[texels, 1]
                                                            - space.arc[texels, 0])
    centre, tangent, _ = axis_frame(hair, strand, arc)
    radius = interp_points(hair, off[:, None], strand, arc)[:, 0]
    sigma = interp_points(hair, sigma_points, strand, arc)
    return centre, tangent, radius, sigma, cosine_about(random_radial(tangent, rng), rng)


def chiang_reference(space: StrandSpace, tracer: RayTracer, mesh: FibreMesh,
                     mesh_faces: int, lights: Sequence[Light], texels: np.ndarray,
                     paths: int, seed: int, params: ChiangParams,
                     sigma_points: np.ndarray, max_depth: int = 64, rr_depth: int = 3,
                     exitance: str = "exact") -> tuple[np.ndarray, np.ndarray]:
    """Indirect ``L̄_ind`` of ``texels`` (n,) int for every light, two independent halves
    of ``paths // 2`` paths each: (a, b), each (n, K, 3) float64. ``params``: the fibre
    (its sigma_a ignored); ``sigma_points`` (p, 3) float64 absorption per unit radius at
    every hair point. ``mesh_faces``: scene triangles before the tubes in ``tracer``.

    exitance : "exact" (the reference) or a diagnostic model of the fast path's: at every
    hit, shade toward a fresh ωo drawn as at the texel (density cos θo / π²) and weight
    it by :func:`projection_kernel` toward where the path came from — "isotropic" (no
    weight: the texel's average), "linear", "quadratic" or "second_order" (its projection
    on those orders, in expectation). The difference from "exact" is the error of that
    model alone. Beyond one bounce the kernels' weights multiply and the
    projected variants' variance explodes: use them at ``max_depth = 1``."""
    texels = np.asarray(texels, dtype=np.int64)
    hair = space.hair
    off = outside_offset(hair, mesh.sides)
    k = len(lights)
    sig_pt = np.asarray(sigma_points, dtype=np.float64)

    def shade(beta, centre, tangent, radius, wo, sigma, h, rng):
        return fibre_nee(lights, tracer, params, beta, centre, tangent, radius, wo, sigma,
                         h, rng)

    def trace(owner: np.ndarray, rng: np.random.Generator, acc: np.ndarray) -> None:
        n = len(owner)
        centre, tangent, radius, sigma, wo = fibre_starts(space, off, sig_pt, texels[owner],
                                                          rng)
        beta = np.ones((n, 3))
        alive = np.arange(n)
        for depth in range(max_depth + 1):  # the texel, then up to max_depth fibre hits
            if not len(alive):
                break
            h = 2 * rng.random(len(alive)) - 1
            tg, c, r, sg = tangent[alive], centre[alive], radius[alive], sigma[alive]
            if depth > 0:
                np.add.at(acc, owner[alive], shade(beta[alive], c, tg, r, wo[alive], sg, h,
                                                   rng))
            if depth == max_depth:
                break
            wi, weight = sample_scattering(tg, wo[alive], h, params, rng, sg)
            beta[alive] *= weight
            hits = tracer.intersect(c + r[:, None] * facing(tg, wi), wi)
            fib = hits.triangle >= mesh_faces
            alive, wi = alive[fib], wi[fib]
            if not len(alive):
                break
            tangent[alive], centre[alive], radius[alive], sigma[alive] = fibre_at_hits(
                hair, mesh, off, sig_pt, hits.triangle[fib] - mesh_faces,
                hits.barycentric[fib])
            wo[alive] = -wi
            if exitance != "exact":  # shade toward a fresh ωo, weighted by the kernel
                fresh = cosine_about(random_radial(tangent[alive], rng), rng)
                beta[alive] *= projection_kernel(tangent[alive], fresh, -wi,
                                                 EXITANCE_ORDERS[exitance])[:, None]
                wo[alive] = fresh
            if depth + 1 >= rr_depth:
                alive = roulette(beta, alive, rng)

    return two_halves(len(texels), k, paths, seed, trace)
