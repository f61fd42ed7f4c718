"""The transport stage: the lighting database of a bake (paper 4.1).

:func:`bake_dataset` traces the transport operators once (:func:`trace_operators`; today
the surface gather, :mod:`prtcore.transport.surface`), evaluates direct light at the
measurement points and the texels (:mod:`prtcore.transport.direct`), adds the operators'
first-bounce corrections (the near field) and solves all bounces for every configuration
at once over the sum of the operators (:func:`operator_matrix`,
:func:`prtcore.transport.solve.solve_indirect`). :func:`check_bake_memory` refuses, before
anything is allocated, a bake whose estimated peak memory — this stage's own arrays plus
each operator's :meth:`~prtcore.transport.base.TransportOperator.estimate_bytes` — exceeds
the limit.

A new operator (the subsurface random walk, ``prtcore/transport/subsurface.py``; see
:mod:`prtcore.transport.base`) joins by its name in ``operators``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from prtcore.core.errors import LimitExceeded
from prtcore.core.materials import clamp_albedo, has_translucency
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Scene
from prtcore.core.spec import TransportSpec
from prtcore.intake.points import MeasurementPoints
from prtcore.receivers.texels import TexelSpace
from prtcore.transport.base import TransportOperator, TransportTerm, operator_for
from prtcore.transport.coarse import coarsen_texels, grid_factor
from prtcore.transport.direct import direct_radiance
from prtcore.transport.solve import (
    SOLVE_BLOCK_BYTES,
    SOLVE_WORK_ARRAYS,
    SOLVE_WORK_ARRAYS_COARSE,
    solve_indirect,
)

#: The operators a bake runs, in order (registry names, :mod:`prtcore.transport.base`).
DEFAULT_OPERATORS = ("surface",)
#: ... when the scene has a translucent material (docs/subsurface.md)
TRANSLUCENT_OPERATORS = ("surface", "subsurface")
#: the timed stages of :func:`bake_dataset` after its operators', in the order they run
LIGHT_STAGES = ("direct points", "direct texels", "near field", "indirect solve")
#: the timed stages of :func:`bake_dataset`, in the order they run (every operator's)
STAGES = (*(operator_for(n).stage for n in TRANSLUCENT_OPERATORS), *LIGHT_STAGES)


def operators_for(scene: Scene) -> tuple[str, ...]:
    """The operators a bake of ``scene`` runs: the surface gather, and the subsurface
    walks when a material is translucent."""
    return TRANSLUCENT_OPERATORS if has_translucency(scene) else DEFAULT_OPERATORS
#: Memory model of a bake (bytes; :func:`estimate_bake_bytes`), measured as peak RSS on the
#: Cornell box at 512² and 1024² with 4–16 gather rays and 30–96 configurations
#: (tests/stability) and rounded up, so that it overestimates by 10–30 %: per covered
#: texel (texel space, gather bookkeeping, interpreter), per texel and configuration
#: (texel direct and indirect, (T, K, 3) float32 each, and at most as much again for the
#: near field's first-bounce correction), plus the solver's working arrays
#: (SOLVE_WORK_ARRAYS more per configuration, up to SOLVE_BLOCK_BYTES), plus each operator's own
#: (:mod:`prtcore.transport.surface`: per texel and gather ray, and per ray in flight), plus
#: the process itself (MEM_PROCESS: the interpreter, numpy/scipy/Embree and numba's compiled
#: kernels; measured 367 MiB peak RSS on a 64² Cornell bake with 796 texels, 277 MiB of it
#: after the imports). MEM_PER_TEXEL was 1536 until the lightmap filters were built in place
#: (f80ecec: 1.4 → 0.8 GiB for the three filters of a 1024² atlas); re-measured then
#: (peak RSS, Cornell, this model / peak): 512² M = 8 K = 30: 783 MiB, 1.45×; 512² M = 16
#: K = 96: 1223 MiB, 1.63×; 1024² M = 8 K = 30: 2129 MiB, 1.43×; 256² M = 16 K = 96:
#: 484 MiB, 1.71× (with 1536 it was 1.56–1.74×, the 512² check at the 1.6× edge).
MEM_PROCESS = 384 << 20
MEM_PER_TEXEL = 1024
MEM_PER_TEXEL_CONFIG = 36


@dataclass(frozen=True)
class Dataset:
    """The lighting database of a bake (paper 4.1), one column per configuration.

    lights : (K,) the configurations, training first, then held-out (``stats["train"]``
        says how many are training; the caller splits)
    direct_points : (P, K, 3) float32 direct outgoing radiance ρ/π·E_d at the measurement
        points, each the average of its supersample cluster
    direct_texels : (T, K, 3) float32 direct outgoing radiance at the texels, or None when
        not kept (:func:`light_configurations` ``keep_direct_texels``: the fit never reads
        it, and it is as large as the lightmaps themselves — 1.2 GB for a 1024² atlas and
        144 lights)
    indirect : (T, K, 3) float32 indirect outgoing radiance ρ/π·E_ind at the texels (light
        that bounced at least once, all bounces)
    iterations : bounces computed (1 = single bounce)
    residual : relative change of the last bounce, max over configurations and channels
        (``‖ΔE_k‖ / ‖E_k‖``); below ``spec.tolerance`` when ``stats["converged"]``
    stats : rays traced, seconds per sub-stage, buried/moved texels, back-face fraction, …
    """

    lights: tuple[Light, ...]
    direct_points: np.ndarray
    direct_texels: np.ndarray | None
    indirect: np.ndarray
    iterations: int
    residual: float
    stats: dict = field(default_factory=dict)



@dataclass(frozen=True)
class Traced:
    """One transport operator traced for one geometry: the operator, its term and the rays
    tracing it took."""

    operator: TransportOperator
    term: TransportTerm
    rays: int


def trace_operators(scene: Scene, texels: TexelSpace, tracer: RayTracer,
                    spec: TransportSpec, timer: StageTimer | None = None,
                    operators: Sequence[str] = DEFAULT_OPERATORS) -> tuple[Traced, ...]:
    """Build every operator of ``operators`` (registry names) once, in order, each timed as
    its ``stage``."""
    traced = []
    for op in (operator_for(n) for n in operators):
        rays0 = tracer.rays_traced
        term = op.build(scene, texels, tracer, spec, timer)
        traced.append(Traced(op, term, tracer.rays_traced - rays0))
    return tuple(traced)


def operator_matrix(traced: Sequence[Traced]) -> sp.csr_matrix:
    """The operator the solver iterates: the sum of the terms' (T, T) matrices, float32 CSR
    with sorted indices. One term's matrix is used as it is."""
    if len(traced) == 1:
        return traced[0].term.matrix
    total = traced[0].term.matrix.astype(np.float32)
    for t in traced[1:]:
        total = total + t.term.matrix.astype(np.float32)
    total = sp.csr_matrix(total)
    total.sum_duplicates()
    return total


