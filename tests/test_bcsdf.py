"""The Chiang et al. 2016 hair BCSDF (prtcore/core/bcsdf.py): energy conservation (white
furnace), absorption, attenuation identities."""

from __future__ import annotations

import numpy as np
import pytest

from prtcore.core.bcsdf import ChiangParams, attenuation, scattering, sigma_a_from_melanin


def _sphere(rng, n):
    w = rng.normal(size=(n, 3))
    return w / np.linalg.norm(w, axis=1, keepdims=True)


def _albedo(params: ChiangParams, seed: int, n: int = 400_000) -> np.ndarray:
    """∫ S(wo, wi) dωi averaged over h, for one random wo (uniform sphere sampling)."""
    rng = np.random.default_rng(seed)
    t = np.tile([0.0, 0.0, 1.0], (n, 1))
    wo = np.tile(_sphere(rng, 1), (n, 1))
    h = rng.uniform(-1, 1, n)
    s = scattering(t, wo, _sphere(rng, n), h, params)
    return 4 * np.pi * s.mean(axis=0)


@pytest.mark.parametrize("beta_m, beta_n, seed", [(0.2, 0.3, 0), (0.4, 0.6, 1),
                                                  (0.7, 0.9, 2), (0.3, 0.2, 3)])
def test_white_furnace_a_non_absorbing_fibre_neither_creates_nor_loses_energy(
        beta_m, beta_n, seed):
    albedo = _albedo(ChiangParams(beta_m=beta_m, beta_n=beta_n), seed)
    np.testing.assert_allclose(albedo, 1.0, atol=0.05)


def test_melanin_absorbs_blue_more_than_red():
    params = ChiangParams(sigma_a=tuple(sigma_a_from_melanin(0.8, 0.2)))
    albedo = _albedo(params, 5)
    assert albedo.max() < 0.9 and albedo[0] > albedo[1] > albedo[2]


def test_attenuations_sum_to_one_without_absorption():
    h = np.linspace(-0.99, 0.99, 51)
    cos_o = np.full_like(h, 0.8)
    a, _, _ = attenuation(cos_o, h, ChiangParams())
    np.testing.assert_allclose(a.sum(axis=0), 1.0, atol=1e-9)
    a, _, _ = attenuation(cos_o, h, ChiangParams(sigma_a=(0.5, 1.0, 2.0)))
    assert (a.sum(axis=0) < 1).all()
