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

(The weights are those of a local linear fit, a plane through the neighbours, whose
intercept is taken; the average is its fallback.)

**The fibre's direction** (``direction="t2"``, the Chiang fibre's,
``hair.denoise_direction``; denoised by default for hair alone, not with a mesh). A Chiang
texel stores ``(1/π²) ∫ L_i(ω) Ā(θ) cos θ dω`` with sin θ = t·ω: the incident field
against a kernel zonal about the fibre's direction t, so by Funk–Hecke each band of the
field reaches the texel scaled and evaluated at t. Neighbours pointing other ways differ
in truth, through the field's low bands; the fit takes the five second-band terms of t
(:func:`direction_terms`) besides the plane. On the 10k hairball
at the bake's rays: second-order exitance 6.8 % (light) and 7.3 % (dark) per texel
against the path tracer, 7.9 % and 9.0 % with the plane alone, 14.0 % and 16.4 %
undenoised (docs/hair.md, "Denoising the Chiang fibre").

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

#: the default k (``hair.denoise_neighbours``): on the 10k hairball at the bake's defaults
#: the rRMSE against the path tracer falls from 16 % to 7 % with no bias (docs/hair.md)
DEFAULT_NEIGHBOURS = 64
#: texels whose neighbours are found and fitted at once (a few (chunk, k, 4) float64
#: temporaries: 33 MB each at k = 64)
QUERY_CHUNK = 1 << 14
#: columns (lights × channels) filtered at once, so the temporary stays small
COLUMN_BLOCK = 48
#: the ridge on the local fit's slopes, relative to the row's weight (the slopes are fitted
#: in units of the kernel radius): it keeps the fit of neighbours that lie nearly on a line
#: or a plane (a lone strand, a flat lock) from extrapolating, and pulls it towards the
#: kernel average there
SLOPE_RIDGE = 1e-3
#: a row whose local-linear weights sum to more than this in absolute value (its noise
#: gain) keeps the kernel average's weights instead
MAX_GAIN = 2.5
#: the fibre-direction terms a kernel's fit may take besides the plane (the values of
#: ``hair.denoise_direction`` once resolved): "t2", the five second-order (traceless
#: t tᵀ) components; "t12", also t itself (the tilt's odd part)
DIRECTIONS = ("t2", "t12")


@dataclass(frozen=True)
class NeighbourKernel:
    """The denoising filter of T texels.

    matrix : (T, T) float32 CSR; row i the weights of texel i's k nearest texels, which
        sum to 1 (they may be negative with ``local_linear``)
    neighbours : k
    radius : (T,) float64 the kernel radius h of every texel (metres)
    local_linear : whether the weights are those of a local linear fit rather than the
        kernel average
    direction : "none" or one of :data:`DIRECTIONS`: the fibre-direction terms fitted
        besides the plane
    """

    matrix: sp.csr_matrix
    neighbours: int
    radius: np.ndarray
    local_linear: bool = False
    direction: str = "none"


def direction_terms(tangent: np.ndarray, direction: str) -> np.ndarray:
    """(..., D) float64 the fibre-direction regressors of unit tangents ``tangent`` (..., 3):
    "t2" the five components of the traceless tensor ``t tᵀ − I/3`` (D = 5: the second
    band, to which a radially averaged fibre's response to incident light reduces by
    Funk–Hecke, its first band vanishing without tilt), "t12" also t (D = 8)."""
    t = np.asarray(tangent, dtype=np.float64)
    x, y, z = t[..., 0], t[..., 1], t[..., 2]
    terms = [x * y, y * z, z * x, 0.5 * (x * x - y * y), 0.5 * (z * z - 1.0 / 3.0) * 3 ** 0.5]
    if direction == "t12":
        terms += [x, y, z]
    elif direction != "t2":
        raise ValueError(f"direction_terms: direction must be one of {DIRECTIONS}, "
                         f"got {direction!r}")
    return np.stack(terms, axis=-1)


