"""The transport of a hair + mesh bake (docs/hair.md, "Hair + glTF mesh in one bake"): one
lighting database over the mesh's atlas texels and the hair's strand texels, with light
going both ways between them.

Receivers are numbered mesh first: rows [0, T_m) are the atlas texels
(:class:`~prtcore.receivers.texels.TexelSpace`), rows [T_m, T_m + T_h) the strand texels
(:class:`~prtcore.receivers.strands.StrandSpace`); :class:`prtcore.receivers.combined.
CombinedSpace` holds both. The tracer is :func:`prtcore.transport.fibre.hair_tracer` of
the hair and the mesh: the mesh's triangles [0, F), then the fibre tubes.

The operator is four blocks::

    G = | G_mm  G_mh |   mesh rows: the surface gather's rays (gather_operator), a hit on a
        | G_hm  G_hh |   tube goes to the two texel centres about it on its strand
                         (:class:`StrandHits`, :meth:`StrandHits.interpolated`);
                         hair rows: the fibre gather's rays (fibre_gather), a hit on the
                         front of the mesh goes to its atlas texel (the surface gather's
                         HitMapper: the same TEXCOORD_1 lookup)

solved once by :func:`prtcore.transport.solve.solve_indirect` with the albedos stacked.
The first bounce carries the hair's direct light's first azimuthal harmonic into every row
that sees a fibre — the mesh's rows too (a scalp under hair sees the hair's unlit
underside, not its mean) — and the mesh rows' near field. Later bounces are radially
constant, as for hair alone, unless the strand texels stack their harmonics
(``harmonics`` all_bounces, mesh_bounces, turn_bounces, adaptive:
:func:`bake_hair_mesh_dataset`).
The hair shadows the head and the head shadows the hair: every shadow ray is traced
against both.
"""

from __future__ import annotations

import dataclasses
import functools
import threading
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from prtcore.core.fibres import FibreMesh, transported_frames
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Scene
from prtcore.core.sparse import permute_csr
from prtcore.core.spec import TransportSpec
from prtcore.intake.points import MeasurementPoints
from prtcore.receivers.strands import StrandSpace
from prtcore.receivers.texels import TexelSpace, morton_order
from prtcore.transport.dataset import Dataset, add_first_bounce, direct_at_points
from prtcore.transport.direct import direct_radiance, near_field_correction
from prtcore.transport.fibre import (
    STACKED_HARMONICS,
    STRAIGHT_TURN_DEG,
    FibreTerm,
    MeshHits,
    direct_and_first_bounce,
    direct_sample_count,
    fibre_direct,
    fibre_gather,
    fibre_hits,
    fourier_rows,
    harmonic_receivers,
)
from prtcore.transport.gather import HitMapper, NearField, gather_operator, near_field_reach
from prtcore.transport.solve import solve_indirect


