"""The indirect solve: all bounces for all configurations at once (paper 4.1).

``(I − Gρ)⁻¹ Gρ E_d`` for all K × 3 right-hand sides together, one sparse × dense product
per step: the Neumann series (one bounce per product) or, by default, a Chebyshev
iteration on the spectrum of Gρ that needs about half the products
(:func:`solve_indirect`). G is the transport operators' matrix
(:func:`prtcore.transport.dataset.operator_matrix`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from contextlib import nullcontext

import numba
import numpy as np
import scipy.sparse as sp

from prtcore.core.materials import clamp_albedo
from prtcore.core.progress import StageTimer
from prtcore.core.sparse import SparseProduct
from prtcore.transport import kernels
from prtcore.transport.coarse import Coarsening

#: Rows per float32 partial sum of column norms (the partial sums add up in float64).
NORM_BLOCK = 1 << 12
#: Arnoldi steps estimating the spectrum of Gρ for the Chebyshev iteration.
ARNOLDI_STEPS = 12
#: Relative widening of the Arnoldi interval (Ritz values lie inside the spectrum's hull).
SPECTRUM_MARGIN = 0.05
#: The Chebyshev iteration is abandoned for the plain series if the relative change grows
#: beyond this factor of the smallest one seen (a spectrum outside the interval).
CHEBYSHEV_DIVERGENCE = 4.0
#: Bytes for the solver's working arrays (SOLVE_WORK_ARRAYS of T × block × 3 float32 for
#: "chebyshev", allocated once per block); the K configurations are solved in column
#: blocks that fit. Fewer, wider blocks are faster: each non-zero of G is read once per
#: product for all the block's columns.
SOLVE_BLOCK_BYTES = 2 << 30
#: The Chebyshev iteration's working arrays: solution, residual, step and ρ∘step, and the
#: next step and its ρ∘step (the fused step reads the old ones while writing the new).
SOLVE_WORK_ARRAYS = 6
#: … and on the coarse grid (prtcore.transport.coarse): the first bounce, the solution and
#: ρ∘solution at full resolution (the cells' arrays are a few per cent of these).
SOLVE_WORK_ARRAYS_COARSE = 3
#: Full-resolution steps ``E ← b + A·E`` after the coarse grid's solution (see
#: :mod:`prtcore.transport.coarse`).
#: Each damps the grid's error by about the spectral radius of A and smooths it: the
#: grid's relative RMSE against the full solve (benchmarks/coarse_solve.py, Cornell box
#: 256², 4 × 4 cells) is 1.25 % after one step, 0.36 % after two, 0.15 % after three.
FINE_STEPS = 2
#: Solver methods (see :func:`solve_indirect`).
SOLVE_METHODS = ("chebyshev", "neumann")


class ChannelProduct:
    """``A_c @ x`` with ``A_c = shared + extra[c]``: a :class:`SparseProduct` of the shared
    matrix on all columns plus, per colour channel c, its own matrix on that channel's
    columns (x's columns are (configuration, channel) pairs, channel fastest). The
    subsurface walks' operator differs per channel (docs/subsurface.md)."""

    def __init__(self, shared: sp.csr_matrix, extra, threads: int = 2):
        self.shared = SparseProduct(shared, threads)
        self.extra = [SparseProduct(m if m.dtype == np.float32 else m.astype(np.float32),
                                    threads) for m in extra]
        self.shape = shared.shape

    def __call__(self, x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        out = self.shared(x, out)
        for c, prod in enumerate(self.extra):
            out[:, c::3] += prod(np.ascontiguousarray(x[:, c::3]))
        return out


def col_norms(x: np.ndarray) -> np.ndarray:
    """‖x[:, j]‖ over rows for x (T, ...) float32 → x.shape[1:] float64 (float32 sums over
    row blocks of NORM_BLOCK, accumulated in float64)."""
    x2 = x.reshape(len(x), -1)
    out = np.zeros(x2.shape[1])
    for i in range(0, len(x2), NORM_BLOCK):
        xi = x2[i:i + NORM_BLOCK]
        out += np.einsum("ij,ij->j", xi, xi)
    return np.sqrt(out).reshape(x.shape[1:])


def relative_change(change: np.ndarray, total: np.ndarray) -> float:
    """max over columns of change / total, columns with total 0 skipped."""
    live = total > 0
    return float((change[live] / total[live]).max()) if live.any() else 0.0


def spectrum_interval(product: SparseProduct, rho: np.ndarray, steps: int = ARNOLDI_STEPS
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Interval [lo, hi] per channel holding the (real parts of the) eigenvalues of
    ``A_c = G·diag(ρ_c)``.

    product : G as a :class:`SparseProduct`; rho : (T, 3) clamped albedo. Arnoldi with
    ``steps`` steps per channel from a fixed positive start vector (the three channels
    share each sparse product); the extreme real parts of the Ritz values, widened by
    SPECTRUM_MARGIN because Ritz values approach the spectrum from inside. A_c is
    non-negative, so its spectral radius is its largest real eigenvalue (Perron–Frobenius)
    and ``lo ≥ −hi``. Returns lo, hi : (3,) float64 with −1 < lo < hi < 1.
    """
    t = product.shape[0]
    m = max(1, min(steps, t))
    rho = np.asarray(rho, dtype=np.float64)
    basis = np.zeros((3, m + 1, t))
    h = np.zeros((3, m + 1, m))
    v = np.random.default_rng(0).random((3, t)) + 0.5
    basis[:, 0] = v / np.linalg.norm(v, axis=1, keepdims=True)
    size = [m, m, m]
    active = np.ones(3, dtype=bool)
    for j in range(m):
        src = (basis[:, j].T * rho).astype(np.float32)  # (T, 3)
        w = product(src).astype(np.float64).T  # (3, T)
        for c in np.flatnonzero(active):
            wc = w[c]
            scale = np.linalg.norm(wc)
            for _ in range(2):  # Gram–Schmidt, twice for stability
                coef = basis[c, :j + 1] @ wc
                wc = wc - coef @ basis[c, :j + 1]
                h[c, :j + 1, j] += coef
            nrm = np.linalg.norm(wc)
            h[c, j + 1, j] = nrm
            if nrm <= 1e-9 * max(scale, 1e-300):
                size[c] = j + 1
                active[c] = False
            else:
                basis[c, j + 1] = wc / nrm
        if not active.any():
            break
    lo, hi = np.zeros(3), np.zeros(3)
    for c in range(3):
        ritz = np.linalg.eigvals(h[c, :size[c], :size[c]]).real
        top = float(ritz.max(initial=0.0))
        bottom = float(ritz.min(initial=0.0))
        hi[c] = min(top + SPECTRUM_MARGIN * max(top, 0.0) + 0.01, 0.999)
        lo[c] = max(min(bottom, 0.0) - SPECTRUM_MARGIN * (top - bottom) - 0.01, -hi[c])
    return lo, hi


def solve_indirect(matrix: sp.csr_matrix, albedo: np.ndarray, direct: np.ndarray,
                   max_bounces: int, tolerance: float, timer: StageTimer | None = None,
                   method: str = "chebyshev", threads: int = 2,
                   first_bounce: tuple[np.ndarray, np.ndarray] | None = None,
                   channel_matrices: tuple | None = None,
                   coarse: Coarsening | None = None, out: np.ndarray | None = None,
                   product: Callable | None = None, order: np.ndarray | None = None
                   ) -> tuple[np.ndarray, int, float, dict]:
    """All bounces of indirect light for every configuration and channel at once.

    matrix : (T, T) gather operator G (CSR, used as float32); albedo : (T, 3) raw texel
    albedo (clamped here); direct : (T, K, 3) direct outgoing radiance L_d = ρ/π·E_d.
    Solves ``E_ind = G·(ρ∘(E_d + E_ind))``, i.e. ``(I − A) E_ind = b`` with ``A = Gρ``
    and the first bounce ``b = A E_d = π G L_d``. Every product is a sparse × dense
    product with all 3K columns (float32 data; norms accumulate in float64). The solution
    is the Neumann series ``Σ_{n≥0} Aⁿ b``, convergent because rows of G sum to ≤ 1 and
    ρ ≤ 0.99.

    method "neumann": one bounce per product, ``term ← A·term``; after n products the
    result is exactly the light of bounces 1 … n.
    method "chebyshev" (default): Chebyshev iteration (Saad, *Iterative Methods for Sparse
    Linear Systems*, alg. 12.1) on the interval from :func:`spectrum_interval`: the
    spectrum of A is real up to Monte Carlo noise (form factors are reciprocal), so the
    error falls by ≈ (√κ − 1)/(√κ + 1) per product, κ = (1 − lo)/(1 − hi), instead of by
    the spectral radius hi — for the Cornell box 0.3 instead of 0.6, about half the
    products. Should the change grow (a spectrum outside the interval) the block is
    solved again with "neumann" (``stats["fallback"]``).

    Both stop when the relative change ``‖ΔE_k‖/‖E_k‖`` of every configuration k and
    channel is below ``tolerance`` (``stats["converged"]``), or after ``max_bounces``
    products counting the first bounce. max_bounces = 1 gives exactly the single-bounce
    light; an unconverged "chebyshev" result is the Chebyshev approximant of that degree.
    Configurations are solved in column blocks so that the working arrays
    (SOLVE_WORK_ARRAYS of T × block × 3 float32) stay within SOLVE_BLOCK_BYTES.

    first_bounce : (rows, values (r, K, 3)) added to ``G L_d`` at those rows — the near
    field's correction (:func:`prtcore.transport.direct.near_field_correction`).

    channel_matrices : three (T, T) CSR added to G for the R, G and B channels
    (:class:`ChannelProduct`; the subsurface walks), or None.

    coarse : a :class:`~prtcore.transport.coarse.Coarsening` of the texels, or None: the
    first bounce stays at full resolution and the iteration (either method) runs on the
    coarse cells, ``E ≈ b + A·P·(I − A_c)⁻¹·R·b`` (:mod:`prtcore.transport.coarse`;
    ``stats["coarse"]``). Ignored with channel_matrices and for max_bounces = 1.

    out : a C-contiguous (T, K, 3) float32 array for the result, or None (a new one). It may
    be ``direct`` itself: each block of configurations is read whole before its result is
    written, which saves the memory of one (T, K, 3) array when the caller no longer needs
    the direct light.

    product : the operator as a ready product (``product(x (T, 3K)) → (T, 3K)`` float32,
    with ``.shape``; e.g. :class:`prtcore.core.sparse.RayBlockProduct`) instead of
    ``matrix`` and ``channel_matrices`` (then None); no coarse grid, and the Neumann series
    whatever ``method`` says (the fused Chebyshev step reads CSR arrays).

    order : (T,) int64, a permutation of the rows, or None: ``matrix`` is given with its
    rows and columns in this order (``P G Pᵀ``, :func:`prtcore.core.sparse.permute_csr`)
    while albedo, direct, first_bounce and out stay in the caller's order; each block of
    ``direct`` is read and the result written through the permutation. Rows of spatial
    neighbours side by side let a product's gathered rows share the cache: the 10k
    hairball's strand texels in Morton order (:attr:`prtcore.receivers.strands.
    StrandSpace.morton`) solve about twice as fast as strand by strand (docs/hair.md).
    The caller permutes, so that it can let the original go before the solve's working
    arrays exist (its peak then holds one operator). The same numbers up to float32
    summation order. Not with channel_matrices, coarse or product.

    Returns the indirect outgoing radiance ρ/π·E_ind (T, K, 3) float32, the number of
    products (bounces), the residual (the largest last relative change; 1.0 after a single
    bounce) and stats.
    """
    if method not in SOLVE_METHODS:
        raise ValueError(f"solve_indirect: method must be one of {SOLVE_METHODS}, got "
                         f"{method!r}")
    ctx = timer.stage("indirect solve") if timer is not None else nullcontext()
    with ctx:
        if order is not None:
            if channel_matrices is not None or coarse is not None or product is not None:
                raise ValueError("solve_indirect: order works with a plain matrix only "
                                 "(no channel_matrices, coarse or product)")
            order = np.asarray(order, dtype=np.int64)
            inv = np.empty_like(order)
            inv[order] = np.arange(len(order))
            albedo = np.asarray(albedo)[order]
            if first_bounce is not None:
                first_bounce = (inv[np.asarray(first_bounce[0])], first_bounce[1])
        return _solve(matrix, albedo, direct, int(max_bounces), float(tolerance), method,
                      threads, first_bounce, channel_matrices, coarse, out, product,
                      order)


def _solve(matrix, albedo, direct, max_bounces, tolerance, method, threads, extra=None,
           channel_matrices=None, coarse=None, out=None, given=None, order=None):
    t, k = direct.shape[:2]
    rho, _ = clamp_albedo(np.asarray(albedo, dtype=np.float64))
    rho32 = rho.astype(np.float32)
    g = None if given is not None else \
        matrix if matrix.dtype == np.float32 else matrix.astype(np.float32)
    if out is None:
        out = np.zeros((t, k, 3), dtype=np.float32)
    elif out.shape != (t, k, 3) or out.dtype != np.float32 or not out.flags.c_contiguous:
        raise ValueError(f"solve_indirect: out must be C-contiguous float32 {(t, k, 3)}, got "
                         f"{out.dtype} {out.shape}")
    stats: dict = {"method": method, "converged": True, "blocks": []}
    if max_bounces < 1 or t == 0 or k == 0:
        out[...] = 0
        return out, 0, 0.0, stats
    if given is not None:  # the fused Chebyshev step reads CSR arrays: Neumann series
        product, coarse, method = given, None, "neumann"
        stats["method"] = method
    else:
        product = SparseProduct(g, threads) if channel_matrices is None else \
            ChannelProduct(g, channel_matrices, threads)
    t0 = time.perf_counter()
    if coarse is not None and (max_bounces < 2 or channel_matrices is not None):
        coarse = None  # one bounce needs no grid; the walks' per-channel matrices stay exact
    if coarse is not None:
        it_product = SparseProduct(coarse.operator(g), threads)
        it_rho = clamp_albedo(coarse.restrict(rho))[0]
        stats["coarse"] = {"factor": coarse.factor, "cells": coarse.cells,
                           "nnz": len(it_product.data), "nnz_fine": int(g.nnz)}
    else:
        it_product, it_rho = product, rho
    it_rho32 = it_rho.astype(np.float32)
    lo = hi = None
    if method == "chebyshev" and max_bounces > 1:
        lo, hi = spectrum_interval(it_product, it_rho)
        stats["interval"] = {"lo": lo.tolist(), "hi": hi.tolist()}
    stats["seconds_interval"] = time.perf_counter() - t0
    per_block = max(1, min(k, int(SOLVE_BLOCK_BYTES // max(1, SOLVE_WORK_ARRAYS * t * 3 * 4))))
    bounces_all, resid_all = 0, 0.0

    def first_bounce(k0: int, k1: int) -> np.ndarray:
        ld = np.ascontiguousarray(direct[:, k0:k1] if order is None else direct[order, k0:k1],
                                  dtype=np.float32)
        b = product(ld.reshape(t, -1)).reshape(t, k1 - k0, 3)
        if extra is not None:  # ≥ 0 exactly; float32 round-off must not make it negative
            rows = extra[0]
            b[rows] = np.maximum(b[rows] + extra[1][:, k0:k1], np.float32(0))
        b *= np.float32(math.pi)
        return b

    def iterate(b: np.ndarray, bounces: int, again) -> tuple:
        """All bounces from the first, b (overwritten), on the iteration's grid."""
        if method == "neumann":
            return _neumann(it_product, it_rho32, b, bounces, tolerance)
        x, n, resid, conv = _chebyshev(it_product, it_rho32, b, lo, hi, bounces, tolerance)
        if x is None:  # diverged (b was overwritten): plain series from scratch
            stats["fallback"] = stats.get("fallback", 0) + 1
            x, n2, resid, conv = _neumann(it_product, it_rho32, again(), bounces, tolerance)
            n += n2
        return x, n, resid, conv

    scale = rho32 / np.float32(math.pi)  # E → outgoing radiance ρ/π·E, (T, 3) float32
    for k0 in range(0, k, per_block):
        k1 = min(k, k0 + per_block)
        t1 = time.perf_counter()
        b = first_bounce(k0, k1)
        if max_bounces == 1:
            x, n, resid, conv = b, 1, 1.0, tolerance >= 1.0
            x *= scale[:, None, :]
        elif coarse is not None:
            def restricted(b=b):
                return coarse.restrict(b).astype(np.float32)
            xc, n, resid, conv = iterate(restricted(), max_bounces - 1, restricted)
            # bounce 1 at full resolution, the rest gathered from the cells' solution
            x = _closing_steps(product, rho32, xc, coarse.cell, b, scale)  # scaled
            n += FINE_STEPS
            del xc
        else:
            x, n, resid, conv = iterate(b, max_bounces,
                                        lambda k0=k0, k1=k1: first_bounce(k0, k1))
            x *= scale[:, None, :]
        if order is None:
            out[:, k0:k1] = x
        else:
            out[order, k0:k1] = x
        del x, b
        stats["blocks"].append({"configurations": [k0, k1], "bounces": n, "residual": resid,
                                "converged": conv, "seconds": time.perf_counter() - t1})
        stats["converged"] = stats["converged"] and conv
        bounces_all = max(bounces_all, n)
        resid_all = max(resid_all, resid)
    return out, bounces_all, resid_all, stats


def _closing_steps(product: SparseProduct, rho32: np.ndarray, xc: np.ndarray,
                   cell: np.ndarray, b: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """FINE_STEPS full-resolution steps ``E ← b + G (ρ ∘ E)`` from the cells' solution
    xc (cells, k, 3) float32 (texel j starts from its cell's, ``cell`` (T,) int64), the
    last one scaled by ``scale`` (T, 3) float32 (ρ/π: outgoing radiance). The same bits
    as the numpy steps ``E = xc[cell]``, ``E = G (ρ ∘ E)``, ``E += b``, then ``E *= scale``,
    in two passes per step instead of four (:func:`prtcore.transport.kernels.albedo_times`
    reads E through ``cell``, :func:`~prtcore.transport.kernels.product_plus` adds b and
    scales as it writes). b (T, k, 3) float32, the first bounce, is overwritten with the
    result, which is returned (a view of b); two more full-resolution arrays, as before."""
    t = len(b)
    b2 = b.reshape(t, -1)
    rho = np.ascontiguousarray(rho32, dtype=np.float32)
    none = np.zeros((0, 3), dtype=np.float32)
    numba.set_num_threads(product.threads)
    x, x_cell = np.ascontiguousarray(xc.reshape(len(xc), -1), dtype=np.float32), \
        np.asarray(cell, dtype=np.int64)
    src = np.empty_like(b2)
    ident = np.arange(t, dtype=np.int64)
    work = None  # a full-resolution E of the steps between the first and the last
    for step in range(FINE_STEPS):
        last = step == FINE_STEPS - 1
        kernels.albedo_times(x, x_cell, rho, src, product.chunks)
        if last:
            dst = b2  # row i reads b[i] before writing it
        else:  # E's old values are in src now: its buffer takes the new ones
            work = np.empty_like(b2) if work is None else work
            dst = work
        kernels.product_plus(product.indptr, product.indices, product.data, src, b2,
                             scale if last else none, dst, product.chunks)
        x, x_cell = dst, ident
    return b


def _apply(product: SparseProduct, rho32: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A·x = G (ρ ∘ x) for x (T, k, 3) float32."""
    t = len(x)
    return product((x * rho32[:, None, :]).reshape(t, -1)).reshape(x.shape)


def _neumann(product, rho32, b, max_bounces, tolerance):
    """x = Σ_{n<N} Aⁿ b, one product per bounce, until the relative change < tolerance."""
    x = b.copy()
    term = b
    n, resid, conv = 1, 1.0, False
    while n < max_bounces:
        term = _apply(product, rho32, term)
        n += 1
        x += term
        resid = relative_change(col_norms(term), col_norms(x))
        if resid < tolerance:
            conv = True
            break
    return x, n, resid, conv


def _chebyshev(product, rho32, b, lo, hi, max_bounces, tolerance):
    """Chebyshev iteration for (I − A) x = b, A's spectrum in [lo, hi] per channel; each
    step one fused pass (:func:`prtcore.transport.kernels.chebyshev_step`).
    Overwrites b. Returns (None, n, resid, False) when the change grows (divergence)."""
    alpha, beta = 1.0 - hi, 1.0 - lo  # spectrum of I − A
    theta = (beta + alpha) / 2.0
    delta = np.maximum((beta - alpha) / 2.0, 1e-6)
    sigma = theta / delta
    rho_k = 1.0 / sigma
    shape = b.shape
    t = shape[0]
    r = b.reshape(t, -1)  # residual b − (I − A)·0
    d = r / np.tile(theta.astype(np.float32), shape[1])
    x = d.copy()  # x holds bounce 1
    src = np.multiply(d.reshape(shape), rho32[:, None, :]).reshape(t, -1)
    d_new, src_new = np.empty_like(d), np.empty_like(d)  # work arrays, swapped every step
    shared = product.shared if isinstance(product, ChannelProduct) else product
    if isinstance(product, ChannelProduct):  # the channels' matrices, stacked
        e_indptr = np.stack([p.indptr for p in product.extra])
        e_indptr += np.cumsum([0] + [len(p.data) for p in product.extra[:-1]])[:, None]
        e_indices = np.concatenate([p.indices for p in product.extra])
        e_data = np.concatenate([p.data for p in product.extra])
    else:
        e_indptr = np.zeros((3, t + 1), dtype=np.int64)
        e_indices, e_data = np.zeros(0, dtype=np.int32), np.zeros(0, dtype=np.float32)
    parts = (len(shared.chunks) - 1, d.shape[1])
    norm_d, norm_x = np.empty(parts), np.empty(parts)
    numba.set_num_threads(shared.threads)
    n, resid, conv = 1, 1.0, False
    best = np.inf
    while n < max_bounces:
        rho_new = 1.0 / (2.0 * sigma - rho_k)
        kernels.chebyshev_step(shared.indptr, shared.indices, shared.data, e_indptr,
                               e_indices, e_data, rho32, src, d, r, x, src_new, d_new,
                               (2.0 * rho_new / delta).astype(np.float32),
                               (rho_new * rho_k).astype(np.float32), shared.chunks,
                               norm_d, norm_x)
        rho_k = rho_new
        d, d_new, src, src_new = d_new, d, src_new, src
        n += 1  # x now holds bounces 1 … n
        resid = relative_change(np.sqrt(norm_d.sum(axis=0)).reshape(shape[1:]),
                          np.sqrt(norm_x.sum(axis=0)).reshape(shape[1:]))
        best = min(best, resid)
        if resid < tolerance:
            conv = True
            break
        if resid > CHEBYSHEV_DIVERGENCE * best:
            return None, n, resid, False
    return x.reshape(shape), n, resid, conv
