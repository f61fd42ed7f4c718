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

from prtcore.core.fibres import FibreMesh, outside_offset
from prtcore.core.geometry import shading_normals
from prtcore.core.materials import albedo_at, clamp_albedo
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Scene
from prtcore.receivers.strands import StrandSpace
from prtcore.receivers.texels import TexelSpace, sample_texel_regions, texel_regions
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
