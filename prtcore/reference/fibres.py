"""Independent Monte Carlo reference for light in hair with the diffuse fibre model.

The ground truth the fibre transport (:mod:`prtcore.transport.fibre`) is checked against.
It shares the hair, the strand texels (their arc intervals), the fibre tubes, the ray
tracer and the light evaluation (:func:`prtcore.emitters.punctual.irradiance`), but not the
fast path's shortcuts: no texel → texel operator, no radially constant outgoing radiance
at the hit fibre, no iteration to a fixed point.

Estimator (as :mod:`prtcore.reference.pathtracer` for surfaces): a texel's value is the
azimuth- and arc-averaged outgoing radiance ``L̄ = ρ/π · Ē``. A path starts at a point
uniform over the texel's fibre surface (arc uniform in the interval, azimuth uniform)
with the cylinder's radial normal n0, leaves along a cosine-distributed direction about
n0 and at every fibre hit takes the normal a round fibre would present there
(:func:`prtcore.core.fibres.cylinder_normal`: a uniformly random impact parameter across
the fibre, the tube being only the occlusion proxy), x_j on the circumscribed cylinder
along it, adds next-event estimation ``β · ρ_j/π · E_d(x_j, n_j)``
and continues cosine-distributed about n_j with ``β ← β ρ_j``:

    L̄_ind(texel) = ρ0 · E[ Σ_{j≥1} (Π_{i=1}^{j-1} ρ_i) · ρ_j/π · E_d(x_j, n_j) ].

Rays leave fibres from the tube's circumscribed cylinder (:mod:`prtcore.core.fibres`).
After ``rr_depth`` bounces a path survives with probability ``q = min(1, max_c β_c)``
and is divided by q. A miss ends the path; so does a hit on a mesh (one that only
occludes; :mod:`prtcore.reference.hair_mesh` shades mesh hits, for hair + mesh bakes).

Every estimate comes as two independent halves (a, b) so that the reference's own noise
can be removed from an error: ``noise² ≈ mean((a − b)²) / 4`` per texel.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from prtcore.core.fibres import FibreMesh, cylinder_normal, outside_offset, segment_hits
from prtcore.core.geometry import directions_around
from prtcore.core.materials import clamp_albedo
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.emitters.punctual import irradiance
from prtcore.receivers.strands import StrandSpace, axis_frame, interp_points

#: paths traced together per wavefront
PATH_BATCH = 1 << 16


def irradiance_per_light(lights: Sequence[Light], tracer: RayTracer, points: np.ndarray,
            normals: np.ndarray) -> np.ndarray:
    """(n, K, 3) float64 shadowed irradiance of each light."""
    return np.stack([irradiance(li, points, normals, tracer) for li in lights], axis=1)


def cosine_about(normal: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) cosine-distributed unit directions about unit ``normal`` (n, 3)."""
    n = len(normal)
    return directions_around(normal, np.sqrt(rng.random(n)), 2 * np.pi * rng.random(n))


def two_halves(count: int, k: int, paths: int, seed: int, trace) -> tuple[np.ndarray,
                                                                        np.ndarray]:
    """Two independent estimates, each of ``paths // 2`` paths per receiver: ``trace(owner,
    rng, acc)`` adds the contributions of paths from receivers ``owner`` (n,) int64 to
    ``acc`` (count, k, 3) float64, PATH_BATCH paths a call, drawing from ``rng`` (one
    generator per half, from ``seed``). Returns the two means (a, b)."""
    half = paths // 2
    halves = []
    for h in range(2):
        rng = np.random.default_rng([seed, h])
        acc = np.zeros((count, k, 3))
        owner_all = np.repeat(np.arange(count), half)
        for a in range(0, len(owner_all), PATH_BATCH):
            trace(owner_all[a:a + PATH_BATCH], rng, acc)
        halves.append(acc / half)
    return halves[0], halves[1]