def channel_matrices(traced: Sequence[Traced]) -> tuple | None:
    """The per-channel parts of the operator (three (T, T) float32 CSR, summed over the
    terms that have ``channel_matrices``), or None when no term has one."""
    parts = [t.term.channel_matrices for t in traced
             if getattr(t.term, "channel_matrices", None) is not None]
    if not parts:
        return None
    if len(parts) == 1:
        return tuple(parts[0])
    return tuple(sp.csr_matrix(sum(p[c].astype(np.float32) for p in parts))
                 for c in range(3))


def first_bounce_rows(*rows: np.ndarray, configurations: int
                      ) -> tuple[np.ndarray, np.ndarray] | None:
    """A zero first-bounce correction over the union of ``rows`` (each (r,) int), values
    (R, K = ``configurations``, 3) float32, for corrections to be added into in place
    (:func:`~prtcore.transport.direct.near_field_correction`'s ``into``,
    :func:`add_first_bounce`); None without rows."""
    if not rows or not sum(len(r) for r in rows):
        return None
    union = np.unique(np.concatenate([np.asarray(r, np.int64) for r in rows]))
    return union, np.zeros((len(union), int(configurations), 3), np.float32)


def add_first_bounce(a: tuple[np.ndarray, np.ndarray] | None,
                     b: tuple[np.ndarray, np.ndarray] | None
                     ) -> tuple[np.ndarray, np.ndarray] | None:
    """The sum of two first-bounce corrections (rows sorted unique, values (r, K, 3)).
    Where a's rows hold all of b's, b is added into a's values in place and a returned
    (no array of their union beside them: on the 10k head 1.4 GiB)."""
    if a is None or b is None:
        return a if b is None else b
    at = np.searchsorted(a[0], b[0])
    if not len(b[0]) or (at.max() < len(a[0]) and np.array_equal(a[0][at], b[0])):
        a[1][at] += b[1]
        return a
    rows = np.union1d(a[0], b[0])
    out = np.zeros((len(rows), *a[1].shape[1:]), dtype=np.float32)
    out[np.searchsorted(rows, a[0])] += a[1]
    out[np.searchsorted(rows, b[0])] += b[1]
    return rows, out


