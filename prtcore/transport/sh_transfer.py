"""Classic PRT transfer in spherical harmonics (Sloan, Kautz & Snyder 2002), diffuse.

For a diffuse point x with albedo ρ and shading normal n, lit by distant radiance
``L(ω) = Σ_i l_i Y_i(ω)``, the outgoing radiance is ``Σ_i T_i l_i`` (per RGB channel) with

* unshadowed: ``T_i = ρ/π ∫ Y_i(ω) max(0, n·ω) dω`` — in closed form, the clamped cosine
  turned to n (:func:`prtcore.core.sh.zonal_to_direction`);
* shadowed: ``T⁰_i = ρ/π ∫ Y_i(ω) V(x, ω) max(0, n·ω) dω`` — estimated with S stratified
  cosine-distributed rays per point: ``T⁰_i ≈ ρ/S Σ_k Y_i(ω_k) V(x, ω_k)``;
* inter-reflected, one bounce (the poster's T₁ from T₀): ``T¹_i(x) = ρ/π ∫ T⁰_i(y(ω))
  (1 − V(x, ω)) max(0, n·ω) dω``, y(ω) the surface point the ray hits (its front face), with
  T⁰ at y read from where the transfer is stored: interpolated from the vertices
  (per-vertex PRT) or looked up in the dilated transfer texture at y's lightmap UV (transfer
  textures). The same rays serve both terms. Total ``T = T⁰ + T¹``.

Conventions as the path tracer's (:mod:`prtcore.reference.pathtracer`): a direction below
the point's geometric plane contributes nothing; so does a ray hitting a back face (it has
entered geometry). Albedos are clamped for transport. Every random choice comes from
``seed``; points are processed in fixed-size chunks with their own streams, so the result
does not depend on the chunking of the caller.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from prtcore.core import sh
from prtcore.core.geometry import (
    directions_around,
    shading_normals,
    stratified_cosine_directions,
)
from prtcore.core.materials import albedo_at, clamp_albedo
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Scene

#: Points whose rays are traced together (fixed: results do not depend on the caller).
POINT_CHUNK = 1024
#: Transfer kinds, from the cheapest.
KINDS = ("unshadowed", "shadowed", "interreflected")


@dataclass(frozen=True)
class SurfaceSamples:
    """Where transfer is computed.

    position, normal (shading, unit), geometric_normal (unit) : (n, 3) float64;
    albedo : (n, 3) float64 raw linear albedo (clamped for transport here).
    """

    position: np.ndarray
    normal: np.ndarray
    geometric_normal: np.ndarray
    albedo: np.ndarray

    @property
    def count(self) -> int:
        return len(self.position)


@dataclass(frozen=True)
class ShTransfer:
    """Transfer vectors: ``coeffs`` (n, 3, L²) float64 — outgoing radiance of point p in
    channel c is ``coeffs[p, c] @ light[:, c]`` for light SH coefficients (L², 3).

    kind : one of :data:`KINDS`; bands : L; samples : rays per point (0 for unshadowed).
    """

    coeffs: np.ndarray
    kind: str
    bands: int
    samples: int

    def radiance(self, light: np.ndarray) -> np.ndarray:
        """(n, 3) float64 outgoing radiance under light SH coefficients ``light`` (L², 3)."""
        return np.einsum("pcl,lc->pc", self.coeffs, np.asarray(light, np.float64))


def vertex_samples(scene: Scene) -> SurfaceSamples:
    """The scene's vertices as transfer samples (per-vertex PRT): each vertex takes the
    shading normal, geometric normal and albedo of one face that uses it (a fixed choice),
    at that corner. Vertices no face uses get a zero albedo."""
    v = len(scene.positions)
    face = np.full(v, -1, dtype=np.int64)
    corner = np.zeros(v, dtype=np.int64)
    for k in (2, 1, 0):  # a fixed choice among the faces that use a vertex
        idx = scene.faces[::-1, k]
        face[idx] = np.arange(len(scene.faces))[::-1]
        corner[idx] = k
    used = face >= 0
    tri = face[used]
    bary = np.zeros((len(tri), 3))
    bary[np.arange(len(tri)), corner[used]] = 1.0
    albedo = np.zeros((v, 3))
    albedo[used] = albedo_at(scene, tri, bary)
    gn = np.zeros((v, 3))
    gn[:, 1] = 1.0
    v0 = scene.positions[scene.faces[tri]]
    g = np.cross(v0[:, 1] - v0[:, 0], v0[:, 2] - v0[:, 0])
    g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-300)
    gn[used] = g
    normal = np.array(scene.normals, dtype=np.float64)
    normal[used] = shading_normals(scene, tri, bary, g)
    return SurfaceSamples(np.asarray(scene.positions, np.float64), normal, gn, albedo)


def unshadowed_transfer(samples: SurfaceSamples, bands: int) -> ShTransfer:
    """Closed-form unshadowed diffuse transfer (no rays)."""
    rho, _ = clamp_albedo(np.asarray(samples.albedo, np.float64))
    k = sh.basis(samples.normal, bands) * sh.zonal_kernel(sh.clamped_cosine_zonal(bands))
    return ShTransfer(rho[:, :, None] / math.pi * k[:, None, :], "unshadowed", bands, 0)


def shadowed_transfer(scene: Scene, tracer: RayTracer, samples: SurfaceSamples, bands: int,
                      strata: int, seed: int, *, bounce_lookup=None) -> ShTransfer:
    """Shadowed transfer T⁰ from ``strata²`` stratified cosine rays per point; with
    ``bounce_lookup`` also the one-bounce term T¹ (kind "interreflected").

    bounce_lookup : callable (triangle (h,) int64, barycentric (h, 3) float64) → (h, 3, L²)
    float64, the stored T⁰ at hit points (see :func:`vertex_lookup`, :func:`texel_lookup`).
    Cost: n · strata² rays; memory O(POINT_CHUNK · strata² · L²).
    """
    n = samples.count
    s = strata * strata
    rho, _ = clamp_albedo(np.asarray(samples.albedo, np.float64))
    out = np.zeros((n, 3, bands * bands))
    for start in range(0, n, POINT_CHUNK):
        rows = slice(start, min(n, start + POINT_CHUNK))
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(start,)))
        nrm, gn = samples.normal[rows], samples.geometric_normal[rows]
        m = len(nrm)
        d = stratified_cosine_directions(nrm, strata, rng)
        above = np.einsum("msj,mj->ms", d, gn) > 0
        origin = samples.position[rows] + gn * tracer.offset
        owner = np.repeat(np.arange(m), s)
        flat = d.reshape(-1, 3)
        y = sh.basis(flat, bands).reshape(m, s, -1)
        hits = tracer.intersect(origin[owner], flat)
        hit = hits.hit.reshape(m, s)
        free = above & ~hit
        t0 = np.einsum("ms,msl->ml", free.astype(np.float64), y) / s
        block = rho[rows][:, :, None] * t0[:, None, :]
        if bounce_lookup is not None:
            front = (above & hit & hits.front.reshape(m, s)).ravel()
            sel = np.flatnonzero(front)
            if len(sel):
                t_hit = bounce_lookup(hits.triangle[sel], hits.barycentric[sel])
                acc = np.zeros((m, 3, bands * bands))
                np.add.at(acc, owner[sel], t_hit)
                block += rho[rows][:, :, None] * acc / s
        out[rows] = block
    kind = "interreflected" if bounce_lookup is not None else "shadowed"
    return ShTransfer(out, kind, bands, s)


def vertex_lookup(scene: Scene, vertex_transfer: ShTransfer):
    """Bounce lookup for per-vertex storage: T⁰ interpolated barycentrically from the
    vertices of the hit triangle (as the vertex-shader runtime interpolates colours)."""
    coeffs = vertex_transfer.coeffs

    def lookup(triangle: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
        return np.einsum("hk,hkcl->hcl", barycentric, coeffs[scene.faces[triangle]])
    return lookup


def texel_lookup(scene: Scene, image: np.ndarray):
    """Bounce lookup for transfer textures: nearest texel of the dilated transfer image
    ``image`` (H, W, 3, L²) at the hit point's lightmap UV (TEXCOORD_1 · (W, H), rows from
    the top), as the fragment-shader runtime reads it."""
    if scene.uv1 is None:
        raise ValueError("transfer textures need lightmap UVs (TEXCOORD_1)")
    uv1 = np.asarray(scene.uv1, np.float64)
    h, w = image.shape[:2]

    def lookup(triangle: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
        uv = np.einsum("hk,hkj->hj", barycentric, uv1[scene.faces[triangle]])
        x = np.clip((uv[:, 0] * w).astype(np.int64), 0, w - 1)
        yy = np.clip((uv[:, 1] * h).astype(np.int64), 0, h - 1)
        return image[yy, x]
    return lookup


# ---------------------------------------------------------------------------------------
# Glossy: the poster's transfer textures for the triple product (TP) and the triple
# product with a fixed light (TPFL)


def _hemisphere_rays(tracer: RayTracer, samples: SurfaceSamples, rows: slice, strata: int,
                     rng: np.random.Generator):
    """Stratified uniform directions over each sample's geometric hemisphere (m, S, 3) and
    their closest hits (:class:`prtcore.core.raytrace.Hits`, m·S rays)."""
    gn = samples.geometric_normal[rows]
    m, s = len(gn), strata * strata
    cell = np.arange(s)
    u = ((np.stack([cell // strata, cell % strata], axis=1)[None, :, :]
          + rng.random((m, s, 2))) / strata).reshape(-1, 2)
    d = directions_around(np.repeat(gn, s, axis=0), u[:, 0], 2.0 * math.pi * u[:, 1])
    origin = samples.position[rows] + gn * tracer.offset
    return d.reshape(m, s, 3), tracer.intersect(np.repeat(origin, s, axis=0), d)


def _hemisphere_projection(tracer: RayTracer, samples: SurfaceSamples, bands: int,
                           strata: int, seed: int, incident, channels: int) -> np.ndarray:
    """SH (n, channels, L²) of an incident function over each sample's geometric hemisphere
    (0 below it): ``∫ Y_i f dω`` estimated with strata² stratified uniform directions,
    ``incident(directions (k, 3), hits)`` → (k, channels) its value along each ray."""
    out = np.zeros((samples.count, channels, bands * bands))
    s = strata * strata
    for start in range(0, samples.count, POINT_CHUNK):
        rows = slice(start, min(samples.count, start + POINT_CHUNK))
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(start,)))
        d, hits = _hemisphere_rays(tracer, samples, rows, strata, rng)
        m, flat = d.shape[0], d.reshape(-1, 3)
        f = np.asarray(incident(flat, hits), np.float64).reshape(m, s, channels)
        y = sh.basis(flat, bands).reshape(m, s, -1)
        out[rows] = 2.0 * math.pi / s * np.einsum("msc,msl->mcl", f, y)
    return out


def visibility_transfer(tracer: RayTracer, samples: SurfaceSamples, bands: int, strata: int,
                        seed: int) -> np.ndarray:
    """The poster's T₀ for the triple product: SH of the visibility V(x, ω) over the whole
    sphere (0 below the geometric plane), ``V_i = ∫ Y_i V dω``: (n, L²) float64."""
    return _hemisphere_projection(tracer, samples, bands, strata, seed,
                                  lambda d, hits: ~hits.hit, 1)[:, 0]


def fixed_light_transfer(tracer: RayTracer, samples: SurfaceSamples, radiance, bands: int,
                         strata: int, seed: int) -> np.ndarray:
    """TPFL's stored vector: SH of the shadowed incident radiance ``L(ω) V(x, ω)`` for one
    fixed distant light, ``radiance`` a callable (k, 3) directions → (k, 3) RGB (e.g.
    :meth:`prtcore.emitters.environment.Environment.radiance`). Same rays and streams as
    :func:`visibility_transfer`. Returns (n, 3, L²) float64."""
    def incident(d: np.ndarray, hits) -> np.ndarray:
        return radiance(d) * ~hits.hit[:, None]
    return _hemisphere_projection(tracer, samples, bands, strata, seed, incident, 3)


def fixed_light_bounce_transfer(tracer: RayTracer, samples: SurfaceSamples, outgoing,
                                bands: int, strata: int, seed: int) -> np.ndarray:
    """The poster's inter-reflection texture T₁ (section 2.1): SH of the *indirect* incident
    radiance for the fixed light, ``B(ω) = (1 − V(x, ω)) L_out(q(ω))`` with q the front face
    the ray hits, ``outgoing`` a callable (triangle (h,), barycentric (h, 3)) → (h, 3) the
    diffuse radiance q sends out, e.g. the stored T₀ at q dotted with the fixed light's SH.
    Same rays and streams as :func:`fixed_light_transfer` (add the two for direct + one
    bounce). Returns (n, 3, L²) float64."""
    def incident(d: np.ndarray, hits) -> np.ndarray:
        radiance = np.zeros((len(d), 3))
        front = np.flatnonzero(hits.hit & hits.front)
        if len(front):
            radiance[front] = outgoing(hits.triangle[front], hits.barycentric[front])
        return radiance
    return _hemisphere_projection(tracer, samples, bands, strata, seed, incident, 3)
