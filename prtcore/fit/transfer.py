"""Fit: direct vectors D and indirect lightmaps I → mean, basis U_n, ridge transfer M_n.

The steps live in their own modules: :mod:`~prtcore.fit.normalise` (1–2),
:mod:`~prtcore.fit.basis` (3–4), the transfer regressor (5; :mod:`~prtcore.fit.ridge`,
registered in :mod:`~prtcore.fit.regressor`) and :mod:`~prtcore.fit.select` (basis count);
this module runs them (:func:`fit_transfer`) and holds the model-side runtime.

Data-driven PRT, Belcour et al. 2022, sections 3–5.

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
    u  += s · r(x'/s)                       (fit.transfer "mlp" only: prtcore.fit.mlp)
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
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from prtcore.core.mlp import transfer_residual, transfer_rows
from prtcore.core.progress import StageTimer
from prtcore.core.tolerances import DIRECT_SVD_REL_TOL
from prtcore.fit.basis import snapshot_basis
from prtcore.fit.model import (
    FitDiagnostics,
    TransferModel,
    blocks,
    default_rows,
    gamma_decode,
    gamma_encode,
)
from prtcore.fit.normalise import check_arguments, normalise
from prtcore.fit.regressor import regressor
from prtcore.fit.select import select_basis_count

# ---------------------------------------------------------------------------------------
# Public functions


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
    transfer: str = "ridge",
    transfer_options: Mapping[str, Any] | None = None,
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
    transfer : the transfer regressor ("ridge" | "mlp", :mod:`prtcore.fit.regressor`)
    transfer_options : the regressor's own options (mlp: :data:`prtcore.fit.mlp.DEFAULTS`)
    """
    return _fit(D, I, basis, ridge, channels, gamma, groups, per_group, holdout, timer,
                intercept, block_rows, np.float32, transfer, transfer_options)


def fit_transfer64(D: np.ndarray, I: np.ndarray, **kwargs: Any) -> TransferModel:
    """:func:`fit_transfer` keeping every model array in float64 (precision checks)."""
    args = {"basis": 16, "ridge": "auto", "channels": "mono", "gamma": None, "groups": None,
            "per_group": False, "holdout": None, "timer": None, "intercept": True,
            "block_rows": None, "transfer": "ridge", "transfer_options": None}
    unknown = set(kwargs) - set(args)
    if unknown:
        raise TypeError(f"fit_transfer64: unknown arguments {sorted(unknown)}")
    args.update(kwargs)
    return _fit(D, I, args["basis"], args["ridge"], args["channels"], args["gamma"],
                args["groups"], args["per_group"], args["holdout"], args["timer"],
                args["intercept"], args["block_rows"], np.float64, args["transfer"],
                args["transfer_options"])


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
    return reconstruct64(model, x, n, group).astype(np.float32)


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
    rows = default_rows(8 * (nb + 1) * 4, None)
    ncol = 1 if mono else 3
    gram = np.zeros((ncol, nb, nb))
    proj = np.zeros((3, nb))
    for sl in blocks(model.texels, rows):
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
    for sl in blocks(model.texels, rows):
        y = _blend(model, sl, s, coef, nb)
        ref = np.asarray(I_ref[sl], dtype=np.float64)
        num += float(np.sum((y - ref) ** 2))
        den += float(np.sum(ref**2))
    if den == 0.0:
        return 0.0 if num == 0.0 else float("inf")
    return float(np.sqrt(num / den))


@dataclass(frozen=True)
class HeldoutErrors:
    """Squared errors of many held-out configurations at several basis sizes, from one pass
    over the texels (:func:`heldout_errors`). H configurations, N sizes.

    ns : (N,) the element counts n (mean included), ascending
    sse : (N, H) float64 ``‖reconstruct(x_h, n) − ref_h‖²`` (Frobenius, float64)
    bound_sse : (N, H) float64 the same for the projection of ref_h onto the first n
        elements (what :func:`projection_bound` squares, times ``ref_ss``)
    ref_ss : (H,) float64 ``‖ref_h‖²``
    negative : (N, H) float64 fraction of texels with a negative channel in the
        reconstruction
    """

    ns: tuple[int, ...]
    sse: np.ndarray
    bound_sse: np.ndarray
    ref_ss: np.ndarray
    negative: np.ndarray


