"""Direct light on the diffuse fibre with the azimuth integrated in closed form.

A diffuse fibre lit by a punctual light whose direction from the axis point is ω sees the
irradiance ``E(φ) = E_l · max(0, cos(φ − φ_l))`` around its circumference: ``φ_l`` is
the azimuth of ω's part ⟂ the tangent, and ``E_l`` the irradiance on the surface point
that faces it (normal ``n_l = ω⊥/|ω⊥|``; ``E_l = E⊥ sin θ``). With the light's
visibility V, the texel's azimuthal mean of ``L = ρ/π · E · V`` is

    mean = L_l/π · V̄,   V̄ = ∫ V(s) ds / 2 over s ∈ [−1, 1],

where ``L_l = ρ/π · E_l`` and s is the lateral position across the fibre's projected
width (the lit half's cosine weight is uniform in s). So each (texel, light, arc sample)
needs one shadow ray, from the surface point at lateral position s, s uniform (strata of
the texel's arc samples, paired at random): an unbiased estimate of V̄, where the sampled
estimator (:func:`prtcore.transport.fibre.direct_of_samples`) shades J stratified
azimuths of which about half face the light, and adds the azimuthal quadrature noise of
J = 4 samples (the mean of ``max(0, cos)`` over four stratified azimuths is 0.25–0.35
against 1/π). The harmonics take V̄ as constant over the lit half:

    order h: L_l · V̄ · c_h · (cos hφ_l, sin hφ_l),   c_1 = 1/2,
    c_h = 2 cos(hπ/2) / (π (1 − h²)) for h ≥ 2.

docs/hair.md has the measured accuracy and speed. Lights without a compiled row (an
environment) are evaluated by the sampled estimator, which integrates the environment per
surface point.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numba
import numpy as np

from prtcore.core.materials import clamp_albedo
from prtcore.core.memory import release_free_memory
from prtcore.core.progress import bar
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.emitters import compiled
from prtcore.emitters.base import emitter_for
from prtcore.receivers.strands import StrandSpace, axis_frame, interp_points

#: texels per task of one light (the shadow rays of neighbouring texels, in Morton order,
#: share Embree's nodes in cache)
FACING_CHUNK = 1 << 13


@dataclass(frozen=True)
class FacingSamples:
    """Where :func:`facing_direct` shades: ``per`` (J) arc samples per texel, stratified
    in the texel's arc interval, stored texel-major in ``order`` (the texels' Morton order
    along their axis points, (T,) int64): ``axis``, ``tangent``, ``u`` (T·J, 3) float64
    the axis point, unit tangent and the fibre frame's transported u there
    (:func:`prtcore.receivers.strands.axis_frame`), ``offset`` (T·J,) float64 the distance
    from the axis at which rays leave (the tube's circumscribed radius,
    :attr:`StrandSpace.ray_offset`), ``lateral`` (T·J,) float64 s ∈ (−1, 1), the
    position across the projected width (J strata, paired with the arc strata by a random
    permutation per texel)."""

    per: int
    order: np.ndarray
    axis: np.ndarray
    tangent: np.ndarray
    u: np.ndarray
    offset: np.ndarray
    lateral: np.ndarray


def facing_samples(space: StrandSpace, per: int, seed: int) -> FacingSamples:
    """``per`` arc samples per texel (stratum j of J, jittered from ``seed``)."""
    t, j = space.count, max(1, int(per))
    rng = np.random.default_rng(seed)
    frac = (np.arange(j)[None, :] + rng.random((t, j))) / j
    arc = space.arc[:, :1] + frac * (space.arc[:, 1:] - space.arc[:, :1])
    order = space.morton
    texel = np.repeat(order, j)
    strand = space.strand[texel]
    arc = arc[order].ravel()
    axis, tangent, u = axis_frame(space.hair, strand, arc)
    off = interp_points(space.hair, space.ray_offset[:, None], strand, arc)[:, 0]
    strata = rng.permuted(np.tile(np.arange(j), (t, 1)), axis=1)
    lateral = 2 * (strata + rng.random((t, j))) / j - 1
    return FacingSamples(j, order, axis, tangent, u, off, lateral[order].ravel())


def harmonic_weights(harmonics: int) -> np.ndarray:
    """c_h for h = 1…H ((H,) float64): the azimuthal harmonics of ``max(0, cos u)`` in
    the convention ``(1/π) ∫ f(u) cos hu du``."""
    h = np.arange(1, harmonics + 1, dtype=np.float64)
    c = np.empty(harmonics)
    c[h == 1] = 0.5
    high = h > 1
    c[high] = 2 * np.cos(h[high] * np.pi / 2) / (np.pi * (1 - h[high] ** 2))
    return c


@numba.njit(cache=True, nogil=True)
def _facing_points(row, axis, tangent, u, offset, lateral, origin, normal, cs
                   ):  # pragma: no cover - compiled
    """Row i, for the light ``row`` (:func:`compiled.light_row`) and the fibre at axis
    point i: ``normal`` the unit ω⊥ (n_l, where the irradiance E_l is evaluated),
    ``origin`` the surface point at lateral position s = ``lateral[i]`` across the
    projected width, ``axis + offset · (√(1 − s²) n_l + s (tangent × n_l))``, and ``cs``
    n_l's azimuth (cos φ_l, sin φ_l) in the frame (u, tangent × u). A light along the
    tangent (|ω⊥| = 0) gives n_l = u, where its irradiance is 0."""
    directional = row[0] == 1.0
    for i in range(len(axis)):
        t0, t1, t2 = tangent[i, 0], tangent[i, 1], tangent[i, 2]
        if directional:
            w0, w1, w2 = row[4], row[5], row[6]
        else:
            w0, w1, w2 = row[1] - axis[i, 0], row[2] - axis[i, 1], row[3] - axis[i, 2]
        d = w0 * t0 + w1 * t1 + w2 * t2
        p0, p1, p2 = w0 - d * t0, w1 - d * t1, w2 - d * t2
        ln = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
        u0, u1, u2 = u[i, 0], u[i, 1], u[i, 2]
        if ln > 0.0:
            n0, n1, n2 = p0 / ln, p1 / ln, p2 / ln
        else:
            n0, n1, n2 = u0, u1, u2
        normal[i, 0], normal[i, 1], normal[i, 2] = n0, n1, n2
        b0, b1, b2 = t1 * n2 - t2 * n1, t2 * n0 - t0 * n2, t0 * n1 - t1 * n0
        s = lateral[i]
        c = math.sqrt(max(0.0, 1.0 - s * s))
        origin[i, 0] = axis[i, 0] + offset[i] * (c * n0 + s * b0)
        origin[i, 1] = axis[i, 1] + offset[i] * (c * n1 + s * b1)
        origin[i, 2] = axis[i, 2] + offset[i] * (c * n2 + s * b2)
        v0, v1, v2 = t1 * u2 - t2 * u1, t2 * u0 - t0 * u2, t0 * u1 - t1 * u0
        cs[i, 0] = n0 * u0 + n1 * u1 + n2 * u2
        cs[i, 1] = n0 * v0 + n1 * v1 + n2 * v2


def facing_direct(space: StrandSpace, tracer: RayTracer, lights: Sequence[Light],
                  drawn: FacingSamples, harmonics: int, progress: bool = True
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The direct light of every strand texel for every light with a compiled row (see
    the module docstring): ``mean`` (T, K, 3) float32 and ``harm`` (2H, T, K, 3) float32
    (rows cos φ, sin φ, cos 2φ, …, :class:`prtcore.transport.fibre.FibreDirect`).
    Columns of lights without a row are left unwritten (the caller fills them)."""
    t, k, j = space.count, len(lights), drawn.per
    mean = np.empty((t, k, 3), dtype=np.float32)
    harm = np.empty((2 * harmonics, t, k, 3), dtype=np.float32)
    rho, _ = clamp_albedo(np.asarray(space.albedo, dtype=np.float64))
    scale = rho / math.pi
    c_h = harmonic_weights(harmonics)
    rows = [emitter_for(light).kernel_row(light) for light in lights]
    tasks = [(kk, a) for kk in range(k) if rows[kk] is not None
             for a in range(0, t, FACING_CHUNK)]

    def one(task: tuple[int, int]) -> None:
        kk, a = task
        b = min(a + FACING_CHUNK, t)
        idx = drawn.order[a:b]
        s = slice(a * j, b * j)
        m = (b - a) * j
        origin, normal, cs = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 2))
        _facing_points(rows[kk], drawn.axis[s], drawn.tangent[s], drawn.u[s],
                       drawn.offset[s], drawn.lateral[s], origin, normal, cs)
        e = np.empty((m, 3))
        o32, d32 = np.empty((m, 3), np.float32), np.empty((m, 3), np.float32)
        tmax, index = np.empty(m, np.float32), np.empty(m, np.int64)
        c = compiled.shadow_rays(rows[kk], origin, normal, 1, tracer.offset, tracer.tfar,
                                 e, o32, d32, tmax, index)
        occluded = tracer.occluded(o32[:c], d32[:c], tmax[:c])
        e[index[:c][occluded]] = 0.0
        lit = e.reshape(b - a, j, 3) * scale[idx][:, None, :]  # L_l per sample
        mean[idx, kk] = lit.mean(axis=1) / math.pi
        ang = np.arctan2(cs[:, 1], cs[:, 0]).reshape(b - a, j)
        for h in range(harmonics):
            for i, f in enumerate((np.cos, np.sin)):
                harm[2 * h + i, idx, kk] = c_h[h] * np.einsum("tjc,tj->tc", lit,
                                                              f((h + 1) * ang)) / j

    if tracer.threads > 1 and len(tasks) > 1:
        with ThreadPoolExecutor(tracer.threads) as ex:
            it = ex.map(one, tasks)
            for _ in bar(it, "direct fibres", total=len(tasks)) if progress else it:
                pass
        release_free_memory()
    else:
        for task in bar(tasks, "direct fibres", total=len(tasks)) if progress else tasks:
            one(task)
    return mean, harm
