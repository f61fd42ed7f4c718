"""Independent Monte Carlo reference for light in hair over a mesh (a hair + mesh bake).

The ground truth :mod:`prtcore.transport.hair_mesh` is checked against. It extends
:mod:`prtcore.reference.fibres` (diffuse fibres, a round fibre's normal at every fibre hit,
the tubes only the occlusion proxy) with Lambertian mesh vertices, as
:mod:`prtcore.reference.pathtracer` shades them (the interpolated shading normal, the
albedo at the hit point, :func:`~prtcore.core.materials.albedo_at`): no texel → texel
operator, no radially constant outgoing radiance, no iteration to a fixed point.

Receivers are numbered as in the bake: rows [0, T_m) the mesh's atlas texels, rows
[T_m, T_m + T_h) the strand texels. A path from a mesh texel starts at a point uniform
over the texel's part of its triangle (:func:`~prtcore.receivers.texels.texel_regions`),
one from a strand texel at a point uniform over its fibre surface. At every vertex:
next-event estimation for each light (shadow rays against the mesh and the tubes), then a
cosine-distributed direction about the vertex's normal; at a mesh vertex a direction below
its geometric plane ends the path, and so do a miss and the back of a mesh face.
Russian roulette after ``rr_depth`` bounces. The mesh origins are not probed for burial
(the test heads are closed and nothing lies inside them).

Every estimate comes as two independent halves (a, b), for
:func:`prtcore.reference.fibres.noise_corrected_error`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from prtcore.core.bcsdf import ChiangParams, sample_scattering
from prtcore.core.fibres import FibreMesh, facing, fibre_at_hits, outside_offset
from prtcore.core.geometry import shading_normals
from prtcore.core.materials import albedo_at, clamp_albedo
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Scene
from prtcore.receivers.strands import StrandSpace, texel_of_hit
from prtcore.receivers.texels import TexelSpace, sample_texel_regions, texel_regions
from prtcore.reference.chiang import (
    EXITANCE_ORDERS,
    fibre_nee,
    fibre_starts,
    projection_kernel,
    random_radial,
)
from prtcore.reference.fibres import (
    cosine_about,
    fibre_vertices,
    irradiance_per_light,
    roulette,
    strand_starts,
    two_halves,
)


def hair_mesh_reference(scene: Scene, texels: TexelSpace, space: StrandSpace,
                        tracer: RayTracer, fibres: FibreMesh, lights: Sequence[Light],
                        rows: np.ndarray, paths: int, seed: int, max_depth: int = 64,
                        rr_depth: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Indirect outgoing radiance (texel-averaged ρ/π · E_ind) of receivers ``rows`` (n,)
    int64 in the combined numbering, for every light, as two independent halves of
    ``paths // 2`` paths each: (a, b), each (n, K, 3) float64. ``tracer`` and ``fibres``:
    :func:`prtcore.transport.fibre.hair_tracer` of ``space`` and ``scene``."""
    rows = np.asarray(rows, dtype=np.int64)
    hair = space.hair
    f, t_m = scene.triangle_count, texels.count
    rho_mesh, _ = clamp_albedo(np.asarray(texels.albedo, np.float64))
    rho_tex, _ = clamp_albedo(np.asarray(space.albedo, np.float64))
    rho_pt, _ = clamp_albedo(hair.color)
    off = outside_offset(hair, fibres.sides)
    mesh_rows = rows[rows < t_m]
    regions = texel_regions(scene, texels, mesh_rows) if len(mesh_rows) else None
    k = len(lights)

    def trace(owner: np.ndarray, rng: np.random.Generator, acc: np.ndarray) -> None:
        row = rows[owner]
        n = len(owner)
        origin = np.empty((n, 3))
        normal = np.empty((n, 3))
        geo = np.zeros((n, 3))  # a mesh vertex's geometric normal, 0 on fibres
        beta = np.empty((n, 3))
        on_mesh = row < t_m
        mi = np.flatnonzero(on_mesh)
        if len(mi):  # a point uniform over the texel's part of its triangle
            local = np.searchsorted(mesh_rows, row[mi])
            tri0 = texels.triangle[row[mi]]
            bary0 = sample_texel_regions(regions, local, rng)
            g0 = tracer.face_normals[tri0]
            normal[mi] = shading_normals(scene, tri0, bary0, g0)
            geo[mi] = g0
            origin[mi] = tracer.surface_point(tri0, bary0) + g0 * tracer.offset
            beta[mi] = rho_mesh[row[mi]]
        hi = np.flatnonzero(~on_mesh)
        if len(hi):  # a point uniform over the strand texel's fibre surface
            tex = row[hi] - t_m
            origin[hi], normal[hi] = strand_starts(space, off, tex, rng)
            beta[hi] = rho_tex[tex]
        alive = np.arange(n)
        for depth in range(1, max_depth + 1):
            if not len(alive):
                break
            d = cosine_about(normal[alive], rng)
            g = geo[alive]
            up = np.einsum("ij,ij->i", d, g) >= 0  # 0 on fibres: always up
            alive, d = alive[up], d[up]
            hits = tracer.intersect(origin[alive], d)
            fib = hits.triangle >= f
            mesh_front = hits.hit & ~fib & hits.front
            keep = fib | mesh_front
            alive, d, fib = alive[keep], d[keep], fib[keep]
            tri, bary = hits.triangle[keep], hits.barycentric[keep]
            if not len(alive):
                break
            m = len(alive)
            p_out = np.empty((m, 3))
            n_out = np.empty((m, 3))
            g_out = np.zeros((m, 3))
            rho = np.empty((m, 3))
            x_shade = np.empty((m, 3))  # where the vertex's irradiance is evaluated
            fi = np.flatnonzero(fib)
            if len(fi):
                p_out[fi], n_out[fi], rho[fi] = fibre_vertices(
                    hair, fibres, off, rho_pt, tri[fi] - f, bary[fi], d[fi], rng)
                x_shade[fi] = p_out[fi]
            si = np.flatnonzero(~fib)
            if len(si):
                fn = tracer.face_normals[tri[si]]
                p = tracer.surface_point(tri[si], bary[si])
                n_out[si] = shading_normals(scene, tri[si], bary[si], fn)
                g_out[si] = fn
                rho[si] = clamp_albedo(albedo_at(scene, tri[si], bary[si]))[0]
                x_shade[si] = p
                p_out[si] = p + fn * tracer.offset
            e = irradiance_per_light(lights, tracer, x_shade, n_out)  # (m, K, 3)
            np.add.at(acc, owner[alive], (beta[alive] * rho / math.pi)[:, None, :] * e)
            beta[alive] *= rho
            origin[alive], normal[alive], geo[alive] = p_out, n_out, g_out
            if depth >= rr_depth:
                alive = roulette(beta, alive, rng)

    return two_halves(len(rows), k, paths, seed, trace)