class StrandHits:
    """The surface gather's hits on fibre tubes → strand texels
    (:class:`prtcore.transport.gather.ForeignHits`), with the azimuth of each hit on its
    fibre kept for the first bounce of the hair's direct harmonics. Impact parameters
    are drawn per batch from ``seed`` and the batch's first row, so the operator does not
    depend on which thread traced which batch."""

    def __init__(self, space: StrandSpace, fibres: FibreMesh, first: int, seed: int):
        self.space, self.fibres, self.first, self.seed = space, fibres, int(first), seed
        self.columns = space.count
        self.frame_u = transported_frames(space.hair)[1]
        # batch → (receiving atlas texels, strand texels hit, (cos ψ, sin ψ), arc fraction)
        self._parts: dict[int, tuple[np.ndarray, ...]] = {}
        self._lock = threading.Lock()

    def __call__(self, batch: int, rows: np.ndarray, triangle: np.ndarray,
                 barycentric: np.ndarray, direction: np.ndarray,
                 distance: np.ndarray | None = None) -> np.ndarray:
        rng = np.random.default_rng([self.seed, 5, batch])
        fh = fibre_hits(self.space, self.fibres, triangle - self.first, barycentric,
                        direction.astype(np.float64), rng, self.frame_u)
        with self._lock:
            self._parts[batch] = (rows, fh.texel, fh.cs.astype(np.float32),
                                  fh.arc.astype(np.float32))
        return fh.texel

    def interpolated(self, valid_rays: np.ndarray, orders: int, root: str | None
                     ) -> tuple[sp.csr_matrix, ...]:
        """The mesh rows' strand block G_mh and its 2H harmonics, 2H + 1 matrices
        (T_m, T_h) float32 CSR: each hit weighs 1/M_valid of its receiving texel
        (``valid_rays`` (T_m,), :attr:`prtcore.transport.gather.Gather.valid_rays`) times
        (1, cos ψ, sin ψ, cos 2ψ, …) up to order H (``orders``), read between the two
        texel centres about it along its strand
        (:meth:`~prtcore.receivers.strands.StrandSpace.arc_weights` with ``root``), or
        as its texel's mean (``root=None``)."""
        keys = sorted(self._parts)
        if keys:
            rows, texel, cs, frac = (np.concatenate([self._parts[k][i] for k in keys])
                                     for i in range(4))
        else:
            rows, texel = np.zeros(0, np.int64), np.zeros(0, np.int64)
            cs, frac = np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
        if root is None:
            cols, aw = texel[:, None], np.ones((len(texel), 1))
        else:
            cols, aw = self.space.arc_weights(texel, frac.astype(np.float64), root)
        del texel, frac
        # float32 entries and int32 indices, (n, 1 or 2) each, n the gather's rays that
        # met a fibre
        aw = aw.astype(np.float32) * (1 / np.maximum(valid_rays[rows], 1)).astype(
            np.float32)[:, None]
        r2 = np.repeat(rows.astype(np.int32), cols.shape[1])
        c2 = cols.ravel().astype(np.int32)
        del rows, cols
        shape = (len(valid_rays), self.columns)
        out = []
        for vb in fourier_rows(np.arctan2(cs[:, 1], cs[:, 0]), orders):
            m = sp.csr_matrix(((aw * vb[:, None]).ravel(), (r2, c2)), shape=shape)
            m.sum_duplicates()
            m.eliminate_zeros()
            m.sort_indices()
            out.append(m)
        return tuple(out)

    def harmonics(self, valid_rays: np.ndarray, orders: int = 1) -> tuple[sp.csr_matrix, ...]:
        """(cos ψ, sin ψ, cos 2ψ, …)-weighted G_mh up to order H (``orders``), each hit
        read as its texel's mean: 2H matrices (T_m, T_h) float32 CSR
        (:meth:`interpolated` with ``root=None``, less its mean block)."""
        return self.interpolated(valid_rays, orders, None)[1:]


def combined_operator(mesh_rows: sp.csr_matrix, term: FibreTerm) -> sp.csr_matrix:
    """The (T_m + T_h)² operator from the mesh rows (T_m, T_m + T_h) and the fibre
    gather's hair rows (``term.mesh`` (T_h, T_m) and ``term.matrix`` (T_h, T_h))."""
    m = sp.vstack([mesh_rows, sp.hstack([term.mesh, term.matrix], format="csr")],
                  format="csr", dtype=np.float32)
    m.sort_indices()
    return m


def harmonic_operator(mesh_rows: sp.csr_matrix, harmonics: tuple[sp.csr_matrix, ...],
                      term: FibreTerm) -> sp.csr_matrix:
    """The (T_m + nT_h)² operator of ``all_bounces`` over the state (mesh texels, strand
    texels' mean, cos φ, sin φ, cos 2φ, …; n = 2H + 1): mesh rows read a fibre hit's
    (mean, cos ψ, sin ψ, …) (``mesh_rows``' strand columns and
    :meth:`StrandHits.harmonics`); strand rows are
    :func:`prtcore.transport.fibre.harmonic_block` and ``term.mesh_block``."""
    top = sp.hstack([mesh_rows, *harmonics], format="csr", dtype=np.float32)
    bottom = sp.hstack([term.mesh_block, term.block], format="csr", dtype=np.float32)
    m = sp.vstack([top, bottom], format="csr", dtype=np.float32)
    m.sort_indices()
    return m


