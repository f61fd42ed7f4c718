"""Denoising the strand texels' indirect light: a kernel average over each texel's nearest
texels in space (``hair.denoise_neighbours``; docs/hair.md, "Denoising the strand texels").

**Why.** A strand texel's indirect light is a Monte Carlo estimate: M gather rays and J
direct samples per texel. On the 10k hairball at the bake's defaults (M = 64, J = 4) two
runs with different seeds differ by 16 % of the light's RMS per texel, while the error they
share against the path tracer (the transport's approximations) is 5 %: the per-texel
error is almost all noise. The irradiance a fibre receives varies smoothly through the hair
volume (it is the fluence of a dense scattering medium), so averaging neighbouring texels
removes noise at little bias; measured in docs/hair.md.

**What.** Each texel's irradiance becomes ``Σ_j w_ij E_j / Σ_j w_ij`` over its k nearest
texels j in space (the texel's axis point :attr:`StrandSpace.position`, itself included),
with Epanechnikov weights ``w = 1 − (d / h)²`` and h the distance to the (k + 1)-th
nearest texel (an adaptive radius, as in photon density estimation: small where the hair
is dense). It is the irradiance ``E = L / ρ`` that is averaged, not the outgoing radiance
L: strands of different colours side by side receive the same light but do not mix their
colours. A texel whose fibre has ρ = 0 in a channel keeps L = 0 there and lends nothing.

The filter is linear and the same for every light, so it commutes with the fit: what a
bundle stores is the denoised dataset's projection.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from prtcore.core.progress import StageTimer
from prtcore.core.sparse import SparseProduct
from prtcore.receivers.strands import StrandSpace
from prtcore.transport.dataset import Dataset

#: the default k (``hair.denoise_neighbours``): the hairball's rRMSE against the path
#: tracer falls from 18 % to 6 % with little bias (docs/hair.md)
DEFAULT_NEIGHBOURS = 32
#: texels whose neighbours are found at once (a (chunk, k + 1) float64 + int64 query)
QUERY_CHUNK = 1 << 16
#: columns (lights × channels) filtered at once, so the temporary stays small
COLUMN_BLOCK = 48


@dataclass(frozen=True)
class NeighbourKernel:
    """The denoising filter of T texels.

    matrix : (T, T) float32 CSR, row i the normalised weights of texel i's k nearest texels
    neighbours : k
    radius : (T,) float64 the kernel radius h of every texel (metres)
    """

    matrix: sp.csr_matrix
    neighbours: int
    radius: np.ndarray


def neighbour_kernel(position: np.ndarray, neighbours: int = DEFAULT_NEIGHBOURS,
                     threads: int = 2) -> NeighbourKernel:
    """The kernel over ``position`` (T, 3) float64 texel points: ``neighbours`` (k)
    nearest points each, itself included (every point when T ≤ k); k ≤ 1: the
    identity."""
    position = np.asarray(position, dtype=np.float64)
    t = len(position)
    if t <= 1 or neighbours <= 1:
        return NeighbourKernel(sp.identity(t, dtype=np.float32, format="csr"), 1,
                               np.zeros(t))
    k = min(int(neighbours), t)
    tree = cKDTree(position)
    cols = np.empty((t, k), dtype=np.int32)
    data = np.empty((t, k), dtype=np.float32)
    radius = np.empty(t)
    for a in range(0, t, QUERY_CHUNK):
        b = min(a + QUERY_CHUNK, t)
        dist, idx = tree.query(position[a:b], k=min(k + 1, t), workers=threads)
        # h: the (k + 1)-th point's distance; with k = T every point counts, the
        # farthest with weight 1 − 1/1.25²
        h = dist[:, -1] if k < t else 1.25 * dist[:, -1]
        # coincident points (h = 0): equal weights
        safe = np.where(h > 0, h, 1.0)[:, None]
        w = np.maximum(1.0 - (dist[:, :k] / safe) ** 2, 0.0)
        w[h == 0] = 1.0
        data[a:b] = w / w.sum(axis=1, keepdims=True)
        cols[a:b] = idx[:, :k]
        radius[a:b] = h
    matrix = sp.csr_matrix((data.reshape(-1), cols.reshape(-1),
                            np.arange(0, t * k + 1, k, dtype=np.int64)), shape=(t, t))
    matrix.sort_indices()
    return NeighbourKernel(matrix, k, radius)


def denoise_irradiance(kernel: NeighbourKernel, radiance: np.ndarray, albedo: np.ndarray,
                       threads: int = 2) -> np.ndarray:
    """Replace ``radiance`` (T, K, 3) float32 outgoing radiance L = ρ/π·E of the kernel's T
    texels **in place** by ``ρ · (W (L / ρ))``, W the kernel with each row's weights
    renormalised over the neighbours whose ρ > 0 in that channel; ``albedo`` (T, 3) the
    fibres' ρ. Returns ``radiance``. Works ``COLUMN_BLOCK`` columns at a time."""
    t = kernel.matrix.shape[0]
    if radiance.shape[0] != t or not radiance.flags.c_contiguous:
        raise ValueError(f"denoise_irradiance: expected a C-contiguous ({t}, K, 3) array, "
                         f"got {radiance.shape}")
    rho = np.asarray(albedo, dtype=np.float32).reshape(t, 3)
    lit = rho > 0
    inv = np.where(lit, 1.0 / np.where(lit, rho, 1.0), 0.0).astype(np.float32)
    product = SparseProduct(kernel.matrix, threads)
    # the weight each row has over the neighbours that lend light, per channel
    norm = product(lit.astype(np.float32))
    scale = np.where(norm > 0, rho / np.where(norm > 0, norm, 1.0), 0.0).astype(np.float32)
    flat = radiance.reshape(t, -1, 3)
    k = flat.shape[1]
    step = max(1, COLUMN_BLOCK // 3)
    for a in range(0, k, step):
        b = min(a + step, k)
        e = (flat[:, a:b] * inv[:, None, :]).reshape(t, -1)
        flat[:, a:b] = product(e).reshape(t, b - a, 3) * scale[:, None, :]
    return radiance


def denoise_dataset(data: Dataset, space: StrandSpace, neighbours: int,
                    albedo: np.ndarray | None = None, first_row: int = 0,
                    timer: StageTimer | None = None, threads: int = 2) -> Dataset:
    """``data`` with its strand texels' indirect light denoised (:func:`denoise_irradiance`
    over :func:`neighbour_kernel` of ``space.position``); the strand texels are rows
    ``first_row`` … ``first_row + T`` of ``data.indirect`` (after a mesh's atlas texels in
    a hair + mesh bake; those are left as they are). ``albedo`` (T, 3): the ρ that divides
    the outgoing radiance (default ``space.albedo``). ``neighbours`` ≤ 1: ``data``
    unchanged. The array is filtered in place (it belongs to the dataset being built) and
    ``stats["denoise"]`` records k, the median kernel radius and the seconds.

    Memory: the kernel's CSR (8 bytes per texel and neighbour) and two blocks of
    ``COLUMN_BLOCK`` columns, after the solve has let go of its operator (at least M ≥ k
    rays of 8 bytes per texel), so the bake's peak is not raised (measured in
    docs/hair.md)."""
    if neighbours <= 1:
        return data
    timer = timer or StageTimer(quiet=True)
    t = space.count
    with timer.stage("denoise"):
        t0 = time.perf_counter()
        kernel = neighbour_kernel(space.position, neighbours, threads)
        rows = data.indirect[first_row:first_row + t]  # a view: contiguous rows
        denoise_irradiance(kernel, rows, space.albedo if albedo is None else albedo,
                           threads)
        seconds = time.perf_counter() - t0
    stats = {**data.stats, "denoise": {"neighbours": kernel.neighbours,
                                       "median_radius_m": float(np.median(kernel.radius)),
                                       "seconds": round(seconds, 3)}}
    return dataclasses.replace(data, stats=stats)
