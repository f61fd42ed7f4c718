"""Independent Monte Carlo reference for the indirect lightmap (`prtcore reference`).

The ground truth the fast transport is checked against, so it shares none of the fast
path's shortcuts: no gather operator, no texel→texel mapping, no iteration to a fixed
point. It shares only the scene, the texel G-buffer (:class:`~prtcore.receivers.texels.TexelSpace`),
light evaluation (:func:`prtcore.emitters.punctual.irradiance`, shadow rays included), the ray
tracer and albedo evaluation (:func:`prtcore.core.materials.albedo_at`, at each hit point).

Estimator
---------
A texel stores outgoing radiance ``L = ρ/π · E``; the indirect lightmap counts only light
that bounced at least once on the asset: ``L_ind(x0) = ρ0/π · E_ind(x0)``. With
``E_ind(x0) = ∫ L_out(x1) cosθ dω = π · E[L_out(x1)]`` under cosine-weighted sampling, and
``L_out(x1) = ρ1/π · (E_d(x1) + E_ind(x1))`` unrolled the same way at every vertex,

    L_ind(x0) = ρ0 · E[ Σ_{j≥1} (Π_{i=1}^{j-1} ρ_i) · ρ_j/π · E_d(x_j) ]

for a path x0 → x1 → x2 … whose directions are cosine-distributed about the shading
normal at each vertex. ``E_d`` (next-event estimation) is the sum over the lights of
:func:`~prtcore.emitters.punctual.irradiance` with shadow rays. After ``rr_depth`` bounces a path
survives Russian roulette with probability ``q = min(1, max_c β_c)`` (β the throughput)
and is divided by ``q``, which keeps the estimator unbiased.

Light sampling (default on): next-event estimation alone is noisy where a light is close
to a surface (``E_d ∝ 1/r²`` spikes on the few paths that land there). So each vertex
x_{j−1} also reaches a vertex y from each light: a ray leaves the light (uniform over the
sphere, the spot's cone, or a disk covering the scene for a directional light), y is its
first hit (area density ``p_l(y)`` ∝ the unoccluded irradiance of a point light), and y
is connected to x_{j−1} by a shadow ray. In area measure the path strategy has density
``p_a(y) = cos_x/π · cos_y/r²``; with the balance heuristic both strategies contribute
``β · ρ_y/π · E_l(y) · p_a/(p_a + p_l)`` (for the path's y: ``V = 1`` by construction; for
the light's y: times the connection's visibility), which sums to the same expectation.

Conventions: a ray that hits the back of a face has entered geometry, where there is no
light: the path ends with no further contribution. A miss ends the path (no
environment). A sampled direction below the geometric plane of its vertex (possible with
interpolated shading normals) ends the path likewise. Path origins are uniform over the
texel's square mapped onto its triangle's plane (``TexelSpace.footprint`` around the
texel centre) intersected with the texel's own triangle, so the texel integrates what it
covers of its triangle. The intersection is clipped exactly
(:func:`~prtcore.receivers.texels.texel_regions`) and sampled directly: a texel that covers 1 % of
its square is sampled as uniformly as a full one. Each origin gets the interpolated
normal at that point and is offset along the geometric normal by the tracer's offset.
ρ0 is the texel's albedo (docs/bundle.md: albedo sampled at the texel). All albedos are
clamped for transport (:func:`~prtcore.core.materials.clamp_albedo`). Origins inside other
geometry (a floor texel under a block: most probe rays from it hit back faces) are left
out of the texel's mean, which is then the mean over the texel's visible part
(``buried_probes``).

Translucent materials (docs/subsurface.md): the boundary sends ρ_b/π · E to both sides,
E the irradiance from outside plus inside. So at a translucent vertex the path goes on
outside (cosine about the shading normal) or inside (cosine about its opposite) with
probability ½ each, its throughput doubled; inside, a volumetric random walk of the
reference's own (:func:`prtcore.reference.medium.medium_walk`: delta tracking with
per-channel weights, Henyey–Greenstein scattering) carries it to the boundary, where the
exit is the next vertex (next-event estimation there as at any vertex; its MIS weight is
1, since the light strategy only reaches vertices seen from outside). For the light
strategy at a translucent vertex the path density is halved (:func:`_connect`).

The paths do not depend on the lights, so :func:`reference_lightmaps` traces them once
for any number of light configurations; light sampling and next-event estimation run per
distinct light, and a configuration sums its lights (linear, as transport is).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack
from dataclasses import dataclass

import numpy as np

from prtcore.core.geometry import directions_around, shading_normals
from prtcore.core.materials import albedo_at, clamp_albedo, translucent_faces
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Scene
from prtcore.emitters.base import emitter_for
from prtcore.emitters.punctual import irradiance, unshadowed_irradiance
from prtcore.receivers.texels import TexelRegions, TexelSpace, sample_texel_regions, texel_regions
from prtcore.reference.medium import medium_walk

#: Paths traced together in one wavefront (fixed, so that results do not depend on how
#: many light configurations share the paths).
PATH_CHUNK = 1 << 16
#: Paths per spp batch (all texels × b samples, b = max(1, PATH_BATCH // texels)).
PATH_BATCH = 1 << 19
#: Default number of bounces before Russian roulette starts.
RR_DEPTH = 3
#: Probe rays per path origin that decide whether it lies inside other geometry.
BURIED_PROBES = 4


def default_tracer(scene: Scene) -> RayTracer:
    """A :class:`RayTracer` over the scene's triangles, scaled to its radius."""
    return RayTracer(scene.positions, scene.faces, scene.radius)


