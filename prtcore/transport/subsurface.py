"""The subsurface random walk as a transport operator (registered as "subsurface";
docs/subsurface.md, paper 6.2).

Light that enters a translucent mesh at one texel, scatters through the medium inside and
leaves at another. By reciprocity it is traced backwards: from every translucent texel x,
M = ``transport.subsurface_walks`` walks leave into the medium from origins uniform over
the texel's region (:func:`prtcore.transport.gather.jittered_origins`, the region the
reference integrates; directions cosine about the inward shading normal), fly
exponential distances with the extinction σ_t, scatter by the Henyey–Greenstein phase
function and end where they reach the boundary again, at the
texel y the light entered through. With the symmetric Lambertian boundary
(:func:`prtcore.core.materials.albedo_at`) a texel sends ρ_b/π · E into the medium, so

    E_inside(x) = Σ_y W_c(x, y) · ρ_b(y) E(y),   W_c(x, y) = 1/M Σ_{walks x→y} α_c^n

— the gather's units (rows receive, columns are the sources' values before albedo), one
matrix per colour channel c (α_c the single-scattering albedo, n the walk's scattering
events). The solver adds W_c to the surface gather G
(:func:`prtcore.transport.solve.solve_indirect`'s ``channel_matrices``).

One set of walks serves every channel whose σ_t is the same: a walk records its count n
and each channel weighs it by α_c^n. A walk survives each scattering event with
probability q = max_c α_c (Russian roulette; its weight becomes (α_c/q)^n ≤ 1), which
ends walks about as fast as absorption would. Channels with a different σ_t get walks of
their own. Walks whose first direction points out of the texel's face, that meet the
front of a face (an opaque object inside), reach a face of another material, or pass
``transport.subsurface_max_scatter`` events bring nothing (counted in the stats).
"""

from __future__ import annotations

import math
from contextlib import nullcontext
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from prtcore.core.geometry import directions_around
from prtcore.core.materials import translucent_faces
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Scene
from prtcore.core.spec import TransportSpec
from prtcore.core.tolerances import offset_origins
from prtcore.receivers.texels import TexelSpace
from prtcore.transport.base import TransportOperator, register
from prtcore.transport.gather import HitMapper, jittered_origins

#: Memory of the walks (bytes; part of the bake's model): per walk in flight (the
#: wavefront's state: starts, positions, directions, counts, hits) and per recorded
#: (receiver, source, count) entry and channel (the COO lists and their CSR). Measured
#: with tracemalloc on the sphere at 96² (16 and 64 walks per texel): 476–479 B per walk
#: at the peak, 0.85–0.92 entries per walk; rounded up to 320 + 3 × 80 = 560 B. The
#: estimate counts every receiver as translucent (an overestimate for mixed scenes).
MEM_PER_WALK = 320
MEM_PER_ENTRY = 80


@dataclass(frozen=True)
class SubsurfaceTerm:
    """The traced subsurface operator.

    matrix : (T, T) float32 CSR, empty (the walks' light differs per channel)
    channel_matrices : three (T, T) float32 CSR, W_c for R, G, B (rows receive, columns
        sorted), row sums ≤ 1
    stats : walks traced, exits, walks ended by roulette, the cap, a front or foreign face
        or an outward first direction, total scattering events, nnz per channel
    """

    matrix: sp.csr_matrix
    channel_matrices: tuple[sp.csr_matrix, sp.csr_matrix, sp.csr_matrix]
    stats: dict = field(default_factory=dict)


def sample_hg(direction: np.ndarray, g: float, u: np.ndarray) -> np.ndarray:
    """Directions scattered from ``direction`` (n, 3) unit by the Henyey–Greenstein phase
    function with mean cosine g; u (n, 2) uniform. Returns (n, 3) float64 unit."""
    if abs(g) < 1e-3:
        cos = 1.0 - 2.0 * u[:, 0]
    else:
        s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u[:, 0])
        cos = (1.0 + g * g - s * s) / (2.0 * g)
    return directions_around(direction, np.clip(cos, -1.0, 1.0), 2.0 * math.pi * u[:, 1])


