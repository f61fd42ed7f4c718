"""The transport stage of a hair bake: the lighting database over strand texels.

As :func:`prtcore.transport.dataset.bake_dataset` for surfaces, with the fibre operators
of :mod:`prtcore.transport.fibre`: direct light at the measurement points (on the hull of
the hair) and at the strand texels (with its azimuthal harmonics), the fibre gather, the
first bounce with the harmonics, and all bounces for every configuration at once. With
the Chiang fibre (``hair.fibre = "chiang"``) the same stages go through
:mod:`prtcore.transport.fibre_chiang`.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np

from prtcore.core.fibres import DEFAULT_SIDES, fibre_tubes
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Scene
from prtcore.core.sparse import permute_csr
from prtcore.core.spec import TransportSpec
from prtcore.intake.points import MeasurementPoints
from prtcore.receivers.strands import StrandSpace
from prtcore.transport.dataset import Dataset, direct_at_points
from prtcore.transport.fibre import (
    STACKED_HARMONICS,
    direct_and_first_bounce,
    direct_sample_count,
    fibre_direct,
    fibre_gather,
    harmonic_receivers,
)
from prtcore.transport.fibre_chiang import (
    ChiangFibre,
    chiang_direct,
    chiang_gather,
    chiang_operator,
    chiang_samples,
)
from prtcore.transport.low_rank import solve_low_rank
from prtcore.transport.solve import solve_indirect

#: the timed stages of :func:`bake_hair_dataset`, in the order they run
STAGES = ("fibre gather", "direct points", "direct fibres", "indirect solve")


def bake_hair_dataset(space: StrandSpace, points: MeasurementPoints, tracer: RayTracer,
                      lights_train: Sequence[Light], lights_holdout: Sequence[Light] = (),
                      spec: TransportSpec | None = None, timer: StageTimer | None = None,
                      scene: Scene | None = None, harmonics: str = "first_bounce",
                      keep_direct_texels: bool = True, fibre: ChiangFibre | None = None,
                      chiang_exitance: str = "isotropic", direct_estimator: str = "facing",
                      direct_samples: int | str = "auto") -> Dataset:
    """The lighting database of a hair bake (``Dataset``: direct at the points, direct and
    indirect at the strand texels, training lights first). ``tracer`` is
    :func:`prtcore.transport.fibre.hair_tracer` of ``space`` and ``scene`` (the mesh of a
    hair + mesh bake, or None). ``direct_estimator`` (``hair.direct``): the diffuse fibre's
    direct-light estimator, ``direct_samples`` (``hair.direct_samples``) its samples per
    texel (:func:`prtcore.transport.fibre.direct_sample_count`).

    harmonics (``hair.harmonics``): "first_bounce" — the direct light's first azimuthal
    harmonic rides the first bounce, later bounces are radially constant; "all_bounces" —
    every texel carries (mean, cos, sin) through every bounce
    (:func:`prtcore.transport.fibre.harmonic_block`: 9× the operator, solved by the
    Neumann series; docs/hair.md has the measured gain and cost); "turn_bounces" — the
    same state, but only the texels whose fibre turns less than
    :data:`~prtcore.transport.fibre.STRAIGHT_TURN_DEG` along them take other fibres'
    light in their harmonics, the others' hold the direct light's
    (:func:`~prtcore.transport.fibre.harmonic_receivers`); "adaptive" — all_bounces when
    fewer than :data:`~prtcore.transport.fibre.SPARSE_FIBRE_SHARE` of the gather's rays
    meet another fibre, turn_bounces otherwise.

    keep_direct_texels : False — the solve writes the indirect light over the texels' direct
    light (``Dataset.direct_texels`` is then None; the fit never reads it), which saves one
    (T, K, 3) float32 array at the peak: 2.4 GB at 140k strands, K = 144.

    fibre : the Chiang fibre (``hair.fibre = "chiang"``,
    :mod:`prtcore.transport.fibre_chiang`; ``harmonics`` is then ignored), or None for the
    diffuse fibre; ``chiang_exitance`` (``hair.chiang.exitance``): what its transport
    carries of each texel's outgoing radiance, "isotropic", "linear", "quadratic" or
    "second_order"."""
    if fibre is not None:
        return _chiang_dataset(space, points, tracer, lights_train, lights_holdout,
                               spec or TransportSpec(), timer or StageTimer(quiet=True),
                               scene, keep_direct_texels, fibre, chiang_exitance,
                               direct_samples)
    spec = spec or TransportSpec()
    timer = timer or StageTimer(quiet=True)
    lights = (*tuple(lights_train), *tuple(lights_holdout))
    # the stacked variants; mesh_bounces without a mesh is first_bounce
    everything = harmonics in STACKED_HARMONICS and harmonics != "mesh_bounces"
    samples = direct_sample_count(direct_estimator, direct_samples, spec.direct_samples)
    rays0 = tracer.rays_traced
    with timer.stage("fibre gather"):
        term = fibre_gather(space, tracer, fibre_tubes(space.hair, DEFAULT_SIDES),
                            scene.triangle_count if scene is not None else 0,
                            spec.gather_rays, spec.seed, all_bounces=everything,
                            harmonic_rows=functools.partial(harmonic_receivers, harmonics,
                                                            space))
    rays1 = tracer.rays_traced
    direct_points = direct_at_points(scene, tracer, lights, points, timer)
    rays2 = tracer.rays_traced
    with timer.stage("direct fibres"):
        if everything:
            direct = fibre_direct(space, tracer, lights, samples, spec.seed + 1,
                                  estimator=direct_estimator)
            direct_mean = direct.mean
        else:  # the first bounce made light block by light block, harmonics not kept
            direct_mean, first = direct_and_first_bounce(
                space, tracer, lights, samples, spec.seed + 1, term, estimator=direct_estimator)
    rays3 = tracer.rays_traced
    t = space.count
    if everything:
        stacked = np.concatenate([direct.mean, direct.harmonics[0], direct.harmonics[1]])
        order = np.concatenate([space.morton + b * t for b in range(3)])
        with timer.stage("indirect solve"):  # its rows in Morton order (solve_indirect)
            block, fibre_stats = permute_csr(term.block, order), term.stats
        del term  # the operator in strand order goes before the solve's arrays come
        indirect, bounces, resid, solve_stats = solve_indirect(
            block, np.tile(space.albedo, (3, 1)), stacked, spec.max_bounces,
            spec.tolerance, timer, method="neumann", threads=tracer.threads, order=order)
        # the truncated azimuthal series of a noisy gather can dip below zero at a few
        # texels; light cannot: clamped, and counted
        negative = int((indirect[:t] < 0).sum())
        indirect = np.maximum(indirect[:t], np.float32(0))
        solve_stats["negative_clamped"] = negative
    else:
        with timer.stage("indirect solve"):  # its rows in Morton order (solve_indirect)
            matrix, fibre_stats = permute_csr(term.matrix, space.morton), term.stats
        del term  # the operator in strand order goes before the solve's arrays come
        indirect, bounces, resid, solve_stats = solve_indirect(
            matrix, space.albedo, direct_mean, spec.max_bounces, spec.tolerance, timer,
            threads=tracer.threads, first_bounce=first,
            out=None if keep_direct_texels else direct_mean, order=space.morton)
    stats = {"train": len(lights_train), "fibre": fibre_stats, "harmonics": harmonics,
             "rays": {"fibre_gather": rays1 - rays0, "direct_points": rays2 - rays1,
                      "direct_fibres": rays3 - rays2}, "solve": solve_stats}
    return Dataset(lights=lights, direct_points=direct_points,
                   direct_texels=direct_mean if keep_direct_texels else None,
                   indirect=indirect, iterations=bounces, residual=resid, stats=stats)


def _chiang_dataset(space: StrandSpace, points: MeasurementPoints, tracer: RayTracer,
                    lights_train: Sequence[Light], lights_holdout: Sequence[Light],
                    spec: TransportSpec, timer: StageTimer, scene: Scene | None,
                    keep_direct_texels: bool, fibre: ChiangFibre,
                    exitance: str = "isotropic", direct_samples: int | str = "auto"
                    ) -> Dataset:
    """:func:`bake_hair_dataset` with the Chiang fibre: the same stages and rays, every
    gather ray and direct sample weighted by the fibre's directional albedo, the three
    channels' operators solved together; ``direct_samples`` J per texel
    (:func:`~prtcore.transport.fibre_chiang.chiang_samples`)."""
    lights = (*tuple(lights_train), *tuple(lights_holdout))
    rays0 = tracer.rays_traced
    with timer.stage("fibre gather"):  # the operator made from the rays, which then go
        term = chiang_gather(space, tracer, fibre_tubes(space.hair, DEFAULT_SIDES),
                             scene.triangle_count if scene is not None else 0,
                             spec.gather_rays, spec.seed, fibre)
        fibre_stats = term.stats
        product, rho = chiang_operator(space, term, fibre, spec.gather_rays, exitance,
                                       tracer.threads)
        del term
    rays1 = tracer.rays_traced
    direct_points = direct_at_points(scene, tracer, lights, points, timer)
    rays2 = tracer.rays_traced
    with timer.stage("direct fibres"):
        direct = chiang_direct(space, tracer, lights,
                               chiang_samples(direct_samples, spec.direct_samples),
                               spec.seed + 1, fibre, exitance)
    rays3 = tracer.rays_traced
    t = space.count
    direct_mean = direct[0].copy() if keep_direct_texels else None
    stacked = direct.reshape(-1, *direct.shape[2:])  # the coefficients stacked: (FT, K, 3)
    del direct
    indirect, bounces, resid, solve_stats = solve_low_rank(
        product, rho, stacked, spec.max_bounces, spec.tolerance, rows=t, timer=timer,
        threads=tracer.threads)
    del stacked
    if exitance != "isotropic":  # the truncated exitance can dip below zero at a few
        # texels; light cannot
        solve_stats["negative_clamped"] = int((indirect < 0).sum())
        np.maximum(indirect, np.float32(0), out=indirect)  # in place: no second copy
    stats = {"train": len(lights_train), "fibre": fibre_stats, "model": "chiang",
             "exitance": exitance,
             "rays": {"fibre_gather": rays1 - rays0, "direct_points": rays2 - rays1,
                      "direct_fibres": rays3 - rays2}, "solve": solve_stats}
    return Dataset(lights=lights, direct_points=direct_points,
                   direct_texels=direct_mean if keep_direct_texels else None,
                   indirect=indirect, iterations=bounces, residual=resid, stats=stats)