def heldout_errors(model: TransferModel, X: np.ndarray, R: np.ndarray, ns,
                   groups: np.ndarray | None = None, block_rows: int | None = None
                   ) -> HeldoutErrors:
    """:func:`reconstruct` and :func:`projection_bound` for H configurations and N basis
    sizes at once: one pass over blocks of texel rows (two with gamma), each size's
    reconstruction the previous one plus its new elements.

    X : (P, H, 3) direct vectors; R : (T, H, 3) reference indirect; ns : element counts
    (1 ≤ n ≤ model.n_basis); groups : (H,) keyframe id of each configuration (per-group
    models). Numbers equal the one-configuration functions' up to float64 round-off
    (:func:`reconstruct` rounds to float32 first; here everything stays float64). Without
    gamma both errors are closed-form, ``‖r‖² − 2cᵀp + cᵀGc`` with ``r = ref − s·m``,
    ``p = Uᵀr``, ``G = UᵀU`` (U the basis) and c the least-squares coefficients (the
    projection) or the runtime's (the reconstruction); the pass over the texels then only
    counts negative texels.
    """
    ns = tuple(sorted(int(n) for n in ns))
    nbs = [_resolve_n(model, n) for n in ns]
    nb_max = max(nbs, default=0)
    X = np.asarray(X)
    H, T = X.shape[1], model.texels
    if R.shape != (T, H, 3):
        raise ValueError(f"heldout_errors: R shape {R.shape}, expected ({T}, {H}, 3)")
    mono = model.channels == "mono"
    s = np.zeros(H)
    U = np.zeros((nb_max, H, 3))  # the runtime coefficients u of each configuration
    for h in range(H):
        s[h], u = coefficients(model, X[:, h], nb_max + 1,
                               None if groups is None else int(groups[h]))
        U[:, h] = u.T
    N = len(ns)
    sse, neg = np.zeros((N, H)), np.zeros((N, H))
    ref_ss, r_ss = np.zeros(H), np.zeros(H)
    gram = np.zeros((1 if mono else 3, nb_max, nb_max))
    proj = np.zeros((nb_max, H, 3))
    rows = default_rows(8 * (6 * 3 * H + 2 * nb_max + 8), block_rows)

    def expand(ub, coef, a, b):  # Σ_{a ≤ i < b} coef_i U_i: (rows, H, 3)
        if mono:
            return (ub[:, a:b] @ coef[a:b].reshape(b - a, 3 * H)).reshape(len(ub), H, 3)
        return np.einsum("tic,ihc->thc", ub[:, a:b], coef[a:b])

    for sl in blocks(T, rows):
        ub = model.basis[sl, :nb_max].astype(np.float64)
        ref = np.asarray(R[sl], dtype=np.float64)
        sm = s[None, :, None] * model.mean[sl].astype(np.float64)[:, None, :]
        r = gamma_encode(ref, model.gamma) - sm
        ref_ss += np.einsum("thc,thc->h", ref, ref)
        r_ss += np.einsum("thc,thc->h", r, r)
        if mono:
            gram[0] += ub.T @ ub
            proj += (ub.T @ r.reshape(len(r), -1)).reshape(nb_max, H, 3)
        else:
            gram += np.einsum("tic,tjc->cij", ub, ub)
            proj += np.einsum("tic,thc->ihc", ub, r)
        y, done = sm, 0
        for i, nb in enumerate(nbs):
            if nb > done:
                y = y + expand(ub, U, done, nb)
                done = nb
            if model.gamma is None:  # the errors are closed-form (below); count negatives
                low = np.minimum(np.minimum(y[..., 0], y[..., 1]), y[..., 2])
                neg[i] += np.count_nonzero(low < 0, axis=0)
                continue
            rec = gamma_decode(y, model.gamma)
            d = rec - ref
            sse[i] += np.einsum("thc,thc->h", d, d)
            neg[i] += (rec < 0).any(axis=2).sum(axis=0)

    coef = np.zeros((N, nb_max, H, 3))  # least-squares coefficients of each size
    for i, nb in enumerate(nbs):
        for c in range(3):
            if nb:
                coef[i, :nb, :, c] = scipy.linalg.lstsq(gram[0 if mono else c][:nb, :nb],
                                                        proj[:nb, :, c])[0]
    bound = np.zeros((N, H))
    if model.gamma is None:
        def closed(c, nb):  # ‖r − U_b c‖² for coefficients c (nb, H, 3)
            gc = (np.einsum("ij,jhc->ihc", gram[0, :nb, :nb], c) if mono
                  else np.einsum("cij,jhc->ihc", gram[:, :nb, :nb], c))
            return np.maximum(r_ss - np.einsum("ihc,ihc->h", c, 2 * proj[:nb] - gc), 0.0)

        for i, nb in enumerate(nbs):
            bound[i] = closed(coef[i, :nb], nb)
            sse[i] = closed(U[:nb], nb)  # the runtime's coefficients: its reconstruction
    else:  # the projection decoded through gamma, as at run time: a second pass
        for sl in blocks(T, rows):
            ub = model.basis[sl, :nb_max].astype(np.float64)
            ref = np.asarray(R[sl], dtype=np.float64)
            sm = s[None, :, None] * model.mean[sl].astype(np.float64)[:, None, :]
            for i, nb in enumerate(nbs):
                d = gamma_decode(sm + expand(ub, coef[i], 0, nb), model.gamma) - ref
                bound[i] += np.einsum("thc,thc->h", d, d)
    return HeldoutErrors(ns=ns, sse=sse, bound_sse=bound, ref_ss=ref_ss,
                         negative=neg / max(T, 1))


