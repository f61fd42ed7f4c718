"""Fit step 4: how many basis elements ship (the spec's n, or "auto").

"auto" with held-out data takes the smallest n whose held-out relative RMSE is within
AUTO_HOLDOUT_MARGIN of the best; without, the smallest n keeping AUTO_ENERGY of the
snapshot energy.
"""

from __future__ import annotations

import time

import numpy as np

from prtcore.core.mlp import Mlp, transfer_residual
from prtcore.fit.basis import SnapshotBasis
from prtcore.fit.model import (
    AUTO_ENERGY,
    AUTO_HOLDOUT_MARGIN,
    blocks,
    default_rows,
    gamma_decode,
    gamma_encode,
)
from prtcore.fit.normalise import Normalised
from prtcore.fit.regressor import TransferFit


def select_basis_count(norm: Normalised, sb: SnapshotBasis, tf: TransferFit,
                       basis: int | str, holdout, block_rows: int | None):
    """Returns (nb, n_method, holdout curve or None, held-out configurations used,
    warnings, seconds); nb counts basis vectors besides the mean."""
    t1 = time.perf_counter()
    warnings: list[str] = []
    nb_max, energy_curve = sb.nb_max, sb.energy_curve
    curve = None
    used = 0
    if holdout is not None:
        curve, used = holdout_curve(sb.mean, sb.basis, tf.transfer, tf.offset, norm.gamma,
                                    norm.mono, holdout, norm.group_ids, norm.P, norm.T,
                                    block_rows, tf.learnt)
    if basis != "auto":
        nb = nb_max
        n_method = "capped" if nb < int(basis) - 1 else "given"
    elif curve is not None and used and np.isfinite(curve).all():
        best = float(np.min(curve))
        nb = int(np.flatnonzero(curve <= best * (1.0 + AUTO_HOLDOUT_MARGIN))[0])
        n_method = "holdout"
    else:
        reach = np.flatnonzero(energy_curve >= AUTO_ENERGY)
        nb = int(reach[0]) if reach.size else nb_max
        n_method = "energy"
        if not reach.size:
            warnings.append(f"basis='auto' capped at {nb_max + 1} elements: energy kept "
                            f"{energy_curve[-1]:.6f} < {AUTO_ENERGY}")
    return nb, n_method, curve, used, warnings, {"select": time.perf_counter() - t1}


def holdout_curve(mean, basis_arr, M, b, gamma, mono, holdout, group_ids, P, T,
                   block_rows, learnt: Mlp | None = None) -> tuple[np.ndarray, int]:
    """Held-out relative RMSE (stacked over configurations, linear units) for n = 1..nb+1.

    learnt : the learnt residual network of the "mlp" regressor (rows ``[c][i]``), or None.

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
    for sl in blocks(T, default_rows(H * 3 * 4, block_rows)):
        ok &= np.isfinite(np.asarray(Ih[sl])).all(axis=(0, 2))
    use = np.flatnonzero(ok)
    nb = M.shape[2]
    u = np.einsum("hcip,phc->hci", M[gidx[use]], xg[:, use, :]) \
        + s[use, None, None] * b[gidx[use]]  # (H, 3, nb)
    if learnt is not None:
        for j, h in enumerate(use):
            u[j] += s[h] * transfer_residual(learnt, xg[:, h, :])
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
        rows = default_rows(8 * (len(use) * 3 * 3 + 3 * nb), block_rows)
        for sl in blocks(T, rows):
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
        rows = default_rows(8 * len(use) * 3 * (nb + 1) * 3, block_rows)
        for sl in blocks(T, rows):
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