def estimate_bake_bytes(texels: int, configurations: int, transport: TransportSpec | int,
                        operators: Sequence[str] = DEFAULT_OPERATORS,
                        coarse: bool = False) -> int:
    """Peak memory of a bake with ``texels`` covered texels and ``configurations`` lights
    (training + held-out), from the measured model above (transport is the peak stage):
    this stage's arrays and every operator's
    :meth:`~prtcore.transport.base.TransportOperator.estimate_bytes`. transport : the
    transport spec, or its gather rays (the other keys at their defaults); coarse : the
    solve iterates on the coarse grid (fewer full-resolution work arrays,
    :func:`solve_uses_grid`)."""
    if not isinstance(transport, TransportSpec):
        transport = TransportSpec(gather_rays=int(transport))
    t, k = int(texels), int(configurations)
    arrays = SOLVE_WORK_ARRAYS_COARSE if coarse else SOLVE_WORK_ARRAYS
    own = MEM_PROCESS + t * MEM_PER_TEXEL + t * k * MEM_PER_TEXEL_CONFIG + min(
        arrays * t * k * 12, SOLVE_BLOCK_BYTES)
    return int(own + sum(operator_for(n).estimate_bytes(t, k, transport) for n in operators))


def solve_uses_grid(spec: TransportSpec, width: int, operators: Sequence[str]) -> bool:
    """Whether the solve of a surface bake iterates on the coarse grid: a grid factor above
    1 for the atlas ``width``, and no operator with per-channel matrices (the subsurface
    walks, which keep the full-resolution solve: :func:`light_texels`)."""
    return grid_factor(spec.coarse_grid, width) > 1 and not any(
        operator_for(n).per_channel for n in operators)


def check_bake_memory(source: str, texels: TexelSpace, spec, limit_bytes: int,
                      operators: Sequence[str] = DEFAULT_OPERATORS,
                      training: int | None = None) -> int:
    """Refuse (:class:`~prtcore.core.errors.LimitExceeded`) a bake whose estimated peak memory
    exceeds ``limit_bytes`` (``IntakeLimits.max_bake_bytes``), before transport allocates.
    spec : the :class:`~prtcore.core.spec.BakeSpec`; training : the training lights of the
    first pass (default ``spec.lights.count``, which must then be a number). Returns the
    estimate."""
    k = int(spec.lights.count if training is None else training) + spec.lights.holdout
    need = estimate_bake_bytes(texels.count, k, spec.transport, operators,
                               coarse=solve_uses_grid(spec.transport, texels.width, operators))
    if need > limit_bytes:
        gib = 1 << 30
        raise LimitExceeded(
            str(source), "", f"the bake would need about {need / gib:.1f} GiB "
            f"({texels.count} covered texels of a {texels.width}×{texels.height} atlas, {k} "
            f"lighting configurations, {spec.transport.gather_rays} gather rays); lower "
            "atlas.resolution, lights.count or transport.gather_rays",
            limit=f"max_bake_bytes={limit_bytes} ({limit_bytes / gib:.1f} GiB)")
    return need


@dataclass(frozen=True)
class TexelLighting:
    """Direct and indirect outgoing radiance at the texels for K lights.

    direct, indirect : (T, K, 3) float32 (direct None when not kept); iterations,
    residual : as :class:`Dataset`;
    stats : "rays" (direct texels, first-bounce corrections such as the near field),
    "solve", "direct_samples".
    """

    direct: np.ndarray | None
    indirect: np.ndarray
    iterations: int
    residual: float
    stats: dict


