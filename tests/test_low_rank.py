"""The indirect solve on a basis of the light columns (prtcore/transport/low_rank.py)
against the full-width Neumann series of the same operator."""

from __future__ import annotations

import numpy as np
import pytest

from prtcore.core.sparse import RayBlockProduct
from prtcore.transport.low_rank import RANK_TOLERANCE, first_bounce_in_place, solve_low_rank
from prtcore.transport.solve import solve_indirect

T, M, K = 400, 48, 64


def _operator(terms: int, seed: int = 0) -> tuple[RayBlockProduct, np.ndarray]:
    """Texels on a line, each with M rays to texels within ±12 of it (a smoothing
    operator, as gather rays are), weights 2 Ā / M with Ā in [0.6, 0.9] per channel (the
    solver's albedo 1/2 makes the rows sum to Ā); with F > 1 the extra coefficients get
    weights of either sign and reads of −d, as the Chiang fibre's projected exitance."""
    rng = np.random.default_rng(seed)
    rows = np.repeat(np.arange(T), M)
    cols = np.clip(rows + rng.integers(-12, 13, len(rows)), 0, T - 1)
    w = np.empty((len(rows), terms, 3))
    w[:, 0] = rng.uniform(0.6, 0.9, (len(rows), 3))
    w[:, 1:] = rng.uniform(-0.3, 0.3, (len(rows), terms - 1, 3))
    read = np.ones((len(rows), terms))
    read[:, 1:] = rng.uniform(-0.5, 0.5, (len(rows), terms - 1))
    return RayBlockProduct(rows, cols, w * (2.0 / M), read, T), np.full((terms * T, 3), 0.5)


def _direct(terms: int, seed: int = 1, dim: float = 1.0) -> np.ndarray:
    """(F T, K, 3) float32: each light a sharp-edged lit interval (a shadow boundary) of
    its own position and width, brightness spread over four decades, light 0 scaled by
    ``dim``; the extra coefficients a tenth of it with either sign."""
    rng = np.random.default_rng(seed)
    x = np.arange(T)
    lo = rng.integers(0, T - 40, K)
    hi = lo + rng.integers(20, 200, K)
    lit = ((x[:, None] >= lo) & (x[:, None] < hi)).astype(np.float64)
    lit *= 10.0 ** rng.uniform(-2, 2, K)
    lit[:, 0] *= dim
    d = np.empty((terms * T, K, 3))
    d[:T] = lit[:, :, None] * rng.uniform(0.5, 1.0, 3)
    for a in range(1, terms):
        d[a * T:(a + 1) * T] = 0.1 * d[:T] * rng.uniform(-1, 1, (T, 1, 1))
    return d.astype(np.float32)


def _full(product, rho, direct, rows, first=None) -> np.ndarray:
    out = solve_indirect(None, rho, direct.copy(), 200, 1e-7, method="neumann",
                         product=product, first_bounce=first)[0]
    return out[:rows]


@pytest.mark.parametrize("terms", [1, 4])
def test_the_basis_solve_agrees_with_the_full_width_solve_light_by_light(terms):
    product, rho = _operator(terms)
    direct = _direct(terms)
    ref = _full(product, rho, direct, T)
    got, _, resid, stats = solve_low_rank(product, rho, direct.copy(), 200, 1e-7,
                                                rows=T)
    assert got.shape == (T, K, 3) and got.dtype == np.float32
    per_light = (np.linalg.norm(got - ref, axis=(0, 2))
                 / np.linalg.norm(ref, axis=(0, 2)))
    # measured 1.3e-3 for both (the basis drops at most 1e-2 of a bounce, and the
    # bounces it runs are the smaller part of the light)
    assert per_light.max() < RANK_TOLERANCE / 3, per_light.max()
    assert stats["converged"] and resid < 1e-7
    assert (stats["bounces"], stats["residual"]) == (len(stats["ranks"]), resid)
    # stopped by max_bounces: unconverged, and how far from the tolerance is reported
    *_, short = solve_low_rank(product, rho, direct.copy(), 3, 1e-7, rows=T)
    assert not short["converged"] and short["bounces"] == 3 and short["residual"] > 1e-3
    # the basis shrank: the later bounces ran on far fewer columns than lights
    assert stats["ranks"][0] == K and min(stats["ranks"]) < K // 4, stats["ranks"]


