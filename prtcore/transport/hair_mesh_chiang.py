"""The transport of a hair + mesh bake with the Chiang fibre (``hair.fibre = "chiang"``,
isotropic exitance): :mod:`prtcore.transport.hair_mesh`'s four blocks with the fibre rows
of :mod:`prtcore.transport.fibre_chiang`.

Receivers are numbered mesh first, as in :mod:`prtcore.transport.hair_mesh`: rows
[0, T_m) the atlas texels, rows [T_m, T_m + T_h) the strand texels, which store the
fibre's direction-averaged exitance L̄ (:mod:`prtcore.core.bcsdf`). The operator::

    W = | G_mm  G_mh |   mesh rows: the surface gather's rays; a ray that hits a fibre reads
        | W_hm  W_hh |   its texel's L̄ (the isotropic exitance, as fibre → fibre)
                         strand rows: the fibre gather's rays, each weighted by the fibre's
                         directional albedo Ā(t·d, σ) per channel — toward another fibre
                         (W_hh, as for hair alone) or toward the front of the mesh (W_hm:
                         the mesh is Lambertian, so its texel's value is exact for any
                         direction)

applied matrix-free from the rays (one :class:`~prtcore.core.sparse.RayBlockProduct` over
T_m + T_h rows, F = 1) and solved by :func:`prtcore.transport.solve.solve_indirect`'s
Neumann series. The near field of both gathers is corrected in the first bounce (the fibre
rays' corrections weighted by their Ā). Linear and quadratic exitance are for hair alone:
the mesh rows would have to read every fibre's exitance toward the ray.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from prtcore.core.fibres import FibreMesh
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Scene
from prtcore.core.sparse import RayBlockProduct
from prtcore.core.spec import TransportSpec
from prtcore.intake.points import MeasurementPoints
from prtcore.receivers.strands import StrandSpace
from prtcore.receivers.texels import TexelSpace
from prtcore.transport.dataset import Dataset, add_first_bounce, direct_at_points
from prtcore.transport.direct import direct_radiance, near_field_correction
from prtcore.transport.fibre import MeshHits
from prtcore.transport.fibre_chiang import (
    ChiangFibre,
    chiang_direct,
    chiang_gather,
    ray_albedo,
)
from prtcore.transport.gather import HitMapper, NearField, gather_operator, near_field_reach
from prtcore.transport.hair_mesh import StrandHits, hair_mesh_stats
from prtcore.transport.solve import solve_indirect


def chiang_mesh_product(mesh_rows, term_rays: tuple, hits: MeshHits, fibre: ChiangFibre,
                        t_m: int, t_h: int, rays: int, threads: int) -> RayBlockProduct:
    """The operator W (see the module docstring) over the T_m + T_h receivers. mesh_rows:
    the surface gather's (T_m, T_m + T_h) CSR; term_rays: the fibre gather's rays to
    fibres (rows, cols, data (n, 6): direction, tangent at the origin); hits: its rays to
    the mesh, with the same data. Strand rows take weight 2 Ā / M per channel (the solver's
    albedo is 1/2 there, as in :func:`prtcore.transport.fibre_chiang.chiang_operator`)."""
    coo = mesh_rows.tocoo()
    order = np.lexsort((coo.col, coo.row))
    m_rows, m_cols = coo.row[order].astype(np.int64), coo.col[order].astype(np.int64)
    m_w = np.repeat(coo.data[order].astype(np.float32)[:, None], 3, axis=1)
    f_rows, f_cols, f_data = term_rays
    h_rows = np.concatenate([np.asarray(f_rows, np.int64), hits.row])
    h_cols = np.concatenate([np.asarray(f_cols, np.int64) + t_m, hits.col])
    h_data = np.concatenate([f_data, hits.data if hits.data is not None
                             else np.zeros((0, f_data.shape[1]), np.float32)])
    h_w = ray_albedo(fibre, h_rows, h_data) * np.float32(2.0 / rays)
    by_row = np.argsort(h_rows, kind="stable")
    rows = np.concatenate([m_rows, h_rows[by_row] + t_m])
    cols = np.concatenate([m_cols, h_cols[by_row]])
    weight = np.concatenate([m_w, h_w[by_row].astype(np.float32)])[:, None, :]
    return RayBlockProduct(rows, cols, weight, np.ones((len(rows), 1), np.float32),
                           t_m + t_h, threads)


def chiang_hair_near_field(hits: MeshHits, texels: TexelSpace, fibre: ChiangFibre,
                           t_m: int, reach: float, rays: int) -> NearField:
    """:func:`prtcore.transport.hair_mesh.hair_near_field` for the Chiang fibre: the fibre
    gather's mesh hits within ``reach`` footprints, each weighted per channel by its ray's
    2 Ā / M (the strand rows' weights in :func:`chiang_mesh_product`)."""
    close = np.flatnonzero(hits.t < near_field_reach(texels, reach)[hits.col])
    w = ray_albedo(fibre, hits.row[close], hits.data[close]) * np.float32(2.0 / rays)
    return NearField(row=t_m + hits.row[close], col=hits.col[close],
                     triangle=hits.triangle[close], barycentric=hits.barycentric[close],
                     weight=w.astype(np.float32))


def bake_chiang_hair_mesh_dataset(scene: Scene, texels: TexelSpace, space: StrandSpace,
                                  fibres: FibreMesh, points: MeasurementPoints,
                                  tracer: RayTracer, lights_train: Sequence[Light],
                                  lights_holdout: Sequence[Light], spec: TransportSpec,
                                  timer: StageTimer, fibre: ChiangFibre,
                                  hair_near: float | None = None) -> Dataset:
    """The lighting database of a hair + mesh bake with the Chiang fibre, as
    :func:`prtcore.transport.hair_mesh.bake_hair_mesh_dataset` (mesh rows first, training
    lights first, the texels' direct light not kept). The same rays as the diffuse
    fibre's bake; the hair's direct light is :func:`chiang_direct`'s."""
    lights = (*tuple(lights_train), *tuple(lights_holdout))
    f, t_m, t_h = scene.triangle_count, texels.count, space.count
    r0 = tracer.rays_traced
    gather = gather_operator(scene, texels, tracer, spec.gather_rays, spec.seed, timer,
                             near_field=spec.near_field, direct_samples=spec.direct_samples,
                             foreign=StrandHits(space, fibres, f, spec.seed))
    r1 = tracer.rays_traced
    with timer.stage("fibre gather"):
        term = chiang_gather(space, tracer, fibres, f, spec.gather_rays, spec.seed, fibre,
                             mesh_texels=HitMapper(scene, texels, tracer), mesh_columns=t_m)
        product = chiang_mesh_product(gather.matrix, term.rays, term.mesh_hits, fibre, t_m,
                                      t_h, spec.gather_rays, tracer.threads)
    r2 = tracer.rays_traced
    fibre_stats, hits = term.stats, term.mesh_hits
    del term
    direct_points = direct_at_points(scene, tracer, lights, points, timer)
    r3 = tracer.rays_traced
    direct = np.empty((t_m + t_h, len(lights), 3), dtype=np.float32)
    with timer.stage("direct texels"):
        direct[:t_m] = direct_radiance(scene, tracer, lights, gather.direct_position,
                                       texels.normal, texels.albedo, timer, "direct texels")
    r4 = tracer.rays_traced
    first = None
    with timer.stage("near field"):
        if gather.near is not None and gather.near.count:
            first = near_field_correction(scene, tracer, gather.near, lights, direct[:t_m],
                                          timer)
        reach = spec.near_field if hair_near is None else hair_near
        if reach > 0 and hits.row.size:
            nf = chiang_hair_near_field(hits, texels, fibre, t_m, reach, spec.gather_rays)
            if nf.count:
                first = add_first_bounce(first, near_field_correction(
                    scene, tracer, nf, lights, direct[:t_m], timer))
    r5 = tracer.rays_traced
    with timer.stage("direct fibres"):
        direct[t_m:] = chiang_direct(space, tracer, lights, max(4, spec.direct_samples),
                                     spec.seed + 1, fibre)[0]
    r6 = tracer.rays_traced
    albedo = np.concatenate([np.asarray(texels.albedo, np.float64), np.full((t_h, 3), 0.5)])
    indirect, bounces, resid, solve_stats = solve_indirect(
        None, albedo, direct, spec.max_bounces, spec.tolerance, timer,
        threads=tracer.threads, first_bounce=first, out=direct, product=product)
    stats = hair_mesh_stats(lights_train, lights_holdout, t_m, t_h, points.count,
                            gather.stats, fibre_stats, (r0, r1, r2, r3, r4, r5, r6),
                            solve_stats, model="chiang", exitance="isotropic")
    return Dataset(lights=lights, direct_points=direct_points, direct_texels=None,
                   indirect=indirect, iterations=bounces, residual=resid, stats=stats)
