"""prtcore.core.sh against independent references: closed-form basis functions, scipy's
adaptive quadrature, Parseval's identity and the clamped cosine's closed-form coefficients."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate
from scipy.spatial.transform import Rotation

from prtcore.core import sh


def _sphere(theta, phi):
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                     np.cos(theta)], axis=-1)


def _sky(d):
    """A smooth, non-symmetric environment (positive radiance): two lobes and a gradient."""
    d = np.atleast_2d(d)
    a = np.array([0.3, 0.8, -0.52])
    a /= np.linalg.norm(a)
    b = np.array([-0.7, 0.1, 0.7])
    b /= np.linalg.norm(b)
    return (np.exp(2.0 * (d @ a - 1.0)) * 3.0 + np.exp(4.0 * (d @ b - 1.0))
            + 0.2 + 0.1 * d[:, 1])


def _scipy_integral(fn, rtol=1e-10, frame=None, theta_max=np.pi):
    """∫_S² fn(ω) dω by scipy's adaptive cubature over (θ, φ), independent of sh's grids.
    ``fn`` maps (n, 3) directions to (n,) or (n, k) values; returns a float or (k,).
    ``frame`` (3, 3), rows (t, s, n): θ is measured from n, up to ``theta_max``."""
    basis_rows = np.eye(3) if frame is None else frame

    def integrand(x):
        w = _sphere(x[:, 0], x[:, 1]) @ basis_rows
        val = fn(w)
        return val * np.sin(x[:, 0]).reshape(-1, *([1] * (np.ndim(val) - 1)))
    res = integrate.cubature(integrand, [0.0, 0.0], [theta_max, 2 * np.pi], rtol=rtol,
                             atol=1e-12)
    assert res.status == "converged"
    return res.estimate


def test_basis_matches_closed_forms_to_band_2():
    rng = np.random.default_rng(1)
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    x, y, z = d.T
    expected = np.stack([
        np.full_like(x, 0.5 / np.sqrt(np.pi)),
        np.sqrt(3 / (4 * np.pi)) * y, np.sqrt(3 / (4 * np.pi)) * z,
        np.sqrt(3 / (4 * np.pi)) * x,
        0.5 * np.sqrt(15 / np.pi) * x * y, 0.5 * np.sqrt(15 / np.pi) * y * z,
        0.25 * np.sqrt(5 / np.pi) * (3 * z * z - 1), 0.5 * np.sqrt(15 / np.pi) * x * z,
        0.25 * np.sqrt(15 / np.pi) * (x * x - y * y)], axis=1)
    np.testing.assert_allclose(sh.basis(d, 3), expected, atol=1e-14)


def test_basis_is_orthonormal_under_scipy_integration():
    # the whole Gram matrix to band 5, integrated adaptively (independent of sh.quadrature)
    gram = _scipy_integral(lambda w: (sh.basis(w, 6)[:, :, None] * sh.basis(w, 6)[:, None, :]
                                      ).reshape(len(w), -1)).reshape(36, 36)
    np.testing.assert_allclose(gram, np.eye(36), atol=1e-8)


def test_quadrature_is_exact_for_its_degree():
    q = sh.quadrature(2 * 5)
    y = sh.basis(q.directions, 6)
    np.testing.assert_allclose((y * q.weights[:, None]).T @ y, np.eye(36), atol=1e-12)
    assert q.weights.sum() == pytest.approx(4 * np.pi)


def test_equirect_mapping_round_trips_and_areas_sum_to_4pi():
    dirs, area = sh.equirect_directions(32, 64)
    assert area.sum() == pytest.approx(4 * np.pi)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0)
    uv = sh.equirect_uv(dirs)
    u, v = np.meshgrid((np.arange(64) + 0.5) / 64, (np.arange(32) + 0.5) / 32)
    np.testing.assert_allclose(uv[..., 0], u, atol=1e-12)
    np.testing.assert_allclose(uv[..., 1], v, atol=1e-12)
    # Mitsuba's envmap: top row is +y, u = 0.25 looks along +x, u = 0.5 along +z
    assert dirs[0, 0, 1] > 0.99
    np.testing.assert_allclose(sh.equirect_uv(np.array([[1.0, 0, 0], [0, 0, 1.0]])),
                               [[0.25, 0.5], [0.5, 0.5]])


def test_equirect_projection_matches_scipy_integration():
    """The environment projected from a 256×512 equirect raster vs each coefficient
    integrated adaptively from the analytic function (the raster's error is O(pixel²))."""
    dirs, _ = sh.equirect_directions(256, 512)
    image = _sky(dirs.reshape(-1, 3)).reshape(256, 512)
    coeffs = sh.project_equirect(image, 5)
    ref = _scipy_integral(lambda w: _sky(w)[:, None] * sh.basis(w, 5))
    np.testing.assert_allclose(coeffs, ref, atol=2e-4)
    # a function sampled by project_function agrees with the raster projection
    np.testing.assert_allclose(sh.project_function(_sky, 5, degree=40), coeffs, atol=2e-4)


def test_reconstruction_error_is_the_truncated_energy():
    """Parseval: ‖f − f_L‖² = ‖f‖² − Σ c², both sides integrated by scipy independently."""
    coeffs = sh.project_function(_sky, 5, degree=60)
    norm2 = _scipy_integral(lambda w: _sky(w) ** 2)
    err2 = _scipy_integral(lambda w: (_sky(w) - sh.evaluate(coeffs, w)) ** 2)
    assert err2 == pytest.approx(norm2 - np.sum(coeffs ** 2), rel=1e-6)
    assert err2 < 0.01 * norm2  # a smooth sky is well captured by 25 coefficients


def test_clamped_cosine_truncation_error_has_its_closed_form():
    bands = 8
    zonal = sh.clamped_cosine_zonal(bands)
    # the closed-form coefficients vs adaptive integration of max(0, cos θ) Y_l0
    for l in range(bands):
        ref, _ = integrate.quad(
            lambda t, l=l: max(0.0, np.cos(t)) * sh.basis(_sphere(t, 0.0)[None], bands)[0,
                                                                                l * (l + 1)]
            * np.sin(t) * 2 * np.pi, 0.0, np.pi, epsabs=1e-12, points=[np.pi / 2])
        assert zonal[l] == pytest.approx(ref, abs=1e-10), l
    coeffs = np.zeros(bands * bands)
    coeffs[[l * (l + 1) for l in range(bands)]] = zonal
    for b in (1, 2, 3, 5, 8):
        trunc = coeffs[:b * b]
        measured, _ = integrate.quad(
            lambda t, tr=trunc: (max(0.0, np.cos(t)) - sh.evaluate(tr, _sphere(t, 0.0)[None])[0])
            ** 2 * np.sin(t) * 2 * np.pi, 0.0, np.pi, epsabs=1e-13, points=[np.pi / 2])
        closed = 2 * np.pi / 3 - np.sum(zonal[:b] ** 2)  # ‖max(0,cos)‖² = 2π/3
        assert measured == pytest.approx(closed, rel=1e-6, abs=1e-12), b
    # the well-known figure: 9 coefficients hold all but < 1% of the irradiance kernel's
    # energy beyond band 0..2 (Ramamoorthi & Hanrahan 2001)
    assert (2 * np.pi / 3 - np.sum(zonal[:3] ** 2)) / (2 * np.pi / 3) < 0.01


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rotation_preserves_band_energy_and_matches_rotated_projection(seed):
    rot = Rotation.random(random_state=seed).as_matrix()
    coeffs = sh.project_function(_sky, 6, degree=50)
    turned = sh.rotate(coeffs, rot)
    np.testing.assert_allclose(sh.band_energy(turned), sh.band_energy(coeffs), rtol=1e-10,
                               atol=1e-14)
    # independently: project the turned function (f(Rᵀ ω)) directly
    direct = sh.project_function(lambda w: _sky(w @ rot), 6, degree=50)
    np.testing.assert_allclose(turned, direct, atol=1e-8)
    m = sh.rotation_matrix(rot, 6)
    np.testing.assert_allclose(m @ m.T, np.eye(36), atol=1e-12)
    rot2 = Rotation.random(random_state=seed + 10).as_matrix()
    np.testing.assert_allclose(sh.rotation_matrix(rot2 @ rot, 6),
                               sh.rotation_matrix(rot2, 6) @ m, atol=1e-12)


def test_rotation_refuses_a_reflection():
    with pytest.raises(ValueError, match="rotation"):
        sh.rotation_matrix(np.diag([1.0, 1.0, -1.0]), 3)


def test_triple_product_is_the_projected_product():
    bands = 4
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=16), rng.normal(size=16)
    # the product of two band-4 functions, projected by scipy-independent dense quadrature
    ref = sh.project_function(lambda w: sh.evaluate(a, w) * sh.evaluate(b, w), bands,
                              degree=30)
    np.testing.assert_allclose(sh.product(a, b), ref, atol=1e-12)
    t = sh.triple_product_tensor(bands)
    np.testing.assert_allclose(t, np.transpose(t, (1, 0, 2)), atol=0)
    np.testing.assert_allclose(t, np.transpose(t, (2, 1, 0)), atol=0)
    np.testing.assert_allclose(t[0], np.eye(16) / np.sqrt(4 * np.pi), atol=1e-14)
    # one entry in closed form: ∫ Y_1,0 Y_1,0 Y_2,0 dω = 1/√(5π)
    assert t[2, 2, 6] == pytest.approx(1.0 / np.sqrt(5 * np.pi), abs=1e-14)


