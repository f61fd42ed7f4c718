"""Environment maps: reading, radiance lookup, SH projection with rotation, importance
sampling (its pdf against the sampled histogram), and the light families built on them."""

from __future__ import annotations

import numpy as np
import pytest

from prtcore.core import sh
from prtcore.core.errors import LightFileError
from prtcore.core.scene import Light
from prtcore.emitters import environment as envmod
from prtcore.emitters.environment import Environment, EnvironmentSampler
from prtcore.io.imageio import write_exr


def _map(h=32):
    """A smooth test sky with a coloured gradient (every pixel > 0)."""
    return envmod.sky_environment(np.array([0.4, 0.7, -0.3]), h)


def test_load_environment_round_trips_an_exr(tmp_path):
    env = _map(16)
    write_exr(tmp_path / "sky.exr", env.image.astype(np.float32))
    back = envmod.load_environment(tmp_path / "sky.exr", scale=2.0)
    np.testing.assert_allclose(back.image, 2.0 * env.image.astype(np.float32), rtol=1e-6)
    assert back.name == "sky.exr"


def test_load_environment_refuses_bad_maps(tmp_path):
    write_exr(tmp_path / "square.exr", np.ones((8, 8, 3), np.float32))
    with pytest.raises(LightFileError, match=r"square\.exr.*twice as wide"):
        envmod.load_environment(tmp_path / "square.exr")
    write_exr(tmp_path / "neg.exr", -np.ones((8, 16, 3), np.float32))
    with pytest.raises(LightFileError, match=r"neg\.exr.*≥ 0"):
        envmod.load_environment(tmp_path / "neg.exr")


def test_radiance_lookup_is_the_pixel_and_follows_rotation():
    env = _map(16)
    dirs, _ = sh.equirect_directions(16, 32)
    np.testing.assert_array_equal(env.radiance(dirs.reshape(-1, 3)),
                                  env.image.reshape(-1, 3))
    rot = envmod.random_rotation(np.random.default_rng(5))
    turned = env.rotated(rot)
    d = dirs.reshape(-1, 3)
    np.testing.assert_array_equal(turned.radiance(d @ rot.T), env.radiance(d))


def test_sh_coefficients_of_a_rotated_map_match_its_radiance():
    """The rotated map's SH (projection, then sh.rotate) vs projecting the rotated
    radiance function directly by dense quadrature of the pixel lookup."""
    rot = envmod.random_rotation(np.random.default_rng(1))
    env = _map(64).rotated(rot)
    direct = sh.project_function(env.radiance, 4, degree=400)
    np.testing.assert_allclose(env.sh_coefficients(4), direct, atol=3e-3)


def test_sampler_pdf_integrates_to_one_and_matches_its_histogram():
    env = _map(16).rotated(envmod.random_rotation(np.random.default_rng(2)))
    s = EnvironmentSampler(env)
    q = sh.quadrature(400)
    assert np.sum(s.pdf(q.directions) * q.weights) == pytest.approx(1.0, abs=2e-3)
    d, pdf = s.sample(np.random.default_rng(3), 200_000)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    np.testing.assert_allclose(pdf, s.pdf(d), rtol=1e-12)
    # histogram over the map's pixels vs the pixel probabilities (chi-square-like check)
    uv = sh.equirect_uv(d @ env.rotation)
    h, w = 16, 32
    pix = (np.minimum((uv[:, 1] * h).astype(int), h - 1) * w
           + np.minimum((uv[:, 0] * w).astype(int), w - 1))
    counts = np.bincount(pix, minlength=h * w)
    _, area = sh.equirect_directions(h, w)
    expect = (s.pdf(sh.equirect_directions(h, w)[0].reshape(-1, 3) @ env.rotation.T)
              * area.ravel() * len(d))
    z = (counts - expect) / np.sqrt(np.maximum(expect, 1.0))
    assert np.mean(z ** 2) < 1.5  # ≈ 1 for a correct sampler


def test_black_environment_cannot_be_sampled():
    with pytest.raises(LightFileError, match="black"):
        EnvironmentSampler(Environment(np.zeros((4, 8, 3))))


def test_light_sh_is_a_delta_projected():
    light = Light(type="directional", color=np.array([1.0, 0.5, 0.25]), intensity=2.0,
                  direction=np.array([0.0, -1.0, 0.0]))
    c = envmod.light_sh(light, 3)
    # irradiance on an up-facing plane: the clamped cosine convolution at +y gives 2·color
    irr = sh.evaluate(sh.convolve_zonal(c, sh.clamped_cosine_zonal(3)),
                      np.array([[0.0, 1.0, 0.0]]))[0]
    # 3 bands of the clamped cosine reproduce cos at the pole to within 7 % (known figure)
    np.testing.assert_allclose(irr, 2.0 * np.array([1.0, 0.5, 0.25]), rtol=0.07)
    with pytest.raises(LightFileError, match="point"):
        envmod.light_sh(Light(type="point", color=np.ones(3), intensity=1.0), 3)


def test_families_are_seeded():
    env = _map(8)
    a = envmod.rotated_family(env, 3, seed=4)
    b = envmod.rotated_family(env, 3, seed=4)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.rotation, y.rotation)
        assert x.rotation[1, 1] == pytest.approx(1.0)  # about the up axis
    sky, sun = envmod.sky_with_sun(np.random.default_rng(1))
    assert sun.direction[1] < 0 and sky.image.min() > 0
    amb, key = envmod.directional_with_ambient(np.random.default_rng(2))
    assert key.type == "directional" and np.ptp(amb.image) == 0
