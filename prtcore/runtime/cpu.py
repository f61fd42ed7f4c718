"""The runtime algorithm on the CPU, from bundle data alone (``prtcore relight``).

Per frame, exactly what an engine does:

1. shade the measurement points' supersamples for the frame's lights
   (``albedo/π · E`` with shadows) and average each cluster → x (P, 3);
2. coefficients: ``s = ‖γ(x)‖``, ``u_c = M_c γ(x)_c + s·b_c`` per channel, plus
   ``s·r(γ(x)/s)`` with a learnt transfer (``fit.transfer: "mlp"``, :mod:`prtcore.core.mlp`);
3. blend the basis planes with one RGB coefficient per plane and undo gamma.

The basis is stored as scalar *planes* packed four per RGBA EXR: planes 0–2 are the mean
(element 0) for R, G, B; then, for "mono", one plane per element 1..n−1 (shared by the
channels); for "rgb", three planes (R, G, B) per element. Plane ``j`` gets the RGB
coefficient vector ``w_j``: mean plane of channel c → ``s·e_c``; mono element i →
``(u_R,i, u_G,i, u_B,i)``; rgb element i, channel c → ``u_c,i·e_c``. Then
``colour = Σ_j plane_j · w_j`` — the paper's 4×3 coefficient matrices, one per texture.

This module is the one source of the runtime formula; the others are checked against it:
the GLSL of :mod:`prtcore.runtime.gl` (``coeff_cs.glsl``, ``blend.glsl``; in
``tests/test_render.py``) and :data:`RUNTIME_FORMULA`, the statement every manifest
carries (``runtime.formula``; defined in :mod:`prtcore.core.formula`, the bottom layer, so
that the bundle writer can name it; clause by clause in ``tests/test_runtime_formula.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from prtcore.core.formula import RUNTIME_FORMULA as RUNTIME_FORMULA  # see the docstring
from prtcore.core.mlp import transfer_residual
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.emitters.punctual import irradiance
from prtcore.io.bundle import RuntimeData


def shade_points(data: RuntimeData, lights: Sequence[Light], tracer: RayTracer | None
                 ) -> np.ndarray:
    """Direct outgoing radiance at the measurement points: (P, 3) float64."""
    pos = data.cluster_position.astype(np.float64)
    nrm = data.cluster_normal.astype(np.float64)
    e = np.zeros((len(pos), 3))
    for light in lights:
        e += irradiance(light, pos, nrm, tracer)
    radiance = data.cluster_albedo.astype(np.float64) / np.pi * e
    sums = np.zeros((data.point_count, 3))
    np.add.at(sums, data.cluster_owner, radiance)
    counts = np.bincount(data.cluster_owner, minlength=data.point_count)[:, None]
    return sums / np.maximum(counts, 1)


def _gamma(v: np.ndarray, g: float | None) -> np.ndarray:
    if g is None or g == 1.0:
        return v
    return np.sign(v) * np.abs(v) ** (1.0 / g)


def plane_weights(data: RuntimeData, x: np.ndarray, n: int | None = None,
                  keyframe: int | None = None) -> np.ndarray:
    """RGB coefficient of every basis plane for direct vector x (P, 3): (q, 3) float64.

    n : elements to use, mean included (planes of later elements get weight 0).
    keyframe : index into the per-keyframe transfers (None: the shared one).
    """
    M, b = data.transfer, data.offset
    if M.ndim == 4:
        k = 0 if keyframe is None else keyframe
        M, b = M[k], b[k]
    n_b = M.shape[1]
    use = n_b if n is None else max(0, min(n - 1, n_b))
    xg = _gamma(np.asarray(x, dtype=np.float64), data.gamma)
    s = float(np.linalg.norm(xg))
    u = np.zeros((3, n_b))
    for c in range(3):
        u[c, :use] = M[c, :use].astype(np.float64) @ xg[:, c] + s * b[c, :use]
    if data.learnt is not None:  # fit.transfer "mlp": u += s·r(x'/s)
        u[:, :use] += s * transfer_residual(data.learnt, xg)[:, :use]
    w = np.zeros((len(data.plane_element), 3))
    for j, (el, ch) in enumerate(zip(data.plane_element, data.plane_channel, strict=True)):
        if el == 0:
            w[j, ch] = s
        elif ch < 0:
            w[j] = u[:, el - 1]
        else:
            w[j, ch] = u[ch, el - 1]
    return w


def blend(data: RuntimeData, weights: np.ndarray) -> np.ndarray:
    """max(Σ_j plane_j · w_j, 0), gamma undone: (h, w, 3) float32 indirect radiance
    (negative light is clamped: the runtime's negative-value policy, core/formula.py and
    docs/bundle.md; the fit's own reconstruction stays linear)."""
    h, w, q = data.planes.shape
    return blend_at(data.planes.reshape(-1, q), weights, data.gamma).reshape(h, w, 3)


def blend_at(planes: np.ndarray, weights: np.ndarray, gamma: float | None) -> np.ndarray:
    """:func:`blend` of planes already sampled somewhere, (n, q) → (n, 3) float32: what a
    fragment shader computes from its bilinear sample of the basis (the GL renderer, the
    viewer); sampling a relit texture instead clamps each texel before filtering, which
    differs where a neighbouring texel is negative."""
    out = np.asarray(planes).astype(np.float32) @ weights.astype(np.float32)
    out = np.maximum(out, np.float32(0.0))
    if gamma is not None and gamma != 1.0:
        out = out ** np.float32(gamma)
    return out


def relight(data: RuntimeData, lights: Sequence[Light], tracer: RayTracer | None,
            n: int | None = None, keyframe: int | None = None) -> np.ndarray:
    """The indirect lightmap for ``lights``: (h, w, 4) float32 RGBA, A = coverage."""
    x = shade_points(data, lights, tracer)
    rgb = blend(data, plane_weights(data, x, n, keyframe))
    return np.concatenate([rgb, data.coverage[:, :, None].astype(np.float32)], axis=2)
