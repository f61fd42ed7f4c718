"""Path-traced reference under a distant environment (issue 17), independent of SH.

Outgoing radiance ``ρ/π ∫ L_in(ω) cos θ dω`` at surface samples, where ``L_in`` is the
environment's own radiance (:meth:`Environment.radiance`, pixel lookup — never its SH
projection) seen through the scene, after up to ``max_depth − 1`` diffuse bounces on the
asset (``max_depth = 1``: direct environment light only, the reference of shadowed
transfer; ``2``: plus one bounce, the reference of T⁰ + T¹).

Estimator, at each path vertex x with throughput β (β = ρ₀ at the sample, times the albedo
of every surface bounced on), two strategies combined by the balance heuristic:

* environment sampling (:class:`EnvironmentSampler`, pdf p_e): a direction ω_e above both
  the shading and geometric planes that escapes the scene adds
  ``β/π · L(ω_e) cos θ_e / p_e · p_e/(p_e + cos θ_e/π)``;
* cosine sampling (pdf cos θ/π): a direction that escapes adds
  ``β · L(ω) · (cos θ/π)/(cos θ/π + p_e(ω))``; one that hits a front face continues the path
  there (β ← β ρ_y); a back face or a direction below the geometric plane ends the path.

Conventions are the project path tracer's (:mod:`prtcore.reference.pathtracer`): albedos
clamped for transport, the ray offset along the geometric normal, one seed for every
random choice (each chunk of samples draws from ``SeedSequence(seed, spawn_key=(pass,
chunk start))``). Two independent halves of the samples give the noise estimate the
accuracy checks remove (DESIGN: corrected err² = raw err² − noise²).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from prtcore.core.geometry import shading_normals
from prtcore.core.materials import albedo_at, clamp_albedo
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Scene
from prtcore.emitters.environment import Environment, EnvironmentSampler
from prtcore.reference.pathtracer import cosine_directions

#: Samples traced together.
CHUNK = 1 << 16


@dataclass(frozen=True)
class EnvironmentReference:
    """mean, half_a, half_b : (n, 3) float64 outgoing radiance (all samples, and each
    independent half); noise2 : (n,) float64 per-sample-point estimate of the squared noise
    of ``mean`` averaged over RGB, ``mean((a − b)²)/4``; spp : samples per point."""

    mean: np.ndarray
    half_a: np.ndarray
    half_b: np.ndarray
    noise2: np.ndarray
    spp: int


def _balance(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    den = p + q
    return np.divide(p, den, out=np.ones_like(den), where=den > 0)


def _trace(scene: Scene, tracer: RayTracer, env: Environment, sampler: EnvironmentSampler,
           px: np.ndarray, nx: np.ndarray, gx: np.ndarray, beta: np.ndarray,
           rng: np.random.Generator, max_depth: int) -> np.ndarray:
    """(m, 3) single-sample estimates for paths starting at (px, nx, gx) with throughput
    beta (m, 3) (ρ₀ applied)."""
    m = len(px)
    value = np.zeros((m, 3))
    idx = np.arange(m)
    for depth in range(1, max_depth + 1):
        if len(idx) == 0:
            break
        origin = px + gx * tracer.offset
        # environment sampling
        we, pe = sampler.sample(rng, len(idx))
        cos_e = np.einsum("ij,ij->i", we, nx)
        ok = np.flatnonzero((cos_e > 0) & (np.einsum("ij,ij->i", we, gx) > 0) & (pe > 0))
        if len(ok):
            free = ~tracer.occluded(origin[ok], we[ok])
            ok = ok[free]
            w = _balance(pe[ok], cos_e[ok] / math.pi)
            value[idx[ok]] += (beta[ok] / math.pi * env.radiance(we[ok])
                               * (cos_e[ok] / pe[ok] * w)[:, None])
        # cosine sampling
        d = cosine_directions(nx, rng.random((len(idx), 2)))
        cos_b = np.einsum("ij,ij->i", d, nx)
        up = np.einsum("ij,ij->i", d, gx) > 0
        idx, beta, d, origin, cos_b = idx[up], beta[up], d[up], origin[up], cos_b[up]
        hits = tracer.intersect(origin, d)
        miss = ~hits.hit
        if miss.any():
            w = _balance(cos_b[miss] / math.pi, sampler.pdf(d[miss]))
            value[idx[miss]] += beta[miss] * env.radiance(d[miss]) * w[:, None]
        keep = hits.hit & hits.front
        if depth == max_depth or not keep.any():
            break
        idx, beta = idx[keep], beta[keep]
        tri, bary = hits.triangle[keep], hits.barycentric[keep]
        gx = tracer.face_normals[tri]
        px = tracer.surface_point(tri, bary)
        nx = shading_normals(scene, tri, bary, gx)
        rho, _ = clamp_albedo(albedo_at(scene, tri, bary))
        beta = beta * rho
    return value


def _two_halves(m: int, spp: int, seed: int, estimate) -> EnvironmentReference:
    """Run ``estimate(ti, rng)`` → (len(ti), 3) single-sample estimates for sample points
    ``ti`` over two independent halves of ``spp`` samples per point, in chunks of CHUNK
    with streams ``SeedSequence(seed, spawn_key=(half, chunk start))``."""
    if int(spp) != spp or spp < 2 or spp % 2:
        raise ValueError(f"reference: spp must be an even integer ≥ 2, got {spp!r}")
    halves = []
    for half in range(2):
        total = np.zeros((m, 3))
        idx = np.tile(np.arange(m), int(spp) // 2)
        for start in range(0, len(idx), CHUNK):
            ti = idx[start:start + CHUNK]
            rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(half, start)))
            v = estimate(ti, rng)
            for c in range(3):
                total[:, c] += np.bincount(ti, weights=v[:, c], minlength=m)
        halves.append(total / (spp // 2))
    a, b = halves
    return EnvironmentReference(0.5 * (a + b), a, b, ((a - b) ** 2).mean(axis=1) / 4.0,
                                int(spp))


def reference_environment(scene: Scene, tracer: RayTracer, env: Environment,
                          position: np.ndarray, normal: np.ndarray,
                          geometric_normal: np.ndarray, albedo: np.ndarray, spp: int,
                          seed: int = 0, max_depth: int = 1) -> EnvironmentReference:
    """Outgoing radiance at n surface samples (position, shading normal, geometric normal,
    raw albedo: (n, 3) float64 each) under ``env``, ``spp`` (even, ≥ 2) paths each."""
    if int(max_depth) != max_depth or max_depth < 1:
        raise ValueError(f"reference: max_depth must be an integer ≥ 1, got {max_depth!r}")
    sampler = EnvironmentSampler(env)
    rho0, _ = clamp_albedo(np.asarray(albedo, np.float64))

    def estimate(ti: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return _trace(scene, tracer, env, sampler, position[ti], normal[ti],
                      geometric_normal[ti], rho0[ti], rng, int(max_depth))
    return _two_halves(len(position), spp, seed, estimate)


def reference_phong(tracer: RayTracer, env: Environment, position: np.ndarray,
                    geometric_normal: np.ndarray, reflected: np.ndarray,
                    specular: np.ndarray, exponent: float, spp: int, seed: int = 0,
                    lobe_bands: int | None = None, scene: Scene | None = None
                    ) -> EnvironmentReference:
    """Glossy (Phong) outgoing radiance from direct environment light, by Monte Carlo:
    ``ρ_s ∫ L(ω) V(x, ω) lobe(ω) dω`` with ``lobe = (n+1)/(2π) max(0, ω·r)^n`` about the
    mirror direction r (``reflected`` (m, 3)), or — with ``lobe_bands`` — that lobe's SH
    truncation to ``lobe_bands`` bands (the same band limit as an SH renderer; it may be
    negative). Directions uniform over each point's geometric hemisphere (V = 0 below it),
    ``spp`` (even) per point, two independent halves for the noise. L is the map's pixel
    lookup. position, geometric_normal, specular : (m, 3) float64. With ``scene``, a
    direction that hits a front face at q also brings the diffuse radiance q sends out
    under the environment (one path-traced sample of its direct light, :func:`_trace`):
    the reference of direct + one bounce."""
    from prtcore.core import sh
    from prtcore.core.geometry import directions_around

    kernel = None if lobe_bands is None else sh.zonal_kernel(
        sh.phong_zonal(exponent, lobe_bands))
    spec = np.asarray(specular, np.float64)
    sampler = EnvironmentSampler(env) if scene is not None else None

    def estimate(ti: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        u = rng.random((len(ti), 2))
        gn = geometric_normal[ti]
        d = directions_around(gn, u[:, 0], 2.0 * math.pi * u[:, 1])
        hits = tracer.intersect(position[ti] + gn * tracer.offset, d)
        incident = np.zeros((len(ti), 3))
        free = ~hits.hit
        incident[free] = env.radiance(d[free])
        if scene is not None:
            q = np.flatnonzero(hits.hit & hits.front)
            tri, bary = hits.triangle[q], hits.barycentric[q]
            gq = tracer.face_normals[tri]
            rho, _ = clamp_albedo(albedo_at(scene, tri, bary))
            incident[q] = _trace(scene, tracer, env, sampler, tracer.surface_point(tri, bary),
                                 shading_normals(scene, tri, bary, gq), gq, rho, rng, 1)
        if kernel is None:
            lobe = (exponent + 1.0) / (2.0 * math.pi) * np.clip(
                np.einsum("ij,ij->i", d, reflected[ti]), 0.0, None) ** exponent
        else:
            # the zonal kernel about r evaluated at d: Σ_l k_l Σ_m Y_lm(r) Y_lm(d)
            lobe = np.einsum("il,il->i", sh.basis(d, lobe_bands) * kernel,
                             sh.basis(reflected[ti], lobe_bands))
        return spec[ti] * (2.0 * math.pi * lobe)[:, None] * incident
    return _two_halves(len(position), spp, seed, estimate)
