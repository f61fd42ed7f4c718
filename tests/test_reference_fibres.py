"""The diffuse-fibre path tracer (prtcore/reference/fibres.py) and the fast fibre transport
checked against it, noise removed (two independent half estimates)."""

from __future__ import annotations

import numpy as np
import pytest

from prtcore.core.hair import make_hair
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
from prtcore.transport.strand_denoise import (
    DEFAULT_NEIGHBOURS,
    denoise_irradiance,
    neighbour_kernel,
)

LIGHTS = tangle_lights()


def test_a_lone_fibre_receives_no_indirect_light():
    s = build_strand_space(make_hair([np.array([[0, 0, 0], [0, 0, 1.0]])], 0.01), 2)
    tracer, mesh = hair_tracer(s)
    a, b = fibre_reference(s, tracer, mesh, 0, LIGHTS[:1], np.arange(2), 64, seed=0)
    assert not a.any() and not b.any()


def test_noise_corrected_error_removes_the_reference_noise():
    rng = np.random.default_rng(0)
    truth = rng.random((2000, 2, 3)) + 1
    a = truth + 0.3 * rng.normal(size=truth.shape)
    b = truth + 0.3 * rng.normal(size=truth.shape)
    fast = truth * 1.05
    err = noise_corrected_error(fast, a, b)
    assert err["bias"] == pytest.approx(0.05, abs=0.01)
    assert err["rrmse"] == pytest.approx(0.05, abs=0.015)
    assert err["raw_rrmse"] > 0.1


@pytest.fixture(scope="module")
def solved():
    h = tangle(600)
    s = build_strand_space(h, 4)
    tracer, mesh = hair_tracer(s)
    direct = fibre_direct(s, tracer, LIGHTS, samples=8, seed=1)
    term = fibre_gather(s, tracer, mesh, 0, rays=64, seed=2)
    const, *_ = solve_indirect(term.matrix, s.albedo, direct.mean, 64, 1e-4)
    harm, *_ = solve_indirect(term.matrix, s.albedo, direct.mean, 64, 1e-4,
                              first_bounce=harmonic_first_bounce(term, direct))
    sel = np.random.default_rng(0).choice(s.count, 120, replace=False)
    ref = fibre_reference(s, tracer, mesh, 0, LIGHTS, sel, paths=128, seed=7)
    avg = fibre_reference(s, tracer, mesh, 0, LIGHTS, sel, paths=128, seed=8,
                          radially_averaged=True)
    return sel, const, harm, ref, avg


def test_fast_fibre_transport_matches_its_own_model_without_bias(solved):
    """Against a reference that makes the same radially constant assumption, the gather
    and solve are unbiased (what is left is the gather's per-texel noise)."""
    sel, const, _, _, avg = solved
    err = noise_corrected_error(const[sel].astype(float), *avg)
    # 3 % (what benchmarks/hair_accuracy.py measures with 300 texels × 1024 paths) plus
    # three standard errors of this small sample's estimate
    assert abs(err["bias"]) < 0.03 + 3 * err["bias_se"], err


def test_harmonic_first_bounce_removes_most_of_the_radial_bias(solved):
    """Against the diffuse-fibre reference (each hit shaded with its own normal): radially
    constant storage is biased bright; the direct light's first harmonic in the first
    bounce removes most of it (benchmarks/hair_accuracy.py gives the figures)."""
    sel, const, harm, ref, _ = solved
    e_const = noise_corrected_error(const[sel].astype(float), *ref)
    e_harm = noise_corrected_error(harm[sel].astype(float), *ref)
    assert e_const["bias"] > 2 * e_const["bias_se"], e_const
    assert abs(e_harm["bias"]) < 0.03 + 3 * e_harm["bias_se"], e_harm
    assert e_harm["bias"] < e_const["bias"] - 0.04, (e_const, e_harm)


def test_denoising_the_strand_texels_removes_most_of_their_noise(solved):
    """The bake's denoising (prtcore.transport.strand_denoise, k = 32) against the
    diffuse-fibre reference: the fast path's per-texel error is mostly its own Monte Carlo
    noise, which averaging neighbouring texels removes without a bias (15 % → 8.5 % here;
    the 10k hairball at the bake's defaults: 16.4 % → 7.9 %, docs/hair.md)."""
    sel, _, harm, ref, _ = solved
    s = build_strand_space(tangle(600), 4)
    den = denoise_irradiance(neighbour_kernel(s.position, DEFAULT_NEIGHBOURS), harm.copy(),
                             s.albedo)
    before = noise_corrected_error(harm[sel].astype(float), *ref)
    after = noise_corrected_error(den[sel].astype(float), *ref)
    assert after["rrmse"] < 0.7 * before["rrmse"], (before, after)
    assert abs(after["bias"]) < 0.03 + 3 * after["bias_se"], after
