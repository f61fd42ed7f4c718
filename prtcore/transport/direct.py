"""Direct light with shadow rays, and the near field's first bounce (paper 4.1).

A texel's direct light is the mean over J points spread over it
(``transport.direct_samples``, :attr:`prtcore.transport.gather.Gather.direct_position`):
one point aliases where a shadow edge runs along a texel column. Every evaluation is
:func:`prtcore.emitters.punctual.irradiance`, the one light evaluation.

Near field: a texel's value stands badly for the light at a point closer than about a
texel — a contact shadow narrower than a texel under a block's foot — so the first bounce
of a gather ray that hits within ``transport.near_field`` footprints of its origin takes
the direct light at the hit point itself (:func:`near_field_correction`; one shadow ray
per near hit and light).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from prtcore.core.geometry import shading_normals
from prtcore.core.materials import albedo_at, clamp_albedo
from prtcore.core.memory import release_free_memory
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Scene
from prtcore.emitters import compiled
from prtcore.emitters.base import emitter_for
from prtcore.emitters.punctual import irradiance
from prtcore.transport.gather import NearField

#: Near hits per chunk in :func:`near_field_correction` (bounds its (chunk, K, 3) array).
NEAR_CHUNK = 1 << 15
#: Points per light evaluation in :func:`direct_radiance` (bounds its temporaries). One
#: embreex call's worth (:data:`prtcore.core.raytrace.CHUNK`): the evaluation's dozens of
#: numpy passes then run on arrays of a few MB that stay in cache (measured on the 512²
#: Cornell box: about 20 % less CPU time than 1 << 19, same numbers).
DIRECT_CHUNK = 1 << 17


def direct_radiance(scene: Scene, tracer: RayTracer, lights: Sequence[Light],
                    positions: np.ndarray, normals: np.ndarray, albedo: np.ndarray,
                    timer: StageTimer | None = None, desc: str = "direct") -> np.ndarray:
    """Direct outgoing radiance ``L = clamp(ρ)/π · E`` for every light.

    positions : (n, 3) float64 surface points, or (n, J, 3): J points per row whose
    irradiance is averaged (a texel's direct samples,
    :attr:`prtcore.transport.gather.Gather.direct_position`);
    normals : (n, 3) float64 unit shading normals; albedo : (n, 3) raw albedo (clamped
    here with :func:`prtcore.core.materials.clamp_albedo`).
    E is :func:`prtcore.emitters.punctual.irradiance` with shadow rays, compiled for the
    punctual lights (:mod:`prtcore.emitters.compiled`: one pass sets up the shadow rays, one
    shades; same numbers). Lights are evaluated on ``tracer.threads`` threads (embreex and
    the kernels release the GIL), one light per task, points in chunks of DIRECT_CHUNK, so
    memory stays at the (n, K, 3) float32 result plus O(DIRECT_CHUNK) per thread.
    Returns (n, K, 3) float32.
    """
    del scene  # the tracer holds the geometry; kept for a uniform stage signature
    positions = np.asarray(positions, dtype=np.float64)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    if positions.ndim == 3 and positions.shape[1] == 1:
        positions = positions[:, 0]
    per = 1 if positions.ndim == 2 else positions.shape[1]
    flat = np.ascontiguousarray(positions.reshape(-1, 3))
    rho, _ = clamp_albedo(np.asarray(albedo, dtype=np.float64))
    scale = rho / math.pi
    out = np.empty((len(normals), len(lights), 3), dtype=np.float32)
    step = max(1, DIRECT_CHUNK // per)

    def one(k: int) -> None:
        row = emitter_for(lights[k]).kernel_row(lights[k])
        if row is None:
            return numpy_light(k)
        m = min(len(normals), step) * per
        e = np.empty((m, 3))
        origin, direction = np.empty((m, 3), np.float32), np.empty((m, 3), np.float32)
        tmax, index = np.empty(m, np.float32), np.empty(m, np.int64)
        for a in range(0, len(normals), step):
            b = min(a + step, len(normals))
            c = compiled.shadow_rays(row, flat[a * per:b * per], normals[a:b], per,
                                     tracer.offset, tracer.tfar, e, origin, direction,
                                     tmax, index)
            occluded = tracer.occluded(origin[:c], direction[:c], tmax[:c])
            compiled.shade(e, index[:c], occluded, per, scale[a:b], out[a:b, k])

    def numpy_light(k: int) -> None:
        for a in range(0, len(positions), step):
            b = a + step
            if per == 1:
                e = irradiance(lights[k], positions[a:b], normals[a:b], tracer)
            else:
                e = irradiance(lights[k], positions[a:b].reshape(-1, 3),
                               np.repeat(normals[a:b], per, axis=0), tracer)
                # the mean over each row's J points, by slices (the kernels' order)
                e = e.reshape(-1, per, 3)
                acc = e[:, 0].copy()
                for j in range(1, per):
                    acc += e[:, j]
                e = acc / per
            out[a:b, k, :] = e * scale[a:b]

    ks = range(len(lights))
    if tracer.threads > 1 and len(lights) > 1:
        with ThreadPoolExecutor(tracer.threads) as ex:
            it = ex.map(one, ks)
            if timer is not None:
                it = timer.bar(it, desc, total=len(lights))
            for _ in it:
                pass
        release_free_memory()  # the workers' arenas (prtcore/core/memory.py)
    else:
        for k in timer.bar(ks, desc, total=len(lights)) if timer is not None else ks:
            one(k)
    return out


def near_field_rows(near: NearField) -> np.ndarray:
    """(r,) or (F r,) int64: the rows :func:`near_field_correction` returns for ``near``
    (its receiving texels sorted unique, each coefficient's at ``rows + offsets[a]``)."""
    return _coefficient_rows(np.unique(near.row), near.offsets)


def _coefficient_rows(rows: np.ndarray, offsets: np.ndarray | None) -> np.ndarray:
    """``rows`` (r,), or each coefficient's ``rows + offsets[a]`` one after another."""
    if offsets is None:
        return rows
    return (rows[None, :] + np.asarray(offsets, np.int64)[:, None]).ravel()


def near_field_correction(scene: Scene, tracer: RayTracer, near: NearField,
                          lights: Sequence[Light], direct_texels: np.ndarray,
                          timer: StageTimer | None = None,
                          into: tuple[np.ndarray, np.ndarray] | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """The first bounce of the near field at the hit points instead of their texels.

    For every near hit (:class:`NearField`) the direct outgoing radiance at the hit point
    (:func:`direct_radiance`, shadow rays included) replaces the value of the texel it maps
    to, ``direct_texels`` (T, K, 3): a receiving texel's first bounce changes by
    ``Σ_hits w · (L_d(hit) − L_d[col])``. Costs one shadow ray per near hit and light.
    Returns rows (r,) int64, the receiving texels (sorted, unique), and their changes
    (r, K, 3) float32; :func:`prtcore.transport.solve.solve_indirect` adds them to the
    first bounce. With per-coefficient weights (``near.offsets``, F of them, increasing
    and at least the rows' span apart) each hit's change is shaded once and weighted F
    times: rows (F r,), coefficient a's at ``rows + offsets[a]`` (:func:`near_field_rows`).

    ``into``: a correction (rows sorted unique, values (R, K, 3) float32) whose rows hold
    every one of these; the changes are added into its values, in place, and it is
    returned. Two corrections of other rows then share one array instead of being summed
    into a third (:func:`prtcore.transport.dataset.first_bounce_rows`).
    """
    k = direct_texels.shape[1]
    rows = np.unique(near.row)
    offsets = np.zeros(1, np.int64) if near.offsets is None else near.offsets
    r = len(rows)
    mine = _coefficient_rows(rows, near.offsets)  # (len(offsets) r,)
    if into is None:
        out = np.zeros((len(mine), k, 3), dtype=np.float32)
        place = np.arange(len(out))
    else:
        place = np.searchsorted(into[0], mine)
        if len(mine) and (place.max() >= len(into[0]) or
                          not np.array_equal(into[0][place], mine)):
            raise ValueError("near_field_correction: into's rows must hold every row of "
                             "the near field")
        out = into[1]
    slot = np.searchsorted(rows, near.row)
    starts = range(0, near.count, NEAR_CHUNK)
    if timer is not None:
        starts = timer.bar(starts, "near field", total=len(starts))
    for a in starts:
        sl = slice(a, a + NEAR_CHUNK)
        tri, bary = near.triangle[sl], near.barycentric[sl]
        point = tracer.surface_point(tri, bary)
        normal = shading_normals(scene, tri, bary, tracer.face_normals[tri])
        ld = direct_radiance(scene, tracer, lights, point, normal, albedo_at(scene, tri, bary))
        ld -= direct_texels[near.col[sl]]
        w = near.weight[sl]
        # rows are sorted: sum each run of equal rows, then add the runs (unique slots)
        sk = slot[sl]
        run = np.flatnonzero(np.r_[True, sk[1:] != sk[:-1]])
        if near.offsets is None:
            ld *= w[:, None, None] if w.ndim == 1 else w[:, None, :]
            out[place[sk[run]]] += np.add.reduceat(ld, run, axis=0)
            continue
        for a in range(len(offsets)):  # the same shading, each coefficient's weights
            out[place[a * r + sk[run]]] += np.add.reduceat(ld * w[:, None, a, :], run,
                                                           axis=0)
    return into if into is not None else (mine, out)

