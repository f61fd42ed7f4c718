"""The seam-aware texel-space filter (prtcore.receivers.smoothing, issue 13)."""

from __future__ import annotations

import numpy as np
import pytest
from scenes import tiny_spec

from prtcore.core.spec import parse_spec
from prtcore.pipeline import run_intake
from prtcore.receivers.smoothing import smooth_texels, smoothing_operator, texel_size
from prtcore.scenes.cornell import write_cornell_box


@pytest.fixture(scope="module")
def box_texels(tmp_path_factory):
    asset = write_cornell_box(tmp_path_factory.mktemp("box") / "box.glb")
    return run_intake(asset, parse_spec(tiny_spec(atlas={"resolution": 64, "padding": 2})),
                      quiet=True).texels


def test_operator_is_row_stochastic_and_local(box_texels):
    tx = box_texels
    W = smoothing_operator(tx)
    assert W.shape == (tx.count, tx.count)
    np.testing.assert_allclose(np.asarray(W.sum(axis=1)).ravel(), 1.0)
    assert np.all(W.diagonal() > 0)
    i, j = W.nonzero()
    h = texel_size(tx)
    assert np.all(np.linalg.norm(tx.position[i] - tx.position[j], axis=1) <= 1.5 * h[i] + 1e-12)
    # never across a crease: neighbours' normals agree
    assert np.all(np.einsum("ij,ij->i", tx.normal[i], tx.normal[j]) >= 0.9)
    # more than the texel itself on most texels (a real filter), radius 0: identity
    assert np.mean(np.diff(W.indptr) > 1) > 0.8
    assert (smoothing_operator(tx, radius=0.0) != 0).nnz == tx.count


def test_constant_irradiance_and_albedo_edges_are_kept(box_texels):
    tx = box_texels
    # outgoing radiance ρ·E/π of a constant irradiance: every albedo edge (red/green walls
    # against the white ceiling and floor) must survive, the values must not change
    rho = np.clip(tx.albedo, 0, 0.99)
    values = rho * 0.7
    np.testing.assert_allclose(smooth_texels(tx, values), values, rtol=1e-12)
    # per-configuration layout (T, K, 3), float32 in → float32 out
    stack = np.stack([values, 2 * values], axis=1).astype(np.float32)
    out = smooth_texels(tx, stack)
    assert out.dtype == np.float32 and out.shape == stack.shape
    np.testing.assert_allclose(out, stack, rtol=1e-5)


def test_no_blending_across_a_crease(box_texels):
    tx = box_texels
    floor = tx.normal[:, 1] > 0.99
    e = np.where(floor, 1.0, 0.0)[:, None] * np.ones(3)
    out = smooth_texels(tx, e, albedo=False)
    np.testing.assert_allclose(out[floor], 1.0)
    walls = np.abs(tx.normal[:, 1]) < 0.01
    np.testing.assert_allclose(out[walls], 0.0)


def test_noise_is_reduced(box_texels):
    tx = box_texels
    rng = np.random.default_rng(0)
    field = 1.0 + 0.3 * tx.position[:, :1]  # smooth, linear in x
    noisy = field + 0.1 * rng.normal(size=(tx.count, 3))
    out = smooth_texels(tx, noisy, albedo=False)
    err_before = np.linalg.norm(noisy - field)
    err_after = np.linalg.norm(out - field)
    assert err_after < 0.5 * err_before


def test_zero_albedo_channel_stays_zero(box_texels):
    tx = box_texels
    rho = np.clip(tx.albedo, 0, 0.99).copy()
    rho[: tx.count // 2, 2] = 0.0

    class Dark:  # same texels, half of them with a black blue channel
        count = tx.count
        position, normal, footprint = tx.position, tx.normal, tx.footprint
        albedo = rho

    values = rho * 0.5
    out = smooth_texels(Dark, values)
    assert np.all(out[: tx.count // 2, 2] == 0.0)
    np.testing.assert_allclose(out, values, rtol=1e-12, atol=1e-15)


def test_shape_is_checked(box_texels):
    with pytest.raises(ValueError, match="smooth_texels"):
        smooth_texels(box_texels, np.zeros((box_texels.count + 1, 3)))


def test_the_filter_is_built_as_the_diagonal_product_left_it(box_texels):
    """_row_stochastic builds W in place; its entries, and their order within each row (the
    order the filter sums a texel's neighbours in), are those of diag(1/Σw) @ W, the
    construction bundles were made with."""
    import scipy.sparse as sp

    from prtcore.receivers.smoothing import _row_stochastic

    rng = np.random.default_rng(3)
    t = 500
    i = np.sort(rng.integers(0, t, 4000))
    j = rng.integers(0, t, 4000)
    pairs = np.unique(np.stack([np.concatenate([i, np.arange(t)]),
                                np.concatenate([j, np.arange(t)])], axis=1), axis=0)
    i, j = pairs[:, 0], pairs[:, 1]
    w = rng.random(len(i)) + 0.1
    W0 = sp.csr_matrix((w, (i, j)), shape=(t, t))
    ref = sp.diags(1.0 / np.asarray(W0.sum(axis=1)).ravel()) @ W0
    got = _row_stochastic(i, j, w.copy(), t)
    for a in ("indptr", "indices", "data"):
        np.testing.assert_array_equal(getattr(got, a), getattr(ref, a))
    x = rng.random((t, 6))
    np.testing.assert_array_equal(got @ x, ref @ x)
