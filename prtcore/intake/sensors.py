"""Measurement points chosen for the transfer: sensor selection by pivoted QR (issue 13).

The runtime predicts the basis coefficients of the indirect lightmap from the direct light
at P measurement points. Choosing those P among N dense candidates (for example the
blue-noise points of :func:`prtcore.intake.points.place_measurement_points` placed with a
larger count) is the sensor-placement problem of reduced-order modelling:

* **Q-DEIM** (Drmač & Gugercin 2016, "A new selection operator for the discrete empirical
  interpolation method"): with Ψ (N × r) an orthonormal basis of the candidates' direct
  signal over the training lights, the column-pivoted QR ``Ψᵀ Π = Q R`` orders the
  candidates so that the first r pivots make the r × r submatrix Ψ_S as well conditioned
  as a greedy choice can (‖Ψ_S⁻¹‖₂ ≤ √(N − r + 1)·√(4^r + 6r − 1)/3, their Theorem 2.1;
  a small multiple of 1 in practice): the direct light at those r points determines the
  r latent amplitudes of the signal.
* **Goal-oriented modes** (the data-driven reconstruction of Manohar et al. 2018, "Data-
  driven sparse sensor placement for reconstruction", with the targets being the basis
  coefficients instead of the field): when fewer points than modes are wanted, the modes
  kept are those that carry the most of the *targets* (the training basis coefficients),
  not the most direct-light energy. Mode j of the direct data (right singular vector v_j)
  explains ``‖C v_j‖²`` of the coefficients C; the r modes with the largest such energy
  are kept, then Q-DEIM runs on them.
* **Coverage for the rest** (oversampling, Manohar et al. 2018 section 3.3, done
  spatially): pivoted QR has nothing left to rank after the effective rank (every further
  pivot is rounding noise), and the weak modes it would rank are where the K training
  lights are noisy samples of the family. By default the QR ranks only the modes that
  carry 99.9 % of the energy and at most half of the P points (:data:`SENSOR_ENERGY`,
  :data:`SENSOR_QR_FRACTION`); the remaining points are filled by farthest-point sampling
  from the points already chosen when candidate positions are given (coverage for lights
  the training set did not show), else by a seeded random draw.

Everything is float64; no explicit inverse is formed (SVD and ``scipy.linalg.qr`` with
pivoting only). The module works on arrays only; :func:`restrict_points` applies a
selection to a :class:`~prtcore.intake.points.MeasurementPoints`.

Layouts (N candidates, K training configurations, C channels, m coefficient rows)::

    direct       : (N, K) or (N, K, C) float — direct radiance at the candidates
    coefficients : (m, K) or (m, K, C) float — the training basis coefficients (targets);
                   C must match ``direct``'s channel count when 3-D
    positions    : (N, 3) float — candidate positions (only for the oversampling fill)
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np
import scipy.linalg

from prtcore.intake.points import MeasurementPoints

#: Singular values of the candidates' direct matrix at or below this fraction of the
#: largest are treated as zero (the rank the pivoted QR can rank).
SENSOR_RANK_TOL = 1e-6
#: Defaults of :func:`select_sensors`, measured by benchmarks/fidelity.py (issue 13; N = 2048
#: candidates; Cornell box, open room, exterior, Duck, monkey; P = 64, 256; K = 128, 512):
#: Q-DEIM on the modes carrying 99.9 % of the direct energy, for at most half of the points,
#: the rest by farthest-point coverage. Pure Q-DEIM (every point by the QR) made the
#: Cornell box's worst held-out light 2× worse than this (42 % vs 19 % at P = 64) and its
#: pooled error 1.6× worse; this rule stayed within 6 % of blue noise where blue noise
#: does well (Cornell box, exterior) and lowered the pooled held-out error 15–43 % on the
#: open room and 16 % on Duck at P = 256.
SENSOR_ENERGY = 0.999
SENSOR_QR_FRACTION = 0.5


@dataclass(frozen=True)
class SensorSelection:
    """The outcome of :func:`select_sensors`.

    indices : (P,) int64 — chosen candidate rows, in the order chosen (pivots first,
        then the fill); all distinct
    qr_count : how many of them the pivoted QR chose (the rest are the fill)
    rank : effective rank of the prepared direct matrix (singular values
        > SENSOR_RANK_TOL·σ_max); the QR ranked qr_count ≤ rank modes
    method : "qdeim" (leading modes by direct energy) | "goal" (modes by coefficient
        energy)
    fill : "none" | "farthest" | "random"
    singular_values : (min(N, K·C),) float64 — of the prepared direct matrix, descending
    target_energy : (qr_count,) float64 or None — fraction of the targets' energy carried
        by each ranked mode, largest first ("goal" only)
    """

    indices: np.ndarray
    qr_count: int
    rank: int
    method: str
    fill: str
    singular_values: np.ndarray
    target_energy: np.ndarray | None = None


def prepare_direct(direct: np.ndarray, *, normalise: bool = True,
                   centre: bool = True) -> np.ndarray:
    """The candidates' direct data as the fit sees it, one row per candidate.

    direct : (N, K) or (N, K, C) float. Each configuration k is divided by the Frobenius
    norm of its candidates' values over points and channels (the fit's normalisation,
    prtcore.fit.transfer step 2; a zero configuration stays zero), then each row is centred
    over the configurations of its channel (the fit's transfer has an intercept).
    Returns (N, K·C) float64, column ``c·K + k`` (channel-major, the fit's "mono" stacking).
    """
    d = np.asarray(direct, dtype=np.float64)
    if d.ndim == 2:
        d = d[:, :, None]
    if d.ndim != 3:
        raise ValueError(f"prepare_direct: direct must be (N, K) or (N, K, C), got {d.shape}")
    if not np.isfinite(d).all():
        raise ValueError("prepare_direct: direct has non-finite values")
    if normalise:
        s = np.sqrt(np.sum(d * d, axis=(0, 2)))
        d = d / np.where(s > 0.0, s, 1.0)[None, :, None]
    if centre:
        d = d - d.mean(axis=1, keepdims=True)
    n, k, c = d.shape
    return np.ascontiguousarray(d.transpose(0, 2, 1).reshape(n, c * k))


def stack_coefficients(coefficients: np.ndarray) -> np.ndarray:
    """(m, K) or (m, K, C) → (m, K·C) float64, column ``c·K + k`` (matching
    :func:`prepare_direct`)."""
    a = np.asarray(coefficients, dtype=np.float64)
    if a.ndim == 2:
        return a.copy()
    if a.ndim != 3:
        raise ValueError(f"coefficients must be (m, K) or (m, K, C), got {a.shape}")
    m, k, c = a.shape
    return np.ascontiguousarray(a.transpose(0, 2, 1).reshape(m, c * k))


def qdeim(modes: np.ndarray, count: int | None = None) -> np.ndarray:
    """Q-DEIM: the first ``count`` pivots of the column-pivoted QR of ``modesᵀ``.

    modes : (N, r) float — columns spanning the signal over N candidates (orthonormal
        columns give Q-DEIM's bound; any full-column-rank basis works)
    count : pivots to return, ≤ min(N, r) (default r): beyond r the pivots are rounding
        noise, so asking for more is an error
    Returns (count,) int64 distinct row indices into ``modes``, most informative first.
    """
    psi = np.asarray(modes, dtype=np.float64)
    if psi.ndim != 2:
        raise ValueError(f"qdeim: modes must be (N, r), got {psi.shape}")
    n, r = psi.shape
    count = r if count is None else int(count)
    if not 0 <= count <= min(n, r):
        raise ValueError(f"qdeim: count {count} outside [0, min(N, r) = {min(n, r)}]")
    if count == 0:
        return np.zeros(0, dtype=np.int64)
    _, piv = scipy.linalg.qr(psi[:, :count].T, mode="r", pivoting=True,
                             check_finite=True)
    return np.asarray(piv[:count], dtype=np.int64)


def farthest_fill(positions: np.ndarray, chosen: np.ndarray, count: int,
                  exclude: np.ndarray | None = None) -> np.ndarray:
    """``count`` more rows of ``positions`` (N, 3) by farthest-point sampling from the
    rows ``chosen`` (Euclidean; ties to the lowest index), never taking the rows
    ``exclude`` (which do not count as covering anything either). Deterministic.
    Returns (count,) int64, disjoint from ``chosen`` and ``exclude``."""
    pos = np.asarray(positions, dtype=np.float64)
    chosen = np.asarray(chosen, dtype=np.int64)
    banned = np.union1d(chosen, np.zeros(0, np.int64) if exclude is None
                        else np.asarray(exclude, dtype=np.int64))
    if count > len(pos) - len(banned):
        raise ValueError(f"farthest_fill: {count} more of {len(pos)} with {len(banned)} "
                         "taken or excluded")
    if count == 0:
        return np.zeros(0, dtype=np.int64)
    if len(chosen):
        d = np.full(len(pos), np.inf)
        for a in range(0, len(chosen), 256):  # (N, 256) blocks of distances
            blk = pos[chosen[a:a + 256]]
            d = np.minimum(d, np.min(np.linalg.norm(pos[:, None, :] - blk[None], axis=2),
                                     axis=1))
    else:
        d = np.linalg.norm(pos - pos.mean(axis=0), axis=1)  # start at the outermost point
    d[banned] = -1.0
    out = np.empty(count, dtype=np.int64)
    for i in range(count):
        j = int(np.argmax(d))
        out[i] = j
        d = np.minimum(d, np.linalg.norm(pos - pos[j], axis=1))
        d[j] = -1.0
        d[banned] = -1.0
    return out


def direct_svd(prepared: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The thin SVD (U, s, Vt) of a :func:`prepare_direct` matrix (N, K·C), float64."""
    return scipy.linalg.svd(prepared, full_matrices=False)


def select_sensors(direct: np.ndarray, count: int,
                   coefficients: np.ndarray | None = None, *,
                   positions: np.ndarray | None = None, seed: int = 0,
                   energy: float = SENSOR_ENERGY, qr_fraction: float = SENSOR_QR_FRACTION,
                   normalise: bool = True, centre: bool = True,
                   rank_tol: float = SENSOR_RANK_TOL,
                   svd: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                   ) -> SensorSelection:
    """Choose ``count`` of N candidate measurement points for the transfer.

    direct : (N, K) or (N, K, C) float — the candidates' direct radiance over the K
        training configurations (any units; see :func:`prepare_direct`)
    count : P, 1 ≤ P ≤ N
    coefficients : None → Q-DEIM on the leading left singular vectors of the prepared
        direct matrix (by σ). (m, K) or (m, K, C) — the training configurations' basis
        coefficients (the mono fit's: coefficient i of channel c's snapshot k at [i, k, c];
        same K, and same C when 3-D) → the modes are ranked by the coefficient energy
        ``‖C v_j‖²`` they carry instead (ties by σ).
    positions : (N, 3) float — candidates' positions for the farthest-point fill; None →
        seeded random fill. The fill skips candidates that no training light reaches
        (all-zero rows of ``direct``) while others remain.
    seed : seeds the random fill only (the QR part is deterministic)
    energy : the QR ranks the fewest modes (in the ranking's order) that carry this
        fraction of the direct energy Σσ² (of the coefficient energy with coefficients);
        1.0 → every mode up to the rank
    qr_fraction : and at most ⌈qr_fraction·P⌉ of them; the other points are the fill.
        ``energy=1, qr_fraction=1`` is plain Q-DEIM with oversampling by the fill.
    normalise, centre : see :func:`prepare_direct`
    rank_tol : singular values ≤ rank_tol·σ_max count as zero
    svd : (U, s, Vt) of ``prepare_direct(direct, normalise=…, centre=…)`` when the caller
        already has it (:func:`direct_svd`; choosing several P from one set of candidates)

    Returns a :class:`SensorSelection`; ``indices`` (P,) int64.
    """
    A = prepare_direct(direct, normalise=normalise, centre=centre)
    n = A.shape[0]
    count = int(count)
    if not 1 <= count <= n:
        raise ValueError(f"select_sensors: count {count} outside [1, N = {n}]")
    if not 0.0 < energy <= 1.0 or not 0.0 < qr_fraction <= 1.0:
        raise ValueError("select_sensors: energy and qr_fraction must be in (0, 1]")
    if positions is not None and np.shape(positions) != (n, 3):
        raise ValueError(f"select_sensors: positions {np.shape(positions)}, expected ({n}, 3)")
    U, s, Vt = direct_svd(A) if svd is None else svd
    rank = int(np.sum(s > rank_tol * s[0])) if s.size and s[0] > 0 else 0
    target_energy = None
    if coefficients is None:
        order = np.arange(rank)
        weight = s[:rank] ** 2
        method = "qdeim"
    else:
        Ct = stack_coefficients(coefficients)
        if Ct.shape[1] != A.shape[1]:
            raise ValueError(f"select_sensors: coefficients give {Ct.shape[1]} columns, "
                             f"direct {A.shape[1]} (K·C must match)")
        carried = np.sum((Ct @ Vt[:rank].T) ** 2, axis=0)  # (rank,) ‖C v_j‖²
        order = np.lexsort((-s[:rank], -carried))  # by coefficient energy, then by σ
        weight = carried[order]
        method = "goal"
    total = float(np.sum(weight))
    cum = np.cumsum(weight) / total if total > 0 else np.ones(rank)
    r_energy = rank if energy >= 1.0 else int(np.searchsorted(cum, energy * (1 - 1e-12)) + 1)
    r = min(rank, r_energy, int(np.ceil(qr_fraction * count)), count)
    keep = np.sort(order[:r])
    if coefficients is not None:
        target_energy = weight[:r] / total if total > 0 else np.zeros(r)
    pivots = qdeim(U[:, keep], r)
    rest = count - r
    if rest == 0:
        fill = "none"
        extra = np.zeros(0, dtype=np.int64)
    else:
        # candidates no training light reaches carry nothing (buried, or facing away from
        # the family): the fill takes them only when the others run out
        dark = np.flatnonzero(~np.any(np.asarray(direct).reshape(n, -1) != 0, axis=1))
        if n - len(np.union1d(pivots, dark)) < rest:
            dark = dark[:0]
        if positions is not None:
            fill = "farthest"
            extra = farthest_fill(positions, pivots, rest, exclude=dark)
        else:
            fill = "random"
            pool = np.setdiff1d(np.arange(n), np.union1d(pivots, dark))
            extra = np.random.default_rng(seed).choice(pool, size=rest, replace=False)
    return SensorSelection(indices=np.concatenate([pivots, extra]).astype(np.int64),
                           qr_count=r, rank=rank, method=method, fill=fill,
                           singular_values=s, target_energy=target_energy)


def restrict_points(points: MeasurementPoints, rows: np.ndarray) -> MeasurementPoints:
    """The measurement points ``rows`` (P,) of ``points``, in that order, each with its own
    supersample cluster (renumbered owners, clusters kept sorted by owner as
    :class:`MeasurementPoints` requires)."""
    rows = np.asarray(rows, dtype=np.int64)
    if len(np.unique(rows)) != len(rows) or (len(rows) and not (
            0 <= rows.min() and rows.max() < points.count)):
        raise ValueError("restrict_points: rows must be distinct indices of the points")
    new_id = np.full(points.count, -1, dtype=np.int64)
    new_id[rows] = np.arange(len(rows))
    owner = new_id[points.cluster_owner]
    keep = np.flatnonzero(owner >= 0)
    order = keep[np.argsort(owner[keep], kind="stable")]
    return replace(
        points,
        position=points.position[rows], normal=points.normal[rows],
        albedo=points.albedo[rows], triangle=points.triangle[rows],
        barycentric=points.barycentric[rows],
        cluster_position=points.cluster_position[order],
        cluster_normal=points.cluster_normal[order],
        cluster_albedo=points.cluster_albedo[order],
        cluster_triangle=points.cluster_triangle[order],
        cluster_barycentric=points.cluster_barycentric[order],
        cluster_owner=owner[order].astype(np.int32))


def concat_points(*sets: MeasurementPoints) -> tuple[MeasurementPoints, list[slice]]:
    """One :class:`MeasurementPoints` holding ``sets`` one after the other (so that one
    transport pass lights them all), and the rows of each set in it.

    Cluster owners are offset by the rows before each set; all sets must share a
    placement. Returns (points, [slice of rows per set]).
    """
    if not sets:
        raise ValueError("concat_points: no point sets")
    if len({s.placement for s in sets}) != 1:
        raise ValueError("concat_points: the sets have different placements")
    offsets = np.cumsum([0, *(s.count for s in sets)])
    fields = ("position", "normal", "albedo", "triangle", "barycentric", "cluster_position",
              "cluster_normal", "cluster_albedo", "cluster_triangle", "cluster_barycentric")
    joined = {f: np.concatenate([getattr(s, f) for s in sets]) for f in fields}
    owner = np.concatenate([s.cluster_owner.astype(np.int64) + o
                            for s, o in zip(sets, offsets[:-1], strict=True)])
    points = replace(sets[0], **joined, cluster_owner=owner.astype(np.int32))
    return points, [slice(int(a), int(b)) for a, b in itertools.pairwise(offsets)]