def test_clamped_cosine_convolution_gives_irradiance():
    """Irradiance from the sky via Funk–Hecke vs direct integration of L(ω) max(0, n·ω)."""
    bands = 9
    coeffs = sh.project_function(_sky, bands, degree=60)
    irr = sh.convolve_zonal(coeffs, sh.clamped_cosine_zonal(bands))
    for n in np.array([[0, 1.0, 0], [0.6, 0, 0.8], [0, -1.0, 0]]):
        t = np.cross(n, [0.3, 0.1, 0.9])
        t /= np.linalg.norm(t)
        ref = _scipy_integral(lambda w, n=n: _sky(w) * (w @ n),
                              frame=np.stack([t, np.cross(n, t), n]), theta_max=np.pi / 2)
        # band 9 clamped-cosine truncation leaves < 0.1% of the kernel's energy
        assert sh.evaluate(irr, n[None])[0] == pytest.approx(ref, rel=2e-3)
    # the kernel turned to a direction: its value there is the truncated cosine lobe
    k = sh.zonal_to_direction(sh.clamped_cosine_zonal(bands), np.array([0.0, 0.0, 1.0]))
    assert sh.evaluate(k, np.array([[0.0, 0.0, 1.0]]))[0] == pytest.approx(1.0, abs=0.03)


def test_bands_are_checked():
    with pytest.raises(ValueError, match="bands"):
        sh.basis(np.zeros((1, 3)), 0)
    with pytest.raises(ValueError, match="square"):
        sh.evaluate(np.zeros(10), np.zeros((1, 3)))
    assert sh.n_coeffs(5) == 25


def test_phong_zonal_against_scipy_and_the_clamped_cosine():
    np.testing.assert_allclose(sh.phong_zonal(1, 6), sh.clamped_cosine_zonal(6) / np.pi,
                               atol=1e-14)
    for n in (8.0, 20.0, 5.5):
        z = sh.phong_zonal(n, 6)
        assert z[0] == pytest.approx(0.5 / np.sqrt(np.pi))  # the lobe integrates to 1
        for l in range(6):
            ref, _ = integrate.quad(
                lambda t, l=l, n=n: (n + 1) / (2 * np.pi) * max(0.0, np.cos(t)) ** n
                * sh.basis(_sphere(t, 0.0)[None], 6)[0, l * (l + 1)] * np.sin(t) * 2 * np.pi,
                0.0, np.pi / 2, epsabs=1e-13)
            assert z[l] == pytest.approx(ref, abs=1e-11), (n, l)
