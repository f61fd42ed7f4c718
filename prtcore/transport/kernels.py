"""Compiled (numba) kernels of the indirect solve: one Chebyshev step fused into a single
pass over the texels, and the coarse solve's closing steps (:mod:`prtcore.transport.solve`);
the CSR × dense row product they build on is :mod:`prtcore.core.sparse`'s.

Why: the solve is memory-bound. With numpy, a Chebyshev step reads and writes the
(T, 3K) float32 arrays about ten times (ρ∘d, the product, four updates, two column
norms); the fused step streams each array once per step, rows split over threads.

Every kernel rounds exactly as the numpy/scipy code it replaces: float32 products and sums
in the same order (scipy's ``csr_matvecs`` adds ``a·x[j]`` into a zeroed row, non-zeros in
storage order), no fused multiply-add (``fastmath`` off), so a bake's numbers do not change.
Column norms accumulate in float64.

Compiled on first use and cached on disk (``cache=True``; numba's cache directory,
``NUMBA_CACHE_DIR`` where the package directory is read-only).
"""

from __future__ import annotations

import numba
import numpy as np

from prtcore.core.sparse import _row_product


@numba.njit(parallel=True, cache=True, nogil=True)
def chebyshev_step(indptr, indices, data, e_indptr, e_indices, e_data, rho, src, d, r, x,
                   src_new, d_new, c_r, c_d, chunks, norm_d,
                   norm_x):  # pragma: no cover - compiled
    """One step of the Chebyshev iteration of :func:`prtcore.transport.solve._chebyshev`,
    all rows in one pass:

    ``ad = A·src − d``; ``r += ad``; ``d_new = d·c_d + r·c_r``; ``x += d_new``;
    ``src_new = ρ∘d_new`` (the next product's input), and the squared column norms of
    d_new and x.

    A = G (indptr, indices, data: CSR float32) plus, on channel c's columns only, the
    channel's own matrix (:class:`prtcore.transport.solve.ChannelProduct`; the subsurface
    walks): e_indptr (3, T + 1) int64 into e_indices / e_data, all zero without. Rounding
    as ChannelProduct: G's sum, then each channel matrix's own sum added to it.
    Arrays (T, 3k) float32 C-contiguous, column ``3·k + channel``: src = ρ∘d (read for all
    rows, so d_new and src_new are separate buffers), d, r, x (updated in place), src_new,
    d_new (written). rho (T, 3) float32; c_r, c_d (3,) float32 per channel; chunks :
    :func:`row_chunks`; norm_d, norm_x (chunks − 1, 3k) float64, overwritten with each
    chunk's partial sums of squares (the caller adds the chunks).
    """
    ncol = d.shape[1]
    for ci in numba.prange(len(chunks) - 1):
        acc = np.empty(ncol, dtype=np.float32)
        acc_c = np.empty(ncol // 3, dtype=np.float32)
        nd = norm_d[ci]
        nx = norm_x[ci]
        nd[:] = 0.0
        nx[:] = 0.0
        for i in range(chunks[ci], chunks[ci + 1]):
            _row_product(indptr, indices, data, src, i, acc)
            for c in range(3):
                if e_indptr[c, i] == e_indptr[c, i + 1]:
                    continue
                acc_c[:] = 0
                for jj in range(e_indptr[c, i], e_indptr[c, i + 1]):
                    g = e_data[jj]
                    sj = src[e_indices[jj]]
                    for kk in range(ncol // 3):
                        acc_c[kk] += g * sj[3 * kk + c]
                for kk in range(ncol // 3):
                    acc[3 * kk + c] += acc_c[kk]
            di, ri, xi = d[i], r[i], x[i]
            dn, sn, rh = d_new[i], src_new[i], rho[i]
            for col in range(ncol):
                c = col % 3
                rv = ri[col] + (acc[col] - di[col])
                ri[col] = rv
                v = di[col] * c_d[c] + rv * c_r[c]
                dn[col] = v
                sn[col] = v * rh[c]
                xv = xi[col] + v
                xi[col] = xv
                nd[col] += np.float64(v) * np.float64(v)
                nx[col] += np.float64(xv) * np.float64(xv)


@numba.njit(inline="always", cache=True)
def _times_channels(x, r, out):  # pragma: no cover - compiled
    """out[3·k + c] = x[3·k + c] · r[c] (float32, one rounding each) for a row of (k, 3)
    values, channel fastest."""
    r0 = r[0]
    r1 = r[1]
    r2 = r[2]
    for kk in range(len(out) // 3):
        c = 3 * kk
        out[c] = x[c] * r0
        out[c + 1] = x[c + 1] * r1
        out[c + 2] = x[c + 2] * r2


@numba.njit(parallel=True, cache=True, nogil=True)
def albedo_times(xin, cell, rho, out, chunks):  # pragma: no cover - compiled
    """out[j] = ρ_j ∘ xin[cell[j]] for every texel j (float32, one rounding per value, as
    numpy's ``xin[cell] * ρ``): the next product's input read through ``cell`` (the coarse
    grid's cells, or the identity), without the full-resolution E gathered first.
    xin (n, 3k), out (T, 3k) float32 C-contiguous (out may be xin when cell is the
    identity), column ``3·k + channel``; cell (T,) int64; rho (T, 3) float32."""
    for ci in numba.prange(len(chunks) - 1):
        for j in range(chunks[ci], chunks[ci + 1]):
            _times_channels(xin[cell[j]], rho[j], out[j])


@numba.njit(parallel=True, cache=True, nogil=True)
def product_plus(indptr, indices, data, src, b, scale, out,
                 chunks):  # pragma: no cover - compiled
    """out[i] = (G·src)[i] + b[i], then × scale[i] per channel when ``scale`` has T rows:
    the product summed as :func:`prtcore.core.sparse.csr_dense` (scipy's order) and the
    two numpy passes after it (``x += b``, ``x *= scale``) done as each row is written.
    src (n, 3k), b and out (T, 3k) float32 C-contiguous (out may be b, not src); scale
    (T, 3) float32 or (0, 3): none; chunks : :func:`row_chunks`."""
    ncol = out.shape[1]
    scaled = scale.shape[0] > 0
    for ci in numba.prange(len(chunks) - 1):
        acc = np.empty(ncol, dtype=np.float32)
        for i in range(chunks[ci], chunks[ci + 1]):
            _row_product(indptr, indices, data, src, i, acc)
            bi = b[i]
            oi = out[i]
            for col in range(ncol):
                acc[col] = acc[col] + bi[col]
            if scaled:
                _times_channels(acc, scale[i], oi)
            else:
                for col in range(ncol):
                    oi[col] = acc[col]
