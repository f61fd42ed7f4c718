"""A seam-aware smoothing filter in texel space (issue 13: noise stays out of the basis).

The fast transport's gather estimates each texel's indirect light with M rays of its own,
so every texel carries its own Monte Carlo error, the same for all K configurations (one
gather operator serves them all). Such error is not noise the SVD can average away: it is
a fixed texel-sized pattern in every snapshot, and the basis reproduces it as texel-sized
blocks. Filtering the snapshots in texel space before the SVD removes most of it.

The filter works on the texels' 3-D samples, not on the atlas image, so it is
seam-aware: two texels on either side of a UV seam (far apart in the atlas, adjacent on
the surface) are neighbours, while two texels adjacent in the atlas but on different
charts are not. Texel i averages the texels j with

    ‖p_j − p_i‖ ≤ r_i,   n_i · n_j ≥ cos_min,   |n_i · (p_j − p_i)| ≤ plane_tol · h_i

(p: position, n: shading normal, h_i: the texel's world-space size, r_i = radius · h_i),
weighted by exp(−‖p_j − p_i‖² / (2 (r_i/2)²)): it does not blend across a crease (the floor
and a wall), across the two sides of a thin wall, or between stacked parallel surfaces.
With ``albedo``, the filter runs on irradiance (values divided by the clamped albedo per
channel, multiplied back after), so an albedo edge stays sharp.
"""

from __future__ import annotations

from itertools import chain

import numba
import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from prtcore.core.materials import clamp_albedo
from prtcore.core.raytrace import default_threads
from prtcore.core.sparse import SparseProduct
from prtcore.receivers.texels import TexelSpace

#: Defaults: Gaussian of σ = radius/2 over 1.5 texel sizes, normals within ~25°, at most
#: half a texel off the tangent plane.
SMOOTH_RADIUS = 1.5
SMOOTH_COS_MIN = 0.9
SMOOTH_PLANE_TOL = 0.5


def texel_size(texels: TexelSpace) -> np.ndarray:
    """(T,) float64 world-space size of each texel: the mean length of its footprint's
    two steps (dP/dx, dP/dy)."""
    fp = np.asarray(texels.footprint, dtype=np.float64)
    return 0.5 * (np.linalg.norm(fp[:, 0], axis=1) + np.linalg.norm(fp[:, 1], axis=1))


def smoothing_operator(texels: TexelSpace, radius: float = SMOOTH_RADIUS,
                       cos_min: float = SMOOTH_COS_MIN,
                       plane_tol: float = SMOOTH_PLANE_TOL) -> sp.csr_matrix:
    """The filter as a row-stochastic sparse matrix W (T × T) float64: ``W @ values``
    smooths (T, …) texel values (module docstring). Every row contains its own texel, so
    a texel with no neighbour keeps its value; radius 0 gives the identity."""
    t = texels.count
    if radius <= 0 or t == 0:
        return sp.identity(t, format="csr", dtype=np.float64)
    return smoothing_operators(texels, (radius,), cos_min, plane_tol)[0]


def smoothing_operators(texels: TexelSpace, radii: tuple[float, ...],
                        cos_min: float = SMOOTH_COS_MIN,
                        plane_tol: float = SMOOTH_PLANE_TOL) -> list[sp.csr_matrix]:
    """:func:`smoothing_operator` for several radii (all > 0) from one neighbour search at
    the largest: the pairs within ``radius · h_i`` of each smaller radius are a subset.
    Returns one (T × T) float64 CSR per radius, in order."""
    pos = np.asarray(texels.position, dtype=np.float64)
    nrm = np.asarray(texels.normal, dtype=np.float64)
    t = len(pos)
    if t == 0:
        return [sp.identity(0, format="csr", dtype=np.float64) for _ in radii]
    h = texel_size(texels)
    r_max = max(radii) * h
    tree = cKDTree(pos)
    parts = []  # per block of rows: (i, j, |p_j − p_i|²) of the pairs that pass the tests
    for a in range(0, t, 4096):
        b = min(a + 4096, t)
        hits = tree.query_ball_point(pos[a:b], r_max[a:b], workers=-1)
        lens = np.fromiter(map(len, hits), dtype=np.int64, count=b - a)
        i = np.repeat(np.arange(a, b), lens)
        j = np.fromiter(chain.from_iterable(hits), dtype=np.int64, count=int(lens.sum()))
        d = pos[j] - pos[i]
        ok = (np.einsum("ij,ij->i", nrm[i], nrm[j]) >= cos_min) & (
            np.abs(np.einsum("ij,ij->i", nrm[i], d)) <= plane_tol * h[i])
        ok |= i == j
        parts.append((i[ok].astype(np.int32), j[ok].astype(np.int32),
                      np.einsum("ij,ij->i", d[ok], d[ok])))
    i, j, d2 = (np.concatenate(x) for x in zip(*parts, strict=True))
    del parts
    out = []
    for radius in radii:
        r = radius * h
        if radius == max(radii):
            ik, jk, dk = i, j, d2
        else:
            keep = (d2 <= r[i] * r[i]) | (i == j)
            ik, jk, dk = i[keep], j[keep], d2[keep]
        sigma = 0.5 * r[ik]
        w = np.exp(-dk / (2.0 * sigma * sigma))
        del sigma, dk
        out.append(_row_stochastic(ik, jk, w, t))
    return out


