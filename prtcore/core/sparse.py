"""Sparse × dense products on all cores, rounding as scipy's (compiled with numba).

``csr_dense`` adds ``a·x[j]`` into a zeroed output row, non-zeros in storage order, as
scipy's ``csr_matvecs`` does, without fused multiply-adds (``fastmath`` off): the same bits
as ``matrix @ x``, rows split over threads. Used by the indirect solve
(:mod:`prtcore.transport.solve`, whose fused Chebyshev step builds on :func:`_row_product`)
and the lightmap filter (:mod:`prtcore.receivers.smoothing`). Compiled on first use and
cached on disk (``cache=True``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

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


@numba.njit(cache=True, inline="always")
def _coefficient_row(i, a, t, first):  # pragma: no cover - compiled
    """Row of texel i's coefficient a in RayBlockProduct's layout (a ≥ 1 needs i ≥ first)."""
    return i if a == 0 else t + (a - 1) * (t - first) + (i - first)


@numba.njit(parallel=True, cache=True, nogil=True)
def ray_blocks(starts, row, col, head_weight, weight, read, t, first, x,
               out):  # pragma: no cover - compiled
    """out (N, c) ← Σ_r over rays: for row coefficient a, ``weight[r, a, col % 3] ·
    Σ_b read[r, b] · x[col[r]'s coefficient b]`` added at row[r]'s coefficient a (out
    zeroed here). Texels below ``first`` carry coefficient 0 only (their other reads are
    skipped, and their rays, the first ``len(head_weight)``, keep that coefficient's
    weights alone: ``head_weight[r]``; ray r ≥ that count has ``weight[r − count]``);
    coefficient a ≥ 1 of texel i ≥ first is row ``T + (a − 1)(T − first) + i − first``
    (with first = 0: ``i + a·T``).

    starts (n_chunks + 1,) int64 ray boundaries that never split one row's rays (rows
    sorted); row, col (n,) int32; head_weight (h, 3), weight (n − h, F, 3) and read (n, F)
    float32; x (N, c) float32 C-contiguous, c = 3·k columns with the colour channel
    fastest."""
    f = read.shape[1]
    c = x.shape[1]
    h = head_weight.shape[0]
    for ci in numba.prange(len(starts) - 1):
        acc = np.empty(c, dtype=x.dtype)
        if starts[ci] < starts[ci + 1]:
            lo = row[starts[ci]]
            hi = row[starts[ci + 1] - 1]
            for a in range(f):
                for i in range(max(lo, first) if a else lo, hi + 1):
                    out[_coefficient_row(i, a, t, first), :] = 0
        for r in range(starts[ci], starts[ci + 1]):
            acc[:] = 0
            j = col[r]
            for b in range(f if j >= first else 1):
                v = read[r, b]
                xb = x[_coefficient_row(j, b, t, first)]
                for k in range(c):
                    acc[k] += v * xb[k]
            i = row[r]
            for a in range(f if i >= first else 1):
                oa = out[_coefficient_row(i, a, t, first)]
                if r < h:
                    w0, w1, w2 = head_weight[r, 0], head_weight[r, 1], head_weight[r, 2]
                else:
                    w0, w1, w2 = weight[r - h, a, 0], weight[r - h, a, 1], weight[r - h, a, 2]
                for k in range(0, c, 3):
                    oa[k] += w0 * acc[k]
                    oa[k + 1] += w1 * acc[k + 1]
                    oa[k + 2] += w2 * acc[k + 2]


class RayBlockProduct:
    """``W @ x`` for an operator given as the rays that build it: ray r from row texel i to
    column texel j adds, per colour channel c, the rank-one block ``weight[r, :, c] ⊗
    read[r, :]`` between i's and j's F coefficients (rows and columns ``texel + a·T``).
    Matrix-free: 8 + 16F bytes a ray instead of F² CSR entries per channel (the Chiang
    fibre's projected exitance, :mod:`prtcore.transport.fibre_chiang`). Rays must come
    sorted by row (as the fibre gather makes them); chunks of rays that never split a row
    go to the threads, so no two write the same row.

    rows, cols (n,) int; weight (n, F, 3), read (n, F) float; texels T. Texels below
    ``first`` (a hair + mesh bake's atlas texels, Lambertian) carry coefficient 0 alone:
    the operator is then N × N with N = T + (F − 1)(T − first), coefficient a ≥ 1 of
    texel i at row ``T + (a − 1)(T − first) + i − first`` (:meth:`coefficient_rows`), and
    those texels' other weights and reads are not used. Their rays, the first
    ``head`` (rows sorted), keep coefficient 0's weights alone (``head_weight`` (head, 3)
    float32; ``weight`` holds the other rays'): 20 + 4F bytes a ray, not 8 + 16F (on the
    10k head's second order half its rays, 1.1 GB). ``head_weight``: those weights given
    apart, with ``weight`` (n − head, F, 3) the others' (:func:`assemble_ray_blocks`, which
    never makes the whole); None: taken from ``weight`` (n, F, 3)."""

    def __init__(self, rows: np.ndarray, cols: np.ndarray, weight: np.ndarray,
                 read: np.ndarray, texels: int, threads: int = 2, first: int = 0,
                 head_weight: np.ndarray | None = None):
        self.row = np.ascontiguousarray(rows, dtype=np.int32)
        self.col = np.ascontiguousarray(cols, dtype=np.int32)
        if len(self.row) > 1 and (np.diff(self.row) < 0).any():
            raise ValueError("RayBlockProduct: rays must be sorted by row")
        self.t, self.first = int(texels), int(first)
        self.head = int(np.searchsorted(self.row, self.first, side="left"))
        if head_weight is None:
            weight = np.asarray(weight)
            head_weight, weight = weight[:self.head, 0], weight[self.head:]
        self.head_weight = np.ascontiguousarray(head_weight, dtype=np.float32)
        self.weight = np.ascontiguousarray(weight, dtype=np.float32)
        self.read = np.ascontiguousarray(read, dtype=np.float32)
        f = self.read.shape[1]
        n = len(self.row)
        if self.head_weight.shape != (self.head, 3) or \
                self.weight.shape != (n - self.head, f, 3):
            raise ValueError(f"RayBlockProduct: {self.head} rays from texels below {first} "
                             f"take weights ({self.head}, 3) and the other {n - self.head} "
                             f"({n - self.head}, {f}, 3), got {self.head_weight.shape} and "
                             f"{self.weight.shape}")
        n_rows = self.t + (f - 1) * (self.t - self.first)
        self.shape = (n_rows, n_rows)
        self.threads = max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS))
        # ray chunks, each boundary moved to the first ray of a row
        cuts = row_chunks(n, self.threads)
        cuts = np.searchsorted(self.row, self.row[np.minimum(cuts, max(n - 1, 0))],
                               side="left") if n else cuts
        cuts[0], cuts[-1] = 0, n
        self.starts = np.unique(cuts).astype(np.int64)
        # rows no ray starts from (texels with no fibre hits) stay zero: cleared per call
        self.idle = np.flatnonzero(np.bincount(self.row, minlength=self.t)[:self.t] == 0)
        self._idle_higher = self.idle[self.idle >= self.first] - self.first

    def coefficient_rows(self, a: int) -> slice:
        """The rows of coefficient ``a``: texels [0, T) for a = 0, [first, T) for a ≥ 1."""
        if a == 0:
            return slice(0, self.t)
        start = self.t + (a - 1) * (self.t - self.first)
        return slice(start, start + self.t - self.first)

    def __call__(self, x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """x : (N, c) with c = 3·k; out : optional (N, c) float32 to fill."""
        x = np.ascontiguousarray(x, dtype=np.float32)
        if x.ndim != 2 or x.shape[0] != self.shape[0] or x.shape[1] % 3:
            # the kernel reads three channels at a time, unchecked
            raise ValueError(f"RayBlockProduct: x must be ({self.shape[0]}, 3k), got "
                             f"{x.shape}")
        if out is None:
            out = np.empty((self.shape[0], x.shape[1]), dtype=np.float32)
        numba.set_num_threads(self.threads)
        ray_blocks(self.starts, self.row, self.col, self.head_weight, self.weight, self.read,
                   self.t, self.first, x, out)
        out[self.idle] = 0
        for a in range(1, self.read.shape[1]):
            out[self.coefficient_rows(a).start + self._idle_higher] = 0
        return out


#: rays whose weights and reads a :class:`RayPart` makes at once in
#: :func:`assemble_ray_blocks` (their float64 temporaries: about 0.2 GB at nine or
#: ten coefficients)
ASSEMBLY_CHUNK = 1 << 18


@dataclass(frozen=True)
class RayPart:
    """One group of a :class:`RayBlockProduct`'s rays, in any row order: ``rows``, ``cols``
    (n,) int (texels) and ``values(sl)`` → (weight (m, F, 3), read (m, F)) float of the
    rays ``sl`` (a slice of the n), made when the assembly reaches them."""

    rows: np.ndarray
    cols: np.ndarray
    values: Callable[[slice], tuple[np.ndarray, np.ndarray]]


@numba.njit(cache=True, nogil=True)
def _places(rows, nxt, out):  # pragma: no cover - compiled
    """out[i] ← nxt[rows[i]], then nxt[rows[i]] += 1, in order: each ray's place in the
    row-sorted arrays (a counting sort's placement, stable)."""
    for i in range(len(rows)):
        r = rows[i]
        out[i] = nxt[r]
        nxt[r] += 1


def assemble_ray_blocks(parts: Sequence[RayPart], texels: int, terms: int,
                        threads: int = 2, first: int = 0,
                        chunk: int = ASSEMBLY_CHUNK) -> RayBlockProduct:
    """The :class:`RayBlockProduct` (``texels``, ``terms`` = F coefficients, ``first``) of
    every part's rays, sorted by row with ties in part order, then in each part's order
    (the order of a stable argsort of the parts' rows concatenated), made without that
    sort: each ray is written at its place (a counting sort), its weight and read made
    ``chunk`` rays at a time and cast to float32 as they are written. The assembly holds
    the product's arrays (8 + 16 F bytes a ray, 20 + 4 F for a ray of a row below
    ``first``) and one chunk's temporaries; a sort of the
    concatenated parts held the parts, the order and a sorted copy beside them (on the
    10k head with the second order, 492 bytes a ray)."""
    counts = np.zeros(texels, np.int64)
    for p in parts:
        r = np.asarray(p.rows)
        if len(r) and (r.min() < 0 or r.max() >= texels):
            raise ValueError(f"assemble_ray_blocks: rows in [0, {texels}), got "
                             f"[{r.min()}, {r.max()}]")
        if len(p.cols) != len(r):
            raise ValueError(f"assemble_ray_blocks: {len(r)} rows and {len(p.cols)} "
                             "columns")
        counts += np.bincount(r, minlength=texels)
    nxt = np.zeros(texels, np.int64)
    np.cumsum(counts[:-1], out=nxt[1:])
    n = int(counts.sum())
    head = int(counts[:max(0, min(first, texels))].sum())  # the rays of rows below first
    del counts
    row, col = np.empty(n, np.int32), np.empty(n, np.int32)
    head_weight = np.empty((head, 3), np.float32)
    weight, read = np.empty((n - head, terms, 3), np.float32), np.empty((n, terms), np.float32)
    for p in parts:
        for a in range(0, len(p.rows), chunk):
            sl = slice(a, min(a + chunk, len(p.rows)))
            r = np.asarray(p.rows[sl], np.int64)
            place = np.empty(len(r), np.int64)
            _places(r, nxt, place)
            row[place], col[place] = r, p.cols[sl]
            w, v = p.values(sl)
            read[place] = v
            low = place < head
            head_weight[place[low]] = w[low, 0]
            weight[place[~low] - head] = w[~low]
    return RayBlockProduct(row, col, weight, read, texels, threads, first,
                           head_weight=head_weight)


def permute_csr(matrix: sp.csr_matrix, order: np.ndarray) -> sp.csr_matrix:
    """``P A Pᵀ`` of a square CSR matrix for the permutation ``order`` ((n,) int64: row i
    of the result is row ``order[i]`` of A, column j likewise), column indices sorted
    within rows. Built row by row (:func:`_permute_rows`): the result's arrays are the
    only allocation of its size (scipy's ``A[order][:, order]`` makes two more)."""
    a = matrix if isinstance(matrix, sp.csr_matrix) else sp.csr_matrix(matrix)
    order = np.asarray(order, dtype=np.int64)
    n = a.shape[0]
    if a.shape != (n, n) or order.shape != (n,):
        raise ValueError(f"permute_csr: a square matrix and a permutation of its rows, got "
                         f"{a.shape} and {order.shape}")
    inv = np.empty(n, dtype=np.int64)
    inv[order] = np.arange(n)
    indptr = np.asarray(a.indptr, dtype=np.int64)
    lengths = np.diff(indptr)[order]
    new_indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(lengths, out=new_indptr[1:])
    indices = np.empty(a.nnz, dtype=a.indices.dtype)
    data = np.empty(a.nnz, dtype=a.data.dtype)
    _permute_rows(indptr, a.indices, a.data, order, inv, new_indptr, indices, data)
    return sp.csr_matrix((data, indices, new_indptr), shape=a.shape)


@numba.njit(parallel=True, cache=True, nogil=True)
def _permute_rows(indptr, indices, data, order, inv, new_indptr, new_indices,
                  new_data):  # pragma: no cover - compiled
    """Row i of the result: row order[i]'s entries with columns mapped through inv,
    sorted by column (a stable sort: duplicates keep their order)."""
    for i in numba.prange(len(order)):
        s, e = indptr[order[i]], indptr[order[i] + 1]
        o = new_indptr[i]
        cols = np.empty(e - s, dtype=np.int64)
        for jj in range(s, e):
            cols[jj - s] = inv[indices[jj]]
        idx = np.argsort(cols, kind="mergesort")
        for q in range(e - s):
            new_indices[o + q] = cols[idx[q]]
            new_data[o + q] = data[s + idx[q]]