def hair_near_field(hits: MeshHits, texels: TexelSpace, t_m: int, reach: float,
                    rays: int) -> NearField:
    """The fibre gather's mesh hits within ``reach`` footprints of the atlas texel hit
    (|dP/dx| + |dP/dy|)/2 as a :class:`~prtcore.transport.gather.NearField` over the
    strand texels' mean rows (combined row T_m + i, weight 1/M): a fibre just above the
    scalp sees the scalp in its own shadow, which the texel's mean does not hold (the
    surface gather's near field, for the hair's rows).

    Not for the harmonic rows of the stacked variants. Correcting them as well (weights
    (2 cos φ_o, 2 sin φ_o)/M, every row a near hit's ray fed) was measured twice: on the
    10k curly and straight heads it takes 2 points of brightness off the scalp, on the
    sparse 2000-strand head it reads the scalp 3.4 points darker (all_bounces, covered
    texels −0.6 → −4.0 %) and doubles its per-texel error (4.0 → 8.9 %); on 500 strands
    at two bounces, −1.7 → −9.3 % (docs/hair.md, "Reading the hair from the scalp"). Why
    it overshoots where the hair is sparse is not understood, so it is not done."""
    close = np.flatnonzero(hits.t < near_field_reach(texels, reach)[hits.col])
    return NearField(row=t_m + hits.row[close], col=hits.col[close],
                     triangle=hits.triangle[close], barycentric=hits.barycentric[close],
                     weight=np.full(len(close), 1 / rays, np.float32))


def hair_mesh_stats(lights_train: Sequence[Light], lights_holdout: Sequence[Light],
                    t_m: int, t_h: int, points: int, gather: dict, fibre: dict,
                    marks: tuple[int, ...], solve: dict, **extra) -> dict:
    """The ``Dataset.stats`` of a hair + mesh bake: counts, both gathers' stats, the rays of
    each stage from the tracer's ray counter read before and after every stage (``marks``:
    7 readings: gather, fibre gather, direct points, direct texels, near field, direct
    fibres), the solve's, and ``extra`` keys."""
    r = marks
    return {"train": len(lights_train), "holdout": len(lights_holdout),
            "texels": {"mesh": t_m, "strands": t_h}, "points": points, "gather": gather,
            "fibre": fibre, **extra,
            "rays": {"gather": r[1] - r[0], "fibre_gather": r[2] - r[1],
                     "direct_points": r[3] - r[2], "direct_texels": r[4] - r[3],
                     "near_field": r[5] - r[4], "direct_fibres": r[6] - r[5],
                     "total": r[6] - r[0]},
            "solve": solve}


def state_order(texels: TexelSpace, space: StrandSpace, n: int) -> np.ndarray:
    """The order in which a hair + mesh bake solves its state (T_m + n·T_h rows: atlas
    texels, then n blocks of strand texels): the atlas and the strands' first block
    together in the Morton order of their positions, so that a head's texels and the
    hair above them sit side by side, then each further block in the strands' Morton
    order (:func:`prtcore.transport.solve.solve_indirect`'s ``order``). (T_m + n·T_h,)
    int64."""
    t_m, t_h = texels.count, space.count
    pos = np.concatenate([texels.position, space.position])
    head = morton_order(pos, np.stack([pos.min(axis=0), pos.max(axis=0)]))
    return np.concatenate([head, *(t_m + b * t_h + space.morton for b in range(1, n))])


