"""Sparse × dense products on all cores, rounding as scipy's (compiled with numba).

``csr_dense`` adds ``a·x[j]`` into a zeroed output row, non-zeros in storage order, as
scipy's ``csr_matvecs`` does, without fused multiply-adds (``fastmath`` off): the same bits
as ``matrix @ x``, rows split over threads. Used by the indirect solve
(:mod:`prtcore.transport.solve`, whose fused Chebyshev step builds on :func:`_row_product`)
and the lightmap filter (:mod:`prtcore.receivers.smoothing`). Compiled on first use and
cached on disk (``cache=True``).
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp

#: Row chunks per thread (load balance: texel rows differ in their non-zeros).
CHUNKS_PER_THREAD = 8


def row_chunks(rows: int, threads: int) -> np.ndarray:
    """Boundaries (c + 1,) int64 of the row chunks the kernels split ``rows`` into."""
    c = max(1, min(rows, CHUNKS_PER_THREAD * max(1, threads)))
    return np.linspace(0, rows, c + 1).astype(np.int64)


@numba.njit(inline="always", cache=True)
def _row_product(indptr, indices, data, x, i, acc):  # pragma: no cover - compiled
    """acc (c,) ← Σ_jj data[jj]·x[indices[jj]] over row i (zeroed first), in acc's dtype."""
    acc[:] = 0
    for jj in range(indptr[i], indptr[i + 1]):
        g = data[jj]
        xj = x[indices[jj]]
        for col in range(len(acc)):
            acc[col] += g * xj[col]


@numba.njit(parallel=True, cache=True, nogil=True)
def csr_dense(indptr, indices, data, x, out, chunks):  # pragma: no cover - compiled
    """out[i] = Σ_jj data[jj]·x[indices[jj]] for every row i (scipy's order).

    indptr (T + 1,) int64 / indices (nnz,) int32 or int64 / data (nnz,) float32 or float64:
    CSR; x (n, c) C-contiguous and out (T, c), overwritten, of data's dtype; chunks :
    :func:`row_chunks`.
    """
    for ci in numba.prange(len(chunks) - 1):
        for i in range(chunks[ci], chunks[ci + 1]):
            _row_product(indptr, indices, data, x, i, out[i])


class SparseProduct:
    """``matrix @ x`` for a CSR matrix and dense (n, c) arrays of ``dtype`` (float32 or
    float64; the matrix is cast to it), rows split over ``threads`` threads
    (:func:`csr_dense`, rounding as scipy's kernel). The CSR arrays and row chunks are
    prepared once, not per product.
    """

    def __init__(self, matrix: sp.csr_matrix, threads: int = 2, dtype: type = np.float32):
        self.dtype = np.dtype(dtype)
        m = matrix if matrix.dtype == self.dtype else matrix.astype(self.dtype)
        self.shape = m.shape
        self.indptr = m.indptr.astype(np.int64)
        # int32 columns as scipy stores them (a copy as int64 would cost 4 bytes per
        # non-zero: 140 MB for the 1024² Cornell box)
        self.indices = m.indices.astype(np.int32, copy=False)
        self.data = np.ascontiguousarray(m.data)
        self.threads = max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS))
        self.chunks = row_chunks(m.shape[0], self.threads)

    def __call__(self, x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """x : (n, c); out : optional (m, c) C-contiguous array of ``dtype`` to fill."""
        x = np.ascontiguousarray(x, dtype=self.dtype)
        if out is None:
            out = np.empty((self.shape[0], x.shape[1]), dtype=self.dtype)
        numba.set_num_threads(self.threads)
        csr_dense(self.indptr, self.indices, self.data, x, out, self.chunks)
        return out
