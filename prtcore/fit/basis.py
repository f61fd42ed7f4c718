"""Fit step 2: the mean and the basis by the snapshot method (paper 4.2).

``A`` holds the mean-subtracted normalised snapshots ("mono": the three channels as
separate columns, one basis; "rgb": one basis per channel). ``G = AᵀA`` is accumulated over
blocks of texel rows, decomposed with ``scipy.linalg.eigh`` (eigenvalues descending, those
≤ ``EIG_REL_TOL·e_max`` dropped, each eigenvector oriented so its largest-magnitude entry
is positive), then ``U = A V Σ⁻¹`` and the coefficients ``C = UᵀA`` block by block.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from prtcore.core.progress import StageTimer
from prtcore.core.tolerances import EIG_REL_TOL
from prtcore.fit.model import AUTO_BASIS_MAX, blocks, default_rows
from prtcore.fit.normalise import Normalised, snapshots


@dataclass(frozen=True, eq=False)
class SnapshotBasis:
    """The mean, the basis candidates and the training coefficients.

    mean : (T, 3) float64; basis : (T, nb_max) mono or (T, nb_max, 3) rgb, ``out_dtype``
    coefficients : (3, nb_max, Kk) float64 — channel c's snapshots in the basis
    eig : per basis (1 mono, 3 rgb) (eigenvalues (descending), eigenvectors, rank)
    rank : available basis rank (max over bases); nb_max : basis vectors computed
    energy_curve : (nb_max + 1,) energy kept by 0..nb_max vectors; e_total, e_cum : the
    eigenvalue sum and its prefix sums; total_ss : Σ In² of the normalised snapshots
    warnings, seconds : what the step noticed and its timings
    """

    mean: np.ndarray
    basis: np.ndarray
    coefficients: np.ndarray
    eig: tuple[tuple[np.ndarray, np.ndarray, int], ...]
    rank: int
    nb_max: int
    energy_curve: np.ndarray
    e_total: float
    e_cum: np.ndarray
    total_ss: float
    warnings: tuple[str, ...]
    seconds: dict[str, float]


def snapshot_basis(I, norm: Normalised, basis: int | str, timer: StageTimer | None,
                   block_rows: int | None, out_dtype) -> SnapshotBasis:
    """Mean and up to ``basis`` − 1 basis vectors (all up to AUTO_BASIS_MAX for "auto")."""
    seconds: dict[str, float] = {}
    warnings: list[str] = []
    T, Kk, mono = norm.T, norm.Kk, norm.mono
    rows = default_rows(8 * 3 * Kk * 3, block_rows)
    nblocks = -(-T // rows)

    def bar(it, desc):
        return timer.bar(it, desc=desc, total=nblocks) if timer is not None else it

    # pass 1: mean and Gram matrix
    t1 = time.perf_counter()
    mean = np.empty((T, 3))
    gram = np.zeros((3 * Kk, 3 * Kk)) if mono else np.zeros((3, Kk, Kk))
    total_ss = 0.0
    for sl in bar(blocks(T, rows), "fit: gram"):
        mb, Xt, ss = snapshots(I, norm, sl)
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

    # eigen-decomposition
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

    # pass 2: basis U = A V Σ⁻¹ and coefficients C = UᵀA
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
        for sl in bar(blocks(T, rows), "fit: basis"):
            _, Xt, _ = snapshots(I, norm, sl)
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
    return SnapshotBasis(mean=mean, basis=basis_arr, coefficients=C, eig=tuple(eig),
                         rank=rank_avail, nb_max=nb_max, energy_curve=energy_curve,
                         e_total=e_total, e_cum=e_cum, total_ss=total_ss,
                         warnings=tuple(warnings), seconds=seconds)
