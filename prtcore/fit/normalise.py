"""Fit step 1: validate the dataset, exclude unusable configurations, normalise.

Each configuration k is divided by ``s_k = ‖γ(D)[:, k, :]‖`` (paper 4.2); configurations
with a zero or non-finite ``s_k`` or a non-finite indirect value are excluded and listed.
The indirect data ``I`` (T, K, 3) is never copied whole: :func:`snapshots` reads blocks of
texel rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prtcore.core.errors import PrtError
from prtcore.fit.model import (
    GAMMA_RANGE,
    UNDERDETERMINED_WARNING,
    blocks,
    default_rows,
    gamma_encode,
)


@dataclass(frozen=True, eq=False)
class Normalised:
    """The normalised training set.

    P, K, T : points, configurations given, texels; Kk : configurations kept
    keep : (Kk,) intp indices kept; all_kept : Kk == K
    sk : (Kk,) float64 direct norms of the kept configurations (gamma space)
    Dn : (P, Kk, 3) float64 normalised direct
    gamma : None or g; mono : channels == "mono"; intercept : the transfer has an offset
    excluded : ({"index", "reason"}, ...); group_ids, group_idx : per-group transfer
    groups (None when shared; group_idx then holds one array of all kept columns)
    groups_diag : {"ids", "counts"} or None; unlit : (u,) intp points lit by nothing
    k_eff : effective configuration count of the regression (Kk − 1 with the offset)
    warnings : what normalisation noticed
    """

    P: int
    K: int
    T: int
    Kk: int
    keep: np.ndarray
    all_kept: bool
    sk: np.ndarray
    Dn: np.ndarray
    gamma: float | None
    mono: bool
    intercept: bool
    excluded: tuple[dict, ...]
    group_ids: tuple[int, ...] | None
    group_idx: tuple[np.ndarray, ...]
    groups_diag: dict | None
    unlit: np.ndarray
    k_eff: int
    warnings: tuple[str, ...]


def check_arguments(D, I, basis, ridge, channels, gamma, groups, per_group):
    """Validate the fit's arguments. Returns (D as array, gamma as float or None, groups)."""
    D = np.asarray(D)
    if D.ndim != 3 or D.shape[2] != 3:
        raise ValueError(f"fit: D must be (P, K, 3), got {D.shape}")
    if not hasattr(I, "shape") or len(I.shape) != 3 or I.shape[2] != 3:
        raise ValueError(f"fit: I must be (T, K, 3), got {getattr(I, 'shape', None)}")
    K = D.shape[1]
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
    return D, gamma, groups


def normalise(D: np.ndarray, I, gamma: float | None, channels: str,
              groups: np.ndarray | None, per_group: bool, intercept: bool,
              block_rows: int | None) -> Normalised:
    """Exclusion and normalisation of checked arguments (see :func:`check_arguments`).

    D : (P, K, 3); I : (T, K, 3) any float array-like (read in row blocks).
    Raises :class:`PrtError` when fewer than 2 (1 without offset) configurations are usable.
    """
    warnings: list[str] = []
    P, K, _ = D.shape
    T = int(I.shape[0])
    Dg = gamma_encode(D, gamma)
    with np.errstate(over="ignore", invalid="ignore"):
        s = np.sqrt(np.sum(Dg**2, axis=(0, 2)))
    i_finite = np.ones(K, dtype=bool)
    for sl in blocks(T, default_rows(K * 3 * 4, block_rows)):
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
    return Normalised(P=P, K=K, T=T, Kk=Kk, keep=keep, all_kept=Kk == K, sk=sk, Dn=Dn,
                      gamma=gamma, mono=channels == "mono", intercept=intercept,
                      excluded=tuple(excluded), group_ids=group_ids,
                      group_idx=tuple(group_idx), groups_diag=groups_diag, unlit=unlit,
                      k_eff=k_eff, warnings=tuple(warnings))


def snapshots(I, norm: Normalised, sl: slice) -> tuple[np.ndarray, np.ndarray, float]:
    """Texel rows ``sl`` of the normalised indirect data: the per-channel mean (rows, 3),
    the mean-subtracted snapshots (rows, 3, Kk) float64 and Σ In² over the rows."""
    blk = np.asarray(I[sl])
    X = np.array((blk if norm.all_kept else blk[:, norm.keep, :]).transpose(0, 2, 1),
                 dtype=np.float64, order="C")  # (rows, 3, Kk)
    if norm.gamma is not None:
        X = gamma_encode(X, norm.gamma)
    X /= norm.sk[None, None, :]
    ss = float(np.einsum("ijk,ijk->", X, X))
    mb = X.mean(axis=2)
    X -= mb[:, :, None]
    return mb, X, ss
