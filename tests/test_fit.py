"""Fit stage: closed-form checks against synthetic linear transport operators.

Every expected value is computed independently of prtcore.fit.transfer (normal equations with
np.linalg.solve, np.linalg.pinv, brute-force refits, np.linalg.svd), never copied from it.
"""

import json

import numpy as np
import pytest

from prtcore.core.errors import PrtError
from prtcore.fit.model import (
    AUTO_ENERGY,
    AUTO_HOLDOUT_MARGIN,
    UNDERDETERMINED_WARNING,
    gamma_decode,
    gamma_encode,
    relative_rmse,
)
from prtcore.fit.ridge import direct_svd, loo_sse, ridge_solve
from prtcore.fit.transfer import (
    fit_transfer,
    fit_transfer64,
    heldout_errors,
    projection_bound,
    reconstruct,
    reconstruct64,
)


def lowrank_operator(rng, T, P, r):
    """Random rank-r transport operator (T, P)."""
    return rng.standard_normal((T, r)) @ rng.standard_normal((r, P)) / np.sqrt(r)


def transport(op, D):
    """I[:, k, c] = op @ D[:, k, c] (colour-independent transport)."""
    return np.einsum("tp,pkc->tkc", op, D)


def coloured_lights(rng, P, K):
    """Direct vectors of K lights with random colours: (P, K, 3)."""
    geometry = rng.uniform(0.0, 1.0, (P, K))
    colour = rng.uniform(0.05, 1.0, (K, 3))
    return geometry[:, :, None] * colour[None, :, :]


def normalised(D, I, gamma=None):
    """Independent normalisation: Dn, In, s (numpy only)."""
    Dg, Ig = (D, I) if gamma is None else (np.sign(D) * np.abs(D) ** (1 / gamma),
                                           np.sign(I) * np.abs(I) ** (1 / gamma))
    s = np.sqrt((Dg**2).sum(axis=(0, 2)))
    return Dg / s[None, :, None], Ig / s[None, :, None], s


def coefficients(model, D, I):
    """C[c] = Uᵀ (In_c − m_c), (3, n−1, K), from the model's own (float64) basis."""
    _, In, _ = normalised(D, I, model.gamma)
    A = In - In.mean(axis=1, keepdims=True)
    U = np.asarray(model.basis, dtype=np.float64)
    if model.channels == "mono":
        return np.stack([U.T @ A[:, :, c] for c in range(3)])
    return np.stack([U[:, :, c].T @ A[:, :, c] for c in range(3)])


def ridge_normal_equations(C, D, lam, intercept=True):
    """min ‖C − b1ᵀ − M D‖² + λ‖M‖² by the normal equations of [1; D] (np.linalg.solve)."""
    P, K = D.shape
    if intercept:
        Z = np.vstack([np.ones((1, K)), D])
        pen = np.diag(np.r_[0.0, np.full(P, lam)])
    else:
        Z, pen = D, lam * np.eye(P)
    theta = np.linalg.solve(Z @ Z.T + pen, Z @ C.T)
    if intercept:
        return theta[1:].T, theta[0]
    return theta.T, np.zeros(C.shape[0])


# ---------------------------------------------------------------------------------------
# (1) exact recovery of a low-rank linear operator


@pytest.mark.parametrize("channels", ["mono", "rgb"])
def test_exact_recovery_of_lowrank_operator(channels):
    rng = np.random.default_rng(1)
    T, P, r, K = 400, 12, 4, 40
    op = lowrank_operator(rng, T, P, r)
    D = coloured_lights(rng, P, K)
    I = transport(op, D)
    m64 = fit_transfer64(D, I, basis=r + 1, ridge=0.0, channels=channels)
    m32 = fit_transfer(D, I, basis=16, ridge=0.0, channels=channels)
    assert m32.n_basis == r + 1  # capped at the rank, and said so
    assert m32.diagnostics.n_basis_method == "capped"
    assert any("capped" in w for w in m32.diagnostics.warnings)
    assert m32.basis.dtype == np.float32 and m32.transfer.dtype == np.float32
    for _ in range(3):
        x = rng.uniform(0.0, 1.0, (P, 3)) * rng.uniform(0.0, 1.0, 3)  # new light, new colour
        truth = op @ x
        assert relative_rmse(reconstruct64(m64, x), truth) < 1e-8
        y32 = reconstruct(m32, x)
        assert y32.dtype == np.float32 and y32.shape == (T, 3)
        assert relative_rmse(y32, truth) < 1e-5