def cosine_directions(normals: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Cosine-weighted directions about unit normals (Malley's method).

    normals : (n, 3) float64 unit; u : (n, 2) float64 uniform in [0, 1).
    Returns (n, 3) float64 unit directions with pdf ``cosθ/π``.
    """
    return directions_around(normals, np.sqrt(np.clip(1.0 - u[:, 0], 0.0, None)),
                             2.0 * math.pi * u[:, 1])


def direct_irradiance(lights: Sequence[Light], points: np.ndarray, normals: np.ndarray,
                      tracer: RayTracer | None) -> np.ndarray:
    """Sum over the lights of shadowed irradiance. points, normals : (n, 3) float64.
    Returns (n, 3) float64."""
    e = np.zeros((len(points), 3))
    if len(points) == 0:
        return e
    for light in lights:
        e += irradiance(light, points, normals, tracer)
    return e


def reference_direct(scene: Scene, texels: TexelSpace, lights: Sequence[Light],
                     tracer: RayTracer | None = None) -> np.ndarray:
    """Direct outgoing radiance ``ρ/π · E_d`` at the texel sample points (no jitter).

    Returns (t, 3) float64; ρ is the texel albedo clamped for transport.
    """
    tracer = tracer if tracer is not None else default_tracer(scene)
    rho, _ = clamp_albedo(np.asarray(texels.albedo, dtype=np.float64))
    e = direct_irradiance(lights, np.asarray(texels.position, np.float64),
                          np.asarray(texels.normal, np.float64), tracer)
    return rho / math.pi * e


def _buried(tracer: RayTracer, origin: np.ndarray, normal: np.ndarray, face_normal: np.ndarray,
            probes: int, rng: np.random.Generator) -> np.ndarray:
    """(m,) bool: more than half of ``probes`` cosine rays from each origin (those above
    its geometric plane) hit back faces — the origin lies inside other geometry."""
    m = len(origin)
    owner = np.repeat(np.arange(m), probes)
    d = cosine_directions(normal[owner], rng.random((len(owner), 2)))
    above = np.flatnonzero(np.einsum("ij,ij->i", d, face_normal[owner]) > 0)
    hits = tracer.intersect(origin[owner[above]], d[above])
    traced = np.bincount(owner[above], minlength=m)
    back = np.bincount(owner[above], weights=hits.hit & ~hits.front, minlength=m)
    return 2 * back > traced


# ---------------------------------------------------------------------------------------
# Light sampling (the second strategy of multiple importance sampling)


def light_key(light: Light) -> int:
    """A stable 63-bit key of a light's parameters: its random stream, whatever else is
    traced alongside (so results per light do not depend on the other lights)."""
    parts = [light.type, *(float(v).hex() for v in np.ravel(light.color)),
             float(light.intensity).hex(), *(float(v).hex() for v in np.ravel(light.position)),
             *(float(v).hex() for v in np.ravel(light.direction)),
             float(light.inner_cone_angle).hex(), float(light.outer_cone_angle).hex(),
             "none" if light.range is None else float(light.range).hex()]
    digest = hashlib.sha256("|".join(parts).encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1


@dataclass(frozen=True)
class LightSampler:
    """Rays leaving a light, and the area density of their first hits.

    Point: uniform over the sphere; spot: uniform in the outer cone; directional: parallel
    rays through a disk of radius ``disk_radius`` (≥ the scene's bounding sphere) about
    ``disk_centre``, perpendicular to the light. Sampling y ∝ that density puts samples
    where direct light is strong (the density of a point light's first hits is
    ``cos/(4π r²)`` ∝ its irradiance).
    """

    light: Light
    disk_centre: np.ndarray
    disk_radius: float

    @classmethod
    def for_scene(cls, light: Light, scene: Scene) -> LightSampler:
        return cls(light, np.asarray(scene.center, np.float64), 1.01 * max(scene.radius, 1e-30))

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """n rays: origins (n, 3), unit directions (n, 3) float64."""
        return emitter_for(self.light).sample_rays(self.light, rng, n, self.disk_centre,
                                                    self.disk_radius)

    def density(self, points: np.ndarray, face_normals: np.ndarray) -> np.ndarray:
        """(n,) area density of first hits at surface points that the light reaches
        unoccluded (callers only ask where the light's irradiance is > 0)."""
        return emitter_for(self.light).first_hit_density(self.light, points, face_normals,
                                                          self.disk_radius)


def _balance(p_this: np.ndarray, p_other: np.ndarray) -> np.ndarray:
    """Balance-heuristic weight p_this / (p_this + p_other) (1 where both vanish)."""
    den = p_this + p_other
    return np.divide(p_this, den, out=np.ones_like(den), where=den > 0)


def _connect(scene: Scene, tracer: RayTracer, sampler: LightSampler, rng: np.random.Generator,
             px: np.ndarray, nx: np.ndarray, gx: np.ndarray, half: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """The light strategy at path vertices x (positions px, shading normals nx, geometric
    normals gx; (n, 3) each): a ray from the light finds a surface point y, which is
    connected to x. Returns the rows of x that got light and their (r, 3) MIS-weighted
    contributions ``ρ_y/π · E(y) · p_path/(p_path + p_light)`` (to be multiplied by the
    path throughput into y). half : (n,) bool, the translucent vertices, whose path
    strategy goes outside with probability ½ (p_path halved, the contribution doubled:
    ``f / (p_path/2 + p_light)``)."""
    origin, w = sampler.sample(rng, len(px))
    hits = tracer.intersect(origin, w)
    rows = np.flatnonzero(hits.hit)
    tri, bary = hits.triangle[rows], hits.barycentric[rows]
    gy = tracer.face_normals[tri]
    y = tracer.surface_point(tri, bary)
    ny = shading_normals(scene, tri, bary, gy)
    e, _, _ = unshadowed_irradiance(sampler.light, y, ny)  # y is the light ray's first hit
    delta = y - px[rows]
    r2 = np.einsum("ij,ij->i", delta, delta)
    r = np.sqrt(r2)
    ok = (e.max(axis=1) > 0) & (r > 0)
    omega = np.divide(delta, r[:, None], out=np.zeros_like(delta), where=r[:, None] > 0)
    cos_x = np.einsum("ij,ij->i", nx[rows], omega)
    cos_y = -np.einsum("ij,ij->i", gy, omega)  # > 0: x sees the front of y
    ok &= (cos_x > 0) & (np.einsum("ij,ij->i", gx[rows], omega) > 0) & (cos_y > 0)
    sel = np.flatnonzero(ok)
    vis = tracer.visible(px[rows[sel]], gx[rows[sel]], y[sel])
    sel = sel[vis]
    if len(sel) == 0:
        return np.zeros(0, np.int64), np.zeros((0, 3))
    p_path = cos_x[sel] / math.pi * cos_y[sel] / r2[sel]
    p_light = sampler.density(y[sel], gy[sel])
    rho, _ = clamp_albedo(albedo_at(scene, tri[sel], bary[sel]))
    if half is None or not half.any():
        return rows[sel], rho * (e[sel] / math.pi) * _balance(p_path, p_light)[:, None]
    side = np.where(half[rows[sel]], 0.5, 1.0)
    return rows[sel], rho * (e[sel] / math.pi) * (
        _balance(p_path * side, p_light) / side)[:, None]


# ---------------------------------------------------------------------------------------
# Paths


def _trace_paths(scene: Scene, tracer: RayTracer, samplers: Sequence[LightSampler],
                 light_rngs: Sequence[np.random.Generator] | None, texels: TexelSpace,
                 regions: TexelRegions, tex: np.ndarray, rng: np.random.Generator,
                 max_depth: int, rr_depth: int, buried_probes: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """One wavefront: a path from each texel in ``tex`` ((m,) int64), shared by every
    light. Returns the (u, m, 3) float64 single-path estimates of ρ0⁻¹ · L_ind per light
    (the texel albedo ρ0 is applied by the caller) and (m,) bool "counts" (False: the
    origin was found buried and the path is left out of its texel's mean).

    With ``light_rngs`` (one generator per light), each vertex is also connected to a
    point found by a ray from each light, and both strategies are weighted by the balance
    heuristic; without, it is plain next-event estimation at each path vertex."""
    m = len(tex)
    value = np.zeros((len(samplers), m, 3))
    tri0 = texels.triangle[tex]
    bary0 = sample_texel_regions(regions, tex, rng)
    gx = tracer.face_normals[tri0]
    px = tracer.surface_point(tri0, bary0)
    nx = shading_normals(scene, tri0, bary0, gx)
    counts = np.ones(m, dtype=bool)
    if buried_probes > 0:
        counts = ~_buried(tracer, px + gx * tracer.offset, nx, gx, buried_probes, rng)
    # compact state of the live paths at vertex x: index into the wavefront, position,
    # normals, and the throughput Π ρ_i into the next vertex
    idx = np.flatnonzero(counts)
    px, nx, gx, tx = px[idx], nx[idx], gx[idx], tri0[idx]
    beta = np.ones((len(idx), 3))
    translucent = translucent_faces(scene)
    media = translucent.any()
    for depth in range(1, max_depth + 1):
        if len(idx) == 0:
            break
        half = translucent[tx] if media else None
        if light_rngs is not None:
            for u, (sampler, lrng) in enumerate(zip(samplers, light_rngs, strict=True)):
                rows, contrib = _connect(scene, tracer, sampler, lrng, px, nx, gx, half)
                value[u, idx[rows]] += beta[rows] * contrib
        d = cosine_directions(nx, rng.random((len(idx), 2)))
        if media:  # a translucent vertex goes inside with probability ½ (weight 2)
            inside = half & (rng.random(len(idx)) < 0.5)
            d[inside] = cosine_directions(-nx[inside], rng.random((int(inside.sum()), 2)))
            beta = beta * np.where(half, 2.0, 1.0)[:, None]
            walk = _through_media(scene, tracer, rng, idx[inside], beta[inside],
                                  px[inside], gx[inside], d[inside], tx[inside])
            out = ~inside
            idx, beta, d, px, nx, gx, half = (idx[out], beta[out], d[out], px[out],
                                              nx[out], gx[out], half[out])
        cos_x = np.einsum("ij,ij->i", d, nx)
        up = np.einsum("ij,ij->i", d, gx) > 0  # below the geometric plane: ends
        idx, beta, d, px, gx, cos_x = idx[up], beta[up], d[up], px[up], gx[up], cos_x[up]
        hits = tracer.intersect(px + gx * tracer.offset, d)
        keep = hits.hit & hits.front  # back face: inside geometry, no light; miss: nothing
        idx, beta, d, cos_x = idx[keep], beta[keep], d[keep], cos_x[keep]
        tri, bary, dist = hits.triangle[keep], hits.barycentric[keep], hits.t[keep]
        p_path = None
        if light_rngs is not None:
            p_path = cos_x / math.pi * -np.einsum("ij,ij->i", tracer.face_normals[tri], d) \
                / np.maximum(dist * dist, np.finfo(np.float64).tiny)
            if media:  # the path went outside with probability ½ at translucent vertices
                p_path = p_path * np.where(half[up][keep], 0.5, 1.0)
        if media:  # the walks' exits join as vertices no light strategy reaches
            idx = np.concatenate([idx, walk[0]])
            beta = np.concatenate([beta, walk[1]])
            tri = np.concatenate([tri, walk[2]])
            bary = np.concatenate([bary, walk[3]])
            if p_path is not None:
                p_path = np.concatenate([p_path, np.full(len(walk[0]), np.inf)])
        if len(idx) == 0:
            break
        fn = tracer.face_normals[tri]
        p = tracer.surface_point(tri, bary)
        ns = shading_normals(scene, tri, bary, fn)
        rho, _ = clamp_albedo(albedo_at(scene, tri, bary))
        weight = beta * rho * (1.0 / math.pi)
        for u, sampler in enumerate(samplers):
            e = irradiance(sampler.light, p, ns, tracer)
            if light_rngs is not None:
                # exits of walks (p_path = ∞) are reached by no light strategy: weight 1
                lit = np.flatnonzero((e.max(axis=1) > 0) & np.isfinite(p_path))
                e[lit] *= _balance(p_path[lit], sampler.density(p[lit], fn[lit]))[:, None]
            value[u, idx] += weight * e
        if depth == max_depth:
            break
        beta = beta * rho
        if depth >= rr_depth:
            q = np.minimum(1.0, beta.max(axis=1))
            live = rng.random(len(idx)) < q
            idx, p, ns, fn, tri = idx[live], p[live], ns[live], fn[live], tri[live]
            beta = beta[live] / q[live, None]
        px, nx, gx, tx = p, ns, fn, tri
    return value, counts


def _through_media(scene: Scene, tracer: RayTracer, rng: np.random.Generator,
                   idx: np.ndarray, beta: np.ndarray, px: np.ndarray, gx: np.ndarray,
                   d: np.ndarray, tri: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Paths entering translucent vertices (positions px, geometric normals gx, inward
    directions d, triangles tri; (n, …)) walk through their material's medium
    (:func:`prtcore.reference.medium.medium_walk`). Returns the exits' path index, the
    throughput into the exit (beta × the walk's weight) (m, 3), triangle and barycentric.
    Directions not below the face's plane end the path, like the outside's."""
    down = np.einsum("ij,ij->i", d, gx) < 0
    parts = []
    mat = scene.face_material[tri]
    for mi in np.unique(mat[down]):
        sel = np.flatnonzero(down & (mat == mi))
        medium = scene.materials[int(mi)].subsurface
        k, t_exit, b_exit, _, w = medium_walk(
            tracer, medium, scene.face_material == mi, px[sel] - gx[sel] * tracer.offset,
            d[sel], rng)
        parts.append((idx[sel[k]], beta[sel[k]] * w, t_exit, b_exit))
    if not parts:
        return (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64),
                np.zeros((0, 3)))
    return tuple(np.concatenate(p) for p in zip(*parts, strict=True))


def reference_lightmaps(scene: Scene, texels: TexelSpace,
                        configurations: Sequence[Sequence[Light]], spp: int, seed: int = 0,
                        tracer: RayTracer | None = None, timer: StageTimer | None = None,
                        max_depth: int = 64, *, rr_depth: int = RR_DEPTH,
                        light_sampling: bool = True, buried_probes: int = BURIED_PROBES,
                        threads: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Path-traced indirect outgoing radiance per texel for k light configurations at once.

    The paths do not depend on the lights, so all configurations share them (each estimate
    is unbiased on its own; their errors are correlated). Each distinct light is estimated
    once, with its own random stream keyed by its parameters (:func:`light_key`), and a
    configuration is the sum of its lights: a configuration's result is the same whether
    it is computed alone or with others, and transport is exactly linear in the lights.

    configurations : k sequences of lights (each summed); spp : paths per texel, ≥ 1;
    seed : the one seed of every random choice (same inputs + seed → bit-identical output);
    max_depth : most bounces on the asset (1 = light that bounced exactly once);
    rr_depth : bounces before Russian roulette (≥ max_depth disables it);
    light_sampling : also reach each path vertex's next vertex from the lights (rays
    leaving the light, connected to the vertex) and combine both strategies by multiple
    importance sampling (balance heuristic) — much lower variance where lights are close
    to surfaces; False: next-event estimation at path vertices only (same expectation);
    buried_probes : n > 0 (default BURIED_PROBES) — each origin is first probed with n
    cosine rays and, when most of them hit back faces, it lies inside other geometry (a
    floor texel partly under a block) and its path is left out, so a partly buried texel
    averages over its visible part, the part that is ever seen (drop samples
    inside geometry; the fast transport does the same; costs n rays per path); 0 — no
    probes: such paths see back faces and bring 0, so the texel averages over its whole
    footprint and comes out darker at contacts;
    threads : wavefronts traced at once (default: the tracer's thread count). Each
    wavefront of PATH_CHUNK paths draws from its own generators,
    ``SeedSequence(seed, spawn_key=(batch, first path[, 1, light key]))``, and sums are
    taken in a fixed order, so the result does not depend on ``threads``.
    Returns ``mean`` (k, t, 3) float64 and ``stderr`` (k, t, 3) float64, the standard error
    of the mean estimated from the per-path samples (0 with fewer than 2 samples; a texel
    whose every origin is buried gets 0).
    Memory: about threads · (u + 12) · PATH_CHUNK · 24 bytes besides the outputs, u the
    number of distinct lights.
    """
    if int(spp) != spp or spp < 1:
        raise ValueError(f"reference: spp must be an integer ≥ 1, got {spp!r}")
    if int(max_depth) != max_depth or max_depth < 1:
        raise ValueError(f"reference: max_depth must be an integer ≥ 1, got {max_depth!r}")
    if int(buried_probes) != buried_probes or buried_probes < 0:
        raise ValueError(f"reference: buried_probes must be an integer ≥ 0, "
                         f"got {buried_probes!r}")
    spp, max_depth, buried_probes = int(spp), int(max_depth), int(buried_probes)
    tracer = tracer if tracer is not None else default_tracer(scene)
    configs = [tuple(c) for c in configurations]
    t, k = texels.count, len(configs)
    total = np.zeros((k, t, 3))
    total_sq = np.zeros((k, t, 3))
    n = np.zeros(t)
    # distinct lights, and which of them each configuration sums
    keys: dict[int, int] = {}
    samplers: list[LightSampler] = []
    members: list[list[int]] = []
    for cfg in configs:
        members.append([])
        for light in cfg:
            key = light_key(light)
            if key not in keys:
                keys[key] = len(samplers)
                samplers.append(LightSampler.for_scene(light, scene))
            members[-1].append(keys[key])
    light_keys = list(keys)
    if t == 0 or not samplers:
        return total, total_sq
    rho0, _ = clamp_albedo(np.asarray(texels.albedo, dtype=np.float64))
    regions = texel_regions(scene, texels)
    per_batch = max(1, min(spp, PATH_BATCH // t))
    batches = [min(per_batch, spp - s) for s in range(0, spp, per_batch)]
    workers = max(1, int(threads)) if threads is not None else tracer.threads

    def chunk(batch: int, start: int, ti: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # own generators per (batch, chunk[, light]): results do not depend on threads
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(batch, start)))
        light_rngs = [np.random.default_rng(np.random.SeedSequence(
            seed, spawn_key=(batch, start, 1, key))) for key in light_keys] \
            if light_sampling else None
        v, counts = _trace_paths(scene, tracer, samplers, light_rngs, texels, regions, ti,
                                 rng, max_depth, rr_depth, buried_probes)
        return v * rho0[ti], counts

    def run(pool: ThreadPoolExecutor | None) -> None:
        it = timer.bar(batches, "reference spp", total=len(batches)) if timer else batches
        for i, b in enumerate(it):
            tex = np.tile(np.arange(t, dtype=np.int64), b)
            starts = range(0, len(tex), PATH_CHUNK)
            parts = [tex[s:s + PATH_CHUNK] for s in starts]
            if pool is None:
                results = (chunk(i, s, ti) for s, ti in zip(starts, parts, strict=True))
            else:
                results = pool.map(chunk, [i] * len(parts), starts, parts)
            for ti, (v, counts) in zip(parts, results, strict=True):  # fixed order
                n[:] += np.bincount(ti[counts], minlength=t)
                for j, mem in enumerate(members):
                    if not mem:
                        continue
                    vj = v[mem[0]] if len(mem) == 1 else v[mem].sum(axis=0)
                    for c in range(3):
                        total[j, :, c] += np.bincount(ti, weights=vj[:, c], minlength=t)
                        total_sq[j, :, c] += np.bincount(ti, weights=vj[:, c] ** 2,
                                                         minlength=t)

    with ExitStack() as stack:
        if timer is not None:
            stack.enter_context(timer.stage("reference"))
        pool = stack.enter_context(ThreadPoolExecutor(workers)) if workers > 1 else None
        run(pool)
    nn = n[None, :, None]
    mean = np.divide(total, nn, out=np.zeros_like(total), where=nn > 0)
    var = np.divide(np.clip(total_sq - nn * mean * mean, 0.0, None), nn * (nn - 1),
                    out=np.zeros_like(total), where=nn > 1)
    return mean, np.sqrt(var)


def reference_lightmap_with_error(scene: Scene, texels: TexelSpace, lights: Sequence[Light],
                                  spp: int, seed: int = 0, tracer: RayTracer | None = None,
                                  timer: StageTimer | None = None, max_depth: int = 64, *,
                                  rr_depth: int = RR_DEPTH, light_sampling: bool = True,
                                  buried_probes: int = BURIED_PROBES, threads: int | None = None
                                  ) -> tuple[np.ndarray, np.ndarray]:
    """Indirect outgoing radiance per texel under ``lights`` (summed) and its standard
    error: ``mean``, ``stderr`` (t, 3) float64 (see :func:`reference_lightmaps`)."""
    mean, err = reference_lightmaps(scene, texels, [lights], spp, seed, tracer, timer,
                                    max_depth, rr_depth=rr_depth,
                                    light_sampling=light_sampling,
                                    buried_probes=buried_probes, threads=threads)
    return mean[0], err[0]


def reference_lightmap(scene: Scene, texels: TexelSpace, lights: Sequence[Light], spp: int,
                       seed: int = 0, tracer: RayTracer | None = None,
                       timer: StageTimer | None = None, max_depth: int = 64, *,
                       rr_depth: int = RR_DEPTH, light_sampling: bool = True,
                       buried_probes: int = BURIED_PROBES, threads: int | None = None
                       ) -> np.ndarray:
    """Path-traced indirect outgoing radiance per texel under ``lights`` (summed):
    (t, 3) float64 (see :func:`reference_lightmaps`)."""
    return reference_lightmap_with_error(scene, texels, lights, spp, seed, tracer, timer,
                                         max_depth, rr_depth=rr_depth,
                                         light_sampling=light_sampling,
                                         buried_probes=buried_probes, threads=threads)[0]
