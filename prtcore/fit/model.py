"""The fitted model and what every fit module shares: gamma, the error metric, blocks.

Shapes and the runtime formula: see :mod:`prtcore.fit.transfer`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from prtcore.core.mlp import Mlp

#: λ grid for ridge="auto", relative to σ_max² (0 is added in front): 25 values.
RIDGE_GRID_REL = tuple(float(v) for v in np.logspace(-8.0, 2.0, 24))
#: basis="auto" without held-out data: smallest n keeping this fraction of the energy
#: (sum of eigenvalues) of the mean-subtracted snapshots.
AUTO_ENERGY = 0.999
#: basis="auto" with held-out data: smallest n whose held-out relative RMSE is within this
#: relative margin of the best.
AUTO_HOLDOUT_MARGIN = 0.01
#: basis="auto" never goes beyond this many elements (mean included): 16 RGBA textures,
#: the top of the prtcore/fit report table.
AUTO_BASIS_MAX = 64
#: Allowed gamma g (values fitted as |v|^(1/g)). g < 1 would expand the dynamic range:
#: at g = 0.05 a direct radiance of 1e6 becomes 1e120 and the float32 model overflows
#: (NaN lightmaps). With g ≥ 1, |v|^(1/g) ≤ max(|v|, 1): encoding never overflows.
#: The upper bound is the spec's (fit.gamma ≤ 10).
GAMMA_RANGE = (1.0, 10.0)
#: Memory budget of one block of texel rows in float64 work arrays.
BLOCK_BYTES = 64 * 2**20

UNDERDETERMINED_WARNING = (
    "more measurement points than configurations: transfer is underdetermined, "
    "ridge regularises it"
)



@dataclass(frozen=True)
class FitDiagnostics:
    """What the fit saw and chose; :meth:`to_dict` is JSON-serialisable (no NaN/inf).

    configurations : K given; used : configurations kept
    excluded : ({"index": k, "reason": str}, ...) — zero or non-finite direct, non-finite
        indirect
    direct_singular_values : per channel, singular values (descending) of the normalised
        (centred when ``intercept``) direct matrix the transfer inverts, all configurations
    direct_condition : per channel σ_max/σ_min over min(P, K_eff) values, None if singular
        (σ_min ≤ DIRECT_SVD_REL_TOL·σ_max) or empty
    direct_effective_rank : per channel #σ_i > DIRECT_SVD_REL_TOL·σ_max
    indirect_singular_values : √eigenvalues of the snapshot Gram matrix (mono: one list;
        rgb: one per channel), descending
    indirect_rank : available basis rank (eigenvalues > EIG_REL_TOL·e_max; rgb: max over
        channels)
    n_basis : chosen element count including the mean; n_basis_requested : the request
    n_basis_method : "given" | "capped" | "energy" | "holdout"
    energy_kept : fraction of snapshot energy in the chosen n−1 basis vectors
    energy_curve : energy kept for 0, 1, ..., n_max−1 basis vectors
    holdout_rmse : held-out relative RMSE for 1..n_max elements (index i ↔ n = i+1), or None
    holdout_used : held-out configurations used (zero-direct ones count; non-finite dropped)
    ridge, ridge_method : chosen λ and "given" | "loo"
    ridge_grid, ridge_cv : the λ grid and, per λ, the leave-one-out relative RMSE in
        normalised (gamma-space) units, basis held fixed (None where undefined)
    intercept : whether the transfer has the offset b
    groups : keyframe ids and their configuration counts (None without groups)
    unlit_points : measurement points that no used configuration lights (rows of D all 0)
    warnings : human-readable notes
    seconds : wall time of the fit's steps
    transfer : the transfer regressor ("ridge" | "mlp")
    learnt : what training the learnt residual measured (:mod:`prtcore.fit.mlp`), or None
    """

    configurations: int
    used: int
    excluded: tuple[dict[str, Any], ...]
    channels: str
    gamma: float | None
    intercept: bool
    direct_singular_values: tuple[tuple[float, ...], ...]
    direct_condition: tuple[float | None, ...]
    direct_effective_rank: tuple[int, ...]
    indirect_singular_values: tuple[tuple[float, ...], ...]
    indirect_rank: int
    n_basis: int
    n_basis_requested: int | str
    n_basis_method: str
    energy_kept: float
    energy_curve: tuple[float, ...]
    holdout_rmse: tuple[float, ...] | None
    holdout_used: int
    ridge: float
    ridge_method: str
    ridge_grid: tuple[float, ...]
    ridge_cv: tuple[float | None, ...]
    groups: dict[str, list[int]] | None
    unlit_points: tuple[int, ...]
    warnings: tuple[str, ...]
    seconds: dict[str, float] = field(default_factory=dict)
    transfer: str = "ridge"
    learnt: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of lists/floats/ints/str/None (json.dumps works, strict JSON)."""
        return jsonable(asdict(self))