def reconstruct64(model: TransferModel, x: np.ndarray, n: int | None = None,
                   group: int | None = None) -> np.ndarray:
    """:func:`reconstruct` in float64 (the model's arrays are promoted): (T, 3) float64."""
    nb = _resolve_n(model, n)
    s, u = coefficients(model, x, n, group)
    out = np.empty((model.texels, 3))
    rows = default_rows(8 * (nb + 4) * 3, None)
    for sl in blocks(model.texels, rows):
        out[sl] = _blend(model, sl, s, u, nb)
    return out


def coefficients(model: TransferModel, x: np.ndarray, n: int | None = None,
                 group: int | None = None) -> tuple[float, np.ndarray]:
    """The runtime's coefficients for direct values x (P, 3): s = ‖γ(x)‖ and u (3, n−1)
    float64 (``u_c = M_c x'_c + s·b_c``, plus ``s·r(x'/s)`` for a learnt transfer)."""
    nb = _resolve_n(model, n)
    M, b = _group_transfer(model, group)
    xg = _check_x(model, x)
    s = float(np.linalg.norm(xg))
    u = np.einsum("cip,pc->ci", M[:, :nb].astype(np.float64), xg) \
        + s * b[:, :nb].astype(np.float64)
    if model.learnt is not None:
        u += s * transfer_residual(model.learnt, xg)[:, :nb]
    return s, u


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




# ---------------------------------------------------------------------------------------
# The fit: normalise → basis → transfer (a registered regressor) → basis count