def light_texels(scene: Scene, texels: TexelSpace, tracer: RayTracer,
                 traced: Sequence[Traced], lights: Sequence[Light], spec: TransportSpec,
                 timer: StageTimer | None = None, keep_direct: bool = True) -> TexelLighting:
    """Direct light at the texels (averaged over the points an operator chose,
    :meth:`~prtcore.transport.base.TransportOperator.direct_position`, else at the texel
    samples), the operators' first-bounce corrections (the near field) and all bounces
    (:func:`solve_indirect`) for ``lights``, on operators traced once
    (:func:`trace_operators`). Sub-stages "direct texels", "near field", "indirect solve".
    keep_direct False: the solve writes the indirect light over the direct light's array
    (one (T, K, 3) float32 array less at the solve's peak) and ``direct`` is None."""
    timer = timer or StageTimer(quiet=True)
    positions = next((p for p in (t.operator.direct_position(t.term) for t in traced)
                      if p is not None), None)
    if positions is None:
        positions = np.asarray(texels.position, dtype=np.float64)[:, None, :]
    rays0 = tracer.rays_traced
    with timer.stage("direct texels"):
        direct = direct_radiance(scene, tracer, lights, positions,
                                 texels.normal, texels.albedo, timer, "direct texels")
    rays1 = tracer.rays_traced
    first = None
    for t in traced:
        first = add_first_bounce(first, t.operator.first_bounce(
            t.term, scene, tracer, tuple(lights), direct, timer))
    rays2 = tracer.rays_traced
    coarse = coarsen_texels(texels.xy, texels.position, texels.normal, texels.footprint,
                            texels.coverage, grid_factor(spec.coarse_grid, texels.width)) \
        if solve_uses_grid(spec, texels.width, [t.operator.name for t in traced]) else None
    indirect, bounces, resid, solve_stats = solve_indirect(
        operator_matrix(traced), texels.albedo, direct, spec.max_bounces, spec.tolerance,
        timer, threads=tracer.threads, first_bounce=first,
        channel_matrices=channel_matrices(traced), coarse=coarse,
        out=None if keep_direct else direct)
    if not keep_direct:
        direct = None
    stats = {"rays": {"direct_texels": rays1 - rays0, "near_field": rays2 - rays1},
             "solve": solve_stats, "direct_samples": int(positions.shape[1])}
    return TexelLighting(direct=direct, indirect=indirect, iterations=bounces,
                         residual=resid, stats=stats)


def direct_at_points(scene: Scene | None, tracer: RayTracer, lights: Sequence[Light],
                     points: MeasurementPoints, timer: StageTimer) -> np.ndarray:
    """Direct outgoing radiance at the measurement points (P, K, 3) float32, each the mean
    of its supersample cluster (timed as "direct points")."""
    with timer.stage("direct points"):
        cl = direct_radiance(scene, tracer, lights, points.cluster_position,
                             points.cluster_normal, points.cluster_albedo, timer,
                             "direct points")
        k = len(lights)
        direct_p = points.average_clusters(cl.reshape(len(cl), 3 * k).astype(np.float64))
        return direct_p.reshape(points.count, k, 3).astype(np.float32)


@dataclass(frozen=True, eq=False)
class Transport:
    """The operators of one geometry, traced once (:func:`open_transport`), ready to light
    any number of configurations (:func:`light_configurations`): automatic sizing adds
    training lights to a bake without tracing the operators again.

    tracer : the bake's ray tracer (counts rays); traced : the operators' terms;
    rays : rays tracing the operators took; seconds : the operators' stage times.
    """

    scene: Scene
    texels: TexelSpace
    points: MeasurementPoints
    spec: TransportSpec
    tracer: RayTracer
    traced: tuple[Traced, ...]
    rays: int
    seconds: dict
    #: the registry names of the operators traced (kept by :meth:`without_operators`)
    operators: tuple[str, ...] = ()

    def without_operators(self) -> Transport:
        """The same geometry with its traced operators dropped (their memory freed once
        unreferenced): what :func:`prtcore.transport.noise.independent_lightmaps`, which
        traces its own, still needs."""
        return dataclasses.replace(self, traced=())


def open_transport(scene: Scene, texels: TexelSpace, points: MeasurementPoints,
                   spec: TransportSpec | None = None, timer: StageTimer | None = None,
                   tracer: RayTracer | None = None,
                   operators: Sequence[str] | None = None) -> Transport:
    """Trace the operators of ``operators`` (registry names; None: :func:`operators_for` the
    scene, the subsurface walks join when a material is translucent) once, each timed as
    its stage."""
    spec = spec or TransportSpec()
    timer = timer or StageTimer(quiet=True)
    tracer = tracer or RayTracer(scene.positions, scene.faces, scene.radius)
    operators = operators_for(scene) if operators is None else tuple(operators)
    before = dict(timer.seconds)
    rays0 = tracer.rays_traced
    traced = trace_operators(scene, texels, tracer, spec, timer, operators)
    seconds = {t.operator.stage: timer.seconds[t.operator.stage]
               - before.get(t.operator.stage, 0.0) for t in traced}
    return Transport(scene=scene, texels=texels, points=points, spec=spec, tracer=tracer,
                     traced=traced, rays=tracer.rays_traced - rays0, seconds=seconds,
                     operators=tuple(t.operator.name for t in traced))