def _intercept_weights(x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The weights (n, k) float64 that give the intercept of the weighted least-squares fit
    of regressors ``x`` (n, k, 1 + D) (the first column ones, the rest zero at the texel
    itself) through each row's k neighbours of kernel weights ``w`` (n, k), the D slopes
    under a ridge of ``SLOPE_RIDGE`` × the row's weight; and whether each row's noise gain
    Σ|l| is finite and within ``MAX_GAIN``."""
    n, _, d = x.shape
    xtw = x.transpose(0, 2, 1) * w[:, None, :]  # (n, 1 + D, k)
    gram = xtw @ x
    ridge = SLOPE_RIDGE * w.sum(axis=1)
    gram[:, 1:, 1:] += ridge[:, None, None] * np.eye(d - 1)
    e0 = np.zeros((n, d, 1))
    e0[:, 0] = 1.0
    coef = np.linalg.solve(gram, e0)  # (n, 1 + D, 1): the first row of gram⁻¹
    lw = (xtw.transpose(0, 2, 1) @ coef)[..., 0]
    gain = np.abs(lw).sum(axis=1)
    return lw, np.isfinite(gain) & (gain <= MAX_GAIN)


def _local_linear_weights(offset: np.ndarray, w: np.ndarray,
                          turn: np.ndarray | None = None) -> np.ndarray:
    """The weights (n, k) float64 that give the intercept of the weighted least-squares
    plane ``E(x) ≈ a + b·(x − x_i)`` through each row's k neighbours: ``offset`` (n, k, 3)
    float64 their positions relative to the texel in units of its kernel radius, ``w``
    (n, k) float64 the kernel's weights. With ``turn`` (n, k, D) float64, the neighbours'
    fibre-direction terms less the texel's own (:func:`direction_terms`), the fit is
    ``a + b·(x − x_i) + c·(f(t) − f(t_i))``: a fibre whose response depends on its direction
    (the Chiang fibre's lobes) is compared with neighbours of other directions through it.
    The slopes carry a ridge of ``SLOPE_RIDGE`` × the row's weight; a row with a noise
    gain Σ|l| above ``MAX_GAIN`` takes the plane's weights (without ``turn``), and failing
    that ``w`` normalised.
    """
    n, k = w.shape
    x = np.concatenate([np.ones((n, k, 1)), offset], axis=2)
    out = np.empty((n, k))
    todo = np.arange(n)  # the rows still without weights, fitted by ever fewer terms
    for design in ([] if turn is None else [np.concatenate([x, turn], axis=2)]) + [x]:
        lw, ok = _intercept_weights(design[todo], w[todo])
        out[todo[ok]] = lw[ok]
        todo = todo[~ok]
    out[todo] = w[todo] / w[todo].sum(axis=1, keepdims=True)
    return out


def neighbour_kernel(position: np.ndarray, neighbours: int = DEFAULT_NEIGHBOURS,
                     threads: int = 2, local_linear: bool = True,
                     lend: np.ndarray | None = None, tangent: np.ndarray | None = None,
                     direction: str = "none") -> NeighbourKernel:
    """The kernel over ``position`` (T, 3) float64 texel points: each texel's ``neighbours``
    (k) nearest points (every point when T ≤ k), itself included, with Epanechnikov weights
    of an adaptive radius, and with ``local_linear`` (the default) the weights of the local
    linear fit under them (:func:`_local_linear_weights`); with ``direction`` (one of
    :data:`DIRECTIONS`) that fit also takes the terms of the fibres' ``tangent`` (T, 3)
    float64. ``lend`` (T,) bool: only those texels are anyone's neighbours (a texel that
    lends nothing still gets a row). k ≤ 1: the identity."""
    position = np.asarray(position, dtype=np.float64)
    terms = None
    if direction != "none":
        if tangent is None or np.shape(tangent) != position.shape:
            raise ValueError("neighbour_kernel: a directional kernel needs the texels' "
                             f"tangents ({position.shape}), got "
                             f"{None if tangent is None else np.shape(tangent)}")
        terms = direction_terms(tangent, direction)
    t = len(position)
    source = np.arange(t) if lend is None else np.flatnonzero(lend)
    if t <= 1 or neighbours <= 1 or len(source) <= 1:
        if lend is not None and len(source) < t and neighbours > 1:
            raise ValueError("neighbour_kernel: fewer than two texels lend light")
        return NeighbourKernel(sp.identity(t, dtype=np.float32, format="csr"), 1,
                               np.zeros(t))
    k = min(int(neighbours), len(source))
    tree = cKDTree(position[source])
    cols = np.empty((t, k), dtype=np.int32)
    data = np.empty((t, k), dtype=np.float32)
    radius = np.empty(t)
    for a in range(0, t, QUERY_CHUNK):
        b = min(a + QUERY_CHUNK, t)
        dist, idx = tree.query(position[a:b], k=min(k + 1, len(source)), workers=threads)
        # h: the (k + 1)-th point's distance; with k = all points every one counts, the
        # farthest with weight 1 − 1/1.25²
        h = dist[:, -1] if k < len(source) else 1.25 * dist[:, -1]
        # coincident points (h = 0): equal weights
        safe = np.where(h > 0, h, 1.0)[:, None]
        w = np.maximum(1.0 - (dist[:, :k] / safe) ** 2, 0.0)
        w[h == 0] = 1.0
        idx = source[idx[:, :k]]
        if local_linear and k >= 4:
            offset = (position[idx] - position[a:b, None, :]) / safe[..., None]
            turn = None if terms is None else terms[idx] - terms[a:b, None, :]
            data[a:b] = _local_linear_weights(offset, w, turn)
        else:
            data[a:b] = w / w.sum(axis=1, keepdims=True)
        cols[a:b] = idx
        radius[a:b] = h
    matrix = sp.csr_matrix((data.reshape(-1), cols.reshape(-1),
                            np.arange(0, t * k + 1, k, dtype=np.int64)), shape=(t, t))
    matrix.sort_indices()
    local_linear = local_linear and k >= 4
    return NeighbourKernel(matrix, k, radius, local_linear,
                           direction if local_linear else "none")


def denoise_irradiance(kernel: NeighbourKernel, radiance: np.ndarray, albedo: np.ndarray,
                       threads: int = 2, position: np.ndarray | None = None,
                       tangent: np.ndarray | None = None) -> np.ndarray:
    """Replace ``radiance`` (T, K, 3) float32 outgoing radiance L = ρ/π·E of the kernel's T
    texels **in place** by ``ρ · max(W (L / ρ), 0)``, W the kernel; ``albedo`` (T, 3) the
    fibres' ρ. In a channel where some fibres have ρ = 0 (they tell nothing of the light
    they receive) W is rebuilt over the others, which needs ``position`` (and ``tangent``
    for a directional kernel). Returns
    ``radiance``. Works ``COLUMN_BLOCK`` columns at a time."""
    t = kernel.matrix.shape[0]
    if radiance.shape[0] != t or not radiance.flags.c_contiguous:
        raise ValueError(f"denoise_irradiance: expected a C-contiguous ({t}, K, 3) array, "
                         f"got {radiance.shape}")
    rho = np.asarray(albedo, dtype=np.float32).reshape(t, 3)
    lit = rho > 0
    flat = radiance.reshape(t, -1, 3)
    channels: dict[bytes, list[int]] = {}
    for c in range(3):
        channels.setdefault(np.packbits(lit[:, c]).tobytes(), []).append(c)
    for chans in channels.values():
        lend = lit[:, chans[0]]
        if lend.sum() < 2:  # nothing to average
            continue
        ker = kernel
        if not lend.all():
            if position is None:
                raise ValueError("denoise_irradiance: fibres with ρ = 0 in a channel need "
                                 "the texels' positions to rebuild the kernel")
            ker = neighbour_kernel(position, kernel.neighbours, threads,
                                   kernel.local_linear, lend, tangent, kernel.direction)
        _filter(SparseProduct(ker.matrix, threads), flat, rho, chans)
    return radiance


def _filter(product: SparseProduct, flat: np.ndarray, rho: np.ndarray,
            chans: list[int]) -> None:
    """``flat[:, :, c]`` ← ρ_c · max(W (L_c / ρ_c), 0) for the channels ``chans``, in place
    (0 where ρ_c = 0)."""
    t, k, _ = flat.shape
    r = rho[:, chans]
    inv = np.where(r > 0, 1.0 / np.where(r > 0, r, 1.0), 0.0).astype(np.float32)
    step = max(1, COLUMN_BLOCK // len(chans))
    for a in range(0, k, step):
        b = min(a + step, k)
        e = (flat[:, a:b][:, :, chans] * inv[:, None, :]).reshape(t, -1)
        out = np.maximum(product(e), 0.0).reshape(t, b - a, len(chans))
        flat[:, a:b, chans] = out * r[:, None, :]


def denoise_dataset(data: Dataset, space: StrandSpace, neighbours: int,
                    albedo: np.ndarray | None = None, first_row: int = 0,
                    timer: StageTimer | None = None, threads: int = 2,
                    direction: str = "none") -> Dataset:
    """``data`` with its strand texels' indirect light denoised (:func:`denoise_irradiance`
    over :func:`neighbour_kernel` of ``space.position``, with ``direction`` of
    ``space.tangent`` too); the strand texels are rows
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
        kernel = neighbour_kernel(space.position, neighbours, threads,
                                  tangent=space.tangent, direction=direction)
        rows = data.indirect[first_row:first_row + t]  # a view: contiguous rows
        denoise_irradiance(kernel, rows, space.albedo if albedo is None else albedo,
                           threads, space.position, space.tangent)
        seconds = time.perf_counter() - t0
    stats = {**data.stats, "denoise": {"neighbours": kernel.neighbours,
                                       "direction": None if kernel.direction == "none"
                                       else kernel.direction,
                                       "median_radius_m": float(np.median(kernel.radius)),
                                       "seconds": round(seconds, 3)}}
    return dataclasses.replace(data, stats=stats)
