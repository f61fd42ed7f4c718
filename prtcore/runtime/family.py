"""Is a light of the family the bake was trained on? The span of the training lights'
direct vectors at the measurement points, and a light's residual outside it.

A light whose direct vector x (P, 3) has a large part outside that span is one the
transfer never saw: its error is not bounded by the bake's held-out figures. ``relight``
and ``render`` print the measure and warn above the bundle's threshold.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from prtcore.core.tolerances import FAMILY_RESIDUAL_FLOOR, FAMILY_SPAN_REL_TOL


def direct_span(D: np.ndarray) -> np.ndarray:
    """Orthonormal basis (3P, r) float64 of the span of the configurations' direct vectors.

    D : (P, K, 3) direct radiance at the measurement points; each configuration is
    flattened point-major (x.ravel() of its (P, 3) vector) and scaled to unit norm (zero
    ones dropped), so every light counts the same whatever its intensity.
    """
    D = np.asarray(D, dtype=np.float64)
    A = D.transpose(0, 2, 1).reshape(-1, D.shape[1])  # column k = D[:, k, :].ravel()
    cols = np.linalg.norm(A, axis=0)
    A = A[:, cols > 0] / cols[cols > 0]
    if A.shape[1] == 0:
        return np.zeros((A.shape[0], 0))
    u, s, _ = scipy.linalg.svd(A, full_matrices=False)
    return u[:, s > FAMILY_SPAN_REL_TOL * s[0]]


def family_residual(span: np.ndarray, x: np.ndarray) -> float:
    """‖x − Q Qᵀ x‖ / ‖x‖ for a direct vector x (P, 3) and a span Q (3P, r); 0 for x = 0
    (a light that reaches no measurement point relights to exactly 0)."""
    v = np.asarray(x, dtype=np.float64).reshape(-1)
    nv = float(np.linalg.norm(v))
    if nv == 0.0:
        return 0.0
    q = np.asarray(span, dtype=np.float64)
    return float(np.linalg.norm(v - q @ (q.T @ v)) / nv)


def warn_above(heldout_residuals: np.ndarray) -> float:
    """The residual above which a light is reported out of family."""
    worst = float(np.max(heldout_residuals)) if len(heldout_residuals) else 0.0
    return max(2.0 * worst, FAMILY_RESIDUAL_FLOOR)