@dataclass(frozen=True, eq=False)
class TransferModel:
    """The fitted data-driven PRT model (see the module docstring for the runtime formula).

    n_b = n − 1 basis vectors besides the mean; G keyframe groups when per-group.

    mean : (T, 3) float32 — element 0: per-channel mean of the normalised (gamma-space)
        indirect vectors
    basis : (T, n_b) float32 for "mono" (shared by R, G, B); (T, n_b, 3) float32 for "rgb"
    transfer : (3, n_b, P) float32, or (G, 3, n_b, P) per keyframe group
    offset : (3, n_b) float32, or (G, 3, n_b) — the coefficient offset b, scaled by s
    gamma : None or g in GAMMA_RANGE (values fitted as sign(v)|v|^(1/g))
    channels : "mono" | "rgb"
    ridge : λ used
    group_ids : keyframe ids, in the order of the transfer's first axis (None: shared)
    diagnostics : :class:`FitDiagnostics`
    learnt : "mlp" transfer: the residual network (:mod:`prtcore.core.mlp`, outputs
        3·n_b rows ``[c][i]``) whose ``s·r(x'/s)`` is added to u; None for ridge
    """

    mean: np.ndarray
    basis: np.ndarray
    transfer: np.ndarray
    offset: np.ndarray
    gamma: float | None
    channels: str
    ridge: float
    group_ids: tuple[int, ...] | None
    diagnostics: FitDiagnostics
    learnt: Mlp | None = None

    @property
    def n_basis(self) -> int:
        """Basis elements including the mean."""
        return int(self.basis.shape[1]) + 1

    @property
    def points(self) -> int:
        return int(self.transfer.shape[-1])

    @property
    def texels(self) -> int:
        return int(self.mean.shape[0])


def gamma_encode(values: np.ndarray, gamma: float | None) -> np.ndarray:
    """Sign-preserving power sign(v)·|v|^(1/gamma); float64 copy (identity for None)."""
    v = np.array(values, dtype=np.float64)
    if gamma is None or gamma == 1.0:
        return v
    out = np.abs(v)
    np.power(out, 1.0 / gamma, out=out)
    return np.copysign(out, v, out=out)


def gamma_decode(values: np.ndarray, gamma: float | None) -> np.ndarray:
    """Inverse of :func:`gamma_encode` for the runtime: max(v, 0)^gamma, float64.

    Negative gamma-space values are clamped to 0 first. For None, a float64 copy, unclamped.
    """
    v = np.array(values, dtype=np.float64)
    if gamma is None:
        return v
    return np.maximum(v, 0.0) ** gamma


def relative_rmse(a: np.ndarray, b: np.ndarray) -> float:
    """‖a − b‖ / ‖b‖, Frobenius over every entry (all texels, all channels), in float64.

    a, b : same shape (e.g. (T, 3) reconstruction and reference; pass covered texels only).
    Returns 0.0 when both are zero and inf when only b is zero.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"relative_rmse: shapes differ, {a.shape} vs {b.shape}")
    num = float(np.linalg.norm(a - b))
    den = float(np.linalg.norm(b))
    if den == 0.0:
        return 0.0 if num == 0.0 else float("inf")
    return num / den


def blocks(total: int, rows: int) -> Iterator[slice]:
    for start in range(0, total, rows):
        yield slice(start, min(start + rows, total))


def default_rows(bytes_per_row: int, block_rows: int | None) -> int:
    if block_rows is not None:
        return max(1, int(block_rows))
    return max(1, BLOCK_BYTES // max(1, bytes_per_row))


def jsonable(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): jsonable(w) for k, w in v.items()}
    if isinstance(v, list | tuple):
        return [jsonable(w) for w in v]
    if isinstance(v, np.ndarray):
        return [jsonable(w) for w in v.tolist()]
    if isinstance(v, bool | np.bool_):
        return bool(v)
    if isinstance(v, int | np.integer):
        return int(v)
    if isinstance(v, float | np.floating):
        f = float(v)
        return f if np.isfinite(f) else None
    return v