def _row_stochastic(i: np.ndarray, j: np.ndarray, w: np.ndarray, t: int) -> sp.csr_matrix:
    """W (T × T) float64 CSR with W[i, j] = w / Σ_row w, from pairs sorted by (i, j) without
    duplicates, built in place (no COO → CSR copies and no diagonal × W product: 1.4 GiB
    of temporaries for the three filters of a 1024² atlas). The entries are as that product
    left them, each row's columns in descending order: the filter sums a texel's neighbours
    in that order (tests/test_smoothing.py checks against the product), so bundles do not
    change with the construction."""
    count = np.bincount(i, minlength=t)
    indptr = np.zeros(t + 1, dtype=np.int64)
    np.cumsum(count, out=indptr[1:])
    W = sp.csr_matrix((w, j.astype(np.int32, copy=False), indptr), shape=(t, t))
    norm = np.asarray(W.sum(axis=1)).ravel()
    W.data *= np.repeat(1.0 / norm, count)
    # each row reversed: position p of row r goes to indptr[r] + indptr[r + 1] − 1 − p
    rev = np.repeat(indptr[:-1] + indptr[1:] - 1, count) - np.arange(len(w))
    W.indices = W.indices[rev]
    W.data = W.data[rev]
    W.has_sorted_indices = False
    return W


def smooth_texels(texels: TexelSpace, values: np.ndarray, *, albedo: bool = True,
                  operator: sp.csr_matrix | None = None, **kw) -> np.ndarray:
    """Smooth per-texel values with :func:`smoothing_operator`.

    values : (T, 3) or (T, K, 3) float — outgoing radiance per texel (the last axis is the
        channel when ``albedo``), e.g. the dataset's indirect lightmaps
    albedo : filter irradiance (values / clamped albedo) over the neighbours whose albedo
        in that channel is > 0, and multiply back, so albedo edges stay sharp; a texel with
        zero albedo in a channel stays 0 there (its outgoing radiance)
    operator : a W from :func:`smoothing_operator` (built from ``kw`` when None)
    Returns the same shape, float32 when ``values`` is float32 (computed in float32), else
    float64.
    """
    v = np.asarray(values)
    if v.shape[0] != texels.count or v.shape[-1] != 3 or v.ndim not in (2, 3):
        raise ValueError(f"smooth_texels: values {v.shape}, expected ({texels.count}, 3) "
                         f"or ({texels.count}, K, 3)")
    W = operator if operator is not None else smoothing_operator(texels, **kw)
    dt = np.float32 if v.dtype == np.float32 else np.float64
    return _filtered(v.astype(dt, copy=False), _prepared(texels, W, dt, albedo))


def _prepared(texels: TexelSpace, W: sp.csr_matrix, dt: type, albedo: bool) -> tuple:
    """What :func:`_filtered` needs, computed once per filter: W in the values' precision
    ``dt`` (a :class:`~prtcore.core.sparse.SparseProduct`: scipy's product on all cores),
    and with ``albedo`` the per-texel scale to irradiance (1/ρ, 0 where ρ = 0) and back
    (ρ over the filtered weight of the neighbours with ρ > 0), (T, 3) ``dt``."""
    Wd = SparseProduct(W, default_threads(), dt)  # W @ x on all cores, scipy's rounding
    if not albedo:
        return Wd, None, None
    rho, _ = clamp_albedo(np.asarray(texels.albedo, dtype=np.float64))
    valid = (rho > 0).astype(np.float64)  # (T, 3)
    inv = np.divide(1.0, rho, out=np.zeros_like(rho), where=rho > 0).astype(dt)
    den = np.asarray(W @ valid)  # (T, 3)
    back = (rho / np.where(den > 0, den, 1.0)).astype(dt)
    return Wd, inv, back


@numba.njit(parallel=True, cache=True, nogil=True)
def _scale(x, s, out):  # pragma: no cover - compiled
    """out[i, k, c] = x[i, k, c] · s[i, c] for (T, K, 3) x and out (out may be x; x may be
    strided) and (T, 3) s of the same dtype: numpy's products, rows on all cores."""
    for i in numba.prange(x.shape[0]):
        for k in range(x.shape[1]):
            for c in range(x.shape[2]):
                out[i, k, c] = x[i, k, c] * s[i, c]


def _filtered(v: np.ndarray, prepared: tuple) -> np.ndarray:
    """Values (T, 3) or (T, K, 3) through a :func:`_prepared` filter, in their own precision
    (float32 lightmaps: float32 sums of a few dozen weights): scale, product, scale back
    (the scalings compiled, on all cores)."""
    Wd, inv, back = prepared
    x = v.reshape(len(v), -1, 3)
    if inv is None:
        y = Wd(x.reshape(len(v), -1)).reshape(x.shape)
    else:
        e = np.empty(x.shape, dtype=inv.dtype)
        _scale(x, inv, e)  # irradiance; 0 where the albedo is
        y = Wd(e.reshape(len(v), -1)).reshape(x.shape)
        del e
        _scale(y, back, y)
    return y.reshape(v.shape)


def denoise_lightmaps(texels: TexelSpace, I: np.ndarray, radius: float | None = None,
                      block: int = 16, *, operator: sp.csr_matrix | None = None,
                      out: np.ndarray | None = None) -> np.ndarray:
    """Lightmaps I (T, K, 3) through the seam-aware filter of ``radius`` texels (or the
    given ``operator``), ``block`` configurations at a time: (T, K, 3) float32 (the fit's
    ``fit.denoise``). ``out`` may be I itself (in place: each block is read whole before
    it is written), which saves a copy of the lightmaps."""
    W = operator if operator is not None else smoothing_operator(texels, radius=radius)
    prepared = _prepared(texels, W, np.float32, True)  # once, not per block
    out = np.empty(I.shape, dtype=np.float32) if out is None else out
    for k0 in range(0, I.shape[1], block):
        out[:, k0:k0 + block] = _filtered(
            np.asarray(I[:, k0:k0 + block], dtype=np.float32), prepared)
    return out
