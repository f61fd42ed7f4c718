"""The environment path tracer against closed forms: a plane open to the sky."""

from __future__ import annotations

import numpy as np
import pytest

from prtcore.core.raytrace import RayTracer
from prtcore.emitters.environment import Environment, constant_environment
from prtcore.reference.environment import reference_environment


def _plane_tracer():
    # a far-away tiny triangle: nothing occludes the samples on the plane y = 0
    pos = np.array([[50.0, 50.0, 50.0], [51.0, 50.0, 50.0], [50.0, 51.0, 50.0]])
    return RayTracer(pos, np.array([[0, 1, 2]]), 1.0)


def _samples(n=64):
    rng = np.random.default_rng(0)
    p = np.zeros((n, 3))
    p[:, [0, 2]] = rng.uniform(-1, 1, (n, 2))
    up = np.tile([0.0, 1.0, 0.0], (n, 1))
    return p, up, up, np.tile([0.5, 0.6, 0.7], (n, 1))


def test_constant_sky_on_an_open_plane_gives_albedo_times_radiance():
    p, n, g, rho = _samples()
    ref = reference_environment(None, _plane_tracer(), constant_environment([2.0, 1.0, 0.5]),
                                p, n, g, rho, 64, seed=1)
    expect = rho * [2.0, 1.0, 0.5]
    # unbiased (the mean over points to 0.5 %), and the halves' noise estimate is the
    # error's size: mean squared error / mean noise² ≈ 1 (64 points: within [0.4, 2.5])
    np.testing.assert_allclose(ref.mean.mean(axis=0), expect.mean(axis=0), rtol=0.005)
    ratio = ((ref.mean - expect) ** 2).mean() / ref.noise2.mean()
    assert 0.4 < ratio < 2.5, ratio


def test_upper_half_sky_on_a_tilted_plane():
    """A sky of radiance 1 above the horizon only, a plane tilted by α = 60°: the
    irradiance has the closed form π/2 · (1 + cos α)."""
    h = 64
    img = np.zeros((h, 2 * h, 3))
    img[: h // 2] = 1.0
    env = Environment(img)
    p, _, _, rho = _samples(16)
    a = np.radians(60.0)
    nrm = np.tile([np.sin(a), np.cos(a), 0.0], (16, 1))
    ref = reference_environment(None, _plane_tracer(), env, p, nrm, nrm, rho, 2048, seed=2)
    expect = rho / np.pi * (np.pi / 2 * (1 + np.cos(a)))
    np.testing.assert_allclose(ref.mean.mean(axis=0), expect[0], rtol=0.01)


def test_spp_is_checked():
    p, n, g, rho = _samples(2)
    with pytest.raises(ValueError, match="even"):
        reference_environment(None, _plane_tracer(), constant_environment([1, 1, 1]),
                              p, n, g, rho, 3)
