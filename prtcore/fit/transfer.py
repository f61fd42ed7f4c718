"""Fit: direct vectors D and indirect lightmaps I → mean, basis U_n, ridge transfer M_n.

Data-driven PRT, Belcour et al. 2022, sections 3–5 (DESIGN 5).

Input layout (K lighting configurations, P measurement points, T texels, channels R, G, B)::

    D : (P, K, 3) float   direct outgoing radiance at the measurement points
    I : (T, K, 3) float   indirect outgoing radiance per lightmap texel

Fitting, in this order (everything in float64):

1. **Gamma** (optional, paper 5.3). With ``gamma=g`` every value v of D and I is replaced by
   the sign-preserving power ``γ(v) = sign(v)·|v|^(1/g)`` *before* anything else, so the
   whole fit (normalisation, mean, basis, transfer) lives in gamma space, as the paper
   gamma-corrects "the values in the dataset".
2. **Normalisation** (paper 4.2). ``s_k = ‖γ(D)[:, k, :]‖`` (Frobenius over points and
   channels). Configurations with ``s_k == 0``, a non-finite ``s_k`` or any non-finite
   indirect value are excluded (listed in the diagnostics). Both ``D[:, k]`` and ``I[:, k]``
   are divided by ``s_k``: ``Dn``, ``In``.
3. **Mean** (element 0 of the basis). ``m[:, c] = mean_k In[:, k, c]`` — one mean *per
   channel* in both channel modes, so element 0 keeps the colour of the average indirect
   light (a grey mean would push that colour into the basis).
4. **Basis** (snapshot method, paper 4.2). ``A`` holds the mean-subtracted snapshots:
   "mono" stacks the three channels as separate columns, ``A = [In_R − m_R | In_G − m_G |
   In_B − m_B]`` (T × 3K, column ``c·K + k``), one basis for all channels (paper 5.2);
   "rgb" uses one ``A_c = In_c − m_c`` (T × K) and one basis per channel. ``G = AᵀA`` is
   accumulated over blocks of texel rows (memory stays bounded for T ~ 1e6), decomposed with
   ``scipy.linalg.eigh``, eigenvalues sorted descending, those ≤ ``EIG_REL_TOL·e_max``
   dropped (that count is the available rank), and ``U = A V Σ⁻¹`` computed block-wise by
   dividing columns by the singular values ``σ = √e``. Each eigenvector is oriented so that
   its largest-magnitude entry is positive (a deterministic sign). Coefficients
   ``C = UᵀA``.
5. **Transfer** (paper 4.3 eq. 14, ridge). Per channel c (and per keyframe group when
   ``per_group``), with ``Dc = Dn[:, :, c]`` (P × K) and ``Cc`` the coefficients of channel
   c's snapshots (n−1 × K), fit the affine ridge model ``Cc ≈ b 1ᵀ + M Dc``::

       min over M, b of ‖Cc − b 1ᵀ − M Dc‖² + λ‖M‖²      (b is not penalised)

   through the thin SVD of the centred direct matrix ``Dc − d̄ 1ᵀ = Ud diag(σ) Vdᵀ``:
   ``M = (Cc − c̄ 1ᵀ) Vd diag(σ/(σ²+λ)) Udᵀ`` and ``b = c̄ − M d̄``. Singular values
   ≤ ``DIRECT_SVD_REL_TOL·σ_max`` are dropped, so λ → 0 gives the minimum-norm least
   squares solution, never a blow-up. No inverse and no pseudo-inverse of ``D Dᵀ`` is formed.

   Why the offset b: the paper's runtime ``y = s·m + U M x`` with M regressed on the
   mean-subtracted coefficients cannot reproduce even an exactly linear, low-rank transport
   ``y = T x`` for new x, because ``s = ‖x‖`` is not linear in x. The unpenalised intercept
   makes it exact in that case (then ``m + U b = 0``), keeps the paper's structure and
   its truncation property (rows of M and b are independent regressions, so the first n−1
   rows are exactly the n-element fit), and allows one intercept per keyframe with a
   single shared mean. With ``intercept=False`` b = 0 and M is the paper's eq. 14 exactly.

Runtime (what :func:`reconstruct` does, and what an engine must do with a bundle)::

    x  : (P, 3) direct radiance shaded at the measurement points (original units)
    x' = γ(x)                               (identity without gamma)
    s  = ‖x'‖                               (Frobenius over points and channels)
    u_c = M_c x'_c + s · b_c                 (n−1 coefficients, per channel c)
    y'_c = s · m_c + Σ_i u_c,i · U_i         (mono: shared U_i; rgb: U_i,c)
    y  = max(y', 0)^g                       (only with gamma; without gamma y = y' unclamped)

This is positively homogeneous: ``reconstruct(a·x) = a·reconstruct(x)`` for a > 0, with or
without gamma. With gamma, negative gamma-space values are clamped to 0 before the inverse
power (a negative value has no radiance meaning; a sign-preserving inverse would produce
negative radiance). Without gamma nothing is clamped (the result is linear in the data).

The bundle layout this implies: element 0 = ``mean``; elements 1..n−1 = ``basis`` columns;
``transfer`` M (3, n−1, P); ``offset`` b (3, n−1); "16 basis elements" = mean + 15.

λ is absolute, in the units of the normalised (gamma-space) direct data, whose columns
have unit Frobenius norm. ``ridge="auto"`` picks λ from {0} ∪ σ_max²·logspace(−8, 2, 24)
(σ_max: the largest singular value of the centred normalised direct matrices) by exact
closed-form leave-one-out cross-validation of the transfer (basis held fixed).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import scipy.linalg

from prtcore.core.errors import PrtError
from prtcore.core.progress import StageTimer
from prtcore.core.tolerances import DIRECT_SVD_REL_TOL, EIG_REL_TOL, LOO_LEVERAGE_TOL

# ---------------------------------------------------------------------------------------
# Constants (numerical tolerances live in prtcore/tolerances.py)

#: λ grid for ridge="auto", relative to σ_max² (0 is added in front): 25 values.
RIDGE_GRID_REL = tuple(float(v) for v in np.logspace(-8.0, 2.0, 24))
#: basis="auto" without held-out data: smallest n keeping this fraction of the energy
#: (sum of eigenvalues) of the mean-subtracted snapshots.
AUTO_ENERGY = 0.999
#: basis="auto" with held-out data: smallest n whose held-out relative RMSE is within this
#: relative margin of the best.
AUTO_HOLDOUT_MARGIN = 0.01
#: basis="auto" never goes beyond this many elements (mean included): 16 RGBA textures,
#: the top of the DESIGN 5 report table.
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


# ---------------------------------------------------------------------------------------
# Data


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

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of lists/floats/ints/str/None (json.dumps works, strict JSON)."""
        return _jsonable(asdict(self))


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


