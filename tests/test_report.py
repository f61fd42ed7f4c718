"""report.truncate: the diagnostics describe the model that ships, at the spec's n."""

from __future__ import annotations

import numpy as np

from prtcore.fit.transfer import fit_transfer
from prtcore.report import truncate


def _data(K: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    return np.abs(rng.normal(size=(6, K, 3))) + 0.1, np.abs(rng.normal(size=(40, K, 3)))


def test_requested_n_is_the_specs_even_when_the_fit_is_capped():
    D, I = _data(K=3)
    full = fit_transfer(D, I, basis=64)  # the report table's size; rank caps it
    assert full.n_basis < 16
    d = truncate(full, 16).diagnostics
    assert d.n_basis_requested == 16 and d.n_basis_method == "capped"
    assert [w for w in d.warnings if w.startswith("basis count ")] == [
        f"basis count 16 capped at {full.n_basis}: the indirect data has rank "
        f"{d.indirect_rank} after mean subtraction"]


def test_truncation_below_the_fit_reports_the_given_n():
    D, I = _data(K=12)
    full = fit_transfer(D, I, basis=20)
    d = truncate(full, 4).diagnostics
    assert (d.n_basis, d.n_basis_requested, d.n_basis_method) == (4, 4, "given")
    assert not any(w.startswith("basis count ") for w in d.warnings)
