"""The indirect solve on a basis of the light columns (the Chiang fibre's solves).

Every configuration k is solved by the same linear operator, so the solve commutes with
any mixing of the K columns: ``solve(X V) = solve(X) V``. The direct light of K lights
is not of low rank (hard shadows), but each bounce smooths it: on the 1000-strand
tangle under 256 spot lights, 136 columns hold the first bounce to 1 % (Frobenius),
88 the second, 47 the fourth and 32 the sixth (docs/hair.md, "Solving on a basis of the
lights"). :func:`solve_low_rank` therefore takes the first bounce at full width, then
carries the light on an orthonormal basis of its columns (the leading eigenvectors of
their Gram matrix, dropping at most ``rank_tolerance`` of the Frobenius norm), shrinking
the basis again as later bounces allow, and adds each bounce back in full.

Columns are first scaled to one norm each (per light, over rows and channels), so a dim
light is kept as well as a bright one: the relative error per light stays near
``rank_tolerance``, not the error of the sum.
"""

from __future__ import annotations

import time
from contextlib import nullcontext

import numpy as np

from prtcore.core.errors import TransportDiverged
from prtcore.core.materials import clamp_albedo
from prtcore.core.progress import StageTimer
from prtcore.core.sparse import RayBlockProduct
from prtcore.transport.solve import NORM_BLOCK, col_norms, relative_change, solve_indirect

#: Frobenius share of the (per light normalised) light columns a basis may drop, when it
#: is first taken and at every shrinking. Checked against the full-width solve
#: (tests/test_low_rank.py; benchmarks/low_rank_solve.py; docs/hair.md)
RANK_TOLERANCE = 1e-2
#: bounces stay at full width until the basis needs at most this share of the lights: the
#: basis' light then lives in the direct light's own buffer, two copies side by side
#: (no array of the direct light's size is allocated)
BASIS_SHARE = 0.25
#: the basis is shrunk again when the rank the current bounce needs is at most this
#: share of the current one (each shrinking costs one product's worth of memory traffic)
SHRINK_SHARE = 0.8
#: rows of a full-width bounce that enter the Gram matrix deciding the basis: every
#: s-th row with s = rows // (GRAM_ROWS_PER_LIGHT · K) (at least 1): the Gram matrix of
#: all rows costs as much as a product at K = 512
GRAM_ROWS_PER_LIGHT = 64
#: the series is taken to diverge when this many bounces in a row each grew (the
#: Frobenius norm of what a bounce adds, over the rows returned): a convergent series
#: shrinks by about its spectral radius a bounce (0.7–0.9 for light hair). The 300-strand
#: head's second order at 16 fibre rays grew 1.67× a bounce; its result after 16 bounces
#: was garbage (benchmarks/hair_mesh_chiang_bounces.py)
DIVERGING_BOUNCES = 3


def _gram(x: np.ndarray, stride: int = 1) -> np.ndarray:
    """Σ over rows (every ``stride``-th) and channels of x[i, :, c] x[i, :, c]ᵀ for x
    (N, r, 3) float32 → (r, r) float64, in float32 row blocks accumulated in float64."""
    r = x.shape[1]
    out = np.zeros((r, r))
    step = NORM_BLOCK * stride
    for a in range(0, len(x), step):
        blk = np.ascontiguousarray(np.moveaxis(x[a:a + step:stride], 2, 1)).reshape(-1, r)
        out += (blk.T @ blk).astype(np.float64)
    return out


def _basis(gram: np.ndarray, tolerance: float) -> np.ndarray:
    """(r, r') float64: the leading eigenvectors of the Gram matrix (r, r) that keep all
    but ``tolerance`` of the Frobenius norm (at least one)."""
    lam, vec = np.linalg.eigh(gram)
    lam, vec = np.clip(lam[::-1], 0.0, None), vec[:, ::-1]
    total = lam.sum()
    if total <= 0:
        return vec[:, :1]
    dropped = np.sqrt(np.maximum(total - np.cumsum(lam), 0.0) / total)
    keep = int(np.argmax(dropped <= tolerance)) + 1
    return vec[:, :keep]