# ---------------------------------------------------------------------------------------
# Public functions


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


def fit_transfer(
    D: np.ndarray,
    I: np.ndarray,
    basis: int | str = 16,
    ridge: float | str = "auto",
    channels: str = "mono",
    gamma: float | None = None,
    groups: np.ndarray | None = None,
    per_group: bool = False,
    holdout: tuple[np.ndarray, ...] | None = None,
    timer: StageTimer | None = None,
    *,
    intercept: bool = True,
    block_rows: int | None = None,
) -> TransferModel:
    """Fit mean, basis and transfer (module docstring) and return a float32 model.

    D : (P, K, 3) float — direct at the measurement points per configuration
    I : (T, K, 3) float — indirect per texel per configuration (any float dtype; read in
        blocks of texel rows, never copied whole)
    basis : element count n including the mean (≥ 1), or "auto"
    ridge : λ ≥ 0 (absolute, normalised units) or "auto" (leave-one-out CV)
    channels : "mono" (one basis, per-channel transfer) | "rgb" (basis per channel)
    gamma : None or 1 ≤ g ≤ 10 (paper 5.3; fit on sign(v)|v|^(1/g); GAMMA_RANGE)
    groups : (K,) int keyframe ids; one basis for all, transfer shared unless ``per_group``
    per_group : one transfer (and offset) per keyframe id
    holdout : (D_h (P, H, 3), I_h (T, H, 3)[, groups_h (H,)]) — held-out configurations for
        basis="auto" (groups_h required when per_group)
    timer : progress bars over texel blocks (step timings go to ``diagnostics.seconds``)
    intercept : fit the transfer offset b (default; False gives the paper's eq. 14 as is)
    block_rows : texel rows per block (default from BLOCK_BYTES)
    """
    return _fit(D, I, basis, ridge, channels, gamma, groups, per_group, holdout, timer,
                intercept, block_rows, np.float32)


def _fit_transfer64(D: np.ndarray, I: np.ndarray, **kwargs: Any) -> TransferModel:
    """:func:`fit_transfer` keeping every model array in float64 (precision checks)."""
    args = {"basis": 16, "ridge": "auto", "channels": "mono", "gamma": None, "groups": None,
            "per_group": False, "holdout": None, "timer": None, "intercept": True,
            "block_rows": None}
    unknown = set(kwargs) - set(args)
    if unknown:
        raise TypeError(f"_fit_transfer64: unknown arguments {sorted(unknown)}")
    args.update(kwargs)
    return _fit(D, I, args["basis"], args["ridge"], args["channels"], args["gamma"],
                args["groups"], args["per_group"], args["holdout"], args["timer"],
                args["intercept"], args["block_rows"], np.float64)


# ---------------------------------------------------------------------------------------
# Runtime


def reconstruct(
    model: TransferModel, x: np.ndarray, n: int | None = None, group: int | None = None
) -> np.ndarray:
    """Indirect lightmap for direct values ``x``, as an engine computes it.

    x : (P, 3) direct radiance at the measurement points, original (un-normalised) units
    n : basis elements to use, mean included (1 ≤ n ≤ model.n_basis; default all)
    group : keyframe id for a per-group model (ignored by a shared model)
    Returns (T, 3) float32 (computed in float64).
    """
    return _reconstruct64(model, x, n, group).astype(np.float32)