def _walks(tracer: RayTracer, mapper: HitMapper, origin: np.ndarray, direction: np.ndarray,
           sigma_t: float, survive: float, anisotropy: float, max_scatter: int,
           allowed: np.ndarray, rng: np.random.Generator, timer: StageTimer | None
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Walk every start (origin, direction (n, 3) float64) to the boundary.

    Returns the walk index (m,) int64, exit texel (m,) int64 and scattering events (m,)
    int64 of the walks that left through a face whose material ``allowed[face]``, and
    counts of the others."""
    n = len(origin)
    live = np.arange(n)
    pos = np.asarray(origin, np.float64)
    d = np.asarray(direction, np.float64)
    count = np.zeros(n, dtype=np.int64)
    out_i, out_tex, out_n = [], [], []
    stats = {"front_or_other": 0, "roulette": 0, "capped": 0, "scatter_events": 0}
    steps = range(max_scatter + 1)
    it = timer.bar(steps, "subsurface walks", total=None) if timer is not None else steps
    for _ in it:
        if len(live) == 0:
            break
        u = rng.random(len(live))
        free = -np.log1p(-u) / sigma_t if sigma_t > 0 else np.full(len(live), np.inf)
        o32 = pos.astype(np.float32)
        d32 = d.astype(np.float32)
        hits = tracer.intersect(o32, d32, tmax=free.astype(np.float32))
        hit = hits.hit
        exits = np.flatnonzero(hit)
        if len(exits):
            tri = hits.triangle[exits]
            ok = ~hits.front[exits] & allowed[tri]
            stats["front_or_other"] += int((~ok).sum())
            good = exits[ok]
            if len(good):
                tex = mapper(tri[ok], hits.barycentric[good], good, o32, d32, hits.t[good])
                out_i.append(live[good])
                out_tex.append(tex)
                out_n.append(count[live[good]])
        go = np.flatnonzero(~hit & np.isfinite(free))  # a miss at σ_t = 0: lost
        live, pos, d, free = live[go], pos[go], d[go], free[go]
        pos = pos + d * free[:, None]
        count[live] += 1
        stats["scatter_events"] += len(live)
        if survive < 1.0:
            keep = rng.random(len(live)) < survive
            stats["roulette"] += int((~keep).sum())
            live, pos, d = live[keep], pos[keep], d[keep]
        capped = count[live] > max_scatter
        if capped.any():
            stats["capped"] += int(capped.sum())
            live, pos, d = live[~capped], pos[~capped], d[~capped]
        d = sample_hg(d, anisotropy, rng.random((len(live), 2)))
    stats["capped"] += len(live)
    return _cat(out_i), _cat(out_tex), _cat(out_n), stats


def _cat(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0, np.int64)


def subsurface_operator(scene: Scene, texels: TexelSpace, tracer: RayTracer, walks: int,
                        seed: int, max_scatter: int, timer: StageTimer | None = None
                        ) -> SubsurfaceTerm:
    """Trace W_c for every translucent material of the scene (see the module docstring).

    walks : M per translucent texel; seed : every random choice (same inputs + seed →
    bit-identical operator); max_scatter : events after which a walk is dropped."""
    t = texels.count
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(15,)))
    mapper = HitMapper(scene, texels, tracer)
    trans = translucent_faces(scene)
    rows_c: list[list[np.ndarray]] = [[], [], []]
    cols_c: list[list[np.ndarray]] = [[], [], []]
    vals_c: list[list[np.ndarray]] = [[], [], []]
    stats = {"walks": 0, "exits": 0, "front_or_other": 0, "roulette": 0, "capped": 0,
             "outward_start": 0, "scatter_events": 0, "translucent_texels": 0}
    tri_of = np.asarray(texels.triangle)
    origins = None
    for mi, mat in enumerate(scene.materials):
        medium = mat.subsurface
        if medium is None:
            continue
        own = np.flatnonzero(scene.face_material[tri_of] == mi)
        if not len(own):
            continue
        stats["translucent_texels"] += len(own)
        allowed = trans & (scene.face_material == mi)
        sigma = np.asarray(medium.sigma_t, np.float64)
        alpha = np.asarray(medium.albedo, np.float64)
        for s in np.unique(sigma):  # σ_t = 0: the light crosses without scattering
            chans = np.flatnonzero(sigma == s)
            owner = np.repeat(own, walks)
            geo = np.asarray(texels.geometric_normal, np.float64)[owner]
            shade = np.asarray(texels.normal, np.float64)[owner]
            if origins is None:  # uniform over each texel's region, as the reference
                origins = jittered_origins(scene, texels, walks, rng)[0]
            start = offset_origins(origins[own].reshape(-1, 3), -geo,
                                   tracer.scale).astype(np.float64)
            u = rng.random((len(owner), 2))
            d = directions_around(-shade, np.sqrt(np.clip(1.0 - u[:, 0], 0.0, None)),
                                  2.0 * math.pi * u[:, 1])
            inward = np.einsum("ij,ij->i", d, geo) < 0
            stats["outward_start"] += int((~inward).sum())
            stats["walks"] += len(owner)
            q = float(alpha[chans].max())
            idx = np.flatnonzero(inward)
            wi, tex, nsc, st = _walks(tracer, mapper, start[idx], d[idx], float(s),
                                      max(q, 1e-12), medium.anisotropy, max_scatter,
                                      allowed, rng, timer)
            for k in ("front_or_other", "roulette", "capped", "scatter_events"):
                stats[k] += st[k]
            stats["exits"] += len(wi)
            recv = owner[idx[wi]]
            for c in chans:
                ratio = alpha[c] / q if q > 0 else 0.0
                rows_c[c].append(recv)
                cols_c[c].append(tex)
                vals_c[c].append(ratio ** nsc.astype(np.float64) / walks)
    mats = []
    for c in range(3):
        if rows_c[c]:
            r, cl, v = (np.concatenate(a) for a in (rows_c[c], cols_c[c], vals_c[c]))
        else:
            r = cl = np.zeros(0, np.int64)
            v = np.zeros(0)
        m = sp.coo_matrix((v, (r, cl)), shape=(t, t)).tocsr()
        m.sum_duplicates()
        m.sort_indices()
        mats.append(m.astype(np.float32))
    stats["nnz"] = [int(m.nnz) for m in mats]
    stats["remapped_hits"] = mapper.remapped
    empty = sp.csr_matrix((t, t), dtype=np.float32)
    return SubsurfaceTerm(matrix=empty, channel_matrices=tuple(mats), stats=stats)


@register
class SubsurfaceWalk(TransportOperator):
    """Light through the media of translucent materials: W_c
    (:func:`subsurface_operator`) with the spec's walks, seed and scattering cap."""

    name = "subsurface"
    stage = "subsurface walks"
    per_channel = True
    stats_key = "subsurface"

    def build(self, scene: Scene, receiver: TexelSpace, tracer: RayTracer,
              spec: TransportSpec, timer: StageTimer | None = None) -> SubsurfaceTerm:
        ctx = timer.stage(self.stage) if timer is not None else nullcontext()
        with ctx:
            return subsurface_operator(scene, receiver, tracer, spec.subsurface_walks,
                                       spec.seed, spec.subsurface_max_scatter, timer)

    def estimate_bytes(self, receivers, configurations, spec):
        # every texel may be translucent; each walk may leave one entry per channel
        walks = int(receivers) * int(spec.subsurface_walks)
        return walks * (MEM_PER_WALK + 3 * MEM_PER_ENTRY)