def _mix(x: np.ndarray, v: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out = x · v`` per channel: x (N, r, 3) float32, v (r, r') → out (N, r', 3)
    float32, in row blocks. ``out`` may share x's buffer where it starts no later than x
    and r' ≤ r: each block of x is read whole before its rows of out are written, and
    those lie at or before it."""
    v32 = np.ascontiguousarray(v, dtype=np.float32)
    for a in range(0, len(x), NORM_BLOCK):
        blk = np.matmul(np.moveaxis(x[a:a + NORM_BLOCK], 2, 0), v32)  # (3, b, r')
        out[a:a + NORM_BLOCK] = np.moveaxis(blk, 0, 2)
    return out


def _add_lifted(acc: np.ndarray, z: np.ndarray, lift: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """``acc += z[:rows] · lift`` per channel, acc (rows, K, 3) float32, z (N, r, 3)
    float32, lift (r, K) float32, in row blocks (no (rows, K, 3) temporary); returns the
    norms (K, 3) float64 of what was added and of the new acc."""
    change = np.zeros(acc.shape[1:])
    total = np.zeros(acc.shape[1:])
    for a in range(0, len(acc), NORM_BLOCK):
        e = min(a + NORM_BLOCK, len(acc))
        blk = np.moveaxis(np.matmul(np.moveaxis(z[a:e], 2, 0), lift), 0, 2)
        change += np.einsum("ikc,ikc->kc", blk, blk)
        acc[a:e] += blk
        total += np.einsum("ikc,ikc->kc", acc[a:e], acc[a:e])
    return np.sqrt(change), np.sqrt(total)


class _Growth:
    """Watches the norms of successive bounces and raises :class:`TransportDiverged`
    when :data:`DIVERGING_BOUNCES` in a row grow."""

    def __init__(self):
        self.last, self.run, self.first = None, 0, 0

    def __call__(self, change: np.ndarray, bounce: int) -> None:
        norm = float(np.sqrt((np.asarray(change, np.float64) ** 2).sum()))
        self.run = self.run + 1 if self.last is not None and norm > self.last > 0 else 0
        if self.run == 1:
            self.first = bounce
        ratio = norm / self.last if self.last else 0.0
        self.last = norm
        if self.run >= DIVERGING_BOUNCES:
            raise TransportDiverged(
                f"the indirect solve diverges: each bounce from {self.first} to {bounce} "
                f"added more light than the one before ({ratio:.3f}× at the last), so its "
                "operator sends on more light than it receives; more gather rays "
                "(hair.gather_rays) or a lower hair.chiang.exitance make it converge")


def first_bounce_in_place(product: RayBlockProduct, albedo: np.ndarray, direct: np.ndarray,
                          first_bounce: tuple[np.ndarray, np.ndarray] | None,
                          threads: int = 2) -> None:
    """``direct`` (N, K, 3) float32 C-contiguous ← the first bounce of its light with
    ``first_bounce``'s corrections (:func:`prtcore.transport.solve.solve_indirect`'s, one
    product), in place. A caller that then drops the corrections and solves on with
    :func:`solve_low_rank` (``bounced=True``) does not hold them through the later
    bounces: on the 10k head (K = 528) they are (T_m + F × 10 % T_h) rows of (K, 3),
    1.4 GiB beside the sum of the bounces."""
    if direct.dtype != np.float32 or not direct.flags.c_contiguous:
        raise ValueError(f"first_bounce_in_place: direct must be C-contiguous float32, got "
                         f"{direct.dtype}")
    if direct.shape[0] and direct.shape[1]:
        solve_indirect(None, albedo, direct, 1, 1.0, threads=threads, product=product,
                       first_bounce=first_bounce, out=direct)


def solve_low_rank(product: RayBlockProduct, albedo: np.ndarray, direct: np.ndarray,
                   max_bounces: int, tolerance: float, rows: int | None = None,
                   timer: StageTimer | None = None, threads: int = 2,
                   first_bounce: tuple[np.ndarray, np.ndarray] | None = None,
                   rank_tolerance: float = RANK_TOLERANCE, bounced: bool = False
                   ) -> tuple[np.ndarray, int, float, dict]:
    """:func:`prtcore.transport.solve.solve_indirect` with a ready ``product`` (the
    Neumann series), the later bounces on a basis of the light columns.

    product : (N, N) operator over the receivers' coefficients (``product(x (N, 3k))``);
    albedo : (N, 3) raw albedo; direct : (N, K, 3) float32 C-contiguous direct outgoing
    radiance, overwritten (its buffer is the solve's working memory); first_bounce : as
    in solve_indirect. ``bounced``: ``direct`` already holds the first bounce
    (:func:`first_bounce_in_place`, then without ``first_bounce``), counted as the first
    product. ``rows``: how many leading rows to return (the first exitance
    coefficient of an (F·T)-row operator is rows ``:T``); None for all. ``max_bounces``
    counts every product; the series stops when every light's and channel's relative
    change is below ``tolerance`` (as solve_indirect's).

    Bounces run at full width, each in solve_indirect's column blocks and in place, until
    the basis that holds the current bounce to ``rank_tolerance`` has at most
    :data:`BASIS_SHARE` of the lights; then on that basis, shrunk as the bounces allow.

    Returns the indirect outgoing radiance of the leading rows (rows, K, 3) float32, the
    products, the largest last relative change and stats (``ranks``: the columns each
    bounce ran on; ``needed``: the basis each full-width bounce would have needed;
    ``seconds``; ``bounces`` and ``residual``, the two before, so a report says how far
    from ``tolerance`` an unconverged solve stopped). Raises :class:`TransportDiverged`
    when :data:`DIVERGING_BOUNCES` bounces in a row each grow (a noisy truncated
    exitance can make the operator's spectral radius exceed 1)."""
    ctx = timer.stage("indirect solve") if timer is not None else nullcontext()
    n, k = direct.shape[:2]
    rows = n if rows is None else int(rows)
    if bounced and first_bounce is not None:
        raise ValueError("solve_low_rank: a bounced direct light has had its first-bounce "
                         "corrections")
    if direct.dtype != np.float32 or not direct.flags.c_contiguous:
        raise ValueError(f"solve_low_rank: direct must be C-contiguous float32, got "
                         f"{direct.dtype}")
    with ctx:
        t0 = time.perf_counter()
        stats: dict = {"method": "low_rank", "rank_tolerance": rank_tolerance,
                       "lights": k, "ranks": [], "needed": [], "converged": False}
        if max_bounces < 1 or k == 0 or n == 0:
            return np.zeros((rows, k, 3), np.float32), 0, 0.0, stats
        acc = None
        scale = None
        stride = max(1, n // max(1, GRAM_ROWS_PER_LIGHT * k))
        bounces, resid, lift = 0, 1.0, None
        growth = _Growth()
        if not bounced:
            first_bounce_in_place(product, albedo, direct, first_bounce, threads)
        while bounces < max_bounces:  # full width, in place; the first is taken above
            if bounces:
                solve_indirect(None, albedo, direct, 1, 1.0, threads=threads,
                               product=product, out=direct)
            bounces += 1
            stats["ranks"].append(k)
            if acc is None:
                acc = direct[:rows].copy()
                change = total = col_norms(acc)
                scale = np.sqrt((col_norms(direct) ** 2).sum(axis=1))  # (K,) per light
                scale[scale == 0] = 1.0
            else:
                acc += direct[:rows]
                change, total = col_norms(direct[:rows]), col_norms(acc)
            growth(change, bounces)
            resid = relative_change(change, total)
            if resid < tolerance:
                stats["converged"] = True
                break
            if bounces >= max_bounces or k < 4:
                continue
            gram = _gram(direct, stride) / np.outer(scale, scale)
            v = _basis(gram, rank_tolerance)  # (K, r), normalised lights → basis
            stats["needed"].append(v.shape[1])
            if v.shape[1] <= BASIS_SHARE * k:
                lift = (v * scale[:, None]).T.astype(np.float32)  # (r, K): basis → lights
                break
        if lift is not None and not stats["converged"]:
            bounces, resid = _on_basis(product, albedo, direct, v / scale[:, None], lift,
                                       acc, bounces, max_bounces, tolerance,
                                       rank_tolerance, stats, growth)
        stats["seconds"] = time.perf_counter() - t0
        stats["bounces"], stats["residual"] = bounces, float(resid)  # the report's
        return acc, bounces, resid, stats


def _on_basis(product, albedo, direct, mix, lift, acc, bounces, max_bounces, tolerance,
              rank_tolerance, stats, growth: _Growth) -> tuple[int, float]:
    """The bounces after the full-width ones, on the basis ``mix`` (K, r) (lights → basis)
    with ``lift`` (r, K), adding each into acc (rows, K, 3). The basis' light lives in
    two halves of direct's buffer (N r 3 floats each, r ≤ K / 2), the product writing
    one from the other."""
    n = len(direct)
    r0 = mix.shape[1]
    flat = direct.reshape(-1)
    half = [flat[:n * r0 * 3], flat[n * r0 * 3:2 * n * r0 * 3]]
    z = _mix(direct, mix, half[0].reshape(n, r0, 3))  # in place: half 0 starts the buffer
    cur = 0
    rho32 = clamp_albedo(np.asarray(albedo, dtype=np.float64))[0].astype(np.float32)
    resid = 1.0
    while bounces < max_bounces:
        r = z.shape[1]
        nxt = half[1 - cur][:n * r * 3].reshape(n, r, 3)
        product(z.reshape(n, -1), out=nxt.reshape(n, -1))
        nxt *= rho32[:, None, :]
        z, cur = nxt, 1 - cur
        bounces += 1
        stats["ranks"].append(r)
        change, total = _add_lifted(acc, z, lift)
        growth(change, bounces)
        resid = relative_change(change, total)
        if resid < tolerance:
            stats["converged"] = True
            break
        w = _basis(_gram(z), rank_tolerance)
        if w.shape[1] <= SHRINK_SHARE * r:
            z = _mix(z, w, half[1 - cur][:n * w.shape[1] * 3].reshape(n, w.shape[1], 3))
            cur = 1 - cur
            lift = (w.T @ lift.astype(np.float64)).astype(np.float32)
    return bounces, resid