def projection_bound(
    model: TransferModel, I_ref: np.ndarray, x: np.ndarray, n: int | None = None
) -> float:
    """Best relative RMSE any coefficients could reach with this mean and basis.

    The runtime fixes the mean's coefficient to s = ‖γ(x)‖, so the bound projects
    ``γ(I_ref) − s·m`` (least squares, per channel) onto the first n−1 basis vectors, adds
    ``s·m`` back, decodes gamma (clamped, as at runtime) and returns
    ``relative_rmse(that, I_ref)``.

    I_ref : (T, 3) reference indirect; x : (P, 3) its direct vector; n as in reconstruct.
    """
    nb = _resolve_n(model, n)
    I_ref = np.asarray(I_ref)
    if I_ref.shape != (model.texels, 3):
        raise ValueError(f"projection_bound: I_ref shape {I_ref.shape}, "
                         f"expected ({model.texels}, 3)")
    s = _direct_norm(model, x)
    mono = model.channels == "mono"
    rows = _default_rows(8 * (nb + 1) * 4, None)
    ncol = 1 if mono else 3
    gram = np.zeros((ncol, nb, nb))
    proj = np.zeros((3, nb))
    for sl in _blocks(model.texels, rows):
        r = gamma_encode(I_ref[sl], model.gamma) - s * model.mean[sl].astype(np.float64)
        ub = model.basis[sl, :nb].astype(np.float64)
        if mono:
            gram[0] += ub.T @ ub
            proj += (ub.T @ r).T
        else:
            for c in range(3):
                gram[c] += ub[:, :, c].T @ ub[:, :, c]
                proj[c] += ub[:, :, c].T @ r[:, c]
    coef = np.zeros((3, nb))
    for c in range(3):
        g = gram[0 if mono else c]
        if nb:
            coef[c] = scipy.linalg.lstsq(g, proj[c])[0]
    num = 0.0
    den = 0.0
    for sl in _blocks(model.texels, rows):
        y = _blend(model, sl, s, coef, nb)
        ref = np.asarray(I_ref[sl], dtype=np.float64)
        num += float(np.sum((y - ref) ** 2))
        den += float(np.sum(ref**2))
    if den == 0.0:
        return 0.0 if num == 0.0 else float("inf")
    return float(np.sqrt(num / den))


def _reconstruct64(model: TransferModel, x: np.ndarray, n: int | None = None,
                   group: int | None = None) -> np.ndarray:
    """:func:`reconstruct` in float64 (the model's arrays are promoted): (T, 3) float64."""
    nb = _resolve_n(model, n)
    M, b = _group_transfer(model, group)
    xg = _check_x(model, x)
    s = float(np.linalg.norm(xg))
    u = np.einsum("cip,pc->ci", M[:, :nb].astype(np.float64), xg) \
        + s * b[:, :nb].astype(np.float64)
    out = np.empty((model.texels, 3))
    rows = _default_rows(8 * (nb + 4) * 3, None)
    for sl in _blocks(model.texels, rows):
        out[sl] = _blend(model, sl, s, u, nb)
    return out


# ---------------------------------------------------------------------------------------
# Internals: runtime helpers


def _resolve_n(model: TransferModel, n: int | None) -> int:
    if n is None:
        return model.n_basis - 1
    n = int(n)
    if not 1 <= n <= model.n_basis:
        raise ValueError(f"basis element count n={n} outside 1..{model.n_basis}")
    return n - 1


def _group_transfer(model: TransferModel, group: int | None) -> tuple[np.ndarray, np.ndarray]:
    if model.group_ids is None:
        return model.transfer, model.offset
    if group is None:
        raise ValueError("model has one transfer per keyframe group: pass group=<keyframe id>")
    try:
        g = model.group_ids.index(int(group))
    except ValueError:
        raise ValueError(f"keyframe group {group} not in the model's groups "
                         f"{list(model.group_ids)}") from None
    return model.transfer[g], model.offset[g]


def _check_x(model: TransferModel, x: np.ndarray) -> np.ndarray:
    x = np.asarray(x)
    if x.shape != (model.points, 3):
        raise ValueError(f"direct vector x shape {x.shape}, expected ({model.points}, 3)")
    return gamma_encode(x, model.gamma)


def _direct_norm(model: TransferModel, x: np.ndarray) -> float:
    return float(np.linalg.norm(_check_x(model, x)))


def _blend(model: TransferModel, sl: slice, s: float, u: np.ndarray, nb: int) -> np.ndarray:
    """Rows ``sl`` of γ⁻¹(s·m + Σ u_i U_i): (rows, 3) float64; u (3, ≥nb) float64."""
    y = s * model.mean[sl].astype(np.float64)
    ub = model.basis[sl, :nb].astype(np.float64)
    if model.channels == "mono":
        y += ub @ u[:, :nb].T
    else:
        y += np.einsum("tic,ci->tc", ub, u[:, :nb])
    return gamma_decode(y, model.gamma)


