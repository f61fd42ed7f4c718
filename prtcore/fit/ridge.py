"""The ridge transfer regressor (paper 4.3 eq. 14 with an unpenalised offset): the thin
SVD of the centred normalised direct matrix, the closed-form solve for any λ, and exact
leave-one-out residuals for choosing λ. Registered as the "ridge" member of
:mod:`prtcore.fit.regressor`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from prtcore.core.tolerances import DIRECT_SVD_REL_TOL, LOO_LEVERAGE_TOL
from prtcore.fit.basis import SnapshotBasis
from prtcore.fit.model import RIDGE_GRID_REL
from prtcore.fit.normalise import Normalised
from prtcore.fit.regressor import TransferFit, TransferRegressor, register


@dataclass(frozen=True)
class DirectSVD:
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


def direct_svd(D: np.ndarray, intercept: bool) -> DirectSVD:
    """D : (P, K) float64 normalised direct of one channel (one group)."""
    D = np.asarray(D, dtype=np.float64)
    k = D.shape[1]
    dbar = D.mean(axis=1) if intercept else np.zeros(D.shape[0])
    Dc = D - dbar[:, None]
    if Dc.size == 0:
        empty = np.zeros((D.shape[0], 0))
        return DirectSVD(empty, np.zeros(0), np.zeros((0, k)), dbar, np.zeros(0), k, intercept)
    try:
        u, s, vt = scipy.linalg.svd(Dc, full_matrices=False, lapack_driver="gesdd")
    except np.linalg.LinAlgError:
        u, s, vt = scipy.linalg.svd(Dc, full_matrices=False, lapack_driver="gesvd")
    keep = s > DIRECT_SVD_REL_TOL * s[0] if s.size and s[0] > 0 else np.zeros(s.size, bool)
    return DirectSVD(u[:, keep], s[keep], vt[keep], dbar, s, k, intercept)


def centre(svd: DirectSVD, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    cbar = C.mean(axis=1) if svd.intercept else np.zeros(C.shape[0])
    return C - cbar[:, None], cbar


def ridge_solve(svd: DirectSVD, C: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """Ridge transfer for coefficients C (m, K): returns M (m, P) and offset b (m,).

    M = (C − c̄1ᵀ) V diag(σ/(σ²+λ)) Uᵀ, b = c̄ − M d̄ (b = 0 without intercept).
    """
    Cc, cbar = centre(svd, C)
    f = svd.s / (svd.s**2 + lam)
    M = ((Cc @ svd.vt.T) * f) @ svd.u.T
    b = cbar - M @ svd.dbar if svd.intercept else np.zeros(C.shape[0])
    return M, b


def loo_sse(svd: DirectSVD, C: np.ndarray, lams: np.ndarray) -> np.ndarray:
    """Exact leave-one-out squared residuals of the ridge transfer, per row of C and λ.

    C : (m, K); lams : (L,). The fit is a linear smoother with hat matrix
    H = 11ᵀ/K + V diag(σ²/(σ²+λ)) Vᵀ (no 11ᵀ/K term without intercept); the LOO residual
    of configuration k is e_k/(1 − h_kk). Returns (m, L) float64; +inf where some
    1 − h_kk ≤ LOO_LEVERAGE_TOL.
    """
    parts = _loo_parts(svd, C)
    out = np.empty((C.shape[0], len(lams)))
    for j, lam in enumerate(lams):
        e = loo_residuals(svd, C, lam, parts)
        out[:, j] = np.inf if e is None else np.sum(e**2, axis=1)
    return out


def loo_residuals(svd: DirectSVD, C: np.ndarray, lam: float, parts=None
                  ) -> np.ndarray | None:
    """The leave-one-out residuals themselves (see :func:`loo_sse`): (m, K) float64, entry
    (i, k) = row i of configuration k minus the ridge fitted without configuration k; None
    where some 1 − h_kk ≤ LOO_LEVERAGE_TOL. ``parts``: :func:`_loo_parts` of (svd, C)."""
    Cc, Z, v2, base = _loo_parts(svd, C) if parts is None else parts
    phi = svd.s**2 / (svd.s**2 + lam) if svd.s.size else np.zeros(0)
    E = Cc - (Z * phi) @ svd.vt
    denom = 1.0 - (base + phi @ v2)
    if np.any(denom <= LOO_LEVERAGE_TOL):
        return None
    return E / denom


def _loo_parts(svd: DirectSVD, C: np.ndarray):
    """What every λ of :func:`loo_residuals` shares: centred C, its projection on the
    right singular vectors, their squares and the intercept's leverage."""
    Cc, _ = centre(svd, C)
    return Cc, Cc @ svd.vt.T, svd.vt**2, 1.0 / svd.k if svd.intercept else 0.0


@register
class RidgeRegressor(TransferRegressor):
    """Affine ridge per channel (and per keyframe group): λ given, or chosen from
    {0} ∪ σ_max²·RIDGE_GRID_REL by exact leave-one-out cross-validation on every fitted
    row (basis held fixed)."""

    name = "ridge"

    def fit(self, norm: Normalised, basis: SnapshotBasis, setting: float | str,
            options: Mapping[str, Any] | None = None) -> TransferFit:
        t1 = time.perf_counter()
        Dn, intercept, nb_max = norm.Dn, norm.intercept, basis.nb_max
        C = basis.coefficients
        per_group = norm.group_ids is not None
        svds = [[direct_svd(Dn[:, idx, c], intercept) for c in range(3)]
                for idx in norm.group_idx]
        shared_svds = svds[0] if not per_group else [direct_svd(Dn[:, :, c], intercept)
                                                     for c in range(3)]
        smax = max((float(sv.s_all[0]) for row in svds for sv in row if sv.s_all.size),
                   default=0.0)
        grid = np.array(sorted({0.0, *(smax**2 * r for r in RIDGE_GRID_REL)}))
        loo = np.zeros((nb_max, len(grid)))
        for row, idx in zip(svds, norm.group_idx, strict=True):
            for c in range(3):
                if nb_max:
                    loo += loo_sse(row[c], C[c][:, idx], grid)
        # λ is chosen on every fitted row (the given n, or all candidates for basis="auto");
        # the energy outside the basis is the same for every λ and makes cv a relative RMSE.
        tail = max(basis.e_total - float(basis.e_cum[nb_max]), 0.0)
        cv_sse = loo.sum(axis=0) + tail
        cv = np.sqrt(cv_sse / basis.total_ss) if basis.total_ss > 0 else np.zeros(len(grid))
        if setting == "auto":
            finite = np.isfinite(cv)
            lam = float(grid[np.flatnonzero(finite)[np.argmin(cv[finite])]]) \
                if finite.any() else float(grid[-1])
            method = "loo"
        else:
            lam = float(setting)
            method = "given"
        G = len(norm.group_idx)
        M = np.zeros((G, 3, nb_max, norm.P))
        b = np.zeros((G, 3, nb_max))
        for g, (row, idx) in enumerate(zip(svds, norm.group_idx, strict=True)):
            for c in range(3):
                M[g, c], b[g, c] = ridge_solve(row[c], C[c][:, idx], lam)
        return TransferFit(transfer=M, offset=b, regularisation=lam, method=method, grid=grid,
                           cv=cv, direct_singular_values=tuple(sv.s_all for sv in shared_svds),
                           seconds={"transfer": time.perf_counter() - t1})

