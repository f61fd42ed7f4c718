"""Conditioning of the transfer fit on synthetic data (issue 8): coincident and nearly
collinear measurement points, P ≫ K and K ≫ P, n ≥ K, ridge λ from 0 to 1e300.

Data: a non-negative rank-6 transport ``I = T·D`` (T texels × P points), optionally with
1e-3 multiplicative noise on I so that the data are not exactly consistent (that is what
makes an ill-conditioned λ = 0 transfer blow up).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from prtcore.core.tolerances import DIRECT_SVD_REL_TOL
from prtcore.fit.model import UNDERDETERMINED_WARNING, relative_rmse
from prtcore.fit.transfer import fit_transfer, fit_transfer64, reconstruct, reconstruct64

#: float32 model (what a bundle stores) vs float64 model, relative over the lightmap.
F32_RTOL = 1e-5


def _data(rng, T, P, K, noise=0.0, D=None):
    op = np.abs(rng.normal(size=(T, 6))) @ np.abs(rng.normal(size=(6, P)))
    if D is None:
        D = np.abs(rng.normal(size=(P, K, 3)))
    I = np.einsum("tp,pkc->tkc", op, D)
    if noise:
        I = I * (1.0 + noise * rng.normal(size=I.shape))
    return op, D, I


def _centred_normalised(D):
    s = np.sqrt(np.sum(D**2, axis=(0, 2)))
    Dn = D / s[None, :, None]
    return Dn - Dn.mean(axis=1, keepdims=True)


@pytest.mark.parametrize("eps", [1e-1, 1e-3, 1e-6, 1e-9, 1e-12, 0.0])
@pytest.mark.parametrize("ridge", [0.0, "auto"])
def test_nearly_coincident_points_float32_agrees_with_float64(eps, ridge):
    """Points whose direct vectors differ by eps (eps = 0: all points coincide).

    Before the fix (DIRECT_SVD_REL_TOL 1e-12) eps = 1e-9 with λ = 0 kept σ_min/σ_max ≈ 4e-11,
    |M| reached 8e8 and the float32 model was 2 % off the float64 one.
    """
    rng = np.random.default_rng(0)
    P, K = 40, 60
    base = np.abs(rng.normal(size=(1, K, 3)))
    D = base + eps * np.abs(rng.normal(size=(P, K, 3)))
    op, D, I = _data(rng, 300, P, K, noise=1e-3, D=D)
    m32 = fit_transfer(D, I, basis=6, ridge=ridge)
    m64 = fit_transfer64(D, I, basis=6, ridge=ridge)
    x = D[:, 3] + eps * rng.random((P, 3))
    y32 = reconstruct(m32, x).astype(np.float64)
    y64 = reconstruct64(m64, x)
    assert np.isfinite(m32.transfer).all() and np.isfinite(y32).all()
    assert relative_rmse(y32, y64) <= F32_RTOL
    assert relative_rmse(y64, op @ x) <= 5e-3  # noise level 1e-3, no blow-up
    d = m64.diagnostics
    deficient = [w for w in d.warnings if w.startswith("direct matrix rank-deficient")]
    if eps <= 1e-9:  # far below the float32-safe tolerance: reported singular, rank 1
        assert d.direct_condition == (None, None, None)
        assert d.direct_effective_rank == (1, 1, 1)
        assert deficient and "effective rank 1 < 40" in deficient[0]
    elif eps >= 1e-3:
        assert all(c is not None and c < 1.0 / DIRECT_SVD_REL_TOL for c in d.direct_condition)
        assert d.direct_effective_rank == (40, 40, 40) and not deficient


def test_diagnostics_match_numpy_for_coincident_points():
    rng = np.random.default_rng(1)
    P0, K = 10, 30
    D0 = np.abs(rng.normal(size=(P0, K, 3)))
    D = np.concatenate([D0, D0[:4], D0[:4]], axis=0)  # 8 points coincide with 4 others
    _, D, I = _data(rng, 120, D.shape[0], K, D=D)
    d = fit_transfer64(D, I, basis=5, ridge=1e-3).diagnostics
    Dc = _centred_normalised(D)
    for c in range(3):
        sv = np.linalg.svd(Dc[:, :, c], compute_uv=False)
        np.testing.assert_allclose(d.direct_singular_values[c], sv, rtol=1e-9,
                                   atol=1e-12 * sv[0])
        assert d.direct_effective_rank[c] == np.linalg.matrix_rank(
            Dc[:, :, c], tol=DIRECT_SVD_REL_TOL * sv[0]) == P0
        assert d.direct_condition[c] is None  # 18 singular values, 10 non-zero
    # without duplicates: finite condition number equal to numpy's
    _, D1, I1 = _data(rng, 120, P0, K, D=D0)
    d1 = fit_transfer64(D1, I1, basis=5, ridge=1e-3).diagnostics
    Dc1 = _centred_normalised(D1)
    for c in range(3):
        assert d1.direct_condition[c] == pytest.approx(np.linalg.cond(Dc1[:, :, c]), rel=1e-8)
    # 18 points < 29 centred configurations: not underdetermined by count, but the
    # coincident points make the direct matrix rank-deficient, and the fit says so
    assert UNDERDETERMINED_WARNING not in d.warnings
    assert any(w.startswith("direct matrix rank-deficient: effective rank 10 < 18")
               for w in d.warnings)
    assert not any(w.startswith("direct matrix rank-deficient") for w in d1.warnings)


LAMBDAS = [0.0, 1e-300, 1e-30, 1e-12, 1e-6, 1e-2, 1.0, 1e3, 1e12, 1e300]


def test_ridge_from_zero_to_huge_on_rank_deficient_direct():
    """P > K with duplicated points: ‖M(λ)‖ is finite, non-increasing in λ, continuous at
    λ = 0 (the minimum-norm solution, no blow-up) and → 0 for huge λ (then the runtime
    uses the mean coefficients alone)."""
    rng = np.random.default_rng(2)
    P0, K = 30, 12
    D0 = np.abs(rng.normal(size=(P0, K, 3)))
    D = np.concatenate([D0, D0[:10]], axis=0)
    _, D, I = _data(rng, 150, D.shape[0], K, noise=1e-2, D=D)
    norms = []
    models = {}
    for lam in LAMBDAS:
        m = fit_transfer64(D, I, basis=6, ridge=lam)
        assert np.isfinite(m.transfer).all() and np.isfinite(m.offset).all()
        assert np.isfinite(reconstruct(m, D[:, 0])).all()
        norms.append(float(np.linalg.norm(m.transfer)))
        models[lam] = m
    assert all(b <= a * (1 + 1e-12) for a, b in itertools.pairwise(norms)), norms
    np.testing.assert_allclose(models[1e-300].transfer, models[0.0].transfer, rtol=1e-12)
    np.testing.assert_allclose(models[1e-30].transfer, models[0.0].transfer, rtol=1e-9,
                               atol=1e-12)
    assert norms[-1] < 1e-250
    # λ huge: u = s·b with b the mean normalised coefficients → reconstruction of a
    # training configuration equals s·(mean + U·c̄)
    assert np.linalg.norm(models[1e300].offset) > 0
    auto = fit_transfer64(D, I, basis=6, ridge="auto")
    assert auto.diagnostics.ridge_method == "loo" and np.isfinite(auto.ridge)


@pytest.mark.parametrize(("P", "K"), [(400, 12), (4, 150), (20, 20)])
def test_extreme_point_to_configuration_ratios(P, K):
    rng = np.random.default_rng(3)
    op, D, I = _data(rng, 200, P, K)
    m = fit_transfer(D, I, basis=K + 10, ridge="auto")  # n ≥ K: capped at the data's rank
    d = m.diagnostics
    assert np.isfinite(m.transfer).all() and np.isfinite(m.basis).all()
    assert d.n_basis_method == "capped" and m.n_basis <= K
    assert any("capped" in w for w in d.warnings)
    assert (UNDERDETERMINED_WARNING in d.warnings) == (P > K - 1)
    x = np.abs(rng.normal(size=(P, 3)))
    y = reconstruct(m, x)
    assert np.isfinite(y).all()
    if K > 10 * P:  # well-determined: the rank-6 transport is recovered for a new light
        assert relative_rmse(y, op @ x) <= 1e-4


def test_fit_is_invariant_to_configuration_scale_over_twelve_decades():
    rng = np.random.default_rng(4)
    _, D, I = _data(rng, 150, 20, 40)
    a = 10.0 ** rng.uniform(-6, 6, size=40)
    m1 = fit_transfer64(D, I, basis=6, ridge=1e-3)
    m2 = fit_transfer64(D * a[None, :, None], I * a[None, :, None], basis=6, ridge=1e-3)
    for name in ("mean", "basis", "transfer", "offset"):
        np.testing.assert_allclose(getattr(m2, name), getattr(m1, name), rtol=1e-8,
                                   atol=1e-10, err_msg=name)
