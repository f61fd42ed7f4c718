"""The transfer-regressor interface: direct values at the measurement points → basis
coefficients, and the registry of members.

A regressor sees the normalised training set (:class:`~prtcore.fit.normalise.Normalised`)
and the basis coefficients of its snapshots (:class:`~prtcore.fit.basis.SnapshotBasis`) and
returns a :class:`TransferFit`. The members: ridge (:mod:`prtcore.fit.ridge`, linear:
the runtime computes ``u_c = M_c x'_c + s·b_c``) and mlp (:mod:`prtcore.fit.mlp`: ridge
plus a learnt residual ``s·r(x'/s)``, a small network of :mod:`prtcore.core.mlp`). A new
regressor is a new module that subclasses :class:`TransferRegressor`, registers itself
and is imported by ``prtcore.fit.transfer`` (one line).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from prtcore.core.mlp import Mlp
from prtcore.core.registry import Registry
from prtcore.fit.basis import SnapshotBasis
from prtcore.fit.normalise import Normalised


@dataclass(frozen=True, eq=False)
class TransferFit:
    """A fitted linear transfer for nb_max basis vectors, G groups (1 when shared).

    transfer : (G, 3, nb_max, P) float64; offset : (G, 3, nb_max) float64
    regularisation : the chosen regularisation (ridge: λ); method : "given" | "loo" | ...
    grid, cv : candidate regularisations and their cross-validated relative RMSE
    direct_singular_values : per channel, singular values of the (centred) normalised
    direct matrix over all configurations, descending (describes conditioning)
    seconds : timings
    learnt : the learnt residual network (outputs 3·nb_max, rows ``[c][i]``) or None
    learnt_diagnostics : what training measured (JSON data), None for ridge
    warnings : what the regressor noticed, for the fit's warnings
    """

    transfer: np.ndarray
    offset: np.ndarray
    regularisation: float
    method: str
    grid: np.ndarray
    cv: np.ndarray
    direct_singular_values: tuple[np.ndarray, ...]
    seconds: dict[str, float]
    learnt: Mlp | None = None
    learnt_diagnostics: dict[str, Any] | None = None
    warnings: tuple[str, ...] = ()


class TransferRegressor:
    """One way of regressing basis coefficients on direct values."""

    name: ClassVar[str]

    def fit(self, norm: Normalised, basis: SnapshotBasis, setting: float | str,
            options: Mapping[str, Any]) -> TransferFit:
        """``setting`` : the spec's regularisation (a number, or "auto"); ``options`` : the
        member's own settings (names and defaults: the member's docstring)."""
        raise NotImplementedError


_REGISTRY: Registry[TransferRegressor] = Registry("transfer regressor", "name")

#: class decorator: register a regressor under its ``name``
register = _REGISTRY.register
#: the registered regressor called ``name`` (KeyError names the known ones)
regressor = _REGISTRY.get
#: the registered names
regressor_names = _REGISTRY.names
