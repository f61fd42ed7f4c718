"""The path tracer's volumetric random walk (prtcore/reference/medium.py) against closed
forms for slabs with an index-matched boundary and isotropic scattering.

* semi-infinite slab, diffuse (cosine) incidence: the spherical albedo
  ``r_s = 1 − 2 √(1 − ϖ) ∫₀¹ H(μ) μ dμ`` with Chandrasekhar's H-function (Chandrasekhar,
  *Radiative Transfer*, 1950, ch. V; van de Hulst, *Multiple Light Scattering*, 1980,
  tabulates the same), H solved here from its integral equation
  ``1/H(μ) = √(1 − ϖ) + ϖ/2 ∫₀¹ μ' H(μ') / (μ + μ') dμ'`` and checked against the
  identity ``∫₀¹ H dμ = 2/ϖ (1 − √(1 − ϖ))``;
* finite absorbing slab (ϖ = 0), diffuse incidence: transmittance ``2 E₃(τ)``;
  normal incidence: Beer–Lambert ``e^(−τ)``;
* finite scattering slab (τ = 1), diffuse and normal incidence, isotropic and
  Henyey–Greenstein g = 0.5: total reflectance and transmittance against adding-doubling
  (Prahl's ``iadpython``, an independent implementation; it gives 2E₃(τ) and e^(−τ) for
  ϖ = 0 to 2e-4, the tolerance added to the walks' standard errors);
* a conservative medium (ϖ = 1) in a closed box: every walk leaves (energy).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.special import expn

from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Subsurface
from prtcore.reference.medium import henyey_greenstein, medium_walk


def _slab(thickness: float, width: float):
    box = trimesh.creation.box(extents=(width, thickness, width))
    tracer = RayTracer(np.asarray(box.vertices, np.float64), np.asarray(box.faces, np.int64),
                       width)
    return tracer, np.ones(len(box.faces), dtype=bool)


def _medium(albedo: float) -> Subsurface:
    return Subsurface(sigma_t=np.ones(3), albedo=np.full(3, albedo))


def _cosine_down(n: int, rng) -> np.ndarray:
    u = rng.random((n, 2))
    r, phi = np.sqrt(u[:, 0]), 2 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), -np.sqrt(1 - u[:, 0]), r * np.sin(phi)], axis=1)


def spherical_albedo(omega: float, nodes: int = 200) -> float:
    mu, wq = np.polynomial.legendre.leggauss(nodes)
    mu, wq = (mu + 1) / 2, wq / 2
    h = np.ones(nodes)
    for _ in range(5000):
        new = 1 / (np.sqrt(1 - omega) + omega / 2 * (
            (wq * mu * h)[None, :] / (mu[:, None] + mu[None, :])).sum(axis=1))
        done = np.abs(new - h).max() < 1e-14
        h = new
        if done:
            break
    assert (wq * h).sum() == pytest.approx(2 / omega * (1 - np.sqrt(1 - omega)), rel=1e-9)
    return float(1 - 2 * np.sqrt(1 - omega) * (wq * h * mu).sum())


def _walk(thickness, width, albedo, directions, seed=0):
    tracer, faces = _slab(thickness, width)
    n = len(directions)
    origin = np.tile([0.0, thickness / 2 - 1e-6 * thickness, 0.0], (n, 1))
    idx, tri, bary, _, weight = medium_walk(tracer, _medium(albedo), faces, origin,
                                                directions, np.random.default_rng(seed))
    exit_y = tracer.surface_point(tri, bary)[:, 1]
    return idx, exit_y, weight[:, 0]


@pytest.mark.parametrize("omega", [0.5, 0.9])
def test_semi_infinite_slab_reflects_the_spherical_albedo(omega):
    rng = np.random.default_rng(1)
    n = 20_000
    _, y, w = _walk(40.0, 400.0, omega, _cosine_down(n, rng))
    top = y > 19.999
    r = w[top].sum() / n
    noise = w[top].std() / np.sqrt(n) + 1e-4
    # tolerance: 4 standard errors + 0.005 for the finite slab (40 mean free paths)
    assert r == pytest.approx(spherical_albedo(omega), abs=4 * noise + 0.005)


def test_the_albedo_inversion_gives_back_its_colour_as_the_spherical_albedo():
    # Chiang et al. 2016's α(A): a semi-infinite medium of albedo α(A) reflects ≈ A of
    # diffuse light (measured: within 0.005 for A in 0.3 … 0.8)
    from prtcore.core.materials import single_scattering_albedo

    for a in (0.3, 0.5, 0.8):
        assert spherical_albedo(float(single_scattering_albedo(a))) == pytest.approx(
            a, abs=0.01)


def test_absorbing_slab_transmits_2_e3_diffuse_and_beer_lambert_at_normal_incidence():
    rng = np.random.default_rng(2)
    n, tau = 40_000, 0.5
    _, y, w = _walk(tau, 2000.0, 0.0, _cosine_down(n, rng))
    t = w[y < -tau / 2 + 1e-6].sum() / n
    sd = np.sqrt(2 * expn(3, tau) * (1 - 2 * expn(3, tau)) / n)
    assert t == pytest.approx(2 * expn(3, tau), abs=4 * sd)
    normal = np.tile([0.0, -1.0, 0.0], (n, 1))
    _, y, w = _walk(tau, 10.0, 0.0, normal)
    t = w[y < -tau / 2 + 1e-6].sum() / n
    assert t == pytest.approx(np.exp(-tau), abs=4 * np.sqrt(np.exp(-tau) / n))


@pytest.mark.parametrize(("omega", "g"), [(0.5, 0.0), (0.9, 0.0), (0.9, 0.5)])
def test_finite_scattering_slab_matches_adding_doubling(omega, g):
    import iadpython as iad  # pinned dev dependency (pyproject.toml)

    # UR1/UT1: collimated normal incidence (UT1 with the unscattered part), URU/UTU:
    # diffuse incidence; index-matched boundary (n = 1 inside and out)
    ur1, ut1, uru, utu = (float(x) for x in iad.Sample(
        a=omega, b=1.0, g=g, n=1.0, n_above=1.0, n_below=1.0).rt())
    tracer, faces = _slab(1.0, 200.0)
    rng = np.random.default_rng(5)
    n = 40_000
    for directions, r_ref, t_ref in ((_cosine_down(n, rng), uru, utu),
                                     (np.tile([0.0, -1.0, 0.0], (n, 1)), ur1, ut1)):
        origin = np.tile([0.0, 0.5 - 1e-6, 0.0], (n, 1))
        medium = Subsurface(sigma_t=np.ones(3), albedo=np.full(3, omega), anisotropy=g)
        _, tri, bary, _, weight = medium_walk(tracer, medium, faces, origin, directions,
                                              np.random.default_rng(6))
        y = tracer.surface_point(tri, bary)[:, 1]
        w = weight[:, 0]
        for side, ref in ((y > 0.5 - 1e-6, r_ref), (y < -0.5 + 1e-6, t_ref)):
            got = w[side].sum() / n
            se = np.sqrt(max((w * side).var(), 1e-12) / n)
            assert got == pytest.approx(ref, abs=4 * se + 2e-3), (omega, g, got, ref)


def test_conservative_medium_in_a_closed_box_returns_all_light():
    rng = np.random.default_rng(3)
    n = 4000
    idx, _, w = _walk(2.0, 6.0, 1.0, _cosine_down(n, rng))
    assert len(np.unique(idx)) == n
    assert w.sum() == pytest.approx(n, rel=1e-12)


def test_hg_has_mean_cosine_g():
    rng = np.random.default_rng(4)
    w = np.tile([0.0, 1.0, 0.0], (100_000, 1))
    for g in (0.0, 0.6, -0.4):
        d = henyey_greenstein(w, g, rng.random((len(w), 2)))
        assert d[:, 1].mean() == pytest.approx(g, abs=5 / np.sqrt(len(w)))
