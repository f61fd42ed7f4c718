"""The reference path tracer's volumetric random walk (docs/subsurface.md).

Its own code, not the fast operator's (:mod:`prtcore.transport.subsurface`): free flights
are sampled by delta tracking against the majorant σ̄ = max_c σ_t,c, with per-channel
weights (spectral tracking, Kutz et al. 2017, "Spectral and decomposition tracking for
rendering heterogeneous volumes", SIGGRAPH): at a tentative collision the walk scatters
with probability P_s and passes on (a null collision) otherwise, and channel c is weighted
``σ_s,c / (σ̄ P_s)`` or ``(σ̄ − σ_t,c) / (σ̄ (1 − P_s))``. With σ_t shared by the channels
there are no null collisions and the weight of a scattering event is α_c. Scattering
follows the Henyey–Greenstein phase function (sampled by inverting its CDF here, written
out again rather than shared with the operator; the frame about the direction is the
project's one rule, :func:`prtcore.core.geometry.orthonormal_frame`). A walk ends where
it reaches a face: a back face of the medium's own material is an exit; any other face
ends it with no light.
"""

from __future__ import annotations

import math

import numpy as np

from prtcore.core.geometry import orthonormal_frame
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Subsurface


def henyey_greenstein(w: np.ndarray, g: float, u: np.ndarray) -> np.ndarray:
    """New directions (n, 3) about unit w (n, 3) with HG mean cosine g; u (n, 2) uniform."""
    if g == 0.0:
        mu = 2.0 * u[:, 0] - 1.0
    else:
        frac = (1.0 - g * g) / (1.0 + g - 2.0 * g * u[:, 0])
        mu = (1.0 + g * g - frac * frac) / (2.0 * g)
    mu = np.clip(mu, -1.0, 1.0)
    sin = np.sqrt(1.0 - mu * mu)
    phi = 2.0 * math.pi * u[:, 1]
    a, b = orthonormal_frame(w)
    out = (sin * np.cos(phi))[:, None] * a + (sin * np.sin(phi))[:, None] * b \
        + mu[:, None] * w
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def medium_walk(tracer: RayTracer, medium: Subsurface, exit_faces: np.ndarray,
                origin: np.ndarray, direction: np.ndarray, rng: np.random.Generator,
                max_events: int = 1 << 16
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Walk n paths (origin (n, 3) inside the medium, unit direction (n, 3), float64) to
    the boundary.

    exit_faces : (f,) bool, the faces whose back is an exit (the medium's own). Returns,
    for the m walks that exited: their index (m,) int64, triangle (m,) int64, barycentric
    (m, 3), exit direction (m, 3) and RGB weight (m, 3) float64 (the product of the
    tracking weights; its expectation is the light a unit radiance at the exit sends
    back along the walk). Walks still inside after ``max_events`` collisions end (their
    expected weight is negligible for any absorbing medium; a test checks energy with
    α = 1 on a closed mesh)."""
    sig_t = np.asarray(medium.sigma_t, np.float64)
    sig_s = sig_t * np.asarray(medium.albedo, np.float64)
    bar = float(sig_t.max())
    n = len(origin)
    none = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)),
            np.zeros((0, 3)), np.zeros((0, 3)))
    if n == 0:
        return none
    if bar <= 0:  # no medium at all: straight through
        bar = 0.0
    live = np.arange(n)
    x = np.asarray(origin, np.float64).copy()
    w = np.asarray(direction, np.float64).copy()
    weight = np.ones((n, 3))
    # the chance of a real scattering event at a tentative collision
    null = bar - sig_t
    p_s = float(sig_s.mean() / max(sig_s.mean() + null.mean(), 1e-300)) if bar > 0 else 0.0
    outs: list[tuple] = []
    for _ in range(max_events):
        if len(live) == 0:
            break
        if bar > 0:
            s = -np.log(1.0 - rng.random(len(live))) / bar
        else:
            s = np.full(len(live), np.inf)
        hits = tracer.intersect(x.astype(np.float32), w.astype(np.float32),
                                tmax=np.minimum(s, 3.0e38).astype(np.float32))
        reach = hits.hit
        if reach.any():
            r = np.flatnonzero(reach)
            tri = hits.triangle[r]
            ok = ~hits.front[r] & exit_faces[tri]
            r_ok = r[ok]
            outs.append((live[r_ok], tri[ok], hits.barycentric[r_ok], w[r_ok],
                         weight[live[r_ok]]))
        stay = np.flatnonzero(~reach & np.isfinite(s))
        live, x, w, s = live[stay], x[stay], w[stay], s[stay]
        x = x + w * s[:, None]
        scatter = rng.random(len(live)) < p_s
        sc, nu = live[scatter], live[~scatter]
        if len(sc):
            weight[sc] *= sig_s / (bar * p_s)
        if len(nu):
            weight[nu] *= null / (bar * (1.0 - p_s))
        if len(sc):
            w[scatter] = henyey_greenstein(w[scatter], float(medium.anisotropy),
                                           rng.random((int(scatter.sum()), 2)))
        # Russian roulette on the weight (unbiased: survivors are divided by their chance)
        q = np.minimum(1.0, weight[live].max(axis=1))
        alive = rng.random(len(live)) < q
        weight[live[alive]] /= q[alive, None]
        live, x, w = live[alive], x[alive], w[alive]
    if not outs:
        return none
    return tuple(np.concatenate(p) for p in zip(*outs, strict=True))
