"""The runtime formula has one source, prtcore.runtime.cpu (issue 12); the manifest's
statement of it, RUNTIME_FORMULA, is checked here clause by clause: each clause below is
implemented in float64 straight from its words, the clauses must make up the string
exactly, and the composition must equal shade_points → plane_weights → blend for mono and
rgb bases, with and without gamma, for every basis count n.

Tolerance: x is float64 on both sides (1e-12); runtime.cpu forms the offset term s·b in
the bundle's float32, so the weights agree to 1e-6 of their largest; it blends in float32
(as an engine does), so the colour agrees to 1e-5 of Σ_j |plane_j|·|w_j| at each texel
(the sum's own rounding scale; with gamma, that times the derivative of c^gamma).
"""

from __future__ import annotations

import numpy as np
import pytest
from scenes import point_light

from prtcore.core.formula import RUNTIME_FORMULA
from prtcore.emitters.punctual import irradiance
from prtcore.io.bundle import RuntimeData
from prtcore.runtime import cpu


def x_clause(d: RuntimeData, lights) -> np.ndarray:
    """per-point mean over its cluster of albedo/pi * E_direct (P x 3)"""
    pos, nrm = d.cluster_position.astype(np.float64), d.cluster_normal.astype(np.float64)
    e = sum(irradiance(lt, pos, nrm, None) for lt in lights)
    v = d.cluster_albedo.astype(np.float64) / np.pi * e
    return np.stack([v[d.cluster_owner == p].mean(axis=0) for p in range(d.point_count)])


def gamma_clause(x: np.ndarray, g: float | None) -> np.ndarray:
    return x if g is None else np.sign(x) * np.abs(x) ** (1.0 / g)


def s_clause(xg: np.ndarray) -> float:
    return float(np.sqrt((xg ** 2).sum()))


def u_clause(d: RuntimeData, xg: np.ndarray, s: float, use: int) -> np.ndarray:
    M, b = d.transfer.astype(np.float64), d.offset.astype(np.float64)
    u = np.stack([M[c] @ xg[:, c] + s * b[c] for c in range(3)])  # (3, n_b)
    u[:, use:] = 0.0  # elements beyond n are not used
    return u


def weights_clause(d: RuntimeData, s: float, u: np.ndarray) -> np.ndarray:
    w = np.zeros((len(d.plane_element), 3))
    e = np.eye(3)
    for j, (el, ch) in enumerate(zip(d.plane_element, d.plane_channel, strict=True)):
        if el == 0:
            w[j] = s * e[ch]  # mean plane of channel c
        elif ch < 0:
            w[j] = u[:, el - 1]  # mono element i
        else:
            w[j] = u[ch, el - 1] * e[ch]  # rgb element i channel c
    return w


def colour_clause(d: RuntimeData, w: np.ndarray) -> np.ndarray:
    return np.maximum(np.einsum("hwq,qc->hwc", d.planes.astype(np.float64), w), 0.0)


def gamma_undo_clause(c: np.ndarray, g: float | None) -> np.ndarray:
    return c if g is None else c ** g


#: RUNTIME_FORMULA, clause by clause, with the function above that implements each.
CLAUSES = [
    ("x = per-point mean over its cluster of albedo/pi * E_direct (P x 3)", x_clause),
    ("x' = sign(x)|x|^(1/gamma) (identity without gamma)", gamma_clause),
    ("s = ||x'|| (Frobenius)", s_clause),
    ("u_c = transfer[c] @ x'_c + s * offset[c] (c = R, G, B)", u_clause),
    ("plane weights: mean plane of channel c -> s*e_c, mono element i -> (u_R,i, u_G,i, "
     "u_B,i), rgb element i channel c -> u_c,i*e_c", weights_clause),
    ("colour = max(sum_j plane_j * w_j, 0) (negative light is clamped)", colour_clause),
    ("with gamma: colour = colour^gamma", gamma_undo_clause),
]


def test_the_clauses_are_the_formula():
    assert "; ".join(text for text, _ in CLAUSES) == RUNTIME_FORMULA
    assert cpu.RUNTIME_FORMULA is RUNTIME_FORMULA  # the runtime names the same string


def random_runtime(channels: str, gamma: float | None, seed: int) -> RuntimeData:
    """A small bundle's runtime data with random planes, transfer, offset and points."""
    rng = np.random.default_rng(seed)
    n_b, P, S, h, w = 5, 7, 19, 6, 9
    if channels == "mono":
        el = np.r_[0, 0, 0, np.arange(1, n_b + 1)]
        ch = np.r_[0, 1, 2, -np.ones(n_b, int)]
    else:
        el = np.r_[0, 0, 0, np.repeat(np.arange(1, n_b + 1), 3)]
        ch = np.r_[0, 1, 2, np.tile([0, 1, 2], n_b)]
    owner = np.r_[np.arange(P), rng.integers(0, P, S - P)].astype(np.int32)
    normal = rng.normal(size=(S, 3))
    return RuntimeData(
        planes=rng.normal(size=(h, w, len(el))).astype(np.float32),
        plane_element=el.astype(np.int32), plane_channel=ch.astype(np.int8),
        transfer=rng.normal(size=(3, n_b, P)).astype(np.float32),
        offset=rng.normal(size=(3, n_b)).astype(np.float32), gamma=gamma,
        coverage=rng.random((h, w)) > 0.3,
        cluster_position=rng.uniform(-1, 1, (S, 3)).astype(np.float32),
        cluster_normal=(normal / np.linalg.norm(normal, axis=1, keepdims=True)
                        ).astype(np.float32),
        cluster_albedo=rng.uniform(0, 0.99, (S, 3)).astype(np.float32),
        cluster_owner=owner, point_count=P)


@pytest.mark.parametrize(("channels", "gamma"), [("mono", None), ("rgb", None),
                                                 ("mono", 2.2), ("rgb", 1.6)])
def test_runtime_cpu_is_the_formula(channels, gamma):
    d = random_runtime(channels, gamma, seed=len(channels) + int(10 * (gamma or 0)))
    lights = [point_light([0.2, 2.5, 0.1], 3.0), point_light([-2.0, 0.5, 1.5], 1.0)]
    x = x_clause(d, lights)
    np.testing.assert_allclose(cpu.shade_points(d, lights, None), x, rtol=1e-12, atol=0)
    for n in (1, 2, d.n_basis, None):
        use = d.transfer.shape[1] if n is None else n - 1
        xg = gamma_clause(x, gamma)
        s = s_clause(xg)
        w = weights_clause(d, s, u_clause(d, xg, s, use))
        got_w = cpu.plane_weights(d, x, n)
        np.testing.assert_allclose(got_w, w, rtol=0, atol=1e-6 * np.abs(w).max())
        colour = gamma_undo_clause(colour_clause(d, w), gamma)
        got = cpu.blend(d, got_w)
        scale = np.einsum("hwq,qc->hwc", np.abs(d.planes.astype(np.float64)), np.abs(w))
        if gamma is not None:  # d(c^g) = g·c^(g−1)·dc
            scale = gamma * np.maximum(colour, scale) ** ((gamma - 1) / gamma) * scale
        assert (np.abs(got - colour) <= 1e-5 * scale + 1e-30).all(), (channels, gamma, n)