def _blocks(total: int, rows: int) -> Iterator[slice]:
    for start in range(0, total, rows):
        yield slice(start, min(start + rows, total))


def _default_rows(bytes_per_row: int, block_rows: int | None) -> int:
    if block_rows is not None:
        return max(1, int(block_rows))
    return max(1, BLOCK_BYTES // max(1, bytes_per_row))


def _jsonable(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _jsonable(w) for k, w in v.items()}
    if isinstance(v, list | tuple):
        return [_jsonable(w) for w in v]
    if isinstance(v, np.ndarray):
        return [_jsonable(w) for w in v.tolist()]
    if isinstance(v, bool | np.bool_):
        return bool(v)
    if isinstance(v, int | np.integer):
        return int(v)
    if isinstance(v, float | np.floating):
        f = float(v)
        return f if np.isfinite(f) else None
    return v


# ---------------------------------------------------------------------------------------
# Internals: ridge transfer through the SVD of the direct matrix


@dataclass(frozen=True)
class _DirectSVD:
    """Thin SVD of one (centred) normalised direct matrix, kept singular triplets only.

    u : (P, r); s : (r,); vt : (r, K); dbar : (P,) column mean (zeros without intercept);
    s_all : every singular value (descending); k : K; intercept : bool
    """

    u: np.ndarray
    s: np.ndarray
    vt: np.ndarray
    dbar: np.ndarray
    s_all: np.ndarray
    k: int
    intercept: bool


def _direct_svd(D: np.ndarray, intercept: bool) -> _DirectSVD:
    """D : (P, K) float64 normalised direct of one channel (one group)."""
    D = np.asarray(D, dtype=np.float64)
    k = D.shape[1]
    dbar = D.mean(axis=1) if intercept else np.zeros(D.shape[0])
    Dc = D - dbar[:, None]
    if Dc.size == 0:
        empty = np.zeros((D.shape[0], 0))
        return _DirectSVD(empty, np.zeros(0), np.zeros((0, k)), dbar, np.zeros(0), k, intercept)
    try:
        u, s, vt = scipy.linalg.svd(Dc, full_matrices=False, lapack_driver="gesdd")
    except np.linalg.LinAlgError:
        u, s, vt = scipy.linalg.svd(Dc, full_matrices=False, lapack_driver="gesvd")
    keep = s > DIRECT_SVD_REL_TOL * s[0] if s.size and s[0] > 0 else np.zeros(s.size, bool)
    return _DirectSVD(u[:, keep], s[keep], vt[keep], dbar, s, k, intercept)


def _centre(svd: _DirectSVD, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    cbar = C.mean(axis=1) if svd.intercept else np.zeros(C.shape[0])
    return C - cbar[:, None], cbar


def _ridge_solve(svd: _DirectSVD, C: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """Ridge transfer for coefficients C (m, K): returns M (m, P) and offset b (m,).

    M = (C − c̄1ᵀ) V diag(σ/(σ²+λ)) Uᵀ, b = c̄ − M d̄ (b = 0 without intercept).
    """
    Cc, cbar = _centre(svd, C)
    f = svd.s / (svd.s**2 + lam)
    M = ((Cc @ svd.vt.T) * f) @ svd.u.T
    b = cbar - M @ svd.dbar if svd.intercept else np.zeros(C.shape[0])
    return M, b


def _loo_sse(svd: _DirectSVD, C: np.ndarray, lams: np.ndarray) -> np.ndarray:
    """Exact leave-one-out squared residuals of the ridge transfer, per row of C and λ.

    C : (m, K); lams : (L,). The fit is a linear smoother with hat matrix
    H = 11ᵀ/K + V diag(σ²/(σ²+λ)) Vᵀ (no 11ᵀ/K term without intercept); the LOO residual
    of configuration k is e_k/(1 − h_kk). Returns (m, L) float64; +inf where some
    1 − h_kk ≤ LOO_LEVERAGE_TOL.
    """
    Cc, _ = _centre(svd, C)
    Z = Cc @ svd.vt.T
    v2 = svd.vt**2
    base = 1.0 / svd.k if svd.intercept else 0.0
    out = np.empty((C.shape[0], len(lams)))
    for j, lam in enumerate(lams):
        phi = svd.s**2 / (svd.s**2 + lam) if svd.s.size else np.zeros(0)
        E = Cc - (Z * phi) @ svd.vt
        denom = 1.0 - (base + phi @ v2)
        if np.any(denom <= LOO_LEVERAGE_TOL):
            out[:, j] = np.inf
        else:
            out[:, j] = np.sum((E / denom) ** 2, axis=1)
    return out


# ---------------------------------------------------------------------------------------
# Internals: the fit


def _fit(D, I, basis, ridge, channels, gamma, groups, per_group, holdout, timer,
         intercept, block_rows, out_dtype) -> TransferModel:
    seconds: dict[str, float] = {}
    warnings: list[str] = []
    t0 = time.perf_counter()

    # -- validate --------------------------------------------------------------------
    D = np.asarray(D)
    if D.ndim != 3 or D.shape[2] != 3:
        raise ValueError(f"fit: D must be (P, K, 3), got {D.shape}")
    if not hasattr(I, "shape") or len(I.shape) != 3 or I.shape[2] != 3:
        raise ValueError(f"fit: I must be (T, K, 3), got {getattr(I, 'shape', None)}")
    P, K, _ = D.shape
    T = int(I.shape[0])
    if I.shape[1] != K:
        raise ValueError(f"fit: D has {K} configurations but I has {I.shape[1]}")
    if channels not in ("mono", "rgb"):
        raise ValueError(f"fit: channels must be 'mono' or 'rgb', got {channels!r}")
    if basis != "auto" and (isinstance(basis, bool) or not isinstance(basis, int | np.integer)
                            or basis < 1):
        raise ValueError(f"fit: basis must be an int ≥ 1 or 'auto', got {basis!r}")
    if ridge != "auto" and (isinstance(ridge, bool | str) or not np.isfinite(ridge)
                            or ridge < 0):
        raise ValueError(f"fit: ridge must be a float ≥ 0 or 'auto', got {ridge!r}")
    if gamma is not None and not (np.isfinite(gamma) and GAMMA_RANGE[0] <= gamma
                                  <= GAMMA_RANGE[1]):
        raise ValueError(f"fit: gamma must be None or in [{GAMMA_RANGE[0]:g}, "
                         f"{GAMMA_RANGE[1]:g}], got {gamma!r}")
    gamma = None if gamma is None else float(gamma)
    if per_group and groups is None:
        raise ValueError("fit: per_group=True needs groups")
    if groups is not None:
        groups = np.asarray(groups)
        if groups.shape != (K,) or not np.issubdtype(groups.dtype, np.integer):
            raise ValueError(f"fit: groups must be (K,) = ({K},) int, got {groups.shape} "
                             f"{groups.dtype}")
    mono = channels == "mono"

    # -- exclusion and normalisation ---------------------------------------------------
    Dg = gamma_encode(D, gamma)
    with np.errstate(over="ignore", invalid="ignore"):
        s = np.sqrt(np.sum(Dg**2, axis=(0, 2)))
    i_finite = np.ones(K, dtype=bool)
    for sl in _blocks(T, _default_rows(K * 3 * 4, block_rows)):
        i_finite &= np.isfinite(I[sl]).all(axis=(0, 2))
    excluded = []
    for k in range(K):
        if not np.isfinite(s[k]):
            excluded.append({"index": k, "reason": "non-finite direct"})
        elif s[k] == 0.0:
            excluded.append({"index": k, "reason": "zero direct"})
        elif not i_finite[k]:
            excluded.append({"index": k, "reason": "non-finite indirect"})
    keep = np.array(sorted(set(range(K)) - {e["index"] for e in excluded}), dtype=np.intp)
    Kk = len(keep)
    if excluded:
        warnings.append(f"{len(excluded)} of {K} configurations excluded "
                        "(zero or non-finite direct, or non-finite indirect)")
    if Kk < (2 if intercept else 1):
        raise PrtError(f"fit: only {Kk} usable lighting configurations of {K} "
                       "(zero or non-finite direct/indirect)")
    all_kept = Kk == K
    sk = s[keep]
    Dn = Dg[:, keep, :] / sk[None, :, None]  # (P, Kk, 3)

    gk = None if groups is None else groups[keep]
    if per_group:
        group_ids = tuple(int(g) for g in np.unique(gk))
        group_idx = [np.flatnonzero(gk == g) for g in group_ids]
        small = [g for g, idx in zip(group_ids, group_idx, strict=True)
                 if len(idx) < (2 if intercept else 1)]
        if small:
            raise PrtError(f"fit: keyframe groups {small} have too few usable configurations "
                           "for a per-group transfer (need ≥ 2)")
    else:
        group_ids = None
        group_idx = [np.arange(Kk)]
    groups_diag = None
    if groups is not None:
        lost = sorted(set(np.unique(groups).tolist()) - set(np.unique(gk).tolist()))
        if lost:
            warnings.append(f"keyframe groups {lost} lost every configuration to exclusion")
        ids, counts = np.unique(gk, return_counts=True)
        groups_diag = {"ids": [int(i) for i in ids], "counts": [int(c) for c in counts]}

    unlit = np.flatnonzero(np.all(Dn == 0.0, axis=(1, 2)))
    if unlit.size:
        warnings.append(f"{unlit.size} measurement points are lit by no configuration")
    k_eff = Kk - 1 if intercept else Kk
    if P > k_eff:
        warnings.append(UNDERDETERMINED_WARNING)

    def snapshots(sl: slice) -> tuple[np.ndarray, np.ndarray, float]:
        """Rows sl: mean (rows, 3), centred snapshots (rows, 3, Kk), Σ In²."""
        blk = np.asarray(I[sl])
        X = np.array((blk if all_kept else blk[:, keep, :]).transpose(0, 2, 1),
                     dtype=np.float64, order="C")  # (rows, 3, Kk)
        if gamma is not None:
            X = gamma_encode(X, gamma)
        X /= sk[None, None, :]
        ss = float(np.einsum("ijk,ijk->", X, X))
        mb = X.mean(axis=2)
        X -= mb[:, :, None]
        return mb, X, ss

    rows = _default_rows(8 * 3 * Kk * 3, block_rows)
    nblocks = -(-T // rows)

    def bar(it, desc):
        return timer.bar(it, desc=desc, total=nblocks) if timer is not None else it

    # -- pass 1: mean and Gram matrix ---------------------------------------------------
    t1 = time.perf_counter()
    mean = np.empty((T, 3))
    gram = np.zeros((3 * Kk, 3 * Kk)) if mono else np.zeros((3, Kk, Kk))
    total_ss = 0.0
    for sl in bar(_blocks(T, rows), "fit: gram"):
        mb, Xt, ss = snapshots(sl)
        mean[sl] = mb
        total_ss += ss
        if mono:
            A = Xt.reshape(Xt.shape[0], 3 * Kk)
            gram += A.T @ A
        else:
            for c in range(3):
                Ac = Xt[:, c, :]
                gram[c] += Ac.T @ Ac
    seconds["gram"] = time.perf_counter() - t1

    # -- eigen-decomposition -------------------------------------------------------------
    t1 = time.perf_counter()
    eig = []  # per basis (1 mono, 3 rgb): (eigenvalues desc, eigenvectors, rank)
    for g in [gram] if mono else list(gram):
        e, V = scipy.linalg.eigh(g)
        e = np.maximum(e[::-1], 0.0)
        V = V[:, ::-1]
        flip = V[np.argmax(np.abs(V), axis=0), np.arange(V.shape[1])] < 0
        V[:, flip] *= -1.0
        rank = int(np.sum(e > EIG_REL_TOL * e[0])) if e.size and e[0] > 0 else 0
        eig.append((e, V, rank))
    del gram
    rank_avail = max(r for _, _, r in eig)
    if basis == "auto":
        nb_max = min(AUTO_BASIS_MAX - 1, rank_avail)
    else:
        nb_max = min(int(basis) - 1, rank_avail)
        if nb_max < int(basis) - 1:
            warnings.append(f"basis count {int(basis)} capped at {nb_max + 1}: the indirect "
                            f"data has rank {rank_avail} after mean subtraction")
    e_total = sum(float(np.sum(e)) for e, _, _ in eig)
    e_cum = np.zeros(nb_max + 1)
    for e, _, _ in eig:
        e_cum[1:] += np.cumsum(e[:nb_max])
    energy_curve = e_cum / e_total if e_total > 0 else np.ones(nb_max + 1)
    seconds["eigen"] = time.perf_counter() - t1

    # -- pass 2: basis U = A V Σ⁻¹ and coefficients C = UᵀA -----------------------------
    t1 = time.perf_counter()
    W = []
    for e, V, rank in eig:
        w = np.zeros((V.shape[0], nb_max))
        r = min(rank, nb_max)
        w[:, :r] = V[:, :r] / np.sqrt(e[:r])
        W.append(w)
    basis_arr = np.empty((T, nb_max) if mono else (T, nb_max, 3), dtype=out_dtype)
    coef = np.zeros((nb_max, 3 * Kk)) if mono else np.zeros((3, nb_max, Kk))
    if nb_max:
        for sl in bar(_blocks(T, rows), "fit: basis"):
            _, Xt, _ = snapshots(sl)
            if mono:
                A = Xt.reshape(Xt.shape[0], 3 * Kk)
                Ub = A @ W[0]
                coef += Ub.T @ A
                basis_arr[sl] = Ub
            else:
                for c in range(3):
                    Ub = Xt[:, c, :] @ W[c]
                    coef[c] += Ub.T @ Xt[:, c, :]
                    basis_arr[sl, :, c] = Ub
    C = coef.reshape(nb_max, 3, Kk).transpose(1, 0, 2) if mono else coef  # (3, nb, Kk)
    seconds["basis"] = time.perf_counter() - t1

    # -- transfer: SVD of the direct matrices, λ by LOO ---------------------------------
    t1 = time.perf_counter()
    svds = [[_direct_svd(Dn[:, idx, c], intercept) for c in range(3)] for idx in group_idx]
    shared_svds = svds[0] if not per_group else [_direct_svd(Dn[:, :, c], intercept)
                                                 for c in range(3)]
    smax = max((float(sv.s_all[0]) for row in svds for sv in row if sv.s_all.size),
               default=0.0)
    grid = np.array(sorted({0.0, *(smax**2 * r for r in RIDGE_GRID_REL)}))
    loo = np.zeros((nb_max, len(grid)))
    for row, idx in zip(svds, group_idx, strict=True):
        for c in range(3):
            if nb_max:
                loo += _loo_sse(row[c], C[c][:, idx], grid)
    # λ is chosen on every fitted row (the given n, or all candidates for basis="auto");
    # the energy outside the basis is the same for every λ and makes cv a relative RMSE.
    tail = max(e_total - float(e_cum[nb_max]), 0.0)
    cv_sse = loo.sum(axis=0) + tail
    cv = np.sqrt(cv_sse / total_ss) if total_ss > 0 else np.zeros(len(grid))
    if ridge == "auto":
        finite = np.isfinite(cv)
        lam = float(grid[np.flatnonzero(finite)[np.argmin(cv[finite])]]) if finite.any() \
            else float(grid[-1])
        ridge_method = "loo"
    else:
        lam = float(ridge)
        ridge_method = "given"

    G = len(group_idx)
    M = np.zeros((G, 3, nb_max, P))
    b = np.zeros((G, 3, nb_max))
    for g, (row, idx) in enumerate(zip(svds, group_idx, strict=True)):
        for c in range(3):
            M[g, c], b[g, c] = _ridge_solve(row[c], C[c][:, idx], lam)
    seconds["transfer"] = time.perf_counter() - t1

    # -- basis count ---------------------------------------------------------------------
    t1 = time.perf_counter()
    holdout_curve = None
    holdout_used = 0
    if holdout is not None:
        holdout_curve, holdout_used = _holdout_curve(
            mean, basis_arr, M, b, gamma, mono, holdout, group_ids, P, T, block_rows)
    if basis != "auto":
        nb = nb_max
        n_method = "capped" if nb < int(basis) - 1 else "given"
    elif holdout_curve is not None and holdout_used and np.isfinite(holdout_curve).all():
        best = float(np.min(holdout_curve))
        nb = int(np.flatnonzero(holdout_curve <= best * (1.0 + AUTO_HOLDOUT_MARGIN))[0])
        n_method = "holdout"
    else:
        reach = np.flatnonzero(energy_curve >= AUTO_ENERGY)
        nb = int(reach[0]) if reach.size else nb_max
        n_method = "energy"
        if not reach.size:
            warnings.append(f"basis='auto' capped at {nb_max + 1} elements: energy kept "
                            f"{energy_curve[-1]:.6f} < {AUTO_ENERGY}")
    seconds["select"] = time.perf_counter() - t1

    # -- assemble ------------------------------------------------------------------------
    direct_sv = tuple(tuple(float(v) for v in sv.s_all) for sv in shared_svds)
    cond: list[float | None] = []
    eff: list[int] = []
    for sv in shared_svds:
        sa = sv.s_all
        eff.append(int(np.sum(sa > DIRECT_SVD_REL_TOL * sa[0])) if sa.size and sa[0] > 0
                   else 0)
        ok = sa.size and sa[0] > 0 and sa[-1] > DIRECT_SVD_REL_TOL * sa[0]
        cond.append(float(sa[0] / sa[-1]) if ok else None)
    full_rank = min(P, k_eff)
    if full_rank and min(eff) < full_rank:
        warnings.append(f"direct matrix rank-deficient: effective rank {min(eff)} < "
                        f"{full_rank} (coincident or nearly collinear measurement points, "
                        f"or near-duplicate lights); transfer is the minimum-norm solution "
                        f"on the {min(eff)} well-determined directions")
    seconds["total"] = time.perf_counter() - t0
    diag = FitDiagnostics(
        configurations=K,
        used=Kk,
        excluded=tuple(excluded),
        channels=channels,
        gamma=gamma,
        intercept=intercept,
        direct_singular_values=direct_sv,
        direct_condition=tuple(cond),
        direct_effective_rank=tuple(eff),
        indirect_singular_values=tuple(tuple(float(v) for v in np.sqrt(e)) for e, _, _ in eig),
        indirect_rank=rank_avail,
        n_basis=nb + 1,
        n_basis_requested=basis if basis == "auto" else int(basis),
        n_basis_method=n_method,
        energy_kept=float(energy_curve[nb]),
        energy_curve=tuple(float(v) for v in energy_curve),
        holdout_rmse=None if holdout_curve is None else tuple(float(v) for v in holdout_curve),
        holdout_used=holdout_used,
        ridge=lam,
        ridge_method=ridge_method,
        ridge_grid=tuple(float(v) for v in grid),
        ridge_cv=tuple(float(v) if np.isfinite(v) else None for v in cv),
        groups=groups_diag,
        unlit_points=tuple(int(p) for p in unlit),
        warnings=tuple(warnings),
        seconds=seconds,
    )
    transfer = M[:, :, :nb] if per_group else M[0, :, :nb]
    offset = b[:, :, :nb] if per_group else b[0, :, :nb]
    return TransferModel(
        mean=mean.astype(out_dtype),
        basis=np.ascontiguousarray(basis_arr[:, :nb]) if nb < nb_max else basis_arr,
        transfer=np.ascontiguousarray(transfer, dtype=out_dtype),
        offset=np.ascontiguousarray(offset, dtype=out_dtype),
        gamma=gamma,
        channels=channels,
        ridge=lam,
        group_ids=group_ids,
        diagnostics=diag,
    )


def _holdout_curve(mean, basis_arr, M, b, gamma, mono, holdout, group_ids, P, T,
                   block_rows) -> tuple[np.ndarray, int]:
    """Held-out relative RMSE (stacked over configurations, linear units) for n = 1..nb+1.

    Returns (nb_max + 1,) float64 and the number of held-out configurations used.
    """
    if len(holdout) not in (2, 3):
        raise ValueError("fit: holdout must be (D_h, I_h) or (D_h, I_h, groups_h)")
    Dh = np.asarray(holdout[0])
    Ih = holdout[1]
    H = Dh.shape[1] if Dh.ndim == 3 else -1
    if Dh.shape != (P, H, 3) or tuple(Ih.shape) != (T, H, 3):
        raise ValueError(f"fit: holdout shapes {Dh.shape}, {tuple(Ih.shape)}; expected "
                         f"({P}, H, 3) and ({T}, H, 3)")
    if group_ids is not None:
        if len(holdout) != 3:
            raise ValueError("fit: per-group fit needs holdout groups (D_h, I_h, groups_h)")
        gh = np.asarray(holdout[2])
        unknown = sorted(set(gh.tolist()) - set(group_ids))
        if unknown:
            raise ValueError(f"fit: holdout groups {unknown} not among fitted groups")
        gidx = np.array([group_ids.index(int(g)) for g in gh], dtype=np.intp)
    else:
        gidx = np.zeros(H, dtype=np.intp)
    xg = gamma_encode(Dh, gamma)
    with np.errstate(over="ignore", invalid="ignore"):
        s = np.sqrt(np.sum(xg**2, axis=(0, 2)))
    ok = np.isfinite(s)
    for sl in _blocks(T, _default_rows(H * 3 * 4, block_rows)):
        ok &= np.isfinite(np.asarray(Ih[sl])).all(axis=(0, 2))
    use = np.flatnonzero(ok)
    nb = M.shape[2]
    u = np.einsum("hcip,phc->hci", M[gidx[use]], xg[:, use, :]) \
        + s[use, None, None] * b[gidx[use]]  # (H, 3, nb)
    sse = np.zeros(nb + 1)
    ref_ss = 0.0
    su = s[use]
    if gamma is None:
        # Linear: ‖r − U_n u_n‖² = ‖r‖² − 2 u_n·p_n + u_nᵀ B_n u_n with r = I_h − s·m,
        # p = Uᵀr, B = UᵀU (exact for any U), accumulated over blocks; prefix sums give
        # every n at once without forming T × H × 3 × n arrays.
        nbasis = 1 if mono else 3
        B = np.zeros((nbasis, nb, nb))
        p = np.zeros((len(use), 3, nb))
        rr = np.zeros((len(use), 3))
        rows = _default_rows(8 * (len(use) * 3 * 3 + 3 * nb), block_rows)
        for sl in _blocks(T, rows):
            ref = np.asarray(Ih[sl])[:, use, :].astype(np.float64)
            ref_ss += float(np.sum(ref**2))
            r = ref - su[None, :, None] * mean[sl][:, None, :]  # (rows, H, 3)
            rr += np.sum(r**2, axis=0)
            ub = basis_arr[sl].astype(np.float64)
            if mono:
                B[0] += ub.T @ ub
                p += (ub.T @ r.reshape(r.shape[0], -1)).reshape(nb, -1, 3).transpose(1, 2, 0)
            else:
                for c in range(3):
                    B[c] += ub[:, :, c].T @ ub[:, :, c]
                    p[:, c] += (ub[:, :, c].T @ r[:, :, c]).T
        Bc = np.stack([B[0]] * 3) if mono else B  # (3, nb, nb)
        lower = np.tril(Bc, -1)
        diag = np.diagonal(Bc, axis1=1, axis2=2)  # (3, nb)
        step = u * (2.0 * np.einsum("cij,hcj->hci", lower, u) + diag[None] * u) - 2.0 * u * p
        sse[0] = float(np.sum(rr))
        sse[1:] = sse[0] + np.cumsum(np.sum(step, axis=(0, 1)))
        sse = np.maximum(sse, 0.0)
    else:
        rows = _default_rows(8 * len(use) * 3 * (nb + 1) * 3, block_rows)
        for sl in _blocks(T, rows):
            y0 = su[None, :, None] * mean[sl][:, None, :]  # (rows, H, 3)
            ub = basis_arr[sl].astype(np.float64)
            contrib = np.einsum("ti,hci->thci", ub, u) if mono else \
                np.einsum("tic,hci->thci", ub, u)
            Y = np.concatenate([y0[..., None], y0[..., None] + np.cumsum(contrib, axis=3)],
                               axis=3)
            Y = gamma_decode(Y, gamma)
            ref = np.asarray(Ih[sl])[:, use, :].astype(np.float64)
            sse += np.sum((Y - ref[..., None]) ** 2, axis=(0, 1, 2))
            ref_ss += float(np.sum(ref**2))
    if ref_ss == 0.0:
        return np.where(sse == 0.0, 0.0, np.inf), len(use)
    return np.sqrt(sse / ref_ss), len(use)