def test_a_dim_light_keeps_its_own_relative_accuracy():
    """Light 0 is 10⁶ times dimmer than its neighbours: without the per-light scaling the
    basis would drop it (its share of the Frobenius norm is nothing)."""
    product, rho = _operator(1)
    direct = _direct(1, dim=1e-6)
    ref = _full(product, rho, direct, T)
    got = solve_low_rank(product, rho, direct.copy(), 200, 1e-7)[0]
    err0 = np.linalg.norm(got[:, 0] - ref[:, 0]) / np.linalg.norm(ref[:, 0])
    assert err0 < RANK_TOLERANCE / 3, err0


def test_the_first_bounce_correction_and_a_single_bounce():
    """The near field's rows are added to the first bounce at full width; one bounce is
    the first bounce alone, exactly."""
    product, rho = _operator(4)
    direct = _direct(4)
    rows = np.array([3, 50, 51, T + 7])
    extra = np.random.default_rng(2).uniform(0, 5, (len(rows), K, 3)).astype(np.float32)
    ref = _full(product, rho, direct, T, (rows, extra))
    got = solve_low_rank(product, rho, direct.copy(), 200, 1e-7, rows=T,
                         first_bounce=(rows, extra))[0]
    assert np.linalg.norm(got - ref) / np.linalg.norm(ref) < RANK_TOLERANCE / 3
    one = solve_low_rank(product, rho, direct.copy(), 1, 1e-7, rows=T)[0]
    exact = solve_indirect(None, rho, direct.copy(), 1, 1.0, product=product)[0][:T]
    np.testing.assert_array_equal(one, exact)
    # the first bounce taken apart, so the caller can drop its corrections before the
    # later bounces: the same solve bit for bit, at every number of bounces
    for bounces in (1, 3, 200):
        whole = solve_low_rank(product, rho, direct.copy(), bounces, 1e-7, rows=T,
                               first_bounce=(rows, extra))
        bounced = direct.copy()
        first_bounce_in_place(product, rho, bounced, (rows, extra))
        apart = solve_low_rank(product, rho, bounced, bounces, 1e-7, rows=T, bounced=True)
        np.testing.assert_array_equal(apart[0], whole[0])
        assert apart[1:3] == whole[1:3] and apart[3]["ranks"] == whole[3]["ranks"]
    with pytest.raises(ValueError, match="bounced direct light has had its first-bounce"):
        solve_low_rank(product, rho, bounced, 3, 1e-7, first_bounce=(rows, extra),
                       bounced=True)


def test_a_series_that_grows_is_refused_not_returned():
    """An operator that sends on more light than it receives (its rows scaled to sum to
    more than 1: what a truncated exitance from too few rays did on a sparse head) makes
    every bounce larger: the solve raises after DIVERGING_BOUNCES growing bounces, at full
    width or on the basis, naming the keys that mend it, instead of returning the grown
    light."""
    from prtcore import PrtError, TransportDiverged  # public: a pipeline script catches it
    from prtcore.transport.low_rank import DIVERGING_BOUNCES

    assert issubclass(TransportDiverged, PrtError)  # the CLI's exit 2, one line

    product, rho = _operator(1)
    direct = _direct(1)
    # the series' growth a bounce at each scale (power iteration): 3 → 2.2, 1.35 → 1.008
    # (slow: the basis has taken over before it is seen), 1.3 → 0.97 (converges)
    for scale, bounces in ((3.0, "2 to 4"), (1.35, r"\d+ to \d+")):
        hot = RayBlockProduct(product.row, product.col, product.weight * scale,
                              product.read, T)
        with pytest.raises(TransportDiverged, match=rf"diverges: each bounce from "
                           rf"{bounces} added more light .*hair\.gather_rays"):
            solve_low_rank(hot, rho, direct.copy(), 40, 1e-7)
    for scale in (1.0, 1.3):  # convergent: past DIVERGING_BOUNCES without a word
        ok = RayBlockProduct(product.row, product.col, product.weight * scale,
                             product.read, T)
        got = solve_low_rank(ok, rho, direct.copy(), 40, 1e-7)
        assert got[1] > DIVERGING_BOUNCES