def light_configurations(tr: Transport, lights: Sequence[Light], n_train: int,
                         timer: StageTimer | None = None,
                         keep_direct_texels: bool = True) -> Dataset:
    """Direct light at the measurement points and the texels, and all bounces, for
    ``lights`` (the first ``n_train`` training, the rest held out) on operators traced once.
    Sub-stages "direct points", "direct texels", "near field", "indirect solve"."""
    timer = timer or StageTimer(quiet=True)
    scene, points, tracer = tr.scene, tr.points, tr.tracer
    lights = tuple(lights)
    before = dict(timer.seconds)
    rays1 = tracer.rays_traced
    direct_p = direct_at_points(scene, tracer, lights, points, timer)
    rays2 = tracer.rays_traced
    lit = light_texels(scene, tr.texels, tracer, tr.traced, lights, tr.spec, timer,
                       keep_direct=keep_direct_texels)
    _, clamped = clamp_albedo(np.asarray(tr.texels.albedo, dtype=np.float64))
    stats = {
        "train": int(n_train), "holdout": len(lights) - int(n_train),
        "texels": tr.texels.count, "points": points.count,
        "rays": {**{t.operator.stats_key: t.rays for t in tr.traced},
                 "direct_points": rays2 - rays1,
                 **lit.stats["rays"], "total": tr.rays + tracer.rays_traced - rays1},
        "direct_samples": lit.stats["direct_samples"],
        **{t.operator.stats_key: t.term.stats for t in tr.traced},
        "solve": lit.stats["solve"],
        "albedo_clamped_values": clamped,
        "seconds": {**tr.seconds, **{name: timer.seconds[name] - before.get(name, 0.0)
                                     for name in LIGHT_STAGES if name in timer.seconds}},
    }
    return Dataset(lights=lights, direct_points=direct_p, direct_texels=lit.direct,
                   indirect=lit.indirect, iterations=lit.iterations, residual=lit.residual,
                   stats=stats)


def add_training(data: Dataset, extra: Dataset) -> Dataset:
    """``data`` with the training configurations of ``extra`` (all its lights) appended
    after its own training ones and before its held-out ones. Stats: rays and stage seconds
    add up; iterations and residual are the worse of the two passes."""
    k = data.stats["train"]

    def cat(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
        if a is None or b is None:  # not kept (keep_direct_texels=False)
            return None
        return np.concatenate([a[:, :k], b, a[:, k:]], axis=1)

    stats = dict(data.stats)
    stats["train"] = k + len(extra.lights)
    stats["rays"] = {name: data.stats["rays"].get(name, 0) + extra.stats["rays"].get(name, 0)
                     for name in data.stats["rays"]}
    # the operators were traced once: their rays are in ``data`` only
    for t in (n for n in data.stats["rays"] if n not in ("direct_points", "direct_texels",
                                                         "near_field", "total")):
        stats["rays"][t] = data.stats["rays"][t]
    stats["rays"]["total"] = data.stats["rays"]["total"] + sum(
        extra.stats["rays"].get(n, 0) for n in ("direct_points", "direct_texels", "near_field"))
    stats["seconds"] = {n: v + (extra.stats["seconds"].get(n, 0.0) if n in LIGHT_STAGES
                                else 0.0) for n, v in data.stats["seconds"].items()}
    stats["passes"] = data.stats.get("passes", 1) + 1
    lights = (*data.lights[:k], *extra.lights, *data.lights[k:])
    return Dataset(lights=lights, direct_points=cat(data.direct_points, extra.direct_points),
                   direct_texels=cat(data.direct_texels, extra.direct_texels),
                   indirect=cat(data.indirect, extra.indirect),
                   iterations=max(data.iterations, extra.iterations),
                   residual=max(data.residual, extra.residual), stats=stats)


def bake_dataset(scene: Scene, texels: TexelSpace, points: MeasurementPoints,
                 lights_train: Sequence[Light], lights_holdout: Sequence[Light] = (),
                 spec: TransportSpec | None = None, timer: StageTimer | None = None,
                 tracer: RayTracer | None = None,
                 operators: Sequence[str] | None = None) -> Dataset:
    """The transport stage: the operators (gather), direct light, all bounces
    (:func:`open_transport` then :func:`light_configurations`).

    Training and held-out configurations are computed in one pass: ``Dataset.lights`` is
    ``(*lights_train, *lights_holdout)`` and every (…, K, 3) array follows that order;
    ``stats["train"]`` is ``len(lights_train)`` (the caller splits at it).
    Sub-stages are timed on ``timer`` as :data:`STAGES` ("gather operator",
    "direct points", "direct texels", "near field", "indirect solve"). operators :
    registry names (:mod:`prtcore.transport.base`), traced in order; None:
    :func:`operators_for` the scene.
    """
    tr = open_transport(scene, texels, points, spec, timer, tracer, operators)
    return light_configurations(tr, (*tuple(lights_train), *tuple(lights_holdout)),
                                len(lights_train), timer)
