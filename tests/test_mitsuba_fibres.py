"""Mitsuba 3 spot checks of the diffuse-fibre model (prtcore/reference/mitsuba_fibres.py):
Mitsuba's round curves, BSDF and path tracer against prtcore's fibre path tracer and fast
transport, noise of both sides removed. Slow (Mitsuba's scalar variant traces one ray per
Python call): runs with ``pytest -m ""``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from prtcore.receivers.strands import build_strand_space
from prtcore.reference.fibres import fibre_reference, noise_corrected_error
from prtcore.scenes.hair import tangle, tangle_lights
from prtcore.transport.fibre import (
    fibre_direct,
    fibre_gather,
    hair_tracer,
    harmonic_first_bounce,
)
from prtcore.transport.solve import solve_indirect

pytest.importorskip("mitsuba")
pytestmark = pytest.mark.slow


def test_mitsuba_agrees_with_the_fibre_path_tracer_and_the_fast_path():
    from prtcore.reference.mitsuba_fibres import mitsuba_fibre_indirect

    hair = tangle(1000)
    hair = dataclasses.replace(hair, color=np.tile([0.8, 0.6, 0.4], (hair.point_count, 1)))
    space = build_strand_space(hair, 12)
    tracer, mesh = hair_tracer(space)
    lights = tangle_lights()
    direct = fibre_direct(space, tracer, lights, 8, seed=1)
    term = fibre_gather(space, tracer, mesh, 0, rays=128, seed=2)
    fast, *_ = solve_indirect(term.matrix, space.albedo, direct.mean, 64, 1e-4,
                              first_bounce=harmonic_first_bounce(term, direct))
    sel = np.random.default_rng(0).choice(space.count, 300, replace=False)
    mit = mitsuba_fibre_indirect(space, lights, sel, 1024, seed=5)
    ours = fibre_reference(space, tracer, mesh, 0, lights, sel, 1024, seed=7)
    pt = noise_corrected_error(ours, *mit)
    fa = noise_corrected_error(fast[sel].astype(float), *mit)
    # benchmarks/hair_mitsuba.py (600 texels × 2048 Mitsuba rays, 2048 paths): the path
    # tracer through 3-sided tubes is +1.7 ± 0.3 % of Mitsuba's round fibres, rRMSE 3.9 %
    # (the tubes' doing: +0.5 % with 6 sides); the issue's bound is 2 % and 8 %. Here with
    # a quarter of the samples: within 2 % plus three standard errors, and 8 %
    assert abs(pt["bias"]) < 0.02 + 3 * pt["bias_se"], pt
    assert pt["rrmse"] < 0.08, pt
    # the fast path as bakes run it (first-bounce harmonic), M = 128, J = 8: −0.8 % at
    # M = 256 in the benchmark; its rRMSE is the gather's noise (≈ 11 %), not bounded here
    assert abs(fa["bias"]) < 0.05 + 3 * fa["bias_se"], fa


@pytest.mark.parametrize("color", [(0.8, 0.6, 0.4), (0.3, 0.2, 0.1)])
def test_mitsuba_hair_bsdf_agrees_with_the_chiang_path_tracer(color):
    """Mitsuba's own `hair` BSDF (Chiang et al. 2016, on B-spline curves that are our
    polylines) against prtcore.reference.chiang. Measured (100–300 texels × 1024 rays,
    2048 paths): light hair +2.1 ± 2.2 %, rRMSE 1.5 %; dark hair −0.1 ± 1.4 %, 4.2 %;
    with this test's 150 texels × 2048 rays and 4096 paths: −1.2 ± 1.1 % and +2.8 ± 1.3 %,
    rRMSE within the noise (at 1024 rays and 2048 paths the noise-corrected rRMSE, a
    difference of two near-equal noise terms, came out 4 % or 8 % by the draw).
    A BCSDF wrong in its tilt, lobes or σ units fails by far more."""
    from prtcore.core.spec import ChiangSpec
    from prtcore.reference.chiang import chiang_reference
    from prtcore.reference.mitsuba_fibres import mitsuba_fibre_indirect
    from prtcore.transport.fibre_chiang import chiang_fibre

    hair = tangle(1000)
    hair = dataclasses.replace(hair, color=np.tile(color, (hair.point_count, 1)))
    space = build_strand_space(hair, 12)
    tracer, mesh = hair_tracer(space)
    lights = tangle_lights()
    fibre = chiang_fibre(ChiangSpec(), space)
    sel = np.random.default_rng(5).choice(space.count, 150, replace=False)
    ours = chiang_reference(space, tracer, mesh, 0, lights, sel, 4096, 7, fibre.params,
                            fibre.sigma_points)
    mit = mitsuba_fibre_indirect(space, lights, sel, 2048, 9, chiang=dataclasses.replace(
        fibre.params, sigma_a=tuple(fibre.sigma_texels[0])))
    e = noise_corrected_error(ours, *mit)
    assert abs(e["bias"]) < 0.02 + 3 * e["bias_se"], e
    assert e["rrmse"] < 0.08, e
