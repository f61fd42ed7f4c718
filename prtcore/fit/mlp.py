"""The "mlp" transfer regressor: ridge plus a small learnt residual (issue 18).

The transfer is the ridge's (:mod:`prtcore.fit.ridge`, same λ, same data) plus a network
r of :mod:`prtcore.core.mlp` evaluated at the unit direct vector::

    u_c = M_c x'_c + s·b_c + s·r(x'/s)_c         x'/s flattened [c][p]; r (3 n_b,) [c][i]

so the runtime stays positively homogeneous (``u(a·x) = a·u(x)``) and an engine adds one
small pass to the ridge's (docs/bundle.md, ``transfer.learnt``).

**What the network learns.** What the ridge gets wrong on lights it has not seen: its
exact leave-one-out residuals (:func:`prtcore.fit.ridge.loo_residuals`), i.e. for each
training configuration k the basis coefficients minus the ridge fitted without k. The
in-sample residuals would not do: with P ≳ K the ridge nearly interpolates its training
set and leaves the network nothing that generalises.

**Training** (:func:`prtcore.fit.train.train_network`: JAX + optax, float64, full batch,
CPU; deterministic: same data + options → the same weights bit for bit on one machine).
A seeded fifth of the configurations (at least :data:`MIN_VALIDATION`) is held back;
AdamW runs up to ``steps`` steps on the rest and the step count with the lowest
validation error is kept. Then the network is trained again from the same initial
weights on all configurations for that many steps. When the count is 0 (no step helped:
the LOO residuals are not predictable from x'/s with this data) no network ships; the
model is the ridge's, with a warning. Inputs are centred and scaled, targets scaled, and
both are folded into the first and last layer, so the shipped network reads x'/s and
writes coefficients directly. The last layer starts at zero: step 0 is exactly the
ridge.

Options (``fit.mlp_*`` in the spec, :data:`DEFAULTS`): ``width`` neurons per hidden layer,
``layers`` hidden layers, ``steps`` AdamW steps at most, ``seed``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from prtcore.core.errors import PrtError
from prtcore.core.mlp import LEAKY_SLOPE, Mlp, forward
from prtcore.core.spec import FitSpec
from prtcore.fit.basis import SnapshotBasis
from prtcore.fit.normalise import Normalised
from prtcore.fit.regressor import TransferFit, TransferRegressor, register
from prtcore.fit.ridge import RidgeRegressor, direct_svd, loo_residuals
from prtcore.fit.train import train_network

#: the options and their defaults (spec: fit.mlp_width, fit.mlp_layers, fit.mlp_steps,
#: fit.seed)
DEFAULTS: dict[str, int] = {"width": 64, "layers": 2, "steps": 2000, "seed": 0}
#: share of the training configurations held back to choose the step count
VALIDATION_SHARE = 0.2
#: fewest validation configurations; with fewer than twice as many configurations in
#: all, the network is trained for ``steps`` steps without a validation choice
MIN_VALIDATION = 4


def mlp_options(options: Mapping[str, Any] | None) -> dict[str, int]:
    """:data:`DEFAULTS` updated with ``options``; unknown names are refused."""
    opts = dict(DEFAULTS)
    unknown = sorted(set(options or {}) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"mlp transfer: unknown options {unknown} (known: {sorted(DEFAULTS)})")
    opts.update({k: int(v) for k, v in (options or {}).items()})
    if opts["width"] < 1 or opts["layers"] < 1 or opts["steps"] < 0:
        raise ValueError(f"mlp transfer: width, layers ≥ 1 and steps ≥ 0, got {opts}")
    return opts


def learnt_options(fit_spec: FitSpec) -> dict[str, int]:
    """The options of the spec's ``fit`` section (``mlp_*``, ``seed``)."""
    return {"width": fit_spec.mlp_width, "layers": fit_spec.mlp_layers,
            "steps": fit_spec.mlp_steps, "seed": fit_spec.seed}


def loo_targets(norm: Normalised, basis: SnapshotBasis, lam: float) -> np.ndarray:
    """The ridge's leave-one-out residuals of every kept configuration: (Kk, 3, nb_max)
    float64 (normalised coefficient units). Shared transfer only."""
    out = np.zeros((norm.Kk, 3, basis.nb_max))
    for c in range(3):
        svd = direct_svd(norm.Dn[:, :, c], norm.intercept)
        e = loo_residuals(svd, basis.coefficients[c], lam)
        if e is None:
            raise PrtError(f"fit.transfer 'mlp': the ridge's leave-one-out residuals are "
                           f"undefined at λ = {lam:g} (a configuration is interpolated "
                           "exactly); use fit.ridge > 0 or 'auto'")
        out[:, c, :] = e.T
    return out