def test_intercept_false_is_the_papers_formula_and_not_exact():
    """Without the offset (paper eq. 14 as is) a new light is not reproduced exactly."""
    rng = np.random.default_rng(11)
    T, P, r, K = 200, 8, 3, 30
    op = lowrank_operator(rng, T, P, r)
    D = coloured_lights(rng, P, K)
    I = transport(op, D)
    m = fit_transfer64(D, I, basis=r + 1, ridge=0.0, intercept=False)
    assert np.all(m.offset == 0.0)
    C = coefficients(m, D, I)
    Dn, _, _ = normalised(D, I)
    for c in range(3):
        M_ref, _ = ridge_normal_equations(C[c], Dn[:, :, c], 0.0, intercept=False)
        np.testing.assert_allclose(m.transfer[c], M_ref, rtol=1e-8, atol=1e-10)
    x = rng.uniform(0.0, 1.0, (P, 3))
    assert relative_rmse(reconstruct64(m, x), op @ x) > 1e-6


# ---------------------------------------------------------------------------------------
# (2) ridge transfer equals the normal equations; ‖M‖ shrinks with λ


def test_ridge_solve_matches_normal_equations():
    rng = np.random.default_rng(2)
    P, K, m = 6, 25, 4
    D = rng.standard_normal((P, K))
    C = rng.standard_normal((m, K))
    for intercept in (True, False):
        svd = direct_svd(D, intercept)
        norms = []
        for lam in (0.0, 1e-3, 0.1, 1.0, 10.0, 1e3):
            M, b = ridge_solve(svd, C, lam)
            M_ref, b_ref = ridge_normal_equations(C, D, lam, intercept)
            np.testing.assert_allclose(M, M_ref, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(b, b_ref, rtol=1e-9, atol=1e-12)
            norms.append(np.linalg.norm(M))
        assert np.all(np.diff(norms) < 0)


def test_fitted_transfer_matches_normal_equations():
    rng = np.random.default_rng(3)
    T, P, K = 150, 7, 30
    D = coloured_lights(rng, P, K)
    I = transport(rng.standard_normal((T, P)), D) + 0.01 * rng.standard_normal((T, K, 3))
    lam = 0.05
    m = fit_transfer64(D, I, basis=6, ridge=lam, channels="rgb")
    _, In, _ = normalised(D, I)
    np.testing.assert_allclose(m.mean, In.mean(axis=1), rtol=1e-12, atol=1e-14)
    C = coefficients(m, D, I)
    Dn, _, _ = normalised(D, I)
    for c in range(3):
        M_ref, b_ref = ridge_normal_equations(C[c], Dn[:, :, c], lam)
        np.testing.assert_allclose(m.transfer[c], M_ref, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(m.offset[c], b_ref, rtol=1e-8, atol=1e-10)
    assert m.diagnostics.ridge == lam and m.diagnostics.ridge_method == "given"


# ---------------------------------------------------------------------------------------
# (3) closed-form leave-one-out equals brute-force refits


@pytest.mark.parametrize("intercept", [True, False])
def test_loo_closed_form_equals_brute_force(intercept):
    rng = np.random.default_rng(4)
    P, K, m = 4, 14, 3
    D = rng.standard_normal((P, K))
    C = rng.standard_normal((m, P)) @ D + 0.3 * rng.standard_normal((m, K)) + 0.5
    lams = np.array([0.0, 1e-2, 0.3, 5.0])
    closed = loo_sse(direct_svd(D, intercept), C, lams)
    for j, lam in enumerate(lams):
        brute = np.zeros(m)
        for k in range(K):
            rest = np.delete(np.arange(K), k)
            M, b = ridge_normal_equations(C[:, rest], D[:, rest], lam, intercept)
            brute += (C[:, k] - b - M @ D[:, k]) ** 2
        np.testing.assert_allclose(closed[:, j], brute, rtol=1e-9)


def test_auto_ridge_is_the_cv_minimum():
    rng = np.random.default_rng(5)
    T, P, K = 120, 10, 30
    D = coloured_lights(rng, P, K)
    I = transport(rng.standard_normal((T, P)), D) + 0.2 * rng.standard_normal((T, K, 3))
    m = fit_transfer(D, I, basis=6, ridge="auto")
    d = m.diagnostics
    assert d.ridge_method == "loo" and len(d.ridge_grid) == 25 and d.ridge_grid[0] == 0.0
    cv = np.array([np.inf if v is None else v for v in d.ridge_cv])
    assert d.ridge == d.ridge_grid[int(np.argmin(cv))]
    assert m.ridge == d.ridge
    # the reported curve is the brute-force LOO of the transfer (basis fixed)
    m64 = fit_transfer64(D, I, basis=6, ridge=d.ridge)
    C = coefficients(m64, D, I)
    Dn, In, _ = normalised(D, I)
    j = len(d.ridge_grid) // 2
    lam = d.ridge_grid[j]
    sse = 0.0
    for c in range(3):
        for k in range(K):
            rest = np.delete(np.arange(K), k)
            M, b = ridge_normal_equations(C[c][:, rest], Dn[:, rest, c], lam)
            sse += np.sum((C[c][:, k] - b - M @ Dn[:, k, c]) ** 2)
    A = In - In.mean(axis=1, keepdims=True)
    outside = np.sum(A**2) - np.sum(C**2)  # energy the basis does not hold
    assert d.ridge_cv[j] == pytest.approx(np.sqrt((sse + outside) / np.sum(In**2)), rel=1e-6)


# ---------------------------------------------------------------------------------------
# (4) rank-deficient direct matrix: the λ → 0 limit is the minimum-norm solution


def test_rank_deficient_direct_gives_min_norm_transfer():
    rng = np.random.default_rng(6)
    T, K = 100, 8
    base = coloured_lights(rng, 6, K)
    D = np.concatenate([base, base[:3]], axis=0)  # points 6..8 duplicate 0..2; P=9 > K
    P = D.shape[0]
    I = transport(rng.standard_normal((T, P)), D)
    for lam in (0.0, 1e-30):
        m = fit_transfer64(D, I, basis=4, ridge=lam)
        assert np.all(np.isfinite(m.transfer)) and np.all(np.isfinite(m.offset))
        assert UNDERDETERMINED_WARNING in m.diagnostics.warnings
        C = coefficients(m, D, I)
        Dn, _, _ = normalised(D, I)
        for c in range(3):
            Dc = Dn[:, :, c] - Dn[:, :, c].mean(axis=1, keepdims=True)
            Cc = C[c] - C[c].mean(axis=1, keepdims=True)
            M_ref = Cc @ np.linalg.pinv(Dc)
            np.testing.assert_allclose(m.transfer[c], M_ref, rtol=1e-6, atol=1e-9)
            # minimum norm splits the weight of a duplicated point evenly
            np.testing.assert_allclose(m.transfer[c][:, :3], m.transfer[c][:, 6:], atol=1e-9)
        assert m.diagnostics.direct_condition == (None, None, None)
        assert max(m.diagnostics.direct_effective_rank) <= 6
        y = reconstruct(m, rng.uniform(0.0, 1.0, (P, 3)))
        assert np.all(np.isfinite(y))


# ---------------------------------------------------------------------------------------
# (5) excluded configurations


def test_zero_and_nonfinite_configurations_are_excluded():
    rng = np.random.default_rng(7)
    T, P, K = 80, 6, 20
    D = coloured_lights(rng, P, K)
    I = transport(rng.standard_normal((T, P)), D) + 0.01 * rng.standard_normal((T, K, 3))
    Dbad, Ibad = D.copy(), I.copy()
    Dbad[:, 3, :] = 0.0
    Dbad[0, 5, 1] = np.nan
    Ibad[2, 9, 0] = np.inf
    m = fit_transfer64(Dbad, Ibad, basis=5, ridge=0.01)
    d = m.diagnostics
    assert [e["index"] for e in d.excluded] == [3, 5, 9]
    assert [e["reason"] for e in d.excluded] == [
        "zero direct", "non-finite direct", "non-finite indirect"]
    assert d.used == K - 3 and d.configurations == K
    for a in (m.mean, m.basis, m.transfer, m.offset):
        assert np.all(np.isfinite(a))
    keep = np.delete(np.arange(K), [3, 5, 9])
    ref = fit_transfer64(D[:, keep], I[:, keep], basis=5, ridge=0.01)
    np.testing.assert_allclose(m.basis, ref.basis, atol=1e-12)
    np.testing.assert_allclose(m.transfer, ref.transfer, atol=1e-10)


def test_too_few_configurations_and_bad_arguments_are_refused():
    rng = np.random.default_rng(8)
    D = np.zeros((4, 3, 3))
    D[:, 0] = 1.0
    I = rng.standard_normal((10, 3, 3))
    with pytest.raises(PrtError, match="usable"):
        fit_transfer(D, I)
    D = rng.uniform(size=(4, 6, 3))
    with pytest.raises(ValueError, match="configurations"):
        fit_transfer(D, rng.standard_normal((10, 5, 3)))
    with pytest.raises(ValueError, match="channels"):
        fit_transfer(D, rng.standard_normal((10, 6, 3)), channels="rgba")
    with pytest.raises(ValueError, match="ridge"):
        fit_transfer(D, rng.standard_normal((10, 6, 3)), ridge=-1.0)
    with pytest.raises(ValueError, match="per_group"):
        fit_transfer(D, rng.standard_normal((10, 6, 3)), per_group=True)


# ---------------------------------------------------------------------------------------
# (6) mono vs rgb


def test_mono_equals_rgb_for_white_lights_and_grey_transport():
    rng = np.random.default_rng(9)
    T, P, K = 150, 10, 30
    op = rng.standard_normal((T, P))  # full rank: a truncated basis does not capture it
    white = rng.uniform(0.0, 1.0, (P, K))
    D = np.repeat(white[:, :, None], 3, axis=2)
    I = transport(op, D)
    mono = fit_transfer64(D, I, basis=5, ridge=1e-3, channels="mono")
    rgb = fit_transfer64(D, I, basis=5, ridge=1e-3, channels="rgb")
    xw = rng.uniform(0.0, 1.0, P)
    x = np.repeat(xw[:, None], 3, axis=1)
    y_mono, y_rgb = reconstruct64(mono, x), reconstruct64(rgb, x)
    assert relative_rmse(y_mono, op @ x) > 1e-3  # the comparison is not trivially exact
    assert relative_rmse(y_mono, y_rgb) < 1e-9


def test_mono_reconstructs_unseen_light_colours():
    rng = np.random.default_rng(10)
    T, P, r, K = 200, 10, 3, 40
    op = lowrank_operator(rng, T, P, r)
    D = coloured_lights(rng, P, K)
    I = transport(op, D)
    m = fit_transfer(D, I, basis=r + 1, ridge=0.0, channels="mono")
    d = rng.uniform(0.0, 1.0, P)
    for colour in ([1.0, 0.0, 0.0], [0.0, 0.0, 2.0], [1.0, -0.0, 0.3]):
        x = d[:, None] * np.asarray(colour)[None, :]
        y = reconstruct(m, x)
        assert relative_rmse(y, op @ x) < 1e-5
        for c in range(3):
            if colour[c] == 0.0:
                assert np.max(np.abs(y[:, c])) < 1e-5 * np.max(np.abs(y))


# ---------------------------------------------------------------------------------------
# (7) truncation


@pytest.mark.parametrize("channels", ["mono", "rgb"])
def test_training_error_non_increasing_in_n(channels):
    rng = np.random.default_rng(12)
    T, P, K = 150, 8, 25
    D = coloured_lights(rng, P, K)
    I = transport(rng.standard_normal((T, P)), D) + 0.05 * rng.standard_normal((T, K, 3))
    m = fit_transfer(D, I, basis=12, ridge="auto", channels=channels)
    _, _, s = normalised(D, I)
    errors = []
    for n in range(1, m.n_basis + 1):
        sse = sum(np.sum((reconstruct(m, D[:, k], n=n) - I[:, k]) ** 2) / s[k] ** 2
                  for k in range(K))
        errors.append(sse)
    assert np.all(np.diff(errors) <= 1e-6 * errors[0])
    assert errors[-1] < 0.5 * errors[0]


# ---------------------------------------------------------------------------------------
# (8) gamma


def test_gamma_helpers():
    v = np.array([-4.0, 0.0, 9.0])
    np.testing.assert_allclose(gamma_encode(v, 2.0), [-2.0, 0.0, 3.0])
    np.testing.assert_allclose(gamma_decode(np.array([-2.0, 0.0, 3.0]), 2.0), [0.0, 0.0, 9.0])
    np.testing.assert_array_equal(gamma_decode(v, None), v)  # no clamp without gamma


def test_gamma_round_trip_reproduces_training_and_clamps():
    rng = np.random.default_rng(13)
    T, P, K = 200, 16, 12  # P ≥ K − 1 and λ = 0: the fit interpolates the training set
    D = coloured_lights(rng, P, K)
    I = transport(rng.uniform(0.0, 1.0, (T, P)), D) ** 1.5  # not linear: gamma helps
    m = fit_transfer(D, I, basis=64, ridge=0.0, gamma=2.2)
    assert m.gamma == 2.2 and m.diagnostics.gamma == 2.2
    for k in range(K):
        y = reconstruct(m, D[:, k])
        assert np.all(np.isfinite(y))
        assert relative_rmse(y, I[:, k]) < 1e-4
    y = reconstruct(m, -3.0 * D[:, 0])  # drives the gamma-space result negative
    assert np.all(np.isfinite(y)) and np.all(y >= 0.0)
    y_lin = reconstruct64(m, -3.0 * D[:, 0])
    assert np.any(y_lin == 0.0)  # clamped values exist


# ---------------------------------------------------------------------------------------
# (9) Gram matrix in blocks


@pytest.mark.parametrize("channels", ["mono", "rgb"])
def test_blocked_gram_gives_the_same_basis(channels):
    rng = np.random.default_rng(14)
    T, P, K = 123, 6, 15
    D = coloured_lights(rng, P, K)
    I = transport(rng.standard_normal((T, P)), D) + 0.1 * rng.standard_normal((T, K, 3))
    one = fit_transfer64(D, I, basis=8, ridge=0.01, channels=channels)
    blocked = fit_transfer64(D, I, basis=8, ridge=0.01, channels=channels, block_rows=7)
    np.testing.assert_allclose(blocked.mean, one.mean, atol=1e-13)
    Ua = one.basis.reshape(T, one.basis.shape[1], -1)
    Ub = blocked.basis.reshape(T, blocked.basis.shape[1], -1)
    for i in range(Ua.shape[1]):
        for c in range(Ua.shape[2]):
            sign = np.sign(Ua[:, i, c] @ Ub[:, i, c])
            np.testing.assert_allclose(sign * Ub[:, i, c], Ua[:, i, c], atol=1e-9)
            np.testing.assert_allclose(sign * blocked.transfer[c, i] if channels == "rgb"
                                       else sign * blocked.transfer[:, i],
                                       one.transfer[c, i] if channels == "rgb"
                                       else one.transfer[:, i], atol=1e-8)


def test_basis_is_orthonormal_and_spectrum_matches_numpy_svd():
    rng = np.random.default_rng(15)
    T, P, K = 160, 6, 12
    D = coloured_lights(rng, P, K)
    I = transport(rng.standard_normal((T, P)), D) + 0.05 * rng.standard_normal((T, K, 3))
    m = fit_transfer64(D, I, basis=10, ridge=0.0)
    U = m.basis
    np.testing.assert_allclose(U.T @ U, np.eye(U.shape[1]), atol=1e-10)
    _, In, _ = normalised(D, I)
    A = In - In.mean(axis=1, keepdims=True)
    stacked = np.concatenate([A[:, :, c] for c in range(3)], axis=1)
    sv = np.linalg.svd(stacked, compute_uv=False)
    got = np.array(m.diagnostics.indirect_singular_values[0])
    np.testing.assert_allclose(got[:20], sv[:20], rtol=1e-9)


# ---------------------------------------------------------------------------------------
# (10) automatic choices are reported


@pytest.mark.parametrize("gamma", [None, 2.0])
def test_auto_n_with_holdout_is_reported_and_consistent(gamma):
    rng = np.random.default_rng(16)
    T, P, K, H = 200, 10, 40, 6
    op = rng.standard_normal((T, P)) * np.geomspace(1.0, 1e-3, P)
    D = coloured_lights(rng, P, K)
    I = transport(op, D) + 1e-3 * rng.standard_normal((T, K, 3))
    Dh = coloured_lights(rng, P, H)
    Ih = transport(op, Dh)
    Ih += 0.02 * np.sqrt(np.mean(Ih**2)) * rng.standard_normal(Ih.shape)  # a floor
    m = fit_transfer(D, I, basis="auto", ridge="auto", gamma=gamma, holdout=(Dh, Ih))
    d = m.diagnostics
    assert d.n_basis_method == "holdout" and d.ridge_method == "loo"
    assert d.n_basis_requested == "auto" and d.holdout_used == H
    curve = np.array(d.holdout_rmse)
    n = m.n_basis
    assert d.n_basis == n
    assert curve[n - 1] <= (1 + AUTO_HOLDOUT_MARGIN) * curve.min()
    assert np.all(curve[: n - 1] > (1 + AUTO_HOLDOUT_MARGIN) * curve.min())
    assert n - 1 < int(np.argmin(curve))  # the margin mattered: not simply the minimum
    # independent evaluation of the reported curve, through reconstruct
    full = fit_transfer(D, I, basis=len(curve), ridge=d.ridge, gamma=gamma)
    for nn in range(1, len(curve) + 1):
        ys = np.stack([reconstruct(full, Dh[:, h], n=nn) for h in range(H)], axis=1)
        assert curve[nn - 1] == pytest.approx(relative_rmse(ys, Ih), rel=1e-4)
    json.dumps(d.to_dict(), allow_nan=False)


def test_auto_n_by_energy_without_holdout():
    rng = np.random.default_rng(17)
    T, P, K = 150, 10, 30
    op = rng.standard_normal((T, P)) * np.geomspace(1.0, 1e-3, P)
    D = coloured_lights(rng, P, K)
    I = transport(op, D)
    m = fit_transfer(D, I, basis="auto", ridge=1e-4)
    d = m.diagnostics
    assert d.n_basis_method == "energy" and d.holdout_rmse is None
    _, In, _ = normalised(D, I)
    A = In - In.mean(axis=1, keepdims=True)
    e = np.linalg.svd(np.concatenate([A[:, :, c] for c in range(3)], axis=1),
                      compute_uv=False) ** 2
    kept = np.cumsum(e) / e.sum()
    nb = m.n_basis - 1
    assert kept[nb - 1] >= AUTO_ENERGY > kept[nb - 2]
    assert d.energy_kept == pytest.approx(kept[nb - 1], rel=1e-9)


# ---------------------------------------------------------------------------------------
# (11) scaling


@pytest.mark.parametrize("gamma", [None, 2.2])
def test_reconstruction_is_positively_homogeneous(gamma):
    rng = np.random.default_rng(18)
    T, P, K = 120, 8, 30
    D = coloured_lights(rng, P, K)
    I = np.abs(transport(rng.standard_normal((T, P)), D)) + 0.01
    m = fit_transfer(D, I, basis=6, ridge="auto", gamma=gamma)
    x = rng.uniform(0.0, 1.0, (P, 3))
    y1 = reconstruct(m, x).astype(np.float64)
    assert np.linalg.norm(y1) > 0
    for a in (1e-6, 1.0, 1e6):
        ya = reconstruct(m, a * x).astype(np.float64)
        assert relative_rmse(ya, a * y1) < 1e-6


# ---------------------------------------------------------------------------------------
# keyframe groups, projection bound, diagnostics


def test_per_group_transfer_is_exact_per_keyframe():
    rng = np.random.default_rng(19)
    T, P, r, K = 200, 8, 2, 60
    ops = [lowrank_operator(rng, T, P, r) for _ in range(2)]
    D = coloured_lights(rng, P, K)
    groups = np.array([3, 7] * (K // 2))
    I = np.empty((T, K, 3))
    for g, op in zip((3, 7), ops, strict=True):
        I[:, groups == g] = transport(op, D[:, groups == g])
    per = fit_transfer(D, I, basis=2 * r + 1, ridge=0.0, groups=groups, per_group=True)
    shared = fit_transfer(D, I, basis=2 * r + 1, ridge=0.0, groups=groups)
    assert per.transfer.shape == (2, 3, 2 * r, P) and per.offset.shape == (2, 3, 2 * r)
    assert per.group_ids == (3, 7) and shared.group_ids is None
    assert per.diagnostics.groups == {"ids": [3, 7], "counts": [30, 30]}
    x = rng.uniform(0.0, 1.0, (P, 3))
    for g, op in zip((3, 7), ops, strict=True):
        assert relative_rmse(reconstruct(per, x, group=g), op @ x) < 1e-5
        assert relative_rmse(reconstruct(shared, x, group=g), op @ x) > 1e-2
    with pytest.raises(ValueError, match="group"):
        reconstruct(per, x)


def test_projection_bound_is_a_lower_bound():
    rng = np.random.default_rng(20)
    T, P, K = 150, 8, 30
    op = rng.standard_normal((T, P))
    D = coloured_lights(rng, P, K)
    I = transport(op, D)
    m = fit_transfer(D, I, basis=5, ridge="auto")
    for _ in range(3):
        x = rng.uniform(0.0, 1.0, (P, 3))
        ref = op @ x
        for n in (1, 3, 5):
            bound = projection_bound(m, ref, x, n=n)
            assert 0.0 <= bound <= relative_rmse(reconstruct(m, x, n=n), ref) + 1e-7
    exact = fit_transfer(D, I, basis=64, ridge=0.0)  # full rank: reference in the span
    x = rng.uniform(0.0, 1.0, (P, 3))
    assert projection_bound(exact, op @ x, x) < 1e-5


def test_relative_rmse_closed_form():
    b = np.array([[3.0, 4.0]])
    assert relative_rmse(b + np.array([[0.0, 1.0]]), b) == pytest.approx(0.2)
    assert relative_rmse(np.zeros(2), np.zeros(2)) == 0.0
    assert relative_rmse(np.ones(2), np.zeros(2)) == float("inf")


def test_diagnostics_report_unlit_points_and_spectra():
    rng = np.random.default_rng(21)
    T, P, K = 100, 7, 12
    D = coloured_lights(rng, P, K)
    D[4] = 0.0
    I = transport(rng.standard_normal((T, P)), D)
    m = fit_transfer(D, I, basis=4, ridge=0.0)
    d = m.diagnostics.to_dict()
    text = json.dumps(d, allow_nan=False)
    assert json.loads(text)["unlit_points"] == [4]
    assert any("lit by no configuration" in w for w in d["warnings"])
    Dn, _, _ = normalised(D, I)
    for c in range(3):
        Dc = Dn[:, :, c] - Dn[:, :, c].mean(axis=1, keepdims=True)
        np.testing.assert_allclose(d["direct_singular_values"][c],
                                   np.linalg.svd(Dc, compute_uv=False), rtol=1e-9, atol=1e-14)
    assert d["direct_effective_rank"] == [6, 6, 6] and d["direct_condition"] == [None] * 3
    assert d["n_basis"] == 4 and d["ridge"] == 0.0


@pytest.mark.parametrize("kind", ["mono", "rgb", "gamma", "per_group"])
def test_heldout_errors_equal_the_one_light_functions(kind):
    """The report's one-pass errors (every light, every n) are reconstruct64's and
    projection_bound's, light by light and n by n."""
    rng = np.random.default_rng(21)
    T, P, K, H = 120, 7, 40, 5
    op = rng.standard_normal((T, P))
    D = coloured_lights(rng, P, K + H)
    I = transport(op, D) + 0.05 * rng.standard_normal((T, K + H, 3))  # not in any span
    I[:, :, 1] += 0.2  # a negative reconstruction somewhere, but not everywhere
    kw = {"channels": "rgb"} if kind == "rgb" else {"gamma": 2.2} if kind == "gamma" else {}
    groups = np.arange(K + H) % 2 if kind == "per_group" else None
    if groups is not None:
        kw.update(groups=groups[:K], per_group=True)
    m = fit_transfer(D[:, :K], np.abs(I[:, :K]) if kind == "gamma" else I[:, :K], basis=9,
                     ridge=1e-3, **kw)
    X, R = D[:, K:], I[:, K:]
    ns = (1, 4, 9)
    e = heldout_errors(m, X, R, ns, None if groups is None else groups[K:])
    assert e.ns == ns
    for h in range(H):
        g = None if groups is None else int(groups[K + h])
        ref = R[:, h]
        assert e.ref_ss[h] == pytest.approx(float(np.sum(ref**2)), rel=1e-12)
        for i, n in enumerate(ns):
            rec = reconstruct64(m, X[:, h], n=n, group=g)
            assert e.sse[i, h] == pytest.approx(float(np.sum((rec - ref) ** 2)), rel=1e-9)
            assert e.negative[i, h] == pytest.approx(float(np.mean((rec < 0).any(axis=1))))
            bound = projection_bound(m, ref, X[:, h], n=n)  # the basis is shared by groups
            assert np.sqrt(e.bound_sse[i, h] / e.ref_ss[h]) == pytest.approx(bound, rel=1e-7)
    # the negative count is exercised (gamma's decoding clamps at 0: none there)
    assert (e.negative.max() == 0) if kind == "gamma" else (0 < e.negative.max() < 1)