def _fit(D, I, basis, ridge, channels, gamma, groups, per_group, holdout, timer,
         intercept, block_rows, out_dtype, regressor_name: str = "ridge",
         options: Mapping[str, Any] | None = None) -> TransferModel:
    t0 = time.perf_counter()
    D, gamma, groups = check_arguments(D, I, basis, ridge, channels, gamma, groups, per_group)
    norm = normalise(D, I, gamma, channels, groups, per_group, intercept, block_rows)
    sb = snapshot_basis(I, norm, basis, timer, block_rows, out_dtype)
    tf = regressor(regressor_name).fit(norm, sb, ridge, options or {})
    nb, n_method, curve, used, sel_warnings, sel_seconds = select_basis_count(
        norm, sb, tf, basis, holdout, block_rows)
    seconds = {**sb.seconds, **tf.seconds, **sel_seconds}
    warnings = [*norm.warnings, *sb.warnings, *tf.warnings, *sel_warnings]

    cond: list[float | None] = []
    eff: list[int] = []
    for sa in tf.direct_singular_values:
        eff.append(int(np.sum(sa > DIRECT_SVD_REL_TOL * sa[0])) if sa.size and sa[0] > 0
                   else 0)
        ok = sa.size and sa[0] > 0 and sa[-1] > DIRECT_SVD_REL_TOL * sa[0]
        cond.append(float(sa[0] / sa[-1]) if ok else None)
    full_rank = min(norm.P, norm.k_eff)
    if full_rank and min(eff) < full_rank:
        warnings.append(f"direct matrix rank-deficient: effective rank {min(eff)} < "
                        f"{full_rank} (coincident or nearly collinear measurement points, "
                        f"or near-duplicate lights); transfer is the minimum-norm solution "
                        f"on the {min(eff)} well-determined directions")
    seconds["total"] = time.perf_counter() - t0
    cv = tf.cv
    diag = FitDiagnostics(
        configurations=norm.K,
        used=norm.Kk,
        excluded=norm.excluded,
        channels=channels,
        gamma=gamma,
        intercept=intercept,
        direct_singular_values=tuple(tuple(float(v) for v in sa)
                                     for sa in tf.direct_singular_values),
        direct_condition=tuple(cond),
        direct_effective_rank=tuple(eff),
        indirect_singular_values=tuple(tuple(float(v) for v in np.sqrt(e))
                                       for e, _, _ in sb.eig),
        indirect_rank=sb.rank,
        n_basis=nb + 1,
        n_basis_requested=basis if basis == "auto" else int(basis),
        n_basis_method=n_method,
        energy_kept=float(sb.energy_curve[nb]),
        energy_curve=tuple(float(v) for v in sb.energy_curve),
        holdout_rmse=None if curve is None else tuple(float(v) for v in curve),
        holdout_used=used,
        ridge=tf.regularisation,
        ridge_method=tf.method,
        ridge_grid=tuple(float(v) for v in tf.grid),
        ridge_cv=tuple(float(v) if np.isfinite(v) else None for v in cv),
        groups=norm.groups_diag,
        unlit_points=tuple(int(p) for p in norm.unlit),
        warnings=tuple(warnings),
        seconds=seconds,
        transfer=regressor_name,
        learnt=tf.learnt_diagnostics,
    )
    M, b = tf.transfer, tf.offset
    transfer = M[:, :, :nb] if per_group else M[0, :, :nb]
    offset = b[:, :, :nb] if per_group else b[0, :, :nb]
    basis_arr = sb.basis
    return TransferModel(
        mean=sb.mean.astype(out_dtype),
        basis=np.ascontiguousarray(basis_arr[:, :nb]) if nb < sb.nb_max else basis_arr,
        transfer=np.ascontiguousarray(transfer, dtype=out_dtype),
        offset=np.ascontiguousarray(offset, dtype=out_dtype),
        gamma=gamma,
        channels=channels,
        ridge=tf.regularisation,
        group_ids=norm.group_ids,
        diagnostics=diag,
        learnt=None if tf.learnt is None else tf.learnt.select_outputs(
            transfer_rows(sb.nb_max, nb)).astype(out_dtype),
    )
