"""core/sparse.py and transport/kernels.py: the compiled solve kernels round exactly as the
numpy/scipy formulation they replace (bit for bit), so a bake's numbers do not move."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from prtcore.core.sparse import (
    RayBlockProduct,
    RayPart,
    assemble_ray_blocks,
    csr_dense,
    permute_csr,
    row_chunks,
)
from prtcore.transport import kernels


def _operator(rng, t: int, per_row: int = 9) -> sp.csr_matrix:
    rows = np.repeat(np.arange(t), per_row)
    cols = rng.integers(0, t, len(rows))
    g = sp.csr_matrix((rng.random(len(rows)) / per_row, (rows, cols)), shape=(t, t),
                      dtype=np.float32)
    g.sum_duplicates()
    g.sort_indices()
    return g


@pytest.mark.parametrize("threads", [1, 2])
def test_csr_dense_is_scipys_product(threads):
    rng = np.random.default_rng(0)
    g = _operator(rng, 3001)
    x = rng.random((3001, 30)).astype(np.float32)
    out = np.full((3001, 30), np.nan, dtype=np.float32)
    csr_dense(g.indptr.astype(np.int64), g.indices.astype(np.int64), g.data, x, out,
              row_chunks(3001, threads))
    assert np.array_equal(out, g @ x)


@pytest.mark.parametrize("channels", [False, True])
def test_chebyshev_step_is_the_numpy_step(channels):
    """One fused step equals the numpy step, with G alone and with per-channel matrices
    added (solve.ChannelProduct: the subsurface walks' operator)."""
    rng = np.random.default_rng(1)
    t, k = 2500, 4
    g = _operator(rng, t)
    extra = [_operator(rng, t, per_row=2) for _ in range(3)] if channels else []
    for m in extra:  # some rows without a walk
        m.data[: m.indptr[t // 2]] = 0
        m.eliminate_zeros()
    rho = rng.uniform(0.1, 0.9, (t, 3)).astype(np.float32)
    d, r, x = (rng.standard_normal((t, k, 3)).astype(np.float32) for _ in range(3))
    c_r = np.array([0.7, 0.8, 0.9], dtype=np.float32)
    c_d = np.array([0.3, 0.2, 0.1], dtype=np.float32)
    # numpy, as solve.py wrote it before the fused kernel
    src = (d * rho[:, None, :]).reshape(t, -1)
    ad = g @ src
    for c, m in enumerate(extra):
        ad[:, c::3] += m @ np.ascontiguousarray(src[:, c::3])
    ad = ad.reshape(t, k, 3)
    ad -= d
    r_np = r + ad
    d_np = d * c_d + r_np * c_r
    x_np = x + d_np
    # fused
    chunks = row_chunks(t, 2)
    flat = [a.reshape(t, -1).copy() for a in (d, r, x)]
    src_new, d_new = np.empty_like(src), np.empty_like(src)
    nd, nx = np.empty((len(chunks) - 1, 3 * k)), np.empty((len(chunks) - 1, 3 * k))
    e_ptr = np.zeros((3, t + 1), dtype=np.int64)
    if extra:
        e_ptr = np.stack([m.indptr for m in extra]).astype(np.int64)
        e_ptr += np.cumsum([0, extra[0].nnz, extra[1].nnz])[:, None]
    e_idx = np.concatenate([m.indices for m in extra] or [[]]).astype(np.int64)
    e_dat = np.concatenate([m.data for m in extra] or [[]]).astype(np.float32)
    kernels.chebyshev_step(g.indptr.astype(np.int64), g.indices.astype(np.int64), g.data,
                           e_ptr, e_idx, e_dat, rho, src, flat[0], flat[1], flat[2],
                           src_new, d_new, c_r, c_d, chunks, nd, nx)
    assert np.array_equal(flat[1], r_np.reshape(t, -1))
    assert np.array_equal(d_new, d_np.reshape(t, -1))
    assert np.array_equal(flat[2], x_np.reshape(t, -1))
    assert np.array_equal(src_new, (d_np * rho[:, None, :]).reshape(t, -1))
    assert np.allclose(np.sqrt(nd.sum(axis=0)), np.linalg.norm(d_np.reshape(t, -1), axis=0),
                       rtol=1e-6)
    assert np.allclose(np.sqrt(nx.sum(axis=0)), np.linalg.norm(x_np.reshape(t, -1), axis=0),
                       rtol=1e-6)


@pytest.mark.parametrize("steps", [1, 2, 3])
def test_closing_steps_are_the_numpy_steps(monkeypatch, steps):
    """solve._closing_steps (the fused kernels.closing_step) equals the numpy formulation
    it replaced, bit for bit: E = xc[cell]; FINE_STEPS × (E = G (ρ ∘ E) + b); E *= ρ/π."""
    import math

    from prtcore.core.sparse import SparseProduct
    from prtcore.transport import solve

    monkeypatch.setattr(solve, "FINE_STEPS", steps)
    rng = np.random.default_rng(2)
    t, k, cells = 2000, 5, 300
    g = _operator(rng, t)
    rho = rng.uniform(0.1, 0.9, (t, 3)).astype(np.float32)
    cell = rng.integers(0, cells, t)
    xc = rng.random((cells, k, 3)).astype(np.float32)
    b = rng.random((t, k, 3)).astype(np.float32)
    scale = rho / np.float32(math.pi)
    x = xc[cell]
    for _ in range(steps):
        x = (g @ (x * rho[:, None, :]).reshape(t, -1)).reshape(t, k, 3)
        x += b
    x *= scale[:, None, :]
    got = solve._closing_steps(SparseProduct(g, 2), rho, xc, cell, b.copy(), scale)
    assert got.dtype == np.float32 and np.array_equal(got, x)


@pytest.mark.parametrize("f, first", [(1, 0), (4, 0), (4, 20)])
def test_ray_block_product_is_the_sum_of_its_rank_one_blocks(f, first):
    """RayBlockProduct against the CSR built block by block from the same rays (with
    repeated (row, column) pairs and texels no ray leaves from), per colour channel. With
    ``first``, the texels below it carry coefficient 0 alone (a hair + mesh bake's atlas
    texels): their other weights and reads are ignored, and the operator has
    T + (F − 1)(T − first) rows."""
    rng = np.random.default_rng(0)
    t, n, k = 50, 400, 5
    rows = np.sort(rng.integers(5, t - 5, n))  # rows 0–4 and 45–49 idle
    cols = rng.integers(0, t, n)
    weight = rng.normal(size=(n, f, 3)).astype(np.float32)
    read = rng.normal(size=(n, f)).astype(np.float32)
    size = t + (f - 1) * (t - first)

    def at(i, a):  # texel i's coefficient a, or -1 where it has none
        return np.where(a == 0, i, np.where(i >= first, t + (a - 1) * (t - first) + i - first,
                                             -1))

    x = rng.normal(size=(size, 3 * k)).astype(np.float32)
    product = RayBlockProduct(rows, cols, weight, read, t, threads=2, first=first)
    assert product.shape == (size, size)
    got = product(x)
    want = np.zeros_like(x, dtype=np.float64)
    for c in range(3):
        r = np.concatenate([at(rows, a) for a in range(f) for _ in range(f)])
        q = np.concatenate([at(cols, b) for _ in range(f) for b in range(f)])
        v = np.concatenate([weight[:, a, c] * read[:, b] for a in range(f)
                            for b in range(f)])
        keep = (r >= 0) & (q >= 0)
        m = sp.csr_matrix((v[keep], (r[keep], q[keep])), shape=(size, size))
        want[:, c::3] = m @ x[:, c::3].astype(np.float64)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-4)
    head = int((rows < first).sum())  # their rays keep coefficient 0's three weights
    assert product.head_weight.shape == (head, 3) and product.weight.shape == (n - head, f, 3)
    given = RayBlockProduct(rows, cols, weight[head:], read, t, threads=2, first=first,
                            head_weight=weight[:head, 0])
    assert np.array_equal(given(x), got)  # the same product from its weights given apart
    with pytest.raises(ValueError, match=rf"{head} rays from texels below {first} take "):
        RayBlockProduct(rows, cols, weight[head:], read, t, first=first,
                        head_weight=weight[:, 0])
    for a in range(f):  # each coefficient's rows where the layout says
        sl = product.coefficient_rows(a)
        assert sl.stop - sl.start == (t if a == 0 else t - first)
    with pytest.raises(ValueError, match="sorted"):
        RayBlockProduct(rows[::-1], cols, weight, read, t)
    with pytest.raises(ValueError, match=r"x must be \(\d+, 3k\), got \(\d+, 2\)"):
        product(x[:, :2])  # channels come in threes: the kernel would read past the row


@pytest.mark.parametrize("chunk", [7, 1 << 18])
def test_assembled_ray_blocks_are_the_parts_sorted_by_row_without_the_sort(chunk):
    """assemble_ray_blocks places every part's rays as a stable argsort of the parts' rows
    concatenated would (ties in part order, then in each part's order), bit for bit, its
    float64 values cast to float32 as they are written, and made a chunk at a time (each
    call asks for one slice of its part, in order); rows outside the texels are refused
    by name."""
    rng = np.random.default_rng(3)
    t, f = 40, 4
    sizes = (0, 150, 90, 61)  # an empty part, and rows repeated across parts
    parts, asked, whole = [], [], []
    for i, n in enumerate(sizes):
        rows = rng.integers(0 if i % 2 else 10, t, n)
        cols = rng.integers(0, t, n)
        w = rng.normal(size=(n, f, 3))
        r = rng.normal(size=(n, f))
        whole.append((rows, cols, w, r))

        def values(sl, w=w, r=r, i=i):
            asked.append((i, sl.start, sl.stop))
            return w[sl], r[sl]

        parts.append(RayPart(rows, cols, values))
    got = assemble_ray_blocks(parts, t, f, threads=2, first=5, chunk=chunk)
    order = np.argsort(np.concatenate([p[0] for p in whole]), kind="stable")
    for field, want in zip(("row", "col", "weight", "read"), zip(*whole, strict=True), strict=True):
        want = np.concatenate(want)[order].astype(np.float32 if field in ("weight", "read")
                                                  else getattr(got, field).dtype)
        if field == "weight":  # rows below first keep coefficient 0's weights alone
            head = int((np.concatenate([p[0] for p in whole]) < 5).sum())
            assert got.head == head and got.head_weight.shape == (head, 3)
            assert np.array_equal(got.head_weight, want[:head, 0])
            want = want[head:]
        assert np.array_equal(getattr(got, field), want), field
    assert got.first == 5 and got.shape == (40 + 3 * 35, 40 + 3 * 35)
    want_idle = np.setdiff1d(np.arange(t), np.concatenate([p[0] for p in whole]))
    assert np.array_equal(got.idle, want_idle)
    for i, n in enumerate(sizes):  # each part's slices in order, none larger than chunk
        sl = [(a, b) for j, a, b in asked if j == i]
        assert [a for a, _ in sl] == list(range(0, n, chunk))
        assert all(b - a <= chunk for a, b in sl) and (not n or sl[-1][1] == n)
    bad = RayPart(np.array([3, 40]), np.array([0, 0]), lambda sl: None)
    with pytest.raises(ValueError, match=r"rows in \[0, 40\), got \[3, 40\]"):
        assemble_ray_blocks([bad], t, f)


def test_permute_csr_is_p_a_p_transposed_with_sorted_rows():
    """permute_csr(A, order) equals scipy's A[order][:, order] entry for entry, rows
    sorted by column, duplicates kept (a gather's CSR has none after summing, but the
    permutation must not merge or drop them)."""
    rng = np.random.default_rng(4)
    a = sp.random(300, 300, density=0.05, random_state=5, format="csr", dtype=np.float32)
    a.sort_indices()
    order = rng.permutation(300)
    got = permute_csr(a, order)
    want = a[order][:, order].tocsr()
    want.sort_indices()
    for i in range(300):
        row = got.indices[got.indptr[i]:got.indptr[i + 1]]
        assert np.all(np.diff(row) > 0)
    np.testing.assert_array_equal(got.toarray(), want.toarray())
    dup = sp.csr_matrix((np.array([1.0, 2.0, 3.0], np.float32), np.array([1, 1, 0]),
                         np.array([0, 2, 3, 3])), shape=(3, 3))
    p = permute_csr(dup, np.array([1, 0, 2]))
    assert p.nnz == 3 and np.array_equal(p.toarray(), dup[[1, 0, 2]][:, [1, 0, 2]].toarray())
    with pytest.raises(ValueError, match="square"):
        permute_csr(sp.csr_matrix((2, 3)), np.arange(2))
