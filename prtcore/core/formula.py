"""The runtime formula as a bundle's manifest states it (``manifest.runtime.formula``).

Its source is the code of :mod:`prtcore.runtime.cpu` (``shade_points``, ``plane_weights``,
``blend``): this string is that code's statement for engines, kept in the bottom layer so
that whatever writes a manifest can name it without importing the runtime. Checked
against the source: ``tests/test_runtime_formula.py`` implements each clause and compares
it with :mod:`prtcore.runtime.cpu`; the GLSL (``coeff_cs.glsl``, ``blend.glsl``) is
compared with :mod:`prtcore.runtime.cpu` in ``tests/test_render.py``.
"""

from __future__ import annotations

RUNTIME_FORMULA = (
    "x = per-point mean over its cluster of albedo/pi * E_direct (P x 3); "
    "x' = sign(x)|x|^(1/gamma) (identity without gamma); s = ||x'|| (Frobenius); "
    "u_c = transfer[c] @ x'_c + s * offset[c] (c = R, G, B); "
    "plane weights: mean plane of channel c -> s*e_c, mono element i -> (u_R,i, u_G,i, u_B,i), "
    "rgb element i channel c -> u_c,i*e_c; colour = max(sum_j plane_j * w_j, 0) "
    "(negative light is clamped); with gamma: colour = colour^gamma"
)

#: The clause a bundle with a learnt transfer (``fit.transfer: "mlp"``) adds
#: (``manifest.runtime.learnt``); the network is ``manifest.transfer.learnt``
#: (:mod:`prtcore.core.mlp`, ``prtcore.runtime.cpu.plane_weights``, ``learnt.glsl``).
LEARNT_FORMULA = (
    "before the plane weights: u_c += s * r_c, r = mlp(x'/s) with x'/s flattened "
    "channel-major (index c*P + p; r = 0 when s = 0); mlp: h = leaky_relu(W_j h + b_j) "
    "(slope) for every layer but the last, r = W_L h + b_L, r laid out c*(n-1) + i"
)