def chiang_hair_mesh_reference(scene: Scene, texels: TexelSpace, space: StrandSpace,
                               tracer: RayTracer, fibres: FibreMesh,
                               lights: Sequence[Light], rows: np.ndarray, paths: int,
                               seed: int, params: ChiangParams, sigma_points: np.ndarray,
                               max_depth: int = 64, rr_depth: int = 3,
                               exitance: str = "exact", where: str = "every",
                               fibre_to_mesh: bool = True, scalp_reach: float = 0.0,
                               tally: frozenset | None = None
                               ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`hair_mesh_reference` with Chiang fibres: every fibre vertex is that of
    :func:`prtcore.reference.chiang.chiang_reference` (next-event estimation with the
    BCSDF toward where the path came from, :func:`~prtcore.core.bcsdf.sample_scattering`
    to continue), every mesh vertex this module's Lambertian one. A strand texel's value
    is its direction-averaged exitance L̄ (a view direction with density cos θo / π²), a
    mesh texel's ρ/π · E_ind. ``params``, ``sigma_points`` (p, 3): the fibre, as for
    ``chiang_reference``; ``exitance`` "isotropic", "linear" or "quadratic" shades every
    fibre hit toward a fresh view direction weighted by that model's projection kernel
    instead (:func:`prtcore.reference.chiang.projection_kernel`: the fast path's model,
    for one-bounce checks). ``where`` "every" applies that model at every fibre hit;
    "scalp" only where an atlas texel's own ray meets a fibre (every later vertex exact):
    the error of the mesh's truncated reads of the fibres alone, at any depth;
    "scalp_arc" (with "exact" exitance) moves each such hit to a point uniform over its
    strand texel's arc, shaded toward the ray: the error of reading a texel's mean where
    the scalp sees one point of it; hits nearer than ``scalp_reach`` (metres) stay
    exact there (what a near field of that reach for the scalp's reads would leave).
    ``fibre_to_mesh`` False ends every path that goes from a fibre to the mesh: the light
    the hair sends back to the head left out, for a fast path baked without it.
    ``tally``: a set of (depth, "fibre" | "mesh"); only the next-event estimates at
    those depths' vertices of those kinds are counted (a diagnostic: at depth 2, "mesh"
    from an atlas texel is the light the scalp sends back to itself through one fibre,
    light → mesh → fibre → texel). Every estimate is still drawn, so the paths are the
    untallied reference's draw for draw and the parts of a partition sum to it.
    Returns (a, b), each (n, K, 3) float64, for ``rows`` in the combined numbering."""
    if tally is not None and not {kind for _, kind in tally} <= {"fibre", "mesh"}:
        raise ValueError(f"chiang_hair_mesh_reference: tally's kinds must be 'fibre' or "
                         f"'mesh', not {sorted(tally)!r}")
    if where not in ("every", "scalp", "scalp_arc"):
        raise ValueError(f"chiang_hair_mesh_reference: where must be 'every', 'scalp' or "
                         f"'scalp_arc', not {where!r}")
    rows = np.asarray(rows, dtype=np.int64)
    hair = space.hair
    f, t_m = scene.triangle_count, texels.count
    rho_mesh, _ = clamp_albedo(np.asarray(texels.albedo, np.float64))
    sig_pt = np.asarray(sigma_points, dtype=np.float64)
    off = outside_offset(hair, fibres.sides)
    mesh_rows = rows[rows < t_m]
    regions = texel_regions(scene, texels, mesh_rows) if len(mesh_rows) else None

    def trace(owner: np.ndarray, rng: np.random.Generator, acc: np.ndarray) -> None:
        row = rows[owner]
        n = len(owner)
        fib = row >= t_m  # the vertex is on a fibre (else on the mesh)
        pos, vec, geo = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
        tangent, wo = np.zeros((n, 3)), np.zeros((n, 3))  # fibre vertices
        radius, sigma = np.zeros(n), np.zeros((n, 3))
        beta = np.ones((n, 3))
        mi = np.flatnonzero(~fib)
        if len(mi):  # mesh: origin above a point uniform over the texel, shading normal
            tri0 = texels.triangle[row[mi]]
            bary0 = sample_texel_regions(regions, np.searchsorted(mesh_rows, row[mi]), rng)
            geo[mi] = tracer.face_normals[tri0]
            vec[mi] = shading_normals(scene, tri0, bary0, geo[mi])
            pos[mi] = tracer.surface_point(tri0, bary0) + geo[mi] * tracer.offset
            beta[mi] = rho_mesh[row[mi]]
        hi = np.flatnonzero(fib)
        if len(hi):  # fibre: a point uniform over the arc, a view direction cos θo / π²
            pos[hi], tangent[hi], radius[hi], sigma[hi], wo[hi] = fibre_starts(
                space, off, sig_pt, row[hi] - t_m, rng)
        alive = np.arange(n)
        for depth in range(1, max_depth + 1):
            if not len(alive):
                break
            on = fib[alive]
            d = np.empty((len(alive), 3))
            origin = np.empty((len(alive), 3))
            a_m, a_f = alive[~on], alive[on]
            if len(a_m):  # mesh: a cosine direction; below the face ends the path
                d[~on] = cosine_about(vec[a_m], rng)
                origin[~on] = pos[a_m]
            if len(a_f):  # fibre: the BCSDF's importance sampling
                h = 2 * rng.random(len(a_f)) - 1
                wi, w = sample_scattering(tangent[a_f], wo[a_f], h, params, rng, sigma[a_f])
                beta[a_f] *= w
                d[on] = wi
                origin[on] = pos[a_f] + radius[a_f, None] * facing(tangent[a_f], wi)
            up = np.einsum("ij,ij->i", d, geo[alive]) >= 0  # 0 on fibres: always up
            alive, d, origin = alive[up], d[up], origin[up]
            hits = tracer.intersect(origin, d)
            to_fibre = hits.triangle >= f
            keep = to_fibre | (hits.hit & ~to_fibre & hits.front)
            alive, d, to_fibre = alive[keep], d[keep], to_fibre[keep]
            tri, bary, dist = hits.triangle[keep], hits.barycentric[keep], hits.t[keep]
            if not len(alive):
                break
            if not fibre_to_mesh:  # a fibre's light to the mesh left out
                keep = to_fibre | ~fib[alive]
                alive, d, to_fibre = alive[keep], d[keep], to_fibre[keep]
                tri, bary, dist = tri[keep], bary[keep], dist[keep]
            fi, si = np.flatnonzero(to_fibre), np.flatnonzero(~to_fibre)
            if len(fi):
                v = alive[fi]
                fib[v] = True
                tangent[v], pos[v], radius[v], sigma[v] = fibre_at_hits(
                    hair, fibres, off, sig_pt, tri[fi] - f, bary[fi])
                wo[v] = -d[fi]
                if where == "scalp_arc" and depth == 1:  # the texel's mean, not the hit
                    far = (row[v] < t_m) & (dist[fi] >= scalp_reach)
                    m, mf = v[far], fi[far]
                    pos[m], tangent[m], radius[m], sigma[m], _ = fibre_starts(
                        space, off, sig_pt, texel_of_hit(space, fibres, tri[mf] - f,
                                                         bary[mf]), rng)
                if exitance != "exact":  # the fast path's model: a fresh view, weighted
                    pick = np.full(len(v), where == "every") | (  # by its kernel
                        (depth == 1) & (row[v] < t_m))
                    m = v[pick]
                    wo[m] = cosine_about(random_radial(tangent[m], rng), rng)
                    beta[m] *= projection_kernel(tangent[m], wo[m], -d[fi][pick],
                                                 EXITANCE_ORDERS[exitance])[:, None]
                geo[v] = 0.0
                nee = fibre_nee(lights, tracer, params, beta[v], pos[v], tangent[v],
                                radius[v], wo[v], sigma[v], 2 * rng.random(len(v)) - 1, rng)
                if tally is None or (depth, "fibre") in tally:
                    np.add.at(acc, owner[v], nee)
            if len(si):
                v = alive[si]
                fn = tracer.face_normals[tri[si]]
                p = tracer.surface_point(tri[si], bary[si])
                nrm = shading_normals(scene, tri[si], bary[si], fn)
                rho = clamp_albedo(albedo_at(scene, tri[si], bary[si]))[0]
                e = irradiance_per_light(lights, tracer, p, nrm)  # (m, K, 3)
                if tally is None or (depth, "mesh") in tally:
                    np.add.at(acc, owner[v], (beta[v] * rho / math.pi)[:, None, :] * e)
                beta[v] *= rho
                fib[v] = False
                pos[v], vec[v], geo[v] = p + fn * tracer.offset, nrm, fn
            if depth >= rr_depth:
                alive = roulette(beta, alive, rng)

    return two_halves(len(rows), len(lights), paths, seed, trace)