def fibre_vertices(hair, mesh: FibreMesh, off: np.ndarray, rho_pt: np.ndarray,
                   triangle: np.ndarray, barycentric: np.ndarray, direction: np.ndarray,
                   rng: np.random.Generator, radially_averaged: bool = False
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Path vertices at fibre hits (the tubes' own triangle indices (m,), barycentrics
    (m, 3), ray directions (m, 3)): the point on the circumscribed cylinder along the
    normal a round fibre presents to the ray (a uniformly random impact parameter), that
    normal, and the fibre's clamped albedo ``rho_pt`` interpolated along the segment;
    (m, 3) float64 each. ``radially_averaged``: the normal at a uniformly random azimuth
    instead (see :func:`fibre_reference`)."""
    seg, t = segment_hits(mesh, triangle, barycentric)
    p0 = hair.segment_start[seg]
    a0, b0 = hair.points[p0], hair.points[p0 + 1]
    ax = b0 - a0
    ax /= np.linalg.norm(ax, axis=1, keepdims=True)
    n_hit = cylinder_normal(ax, direction, 2 * rng.random(len(direction)) - 1)
    if radially_averaged:
        w = n_hit
        v = np.cross(ax, w)
        psi = 2 * np.pi * rng.random(len(w))
        n_hit = np.cos(psi)[:, None] * w + np.sin(psi)[:, None] * v
    rho = (1 - t)[:, None] * rho_pt[p0] + t[:, None] * rho_pt[p0 + 1]
    r_out = (1 - t) * off[p0] + t * off[p0 + 1]
    return a0 + t[:, None] * (b0 - a0) + r_out[:, None] * n_hit, n_hit, rho


def roulette(beta: np.ndarray, alive: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Russian roulette: path ``alive`` survives with probability q = min(1, max_c |β_c|)
    and is divided by q (``beta`` (n, 3) updated in place); returns the survivors. The
    magnitude: a projection kernel's weight (:func:`prtcore.reference.chiang.
    projection_kernel`) can make β negative, and a path killed for that would drop its
    light from the mean (+26 % on the 10k head's scalp until 2026-12-06)."""
    q = np.minimum(1.0, np.abs(beta[alive]).max(axis=1))
    keep = rng.random(len(alive)) < q
    beta[alive[keep]] /= q[keep, None]
    return alive[keep]


def strand_starts(space: StrandSpace, off: np.ndarray, tex: np.ndarray,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Path starts uniform over strand texels ``tex`` (n,) int64's fibre surface (arc
    uniform in the interval, azimuth uniform), on the circumscribed cylinder of radius
    ``off`` (p,) (:func:`prtcore.core.fibres.outside_offset`): origin and radial unit
    normal, (n, 3) float64 each."""
    n = len(tex)
    strand = space.strand[tex]
    arc = space.arc[tex, 0] + rng.random(n) * (space.arc[tex, 1] - space.arc[tex, 0])
    axis, tangent, u = axis_frame(space.hair, strand, arc)
    phi = 2 * np.pi * rng.random(n)
    normal = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * np.cross(tangent, u)
    radius = interp_points(space.hair, off[:, None], strand, arc)[:, 0]
    return axis + radius[:, None] * normal, normal


def fibre_reference(space: StrandSpace, tracer: RayTracer, mesh: FibreMesh,
                    mesh_faces: int, lights: Sequence[Light], texels: np.ndarray,
                    paths: int, seed: int, max_depth: int = 64, rr_depth: int = 3,
                    radially_averaged: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Indirect ``L̄_ind`` of ``texels`` (n,) for every light, as two independent halves
    of ``paths`` // 2 paths each: (a, b), each (n, K, 3) float64.

    radially_averaged : shade each hit with a normal of uniformly random azimuth about the
        hit fibre instead of its own radial normal — the fast path's radially constant
        outgoing radiance, in expectation; the difference between the two references is
        the error of that approximation alone (a diagnostic, not the reference)."""
    texels = np.asarray(texels, dtype=np.int64)
    hair = space.hair
    rho_tex, _ = clamp_albedo(space.albedo)
    rho_pt, _ = clamp_albedo(hair.color)
    off = outside_offset(hair, mesh.sides)
    k = len(lights)

    def trace(owner: np.ndarray, rng: np.random.Generator, acc: np.ndarray) -> None:
        tex = texels[owner]
        n = len(owner)
        origin, normal = strand_starts(space, off, tex, rng)
        beta = rho_tex[tex].copy()
        alive = np.arange(n)
        for depth in range(1, max_depth + 1):
            if not len(alive):
                break
            d = cosine_about(normal[alive], rng)
            hits = tracer.intersect(origin[alive], d)
            fib = hits.triangle >= mesh_faces
            alive, d = alive[fib], d[fib]
            if not len(alive):
                break
            o_hit, n_hit, rho = fibre_vertices(
                hair, mesh, off, rho_pt, hits.triangle[fib] - mesh_faces,
                hits.barycentric[fib], d, rng, radially_averaged)
            e = irradiance_per_light(lights, tracer, o_hit, n_hit)  # (m, K, 3)
            contrib = (beta[alive] * rho / np.pi)[:, None, :] * e
            np.add.at(acc, owner[alive], contrib)
            beta[alive] *= rho
            origin[alive] = o_hit
            normal[alive] = n_hit
            if depth >= rr_depth:
                alive = roulette(beta, alive, rng)

    return two_halves(len(texels), k, paths, seed, trace)


def noise_corrected_error(fast: np.ndarray | tuple[np.ndarray, np.ndarray], a: np.ndarray,
                          b: np.ndarray) -> dict[str, float]:
    """Error of ``fast`` against the reference (a + b) / 2 with the reference's noise
    removed: ``rrmse = sqrt(max(0, mean((fast − ref)²) − mean((a − b)²)/4)) / rms(ref)``,
    ``bias = mean(fast − ref) / mean(ref)`` and its standard error ``bias_se`` (texels as
    the independent samples); also the raw rRMSE and the reference's own relative noise.
    ``fast`` given as two independent halves (another reference) has its own noise
    removed too."""
    noise = float(np.mean((a - b) ** 2) / 4)
    if isinstance(fast, tuple):
        noise += float(np.mean((fast[0] - fast[1]) ** 2) / 4)
        fast = (fast[0] + fast[1]) / 2
    ref = (a + b) / 2
    raw = float(np.mean((fast - ref) ** 2))
    rms = float(np.sqrt(np.mean(ref ** 2)))
    # standard error of the bias: per-texel mean differences (lights and channels of a
    # texel share its noise) are the independent samples
    per = (fast - ref).reshape(len(ref), -1).mean(axis=1)
    se = float(np.std(per, ddof=1) / np.sqrt(max(len(per), 1))) if len(per) > 1 else 0.0
    return {"rrmse": float(np.sqrt(max(0.0, raw - noise))) / rms,
            "raw_rrmse": float(np.sqrt(raw)) / rms,
            "reference_noise": float(np.sqrt(noise)) / rms,
            "bias": float(np.mean(fast - ref) / np.mean(ref)),
            "bias_se": se / float(np.mean(ref))}