@register
class MlpRegressor(TransferRegressor):
    """Ridge + a learnt residual (module docstring). Options: :data:`DEFAULTS`."""

    name = "mlp"

    def fit(self, norm: Normalised, basis: SnapshotBasis, setting: float | str,
            options: Mapping[str, Any] | None = None) -> TransferFit:
        opts = mlp_options(options)
        if norm.group_ids is not None:
            raise PrtError("fit.transfer 'mlp' learns one shared transfer; per-keyframe "
                           "transfers (keyframes.transfer 'per_keyframe') need 'ridge'")
        ridge = RidgeRegressor().fit(norm, basis, setting)
        t0 = time.perf_counter()
        if basis.nb_max == 0:
            return ridge
        X = norm.Dn.transpose(1, 2, 0).reshape(norm.Kk, -1)  # (Kk, 3P), [c][p]
        Y = loo_targets(norm, basis, ridge.regularisation).reshape(norm.Kk, -1)
        net, diag = train_residual(X, Y, opts)
        seconds = {**ridge.seconds, "learnt": time.perf_counter() - t0}
        warnings = () if net is not None else (
            "fit.transfer 'mlp': no step of the learnt residual lowered the validation "
            "error of the ridge; the ridge ships alone",)
        return TransferFit(transfer=ridge.transfer, offset=ridge.offset,
                           regularisation=ridge.regularisation, method=ridge.method,
                           grid=ridge.grid, cv=ridge.cv,
                           direct_singular_values=ridge.direct_singular_values,
                           seconds=seconds, learnt=net, learnt_diagnostics=diag,
                           warnings=warnings)


def split(k: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(fit, validation) configuration indices, seeded; no validation below
    2·MIN_VALIDATION configurations."""
    if k < 2 * MIN_VALIDATION:
        return np.arange(k), np.zeros(0, np.intp)
    n_val = max(MIN_VALIDATION, round(VALIDATION_SHARE * k))
    perm = np.random.default_rng(seed).permutation(k)
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


def train_residual(X: np.ndarray, Y: np.ndarray, opts: Mapping[str, int]
                   ) -> tuple[Mlp | None, dict[str, Any]]:
    """Fit the residual network r with r(X[k]) ≈ Y[k] (module docstring).

    X : (K, d_in) float64 unit direct vectors; Y : (K, d_out) float64 targets.
    Returns the network (float64, standardisation folded in), or None when the validation
    chose 0 steps (the network would be zero: the ridge ships alone), and its training
    figures.
    """
    fit_idx, val_idx = split(len(X), opts["seed"])
    widths = (opts["width"],) * opts["layers"]
    steps = opts["steps"]
    t0 = time.perf_counter()
    if len(val_idx):
        _, curve = train_network(X[fit_idx], Y[fit_idx], widths, steps, opts["seed"],
                                 val=(X[val_idx], Y[val_idx]),
                                 desc="mlp transfer (validation)")
        best = int(np.argmin(curve[:, 1]))
        best_step = int(curve[best, 0])
        val_ridge, val_best = float(curve[0, 1]), float(curve[best, 1])
    else:
        curve, best_step, val_ridge, val_best = None, steps, None, None
    net = None if best_step == 0 else train_network(X, Y, widths, best_step, opts["seed"],
                                                    desc="mlp transfer")[0]
    y_ss = float(np.sum(Y**2))
    fitted = np.zeros_like(Y) if net is None else forward(net, X)
    diag = {
        "shipped": net is not None,
        "regressor": "mlp", "widths": list(widths), "activation": "leaky_relu",
        "slope": LEAKY_SLOPE, "seed": opts["seed"], "steps_max": steps, "steps": best_step,
        "configurations": len(X), "validation_configurations": len(val_idx),
        # mean squared leave-one-out residual of the ridge on the validation
        # configurations (step 0) and what the network leaves of it at the chosen step
        "validation_mse_ridge": val_ridge, "validation_mse_mlp": val_best,
        "training_residual_kept": float(np.sum((Y - fitted) ** 2)) / y_ss if y_ss else 0.0,
        "curve": None if curve is None else curve.tolist(),
        "seconds": time.perf_counter() - t0,
    }
    return net, diag