def per_piece(count: int, pieces: int) -> int:
    """⌈n/S⌉: a whole strand texel's ``count`` fibre-gather rays (M) or facing samples
    (J) shared among its S ``pieces`` (``hair.arc_subdivision``), about n in all."""
    return -(-int(count) // int(pieces))


def bake_hair_mesh_dataset(scene: Scene, texels: TexelSpace, space: StrandSpace,
                           fibres: FibreMesh, points: MeasurementPoints, tracer: RayTracer,
                           lights_train: Sequence[Light],
                           lights_holdout: Sequence[Light] = (),
                           spec: TransportSpec | None = None,
                           timer: StageTimer | None = None,
                           harmonics: str = "first_bounce", orders: int = 1,
                           hair_near: float | None = None, direct_estimator: str = "facing",
                           direct_samples: int | str = "auto",
                           arc_reads: str | None = "extrapolate",
                           straight_turn: float = STRAIGHT_TURN_DEG,
                           arc_subdivision: int = 1,
                           fibre_rays: int | None = None) -> Dataset:
    """The lighting database of a hair + mesh bake (``Dataset``: direct at the points,
    indirect at the T_m + T_h texels, mesh first; training lights first; the texels'
    direct light is not kept — the solve writes over it). ``tracer`` and ``fibres``:
    :func:`prtcore.transport.fibre.hair_tracer` of ``space`` and ``scene``. Both gathers
    take ``spec.gather_rays`` rays per texel (the fibre gather ``fibre_rays``,
    ``hair.gather_rays``, where given); the mesh's direct light is averaged over
    ``spec.direct_samples`` points per texel; the hair's comes from ``direct_estimator``
    (``hair.direct``) with ``direct_samples`` (``hair.direct_samples``,
    :func:`prtcore.transport.fibre.direct_sample_count`).

    harmonics (``hair.harmonics``): "first_bounce" — the hair's direct first harmonic rides
    the first bounce of every row; "all_bounces" — the strand texels carry (mean, cos,
    sin) through every bounce and the mesh rows read them at the azimuth they hit
    (:func:`harmonic_operator`, solved by the Neumann series): the light that goes head →
    hair → head keeps the side of the fibre that faced the head; ``orders`` (H) harmonics
    (the state is T_m + (2H + 1) T_h rows; the sampled estimator then takes max(4H, J)
    samples per texel); "mesh_bounces" — the same state and solve, but a strand
    texel's harmonics take light from the mesh (and the direct light) only, never from
    other fibres: later fibre-to-fibre bounces stay radially constant, as in
    first_bounce, while the head → hair → head light keeps its side (docs/hair.md,
    "Which harmonics with a mesh"); "turn_bounces" — all_bounces' rows for the texels
    whose fibre turns less than ``straight_turn`` degrees along them
    (:func:`~prtcore.receivers.strands.texel_turn`), mesh_bounces' for the others
    (docs/hair.md, "Harmonics by how far the fibre turns"); "adaptive" — all_bounces' rows
    when fewer than :data:`~prtcore.transport.fibre.SPARSE_FIBRE_SHARE` of the fibre
    gather's rays meet another fibre (sparse hair), turn_bounces' otherwise (docs/hair.md,
    "Sparse hair takes every fibre's harmonics").

    arc_reads : how a mesh row reads a fibre it hits (:meth:`StrandHits.interpolated`):
    "extrapolate" (between the two texel centres about the hit along its strand, the
    root's slope continued below its first centre), "clamp" (held at the root's first
    centre), or None (the texel's mean, as before 2026-12-05). A scalp's rays hit the
    strands near their roots, where the light falls toward the scalp within a texel
    (docs/hair.md, "Reading the hair from the scalp").

    arc_subdivision : S (``hair.arc_subdivision``): the strand texels are transported as
    S pieces each (:meth:`~prtcore.receivers.strands.StrandSpace.subdivided`): the fibre
    gather traces ⌈M/S⌉ rays per piece and the facing estimator ⌈J/S⌉ samples, so the
    rays are about those of S = 1; everything reads and solves the pieces, and each
    texel's indirect light is the mean of its pieces'
    (:meth:`~prtcore.receivers.strands.StrandSpace.coarsen`). A whole texel's light
    read where another fibre or the scalp sees it is bright under dense curls: the hits
    fall on the deep part of a texel whose other end is lit (docs/hair.md, "Transporting
    each texel in pieces"). The rows are ``space``'s either way."""
    spec = spec or TransportSpec()
    pieces = int(arc_subdivision)
    out_space, space = space, space.subdivided(pieces)
    fibre_rays = per_piece(spec.gather_rays if fibre_rays is None else fibre_rays, pieces)
    samples = direct_sample_count(direct_estimator, direct_samples, spec.direct_samples,
                                  orders if harmonics in STACKED_HARMONICS else 1)
    if direct_estimator == "facing":  # arc samples: ⌈J/S⌉ per piece (the sampled
        # estimator's J > 2H azimuths per piece keep its harmonics unaliased)
        samples = per_piece(samples, pieces)
    timer = timer or StageTimer(quiet=True)
    lights = (*tuple(lights_train), *tuple(lights_holdout))
    f, t_m, t_h = scene.triangle_count, texels.count, space.count
    r0 = tracer.rays_traced
    strands = StrandHits(space, fibres, f, spec.seed)
    gather = gather_operator(scene, texels, tracer, spec.gather_rays, spec.seed, timer,
                             near_field=spec.near_field,
                             direct_samples=spec.direct_samples, foreign=strands)
    r1 = tracer.rays_traced
    everything = harmonics in STACKED_HARMONICS
    with timer.stage("fibre gather"):
        term = fibre_gather(space, tracer, fibres, f, fibre_rays, spec.seed,
                            all_bounces=everything, orders=orders,
                            harmonic_rows=functools.partial(harmonic_receivers, harmonics,
                                                            space, straight_turn),
                            mesh_texels=HitMapper(scene, texels, tracer), mesh_columns=t_m)
    r2 = tracer.rays_traced
    if arc_reads is None:
        mh = strands.harmonics(gather.valid_rays, orders if everything else 1)
    else:  # the mesh rows' strand columns, read along the arc (the gather's own strand
        # columns hold each hit as its texel's mean)
        read = strands.interpolated(gather.valid_rays, orders if everything else 1,
                                    arc_reads)
        gather = dataclasses.replace(gather, matrix=sp.hstack(
            [gather.matrix[:, :t_m], read[0]], format="csr", dtype=np.float32))
        mh = read[1:]
        del read
    if everything:
        matrix = harmonic_operator(gather.matrix, mh, term)
    else:
        matrix = combined_operator(gather.matrix, term)
        both = FibreTerm(matrix=term.matrix, harmonics=tuple(
            sp.vstack([a, b], format="csr", dtype=np.float32)
            for a, b in zip(mh, term.harmonics, strict=True)), stats=term.stats)
    fibre_stats = term.stats
    mesh_hits = term.mesh_hits
    del term, mh
    n = 2 * orders + 1 if everything else 1  # state rows per strand texel
    order = state_order(texels, space, n)
    with timer.stage("indirect solve"):  # the solve's operator in Morton order, made
        # before the direct light's arrays exist (solve_indirect's order)
        matrix = permute_csr(matrix, order)
    direct_points = direct_at_points(scene, tracer, lights, points, timer)
    r3 = tracer.rays_traced
    rows = t_m + n * t_h
    direct = np.empty((rows, len(lights), 3), dtype=np.float32)
    with timer.stage("direct texels"):
        direct[:t_m] = direct_radiance(scene, tracer, lights, gather.direct_position,
                                       texels.normal, texels.albedo, timer, "direct texels")
    r4 = tracer.rays_traced
    near = None
    if gather.near is not None and gather.near.count:
        with timer.stage("near field"):
            near = near_field_correction(scene, tracer, gather.near, lights, direct[:t_m],
                                         timer)
    reach = spec.near_field if hair_near is None else hair_near
    if reach > 0 and mesh_hits.row.size:
        with timer.stage("near field"):
            nf = hair_near_field(mesh_hits, texels, t_m, reach, fibre_rays)
            if nf.count:
                near = add_first_bounce(near, near_field_correction(
                    scene, tracer, nf, lights, direct[:t_m], timer))
    r5 = tracer.rays_traced
    with timer.stage("direct fibres"):
        if everything:
            d = fibre_direct(space, tracer, lights, samples, spec.seed + 1,
                             harmonics=orders, estimator=direct_estimator)
            direct[t_m:t_m + t_h] = d.mean
            for b in range(2 * orders):
                direct[t_m + (b + 1) * t_h:t_m + (b + 2) * t_h] = d.harmonics[b]
            del d
            first = near
        else:
            direct[t_m:], first = direct_and_first_bounce(
                space, tracer, lights, samples, spec.seed + 1, both,
                estimator=direct_estimator)
            first = add_first_bounce(first, near)
    r6 = tracer.rays_traced
    rho_h = np.asarray(space.albedo, np.float64)
    albedo = np.concatenate([np.asarray(texels.albedo, np.float64),
                             *([rho_h] * n)])
    indirect, bounces, resid, solve_stats = solve_indirect(
        matrix, albedo, direct, spec.max_bounces, spec.tolerance, timer,
        method="neumann" if everything else "chebyshev", threads=tracer.threads,
        first_bounce=first, out=direct, order=order)
    if pieces > 1:  # each texel the mean of its pieces (before the clamp below: a piece
        # below zero beside a brighter one is not light to add)
        indirect = np.concatenate([indirect[:t_m],
                                   StrandSpace.coarsen(indirect[t_m:t_m + t_h], pieces)])
    if everything:  # a truncated azimuthal series can dip below zero: clamped, counted
        indirect = indirect[:t_m + out_space.count]
        solve_stats["negative_clamped"] = int((indirect < 0).sum())
        np.maximum(indirect, np.float32(0), out=indirect)
    stats = hair_mesh_stats(lights_train, lights_holdout, t_m, out_space.count,
                            points.count, gather.stats, fibre_stats,
                            (r0, r1, r2, r3, r4, r5, r6), solve_stats, harmonics=harmonics,
                            arc_subdivision={"pieces": pieces, "rays_per_piece": fibre_rays,
                                             "direct_samples_per_piece": samples})
    return Dataset(lights=lights, direct_points=direct_points, direct_texels=None,
                   indirect=indirect, iterations=bounces, residual=resid, stats=stats)
