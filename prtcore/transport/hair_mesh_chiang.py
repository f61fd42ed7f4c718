"""The transport of a hair + mesh bake with the Chiang fibre (``hair.fibre = "chiang"``):
:mod:`prtcore.transport.hair_mesh`'s four blocks with the fibre rows of
:mod:`prtcore.transport.fibre_chiang`.

Receivers are numbered mesh first, as in :mod:`prtcore.transport.hair_mesh`: rows
[0, T_m) the atlas texels, rows [T_m, T_m + T_h) the strand texels, which store the
fibre's direction-averaged exitance L̄ (:mod:`prtcore.core.bcsdf`). The operator::

    W = | G_mm  G_mh |   mesh rows: the surface gather's rays; a ray that hits a fibre reads
        | W_hm  W_hh |   its exitance toward the ray (isotropic: the texel's L̄; linear:
                         c0 − c·d; quadratic: plus its second-order terms)
                         strand rows: the fibre gather's rays, each weighted by the fibre's
                         exitance weights of its direction per channel (isotropic: the
                         directional albedo Ā(t·d, σ)) — toward another fibre (W_hh, as for
                         hair alone) or toward the front of the mesh (W_hm: the mesh is
                         Lambertian, so its texel's value is exact for any direction)

over the F exitance coefficients of every receiver (an atlas texel uses the first),
applied matrix-free from the rays (one :class:`~prtcore.core.sparse.RayBlockProduct` over
T_m + T_h texels) and solved on a basis of the light columns after the first bounce
(:func:`prtcore.transport.low_rank.solve_low_rank`). The near field of both gathers is
corrected in the first bounce (the fibre rays' corrections weighted by their exitance
weights).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence

import numpy as np

from prtcore.core.fibres import FibreMesh
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Scene
from prtcore.core.sparse import ASSEMBLY_CHUNK, RayBlockProduct, RayPart, assemble_ray_blocks
from prtcore.core.spec import TransportSpec
from prtcore.intake.points import MeasurementPoints
from prtcore.receivers.strands import StrandSpace
from prtcore.receivers.texels import TexelSpace
from prtcore.transport.base import operator_for
from prtcore.transport.dataset import (
    Dataset,
    add_first_bounce,
    direct_at_points,
    first_bounce_rows,
)
from prtcore.transport.direct import direct_radiance, near_field_correction, near_field_rows
from prtcore.transport.fibre import HairDensity, MeshHits, direct_block_bytes
from prtcore.transport.fibre_chiang import (
    EXITANCE_TERMS,
    ChiangFibre,
    chiang_direct,
    chiang_gather,
    chiang_samples,
    exitance_reads,
    needs_frames,
    ray_weights,
    texel_frames,
)
from prtcore.transport.fibre_near import (
    NEAR_FIBRE_RAYS,
    NEAR_RAY_BYTES,
    SHADED_HIT_BYTES,
    NearFibreHits,
    NearFibreRays,
    near_fibre_direct,
    near_fibre_rays,
    near_fibre_shaded,
    near_hits_reach,
    shaded_at_point,
    shaded_fibre_correction,
    texel_reads,
)
from prtcore.transport.gather import HitMapper, NearField, gather_operator, near_field_reach
from prtcore.transport.hair_mesh import StrandHits, hair_mesh_stats
from prtcore.transport.low_rank import first_bounce_in_place, solve_low_rank
from prtcore.transport.solve import SOLVE_BLOCK_BYTES, SOLVE_WORK_ARRAYS

#: bytes of one entry of the product (:class:`~prtcore.core.sparse.RayBlockProduct`:
#: int32 row and column, F × 3 float32 weights, F float32 reads), a + b F; and per ray of
#: the assembly's chunk (:func:`~prtcore.core.sparse.assemble_ray_blocks`,
#: :data:`~prtcore.core.sparse.ASSEMBLY_CHUNK` rays) the float64 temporaries of its
#: weights and reads, a + b F (tracemalloc on the 2000-strand head: 1000 bytes at F = 9,
#: 490 at F = 4). Until 2026-12-06 the parts were concatenated and sorted: 24 + 52 F
#: bytes an entry beside the product (469 measured at F = 9) and 48 F per fibre ray for
#: its weights, made whole
PRODUCT_ENTRY_BYTES = (8, 16)
#: the same for an entry of an atlas row (int32 row and column, coefficient 0's three
#: float32 weights, F float32 reads), a + b F: until 2026-12-07 an atlas entry held all
#: F × 3 weights, 168 bytes at F = 10 where it now holds 60 (the 10k head: 1.0 GiB)
ATLAS_ENTRY_BYTES = (20, 4)
ASSEMBLY_RAY_BYTES = (100, 100)
#: bytes per ray that either gather keeps until the product is made (its rows, the texel
#: hit and its direction, and the fibre rays' tangents) and per fibre ray to the mesh,
#: kept for the near field (:class:`~prtcore.transport.fibre.MeshHits`)
RAY_KEPT_BYTES = 40
MESH_HIT_BYTES = 56


def chiang_mesh_bytes(t_m: int, t_h: int, k: int, rays: int, exitance: str,
                      transport: TransportSpec, density: HairDensity | None = None,
                      near_fibres: float = 0.0, *, samples: int,
                      shaded_fibres: float = 0.0) -> int:
    """The transport's own peak memory (bytes, beyond the process and the texels' and
    fibres' fixed costs, which :func:`prtcore.hairbake.check_hair_memory` counts) for
    ``t_m`` atlas and ``t_h`` strand texels (the transport's arc pieces), ``k`` lights
    (training + held-out), ``rays`` gather rays per strand texel (per piece) and
    ``exitance``, ``samples`` J direct-light samples per strand texel
    (:func:`~prtcore.transport.fibre_chiang.chiang_samples`), with ``transport`` the
    spec the gathers' own estimates take, and
    ``density`` (:func:`~prtcore.transport.fibre.hair_density`, traced before the
    transport; None: every ray a hit and every strand texel with near-field rows) the
    shares of rays that make product entries and of strand texels whose near-field
    corrections are kept: the largest of six phases.

    * **Gathers.** The surface gather's and the fibre gather's own estimates, the rays
      to fibres they keep, then the product, at most one entry per gather ray of either
      gather that hits something (entries ≤ T_m a_m M_m + T_h a_h M with ``density``'s
      shares of rays that hit; on the 10k head 11.3 M entries, 74 % of (T_m + T_h) M),
      assembled in place with one chunk's temporaries.
    * **Near field.** The product, the stacked direct light (T_m + F T_h, K, 3) float32
      that the solve works in (the atlas texels carry one coefficient: until 2026-12-06
      they carried F, all but the first zero, which cost the 10k head's second order
      6.6 GiB), the first bounce's near-field corrections (at most T_m + F T_h rows of
      (K, 3); T_m + F × ``near_share`` T_h: on the 10k head 4.4 % of its strand texels)
      in one array that each is added into (until 2026-12-07 twice: the atlas's and the
      fibres' beside their sum), the surface gather's matrix and the fibre rays' mesh
      hits, dropped before the solve (until 2026-12-06 they were kept through it).
    * **Near fibres** (``near_fibres`` > 0, :mod:`prtcore.transport.fibre_near`): the
      atlas rays that meet a fibre within reach (``density``'s share, at most every atlas
      ray) each add NEAR_FIBRE_RAYS entries, kept until the product is made, and their
      direct light one more correction of at most T_m rows beside the corrections it is
      added into (a phase of its own after the direct fibres: the product, the stacked
      direct light and both). Their shadow pieces' visibility (a bit a piece and light,
      at most ⌈K/8⌉ bytes a near hit) is held after the surface gather's matrix and the
      mesh hits are dropped, so it stays below this phase's peak.
    * **Shaded fibres** (``shaded_fibres`` > ``near_fibres``,
      :func:`~prtcore.transport.fibre_near.shaded_fibre_correction`): the atlas rays
      that meet a fibre within that reach (``density``'s ``atlas_shaded_share``, near
      hits included, so a bound) each keep SHADED_HIT_BYTES from the gather until their
      correction is added into the first bounce's, in a phase of its own after the near
      fibres' with as much again of working arrays (their pieces, their rows' slots).
    * **Direct fibres.** The product, the stacked direct light, the near-field
      corrections, and the largest block of :func:`~prtcore.transport.fibre.
      direct_of_samples` (its J samples' radiance and F coefficients for K lights,
      :func:`~prtcore.transport.fibre.direct_block_bytes`, at most DIRECT_BLOCK_BYTES).
      Until 2026-12-07 this phase was not counted and its block grew with J: the 10k
      head at J = 16 peaked at 15.0 GiB (13.97 GiB since, in its solve), 0.7 GiB under
      the estimate; at J = 32 its block alone would have held 4.1 GiB.
    * **Solve.** The product, the stacked direct light, the first bounce's near-field
      corrections and then, once they are dropped, the sum of the bounces beside it
      ((T_m + T_h), K, 3) (until 2026-12-07 the corrections were held through the
      solve, 1.4 GiB on the 10k head), and the solve's working arrays in their column
      blocks (bounded by SOLVE_BLOCK_BYTES).

    An atlas row's entry of the product holds coefficient 0's weights alone
    (ATLAS_ENTRY_BYTES; :class:`~prtcore.core.sparse.RayBlockProduct`'s ``head_weight``).

    Measured (benchmarks/stage_memory.py, 2000 curly strands on the head, 512² atlas:
    139 089 + 20 000 texels, K = 528, M = 64, linear): peak 6.36 GiB in the solve, 3.75
    GiB once the atlas texels carried one coefficient (estimate 6.87 GiB without the
    density probe)."""
    f = EXITANCE_TERMS[exitance]
    n = t_m + t_h
    d = density or HairDensity(1.0)  # at most one entry per gather ray; the atlas keeps
    near_rays = (t_m * transport.gather_rays * d.atlas_near_share * NEAR_FIBRE_RAYS
                 if near_fibres > 0 else 0)
    atlas = t_m * transport.gather_rays * d.atlas_hit_share + near_rays  # the spec's M
    entries = atlas + t_h * rays * d.hit_share
    product = (atlas * (ATLAS_ENTRY_BYTES[0] + ATLAS_ENTRY_BYTES[1] * f)
               + (entries - atlas) * (PRODUCT_ENTRY_BYTES[0] + PRODUCT_ENTRY_BYTES[1] * f))
    gathers = (operator_for("surface").estimate_bytes(t_m, k, transport)
               + operator_for("fibre").estimate_bytes(
                   t_h, k, dataclasses.replace(transport, gather_rays=rays))
               + entries * RAY_KEPT_BYTES + near_rays * NEAR_RAY_BYTES + product
               + ASSEMBLY_CHUNK * (ASSEMBLY_RAY_BYTES[0] + ASSEMBLY_RAY_BYTES[1] * f))
    near = t_m + f * d.near_share * t_h
    stacked = (n + (f - 1) * t_h) * k * 12
    corrections = near * k * 12  # one array, each correction added into it
    shaded = (t_m * transport.gather_rays * d.atlas_shaded_share * SHADED_HIT_BYTES
              if shaded_fibres > near_fibres else 0)  # held from the gather to its phase
    near_stage = (product + stacked + corrections + t_m * transport.gather_rays * 12
                  + t_h * rays * MESH_HIT_BYTES + shaded)
    direct_stage = (product + stacked + corrections + direct_block_bytes(t_h, samples, k, f)
                    + shaded)
    near_fibre_stage = product + stacked + corrections + shaded + (
        t_m * k * 12 if near_fibres > 0 else 0)  # the near hits' direct light
    shaded_stage = product + stacked + corrections + 2 * shaded
    solve = (product + stacked + max(n, near) * k * 12  # the corrections, then the sum
             + min(SOLVE_WORK_ARRAYS * n * k * 12, SOLVE_BLOCK_BYTES))
    return int(max(gathers + shaded, near_stage, direct_stage, near_fibre_stage,
                   shaded_stage, solve))


class StrandRays(StrandHits):
    """:class:`~prtcore.transport.hair_mesh.StrandHits` that also keeps every ray's
    direction: the mesh rows read a hit fibre's exitance toward the ray. With ``reach``
    (T_m,) float64 (world units per atlas texel, :func:`~prtcore.transport.gather.
    near_field_reach`), a hit closer than its texel's reach is a near hit
    (:mod:`prtcore.transport.fibre_near`): kept apart (:meth:`near`) and left out of
    :meth:`rays`. With ``shade`` (T_m,) float64 too, a hit that is not near but closer
    than that is a shaded hit (:meth:`shaded`): it stays in :meth:`rays` and is also
    kept apart, for its direct light at the point met
    (:func:`~prtcore.transport.fibre_near.shaded_fibre_correction`). With ``lit`` (T_m,)
    float64 (at most ``reach``), a near hit beyond it gathers its light at the point but
    reads its direct light from its texel (:meth:`near_lit`)."""

    def __init__(self, space: StrandSpace, fibres: FibreMesh, first: int, seed: int,
                 reach: np.ndarray | None = None, shade: np.ndarray | None = None,
                 lit: np.ndarray | None = None):
        super().__init__(space, fibres, first, seed)
        self.reach, self.shade, self.lit = reach, shade, lit
        self._directions: dict[int, np.ndarray] = {}
        # batch → (near (n,) bool, their tube triangles, barycentrics); the shaded hits'
        self._near: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._shaded: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._lit: dict[int, np.ndarray] = {}  # batch → its near hits within ``lit``

    def __call__(self, batch, rows, triangle, barycentric, direction, distance=None):
        texel = super().__call__(batch, rows, triangle, barycentric, direction)

        def kept(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            return (mask, (triangle[mask] - self.first).astype(np.int64),
                    np.asarray(barycentric[mask], np.float32))
        t = np.asarray(distance) if distance is not None else None
        close = t < self.reach[rows] if self.reach is not None else np.zeros(len(rows), bool)
        with self._lock:
            self._directions[batch] = np.asarray(direction, np.float32)
            if self.reach is not None:
                self._near[batch] = kept(close)
                if self.lit is not None:
                    self._lit[batch] = (t < self.lit[rows])[close]
            if self.shade is not None:
                self._shaded[batch] = kept((t < self.shade[rows]) & ~close)
        return texel

    def _batch(self, k: int, name: str) -> np.ndarray:
        """Batch ``k``'s "row", "texel", "frac" (arc fraction) or "direction" of its hits."""
        if name == "direction":
            return self._directions[k]
        return self._parts[k][{"row": 0, "texel": 1, "frac": 3}[name]]

    def _joined(self, name: str, kept: dict | None) -> np.ndarray:
        """:meth:`_batch` ``name`` of every batch in order, of the hits ``kept`` marks
        (``self._near`` or ``self._shaded``), or of all but the near hits (None)."""
        if kept is not None:
            return np.concatenate([self._batch(k, name)[kept[k][0]] for k in sorted(kept)])
        return np.concatenate([self._batch(k, name)[~self._near[k][0]] if k in self._near
                               else self._batch(k, name) for k in sorted(self._parts)])

    def rays(self, root: str | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every ray that hit a fibre and is not a near hit, in batch order: receiving
        atlas texel (n,) int64, strand texel read (n,) int64, direction (n, 3) float64
        and the read's weight (n,) float64: 1, the texel's mean (``root`` None); or with
        ``root`` ("extrapolate", "clamp") each ray twice, read between the two texel
        centres about the hit along its strand
        (:meth:`~prtcore.receivers.strands.StrandSpace.arc_weights`, weights summing to
        1), as :meth:`StrandHits.interpolated` reads them."""
        if not self._parts:
            return (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)),
                    np.zeros(0))
        rows = self._joined("row", None).astype(np.int64)
        texel = self._joined("texel", None).astype(np.int64)
        d = self._joined("direction", None).astype(np.float64)
        if root is None:
            return rows, texel, d, np.ones(len(rows))
        frac = self._joined("frac", None).astype(np.float64)
        cols, w = self.space.arc_weights(texel, frac, root)
        return np.repeat(rows, 2), cols.ravel(), np.repeat(d, 2, axis=0), w.ravel()

    def near(self) -> NearFibreHits:
        """The near hits, in batch order (:class:`~prtcore.transport.fibre_near.
        NearFibreHits`; none without ``reach``)."""
        return self._hits(self._near)

    def near_lit(self) -> np.ndarray | None:
        """(n,) bool over :meth:`near`'s hits: those whose direct light is shaded at the
        point met (within ``lit``); None without ``lit`` (every one)."""
        if self.lit is None:
            return None
        return (np.concatenate([self._lit[k] for k in sorted(self._near)]) if self._near
                else np.zeros(0, bool))

    def shaded(self) -> NearFibreHits:
        """The shaded hits, in batch order (none without ``shade``)."""
        return self._hits(self._shaded)

    def _hits(self, kept: dict) -> NearFibreHits:
        if not kept:
            return NearFibreHits(np.zeros(0, np.int64), np.zeros(0, np.int64),
                                 np.zeros(0, np.int64), np.zeros((0, 3), np.float32),
                                 np.zeros((0, 3), np.float32))
        keys = sorted(kept)
        return NearFibreHits(row=self._joined("row", kept).astype(np.int64),
                             texel=self._joined("texel", kept).astype(np.int64),
                             triangle=np.concatenate([kept[k][1] for k in keys]),
                             barycentric=np.concatenate([kept[k][2] for k in keys]),
                             direction=self._joined("direction", kept))


def chiang_mesh_product(mesh_rows, strand_rays: tuple, valid_rays: np.ndarray,
                        term_rays: tuple, hits: MeshHits, fibre: ChiangFibre, t_m: int,
                        t_h: int, rays: int, threads: int, exitance: str = "isotropic",
                        frames: tuple | None = None, near: NearFibreRays | None = None
                        ) -> RayBlockProduct:
    """The operator W (see the module docstring) over the receivers' coefficients: the
    T_m + T_h receivers' first, then the strand texels' F − 1 others (an atlas texel
    has coefficient 0 only; :class:`~prtcore.core.sparse.RayBlockProduct` with ``first``
    = T_m, :meth:`~prtcore.core.sparse.RayBlockProduct.coefficient_rows`).

    mesh_rows: the surface gather's (T_m, T_m + T_h) CSR, whose atlas columns are kept;
    strand_rays: its rays to fibres (:meth:`StrandRays.rays`), each weighing its read's
    weight / M_valid of its row (``valid_rays`` (T_m,)) and reading the fibre's exitance
    toward it (:func:`~prtcore.transport.fibre_chiang.exitance_reads`); term_rays: the
    fibre gather's rays to fibres (rows, cols, data (n, 6): direction, tangent at the
    origin); hits: its rays to the mesh, with the same data. Strand rows take the
    exitance weights × 2 / M per channel (the solver's albedo is 1/2 there, as in
    :func:`prtcore.transport.fibre_chiang.chiang_operator`); a ray to the mesh reads its
    texel's one value. ``frames``: :func:`texel_frames` of the strand texels (quadratic exitance).
    ``near``: the rays from the atlas's near fibre hits
    (:func:`~prtcore.transport.fibre_near.near_fibre_rays`; those hits are not in
    ``strand_rays``): mesh rows, each weighing its weight per channel and reading an
    atlas texel's value or a strand texel's exitance toward it."""
    f = EXITANCE_TERMS[exitance]
    coo = mesh_rows.tocsc()[:, :t_m].tocoo()  # atlas → atlas: one value each way
    s_rows, s_texel, s_dir, s_w = strand_rays
    f_rows, f_cols, f_data = term_rays
    f_rows = np.asarray(f_rows, np.int64)
    m_data = hits.data if hits.data is not None else np.zeros((0, 6), np.float32)
    scale = 2.0 / rays

    def first_only(w: np.ndarray) -> np.ndarray:  # (n,) or (n, 3) → (n, F, 3),
        out = np.zeros((len(w), f, 3), np.float32)  # coefficient 0 alone
        out[:, 0] = w[:, None] if w.ndim == 1 else w
        return out

    def unit(n: int) -> np.ndarray:  # (n, F): a Lambertian texel's one value
        out = np.zeros((n, f), np.float32)
        out[:, 0] = 1.0
        return out

    def reads(d: np.ndarray, texel: np.ndarray) -> np.ndarray:  # (n, F) toward d
        frame = None if frames is None else (frames[0][texel], frames[1][texel])
        return np.stack(exitance_reads(d, frame, f), axis=1)

    def weights(rows: np.ndarray, data: np.ndarray) -> np.ndarray:  # (n, F, 3)
        return np.moveaxis(ray_weights(fibre, rows, data, exitance, frames), 0, 1) * scale

    parts = [
        RayPart(coo.row, coo.col, lambda sl: (
            first_only(coo.data[sl].astype(np.float64)), unit(len(coo.data[sl])))),
        RayPart(s_rows, s_texel + t_m, lambda sl: (
            first_only(s_w[sl] * (1.0 / np.maximum(valid_rays[s_rows[sl]], 1))),
            reads(s_dir[sl], s_texel[sl]))),
        RayPart(f_rows + t_m, np.asarray(f_cols, np.int64) + t_m, lambda sl: (
            weights(f_rows[sl], f_data[sl]),
            reads(f_data[sl, :3].astype(np.float64), f_cols[sl]))),
        RayPart(hits.row + t_m, hits.col, lambda sl: (
            weights(hits.row[sl], m_data[sl]), unit(len(hits.row[sl])))),
    ]
    if near is not None:  # the near fibre hits' rays: to the mesh, then to fibres
        on_mesh, on_fibre = np.flatnonzero(near.col < t_m), np.flatnonzero(near.col >= t_m)
        parts += [
            RayPart(near.row[on_mesh], near.col[on_mesh], lambda sl: (
                first_only(near.weight[on_mesh[sl]]), unit(len(on_mesh[sl])))),
            RayPart(near.row[on_fibre], near.col[on_fibre], lambda sl: (
                first_only(near.weight[on_fibre[sl]]),
                reads(near.direction[on_fibre[sl]].astype(np.float64),
                      near.col[on_fibre[sl]] - t_m))),
        ]
    return assemble_ray_blocks(parts, t_m + t_h, f, threads, first=t_m)


def chiang_hair_near_field(hits: MeshHits, texels: TexelSpace, fibre: ChiangFibre,
                           t_m: int, t_h: int, reach: float, rays: int,
                           exitance: str = "isotropic", frames: tuple | None = None
                           ) -> NearField:
    """:func:`prtcore.transport.hair_mesh.hair_near_field` for the Chiang fibre: the fibre
    gather's mesh hits within ``reach`` footprints, each weighted per exitance
    coefficient a and channel by its ray's coefficient-a weight × 2 / M (the strand rows'
    weights in :func:`chiang_mesh_product`), at strand texel i's coefficient-a row
    (``T_m + i`` for a = 0, ``T + (a − 1) T_h + i`` after, T = T_m + T_h: that product's
    layout, offsets a T_h from the first). Shaded once for all F coefficients
    (:func:`~prtcore.transport.direct.near_field_correction`)."""
    close = np.flatnonzero(hits.t < near_field_reach(texels, reach)[hits.col])
    w = ray_weights(fibre, hits.row[close], hits.data[close], exitance, frames) * (2.0 / rays)
    return NearField(row=t_m + hits.row[close], col=hits.col[close],
                     triangle=hits.triangle[close], barycentric=hits.barycentric[close],
                     weight=np.ascontiguousarray(np.moveaxis(w, 0, 1), dtype=np.float32),
                     offsets=np.arange(len(w), dtype=np.int64) * t_h)


def bake_chiang_hair_mesh_dataset(scene: Scene, texels: TexelSpace, space: StrandSpace,
                                  fibres: FibreMesh, points: MeasurementPoints,
                                  tracer: RayTracer, lights_train: Sequence[Light],
                                  lights_holdout: Sequence[Light], spec: TransportSpec,
                                  timer: StageTimer, fibre: ChiangFibre,
                                  hair_near: float | None = None,
                                  exitance: str = "isotropic",
                                  fibre_rays: int | None = None,
                                  arc_reads: str | None = None, near_fibres: float = 0.0,
                                  near_fibre_count: int = NEAR_FIBRE_RAYS,
                                  direct_samples: int | str = "auto",
                                  shaded_fibres: float = 0.0,
                                  gathered_fibres: float = 0.0) -> Dataset:
    """The lighting database of a hair + mesh bake with the Chiang fibre, as
    :func:`prtcore.transport.hair_mesh.bake_hair_mesh_dataset` (mesh rows first, training
    lights first, the texels' direct light not kept). The same rays as the diffuse
    fibre's bake; the hair's direct light is :func:`chiang_direct`'s. ``exitance``
    (``hair.chiang.exitance``): what transport carries of every strand texel's outgoing
    radiance; with more than the average the solve runs over T_m + F T_h rows (the atlas
    texels have coefficient 0 alone), and the few texels whose truncated exitance dips
    below zero are clamped and counted. ``fibre_rays``: the fibre gather's rays per
    strand texel (``hair.gather_rays``; None: ``spec.gather_rays``, which the surface
    gather of the atlas always takes). ``arc_reads``: how an atlas ray reads the fibre it
    hits (:meth:`StrandRays.rays`' ``root``): None, its texel's exitance; "extrapolate" or
    "clamp", between the two texel centres about the hit. ``near_fibres``
    (``hair.chiang.near_fibres``): an atlas ray that meets a fibre closer than this many
    footprints of its texel is shaded at the point it meets
    (:mod:`prtcore.transport.fibre_near`, ``near_fibre_count`` rays from each such hit);
    0: every hit reads its strand texel. ``shaded_fibres`` (``hair.chiang.shaded_fibres``,
    above ``near_fibres``): an atlas ray that meets a fibre beyond ``near_fibres`` but
    closer than this many footprints keeps its texel read for the later bounces, and its
    first bounce takes the fibre's direct light from punctual lights shaded at the point
    met (:func:`~prtcore.transport.fibre_near.shaded_fibre_correction`).
    ``gathered_fibres`` (``hair.chiang.gathered_fibres``, above ``near_fibres``): an atlas
    ray that meets a fibre beyond ``near_fibres`` but closer than this many footprints
    is a near hit whose direct light is its texel's read (its rays gather the fibre's
    light from the mesh and the other fibres at the point; the shaded hits then start
    beyond it). ``direct_samples`` (``hair.direct_samples``): the hair's direct samples per strand
    texel (:func:`chiang_samples`)."""
    lights = (*tuple(lights_train), *tuple(lights_holdout))
    f, t_m, t_h = scene.triangle_count, texels.count, space.count
    r0 = tracer.rays_traced
    rays_to = near_hits_reach(near_fibres, gathered_fibres)
    reach = near_field_reach(texels, rays_to) if rays_to > 0 else None
    shade = (near_field_reach(texels, shaded_fibres) if shaded_fibres > rays_to
             else None)
    lit = near_field_reach(texels, near_fibres) if gathered_fibres > near_fibres else None
    strands = StrandRays(space, fibres, f, spec.seed, reach, shade, lit)
    gather = gather_operator(scene, texels, tracer, spec.gather_rays, spec.seed, timer,
                             near_field=spec.near_field, direct_samples=spec.direct_samples,
                             foreign=strands)
    n_f = EXITANCE_TERMS[exitance]
    frames = texel_frames(space) if needs_frames(exitance) else None
    t = t_m + t_h
    m_h = spec.gather_rays if fibre_rays is None else int(fibre_rays)
    mapper = HitMapper(scene, texels, tracer)
    near, shaded, near_lit = strands.near(), strands.shaded(), strands.near_lit()
    shaded_stats = {"hits": shaded.count}
    near_rays = None
    if near.count:  # the atlas's rays: counted with its gather's
        with timer.stage("near fibres"):
            near_rays = near_fibre_rays(near, gather.valid_rays, space, fibres, fibre, tracer,
                                        f, mapper, t_m, spec.seed + 3, near_fibre_count)
    r1 = tracer.rays_traced
    with timer.stage("fibre gather"):
        term = chiang_gather(space, tracer, fibres, f, m_h, spec.seed, fibre,
                             mesh_texels=mapper, mesh_columns=t_m)
        product = chiang_mesh_product(gather.matrix, strands.rays(arc_reads),
                                      gather.valid_rays,
                                      term.rays, term.mesh_hits, fibre, t_m, t_h,
                                      m_h, tracer.threads, exitance, frames, near_rays)
        del strands
    r2 = tracer.rays_traced
    fibre_stats, hits = term.stats, term.mesh_hits
    del term
    direct_points = direct_at_points(scene, tracer, lights, points, timer)
    r3 = tracer.rays_traced
    direct = np.zeros((product.shape[0], len(lights), 3), dtype=np.float32)
    with timer.stage("direct texels"):
        direct[:t_m] = direct_radiance(scene, tracer, lights, gather.direct_position,
                                       texels.normal, texels.albedo, timer, "direct texels")
    r4 = tracer.rays_traced
    with timer.stage("near field"):
        atlas_near = gather.near if gather.near is not None and gather.near.count else None
        reach = spec.near_field if hair_near is None else hair_near
        nf = chiang_hair_near_field(hits, texels, fibre, t_m, t_h, reach, m_h, exitance,
                                    frames) if reach > 0 and hits.row.size else None
        fields = [x for x in (atlas_near, nf) if x is not None and x.count]
        # one array for every first-bounce correction, each added into it in place: the
        # near fields' and the near fibre hits' (near_fibre_direct's rows)
        first = first_bounce_rows(*map(near_field_rows, fields), np.unique(near.row),
                                  np.unique(shaded.row), configurations=len(lights))
        for x in fields:
            near_field_correction(scene, tracer, x, lights, direct[:t_m], timer, into=first)
        del atlas_near, nf, fields
    r5 = tracer.rays_traced
    gather_stats = gather.stats
    valid_rays = gather.valid_rays
    del gather, hits  # the atlas's matrix and the fibre rays' mesh hits: not in the solve
    with timer.stage("direct fibres"):
        views = []  # each coefficient's strand rows of the stacked direct light
        for a in range(n_f):
            rows = product.coefficient_rows(a)
            views.append(direct[rows.start + (t_m if a == 0 else 0):rows.stop])
        chiang_direct(space, tracer, lights, chiang_samples(direct_samples,
                                                            spec.direct_samples),
                      spec.seed + 1, fibre, exitance, out=views)
        del views
    if near.count:  # the near hits' direct light: at the point met, or as read
        with timer.stage("near fibres (direct)"):  # its rays count as the direct fibres'
            split = near_lit is not None and not near_lit.all()
            point = near.subset(near_lit) if split else near
            if point.count:
                first = add_first_bounce(first, near_fibre_shaded(
                    point, valid_rays, space, fibres, fibre, tracer, lights, exitance,
                    near_fibre_direct(point, valid_rays, direct, product.coefficient_rows,
                                      t_m, t_h, n_f, frames,
                                      [k for k, light in enumerate(lights)
                                       if not shaded_at_point(light)]),
                    spec.seed + 4, stats=near_rays.stats))
            if split:  # beyond ``near_fibres``: the texels' reads
                texel_reads(near.subset(~near_lit), valid_rays, direct,
                            product.coefficient_rows, t_m, t_h, n_f, frames, None, first,
                            1, "gathered fibres (texel reads)")
                near_rays.stats["read_direct"] = int((~near_lit).sum())
            del point
    del near, near_lit
    if shaded.count:  # the shaded hits' direct light: at the point met, less the texel's
        with timer.stage("shaded fibres (direct)"):
            shaded_fibre_correction(shaded, valid_rays, space, fibres, fibre, tracer, lights,
                                    exitance, direct, product.coefficient_rows, t_m, frames,
                                    spec.seed + 5, first, shaded_stats)
    del shaded
    r6 = tracer.rays_traced
    albedo = np.full((product.shape[0], 3), 0.5)
    albedo[:t_m] = texels.albedo
    with timer.stage("indirect solve"):  # the corrections go after the first bounce
        t_solve = time.perf_counter()
        if spec.max_bounces >= 1:
            first_bounce_in_place(product, albedo, direct, first, tracer.threads)
        del first
        indirect, bounces, resid, solve_stats = solve_low_rank(
            product, albedo, direct, spec.max_bounces, spec.tolerance, rows=t,
            threads=tracer.threads, bounced=True)
        solve_stats["seconds"] = time.perf_counter() - t_solve  # the first bounce's too
    del direct
    if n_f > 1:  # the truncated exitance can dip below zero at a few texels; light cannot
        solve_stats["negative_clamped"] = int((indirect < 0).sum())
        np.maximum(indirect, np.float32(0), out=indirect)  # in place: no second copy
    stats = hair_mesh_stats(lights_train, lights_holdout, t_m, t_h, points.count,
                            gather_stats, fibre_stats, (r0, r1, r2, r3, r4, r5, r6),
                            solve_stats, model="chiang", exitance=exitance)
    if near_rays is not None:
        stats["near_fibres"] = near_rays.stats
    if shade is not None:
        stats["shaded_fibres"] = shaded_stats
    return Dataset(lights=lights, direct_points=direct_points, direct_texels=None,
                   indirect=indirect, iterations=bounces, residual=resid, stats=stats)
