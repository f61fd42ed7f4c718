"""Light in hair with the diffuse fibre model (paper 6.3): direct light with self-shadowing
and fibre-to-fibre multiple scattering as a sparse operator over strand texels
(registered as ``"fibre"``).

**The diffuse fibre.** A fibre is a cylinder whose surface is Lambertian with albedo ρ:
at a surface point with (radial) normal n the outgoing radiance is ``ρ/π · E(n)``. A strand
texel stores it averaged over the fibre's azimuth and over the texel's arc interval
(:mod:`prtcore.receivers.strands`): ``L̄ = ρ/π · Ē``. For one unshadowed fibre under a
directional light of illuminance E⊥ at angle θ to the fibre, the azimuthal mean of
``max(0, n·ω)`` is ``sin θ / π``, so ``L̄ = ρ E⊥ sin θ / π²`` (the closed form the tests
check).

**Geometry.** The fibres are traced as triangulated tubes (:mod:`prtcore.core.fibres`,
benchmarked against ribbons in ``benchmarks/hair_geometry.py``); rays leave a fibre from
its tube's circumscribed cylinder, so they never hit their own segment.
:func:`hair_tracer` builds the one tracer of a hair bake: the scene's triangles (a head,
when hair and mesh are baked together) first, then the fibre tubes.

**Direct light** (:func:`fibre_direct`, ``hair.direct``): by default ("facing",
:mod:`prtcore.transport.fibre_facing`) per texel and light one shadow ray per arc sample,
from a point across the fibre's projected width, with the azimuthal mean and harmonics of
the clamped cosine in closed form; or ("sampled") J points on the fibre surface,
stratified in azimuth and jittered in arc length, each with its radial normal, the mean of
their shadowed irradiance Ē (the same light evaluation as surfaces,
:func:`prtcore.emitters.punctual.irradiance` through
:func:`prtcore.transport.direct.direct_radiance`).

**Multiple scattering** (:class:`FibreGather`): from each texel, M cosine-distributed
rays about the radial normal at M surface points (azimuths stratified); a ray that hits
fibre texel j adds 1/M to ``G[i, j]``: the incident radiance it brings is the hit fibre's
outgoing radiance, which the receiver stores radially constant (the paper's
approximation). ``E_ind = G · (ρ ∘ (E_d + E_ind))`` is then solved by
:func:`prtcore.transport.solve.solve_indirect` exactly as for surfaces.

**The first bounce keeps the direct light's azimuthal variation.** Radially constant
storage overestimates light bounced into shadow: a fibre under another sees that one's
dark underside, not its mean. Measured against the project's path tracer
(:mod:`prtcore.reference.fibres`, which shades every hit with its own normal) on a dense
hairball under a sun and a point light, the indirect came out 12 % too bright. So
:func:`fibre_direct` also keeps the first ``HARMONICS`` azimuthal harmonics of the
direct light, the gather records the azimuth ψ of every hit on the hit fibre (the
normal a round fibre presents to the ray, :func:`prtcore.core.fibres.cylinder_normal`),
and
:func:`harmonic_first_bounce` adds ``Σ_h G_h L_h`` to the first bounce (the solver's
``first_bounce``): the bias fell to about 4 % (``benchmarks/hair_accuracy.py``). Later
bounces stay radially constant.

With a mesh that receives (a hair + mesh bake, :mod:`prtcore.transport.hair_mesh`), the
gather's rays that hit the front of the mesh go to its atlas texels (``mesh_texels``);
otherwise a mesh hit brings nothing (the mesh only occludes and shadows).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.stats import qmc

from prtcore.core.fibres import (
    DEFAULT_PIECES,
    DEFAULT_SIDES,
    FibreMesh,
    cylinder_normal,
    fibre_tubes,
    segment_hits,
    transported_frames,
)
from prtcore.core.geometry import directions_around
from prtcore.core.progress import StageTimer, bar
from prtcore.core.raytrace import RayTracer, default_threads
from prtcore.core.scene import Light, Scene
from prtcore.core.sparse import SparseProduct
from prtcore.core.spec import DIRECT_ESTIMATORS, TransportSpec
from prtcore.emitters.base import emitter_for
from prtcore.receivers.strands import StrandSpace, azimuth_frame, texel_turn
from prtcore.receivers.texels import TexelSpace
from prtcore.transport.base import TransportOperator, register
from prtcore.transport.direct import direct_radiance
from prtcore.transport.fibre_facing import facing_direct, facing_samples
from prtcore.transport.gather import hit_share, near_field_reach

#: rays per intersect call of the fibre gather
FIBRE_BATCH = 1 << 18
#: Memory of the fibre gather (bytes): per texel and gather ray (where its sample lies,
#: arc and azimuth, from :meth:`StrandSpace.surface_sample_params`; the (row, column,
#: azimuth) triples before they are summed, their sorting permutation, scipy's COO → CSR
#: copies, and the three CSR matrices), and per ray in flight (the batch's origins,
#: normals and axis points, directions, hit records). Measured (benchmarks/stage_memory.py,
#: the hairball, M = 64, 2026-12-05): the gather stage's peak RSS less the RSS with the
#: tubes built is 60, 79 and 78 bytes a ray at 10k, 40k and 140k strands; 96 covers that
#: with a margin. (40 until then, when the gather was counted on top of the solve's
#: arrays, which it never meets: :func:`prtcore.hairbake.check_hair_memory`'s phases.)
MEM_PER_TEXEL_RAY = 96
MEM_PER_RAY_IN_FLIGHT = 300
#: Memory of the fibre tubes per polyline segment (bytes): prtcore's float64 vertices,
#: faces and face normals plus Embree's copies and BVH, measured at 10k strands × 16
#: segments by benchmarks/hair_geometry.py (89 + 112 MiB) and rounded up; segments cut
#: in two (DEFAULT_PIECES = 2) raised the 10k bake's peak by 0.15 GiB (≈ 1000 bytes a
#: segment), so 2400.
MEM_PER_FIBRE_SEGMENT = 2400
#: Memory of one entry of a fibre operator's CSR matrix (bytes): a float32 value and an
#: int32 column; the gather makes at most one entry per ray and matrix
MEM_PER_OPERATOR_ENTRY = 8


def hair_tracer(space: StrandSpace, scene: Scene | None = None, sides: int = DEFAULT_SIDES,
                threads: int | None = None, pieces: int = DEFAULT_PIECES
                ) -> tuple[RayTracer, FibreMesh]:
    """The tracer of a hair bake and its fibre tubes: ``scene``'s triangles (if any) with
    indices [0, F), then the tubes' with indices F + their own. The scale (ray offsets,
    "infinite" distance) is the radius of everything's bounds. ``pieces``: sub-prisms per
    segment (:data:`prtcore.core.fibres.DEFAULT_PIECES`, for the BVH's sake)."""
    mesh = fibre_tubes(space.hair, sides, pieces)
    if scene is not None and scene.triangle_count:
        positions = np.concatenate([scene.positions, mesh.positions])
        faces = np.concatenate([scene.faces, mesh.faces + len(scene.positions)])
    else:
        positions, faces = mesh.positions, mesh.faces
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    scale = float(np.linalg.norm(hi - lo) / 2)
    return RayTracer(positions, faces, scale=scale, threads=threads), mesh


#: azimuthal harmonics of the direct light carried through the first bounce
HARMONICS = 1

#: Texels per block of :func:`direct_of_samples` at most: Morton-ordered blocks share
#: Embree's nodes in cache (:func:`direct_samples`).
DIRECT_BLOCK = 1 << 14
#: Bytes a block of :func:`direct_of_samples` holds at most (:func:`direct_block`): its
#: samples' radiance (n, J, K, 3) and a weight's F coefficients (F, n, K, 3), float32.
#: Until 2026-12-07 the block was always 16 384 texels, so they grew with (J + F)·K: the
#: 10k head's second order (F = 10, K = 528) held 1.4 GiB of them at J = 4 and 2.5 GiB at
#: J = 16 (peak 15.0 GiB against 13.6), the tangle at J = 32 all of its 10 000 texels'
#: 2.5 GiB.
DIRECT_BLOCK_BYTES = 1 << 29


def direct_block(samples: int, lights: int, terms: int = 0) -> int:
    """Texels per block of :func:`direct_of_samples` for J = ``samples`` surface samples,
    K = ``lights`` and a weight of F = ``terms`` coefficients (0: none, the diffuse
    fibre's mean and harmonics): :data:`DIRECT_BLOCK`, fewer where the block's
    ``(J + F) K`` float32 triples per texel would pass :data:`DIRECT_BLOCK_BYTES`; at
    least one. Each texel's value is the same whichever block computes it."""
    return int(max(1, min(DIRECT_BLOCK,
                          DIRECT_BLOCK_BYTES // _block_texel_bytes(samples, lights, terms))))


def direct_block_bytes(texels: int, samples: int, lights: int, terms: int = 0) -> int:
    """What the largest block of :func:`direct_of_samples` holds (bytes) for ``texels``
    strand texels (:func:`direct_block`): the memory estimates add it to the direct
    light's stage."""
    return min(texels, direct_block(samples, lights, terms)) \
        * _block_texel_bytes(samples, lights, terms)


def _block_texel_bytes(samples: int, lights: int, terms: int) -> int:
    """A texel's share of a direct-light block: (J + F)·K float32 triples."""
    return 12 * (samples + terms) * max(1, lights)


@dataclass(frozen=True)
class FibreDirect:
    """Direct light of the strand texels: the azimuthal mean ``mean`` (T, K, 3) float32,
    L̄_d = ρ/π · Ē_d (what the texel stores), and its azimuthal harmonics ``harmonics``
    (2H, T, K, 3) float32, rows (cos φ, sin φ, cos 2φ, sin 2φ, …):
    ``L_d(φ) ≈ mean + Σ_h (c_h cos hφ + s_h sin hφ)`` in the fibre's frame
    (:func:`prtcore.receivers.strands.azimuth_frame`)."""

    mean: np.ndarray
    harmonics: np.ndarray


#: arc samples per texel of the facing estimator with ``hair.direct_samples = "auto"``
#: (docs/hair.md: the 10k hairball's accuracy and time against the sampled estimator)
FACING_SAMPLES = 2


def direct_sample_count(estimator: str, samples: int | str, transport_samples: int,
                        orders: int = HARMONICS) -> int:
    """Samples per texel of the direct light (``hair.direct_samples``; "auto":
    :data:`FACING_SAMPLES` for "facing", ``max(4·orders, transport.direct_samples)`` for
    "sampled", whose J > 2H stratified azimuths keep H harmonics unaliased)."""
    if samples != "auto":
        return int(samples)
    if estimator == "facing":
        return FACING_SAMPLES
    return max(4 * orders, int(transport_samples))


def fibre_direct(space: StrandSpace, tracer: RayTracer, lights: Sequence[Light],
                 samples: int, seed: int, harmonics: int = HARMONICS,
                 estimator: str = "facing") -> FibreDirect:
    """Direct outgoing radiance of every strand texel for every light, shadowed by
    everything in ``tracer`` (other fibres, the mesh): the azimuthal mean and ``harmonics``
    (H) harmonics. ``estimator`` (:data:`prtcore.core.spec.DIRECT_ESTIMATORS`): "facing"
    (one shadow ray per arc sample and light, :mod:`prtcore.transport.fibre_facing`)
    with ``samples`` arc samples per texel, or "sampled" with ``samples`` (J) surface
    points per texel (:meth:`~prtcore.receivers.strands.StrandSpace.surface_samples`,
    azimuths stratified; harmonics ``(2/J) Σ L_j (cos hφ_j, sin hφ_j)``, J > 2H keeps
    them unaliased)."""
    return direct_of_draw(space, tracer, lights,
                          draw_direct(space, samples, seed, estimator, lights), harmonics,
                          progress=True)


def draw_direct(space: StrandSpace, samples: int, seed: int, estimator: str,
                lights: Sequence[Light]) -> tuple:
    """What the direct light of ``estimator`` draws once for any of ``lights``:
    (:class:`~prtcore.transport.fibre_facing.FacingSamples` or None, :func:`direct_samples`'
    tuple or None). The facing estimator's lights without a compiled row (an
    environment) take the sampled estimator's ``max(4, 2·samples)`` points."""
    if estimator not in DIRECT_ESTIMATORS:
        raise ValueError(f"hair.direct: unknown estimator {estimator!r} "
                         f"(expected one of {', '.join(DIRECT_ESTIMATORS)})")
    if estimator == "sampled":
        return None, direct_samples(space, samples, seed)
    return (facing_samples(space, samples, seed),
            direct_samples(space, max(4, 2 * samples), seed) if _rowless(lights) else None)


def _rowless(lights: Sequence[Light]) -> list[int]:
    """Indices of the lights without a compiled row (an environment): the facing
    estimator leaves them to the sampled one."""
    return [i for i, light in enumerate(lights)
            if emitter_for(light).kernel_row(light) is None]


def direct_of_draw(space: StrandSpace, tracer: RayTracer, lights: Sequence[Light],
                   drawn: tuple, harmonics: int, progress: bool) -> FibreDirect:
    """:func:`fibre_direct` for ``lights`` from :func:`draw_direct`'s ``drawn``."""
    facing, sampled = drawn
    if facing is None:
        return direct_of_samples(space, tracer, lights, sampled, harmonics, progress)
    mean, harm = facing_direct(space, tracer, lights, facing, harmonics, progress)
    rest = _rowless(lights)
    if rest:
        part = direct_of_samples(space, tracer, [lights[i] for i in rest], sampled,
                                 harmonics, progress=False)
        mean[:, rest] = part.mean
        harm[:, :, rest] = part.harmonics
    return FibreDirect(mean, harm)


def direct_samples(space: StrandSpace, samples: int, seed: int) -> tuple:
    """What :func:`fibre_direct` draws once for any lights: the surface samples' origin,
    normal (t, J, 3) and azimuth phi (t, J), and the texels' order (t,) int64 along the
    3-D Morton curve of their axis points. Blocks of texels in that order, not strand by
    strand, let one light's shadow rays from neighbouring texels share Embree's nodes in
    cache (10k hairball: 0.56 → 0.84–0.96 M shadow rays/s on one thread); each texel's
    value is the same whichever block computes it."""
    origin, normal, _, phi = space.surface_samples(samples, seed)
    order = space.morton
    return origin, normal, phi, order


def direct_of_samples(space: StrandSpace, tracer: RayTracer, lights: Sequence[Light],
                      drawn: tuple, harmonics: int, progress: bool,
                      weight: Callable | None = None, terms: int = 0,
                      out: Sequence[np.ndarray] | None = None
                      ) -> FibreDirect | np.ndarray | Sequence[np.ndarray]:
    """:func:`fibre_direct` for ``lights`` from :func:`direct_samples`' ``drawn``,
    :func:`direct_block` texels at a time (a progress bar over them with ``progress``).
    weight : another fibre's weighting of the samples instead of the texel's ρ,
    ``weight(idx (n,) texels, origin (n, J, 3), lights, rad (n, J, K, 3) float32)`` →
    (F, n, K, 3) float32, the F (``terms``) weighted means of the samples'
    ``E/π · max(0, n·ωl) · V`` (``rad``; :mod:`prtcore.transport.fibre_chiang`); the
    result is then those means (F, T, K, 3) float32 (no harmonics), or written into
    ``out``, F (T, K, 3) float32 arrays (views of a larger one: a hair + mesh bake's
    stacked direct light), and ``out`` returned."""
    origin, normal, phi, order = drawn
    t, j, k = space.count, phi.shape[1], len(lights)
    block = direct_block(j, k, terms)
    if weight is None:
        mean = np.empty((t, k, 3), dtype=np.float32)
        harm = np.empty((2 * harmonics, t, k, 3), dtype=np.float32)
    weighted = out  # (F, T, K, 3), allocated when the weight's F is known
    blocks = range(0, t, block)
    for a in bar(blocks, "direct fibres", total=len(blocks)) if progress else blocks:
        idx = order[a:a + block]
        # with a weight, E/π·max(0, n·ω)·V alone (ρ = 1/2 and twice: ρ is clamped < 1)
        rho = space.albedo[idx] if weight is None else np.full((len(idx), 3), 0.5)
        rad = direct_radiance(None, tracer, lights, origin[idx].reshape(-1, 3),
                              normal[idx].reshape(-1, 3), np.repeat(rho, j, axis=0)
                              ).reshape(len(idx), j, k, 3)
        if weight is not None:
            rad *= np.float32(2)
            w = weight(idx, origin[idx], lights, rad)
            if weighted is None:
                weighted = np.empty((len(w), t, k, 3), dtype=np.float32)
            for i in range(len(w)):  # each coefficient's rows (views need not stack)
                weighted[i][idx] = w[i]
            continue
        mean[idx] = rad.mean(axis=1)
        for h in range(harmonics):
            for i, f in enumerate((np.cos, np.sin)):
                harm[2 * h + i, idx] = 2 * np.einsum("tjkc,tj->tkc", rad,
                                                     f((h + 1) * phi[idx])) / j
    if weight is not None:
        return weighted
    return FibreDirect(mean, harm)


@dataclass(frozen=True)
class MeshHits:
    """The fibre gather's rays whose first hit is the front of the mesh (a hair + mesh
    bake), by texel and then in the order of its samples: ``row`` (n,) int64 strand
    texel, ``col`` (n,) int64 atlas texel, ``triangle`` (n,) int64 and ``barycentric``
    (n, 3) float64 the hit, ``t`` (n,) float64 its distance; with :func:`fibre_gather`'s
    ``ray_data``, ``data`` (n, F) float32 its values for these rays (else None)."""

    row: np.ndarray
    col: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    t: np.ndarray
    data: np.ndarray | None = None


@dataclass(frozen=True)
class FibreTerm:
    """The fibre gather. ``matrix`` (T, T) float32 CSR, rows receive: 1/M per ray from
    texel i that hits texel j; ``harmonics``: 2H more such matrices, the same rays
    weighted by (cos ψ, sin ψ, cos 2ψ, sin 2ψ, …) / M, ψ the azimuth of the hit point on
    fibre j (for the first bounce of the direct light's harmonics,
    :func:`harmonic_first_bounce`); ``block``: with ``all_bounces``, the (3T, 3T) gather
    on every texel's (mean, cos, sin) harmonics (:func:`harmonic_block`); ``stats``: rays,
    fibre hits, mesh hits, misses."""

    matrix: sp.csr_matrix
    harmonics: tuple[sp.csr_matrix, ...]
    block: sp.csr_matrix | None = None
    stats: dict = field(default_factory=dict)
    #: with a mesh that receives (a hair + mesh bake): (T, T_m) float32 CSR, 1/M per ray
    #: from strand texel i whose first hit is the front of the mesh at atlas texel j
    mesh: sp.csr_matrix | None = None
    #: the same with ``all_bounces``: (nT, T_m), row block a ∈ (mean, cos, sin, …) of the
    #: receiving texel weighted by (1, 2 cos φ_o, 2 sin φ_o, …) (:func:`harmonic_block`'s w)
    mesh_block: sp.csr_matrix | None = None
    #: with a mesh that receives: every ray's hit on it (:class:`MeshHits`)
    mesh_hits: MeshHits | None = None
    #: with :func:`fibre_gather`'s ``ray_data``: every fibre hit's (row (n,) int32,
    #: column (n,) int32, data (n, F) float32)
    rays: tuple | None = None


def stratified_rays(space: StrandSpace, rays: int, seed: int
                    ) -> tuple[np.ndarray, np.ndarray, Callable]:
    """Randomised quasi-Monte Carlo gather rays: one scrambled Sobol' set of ``rays``
    points in [0, 1)⁴ (scipy.stats.qmc, seeded), shifted modulo 1 by a uniform random
    vector per texel (Cranley–Patterson), so every ray is still uniform (the estimate
    stays unbiased) while a texel's rays cover arc × azimuth × direction evenly.
    Returns the arcs (t·M,) float64 (metres), the surface azimuths (t·M,) float64 and
    ``direction_at(ray)`` → (u, ψ) (n,) each: the cosine lobe's u (cos² of the polar
    angle) and azimuth of rays ``ray`` (n,) int (texel·M + k), made per batch."""
    t = space.count
    bits = max(int(np.ceil(np.log2(max(rays, 1)))), 0)
    point = qmc.Sobol(d=4, scramble=True, seed=np.random.default_rng([seed, 3])
                      ).random_base2(bits)[:rays]  # (M, 4)
    shift = np.random.default_rng([seed, 4]).random((t, 4))

    def at(dim: int, ray: np.ndarray) -> np.ndarray:
        return np.mod(point[ray % rays, dim] + shift[ray // rays, dim], 1.0)

    def grid(dim: int) -> np.ndarray:  # (t, M), without a (t·M,) index array
        return np.mod(point[None, :, dim] + shift[:, None, dim], 1.0)

    arc = space.arc[:, :1] + grid(0) * (space.arc[:, 1:] - space.arc[:, :1])
    return (arc.reshape(-1), (2 * np.pi * grid(1)).reshape(-1),
            lambda ray: (at(2, ray), 2 * np.pi * at(3, ray)))


def fibre_gather(space: StrandSpace, tracer: RayTracer, mesh: FibreMesh, mesh_faces: int,
                 rays: int, seed: int, harmonics: int = HARMONICS,
                 all_bounces: bool = False, mesh_texels: Callable | None = None,
                 mesh_columns: int = 0, orders: int = 1,
                 ray_data: Callable | None = None,
                 harmonic_rows: bool | np.ndarray | Callable[[float], bool | np.ndarray]
                 = True, stratified: bool = False) -> FibreTerm:
    """Trace the fibre-to-fibre operator G with ``rays`` (M) cosine rays per texel.
    ``mesh_faces``: the number of scene triangles before the fibre tubes in ``tracer``.
    mesh_texels : the mesh receives too (a hair + mesh bake): a
    :class:`prtcore.transport.gather.HitMapper` of its ``mesh_columns`` atlas texels;
    rays whose first hit is the front of a mesh face go to :attr:`FibreTerm.mesh` (None:
    mesh hits bring nothing).
    all_bounces : also build :attr:`FibreTerm.block`, the gather on the (mean, cos, sin)
    harmonics of every texel (:func:`harmonic_block`), up to order ``orders``;
    ``harmonic_rows=False``: its harmonic rows take nothing from other fibres (the mesh
    block's still take the mesh's light); a (T,) bool array: only the marked texels'
    do; a function: called with the share of the rays that met a fibre once they are
    traced, it returns one of those (:func:`harmonic_receivers` for "adaptive").
    ``stats["harmonic_receivers"]``: the share of texels whose harmonic rows take other
    fibres' light.
    ray_data : what another fibre needs of every ray that hits a fibre, ``ray_data(texel
    (n,), arc (n,), d (n, 3))`` → (n, F): kept in :attr:`FibreTerm.rays`
    (:mod:`prtcore.transport.fibre_chiang` weights the rays with it).
    stratified : each texel's M rays take their arc, surface azimuth and direction from
    one scrambled Sobol' set shifted per texel (:func:`stratified_rays`) instead of
    independent draws (the arc uniform, the azimuth in M strata, the direction free)."""
    t = space.count
    hair = space.hair
    # the samples' places drawn once (16 bytes a ray), their points made per batch: the
    # (t·M, 3) float64 origins, normals and axis points at once were 72 bytes a ray
    # (6.4 GiB for 140k strands at M = 64)
    if stratified:
        sample_arc, phi, direction_at = stratified_rays(space, rays, seed)
    else:
        sample_arc, phi = (x.reshape(-1) for x in space.surface_sample_params(rays, seed))
    rng = np.random.default_rng([seed, 1])
    frame_u = transported_frames(hair)[1]  # once, not per batch
    rows_all, cols_all, cs_all, po_all, rw_all = [], [], [], [], []
    mesh_rows, mesh_cols, mesh_po, mesh_tri, mesh_bary, mesh_t = [], [], [], [], [], []
    mesh_rw = []
    n_fibre = n_mesh = 0
    total = t * rays
    starts = range(0, total, FIBRE_BATCH)
    # the rays traced texel by texel in the Morton order of the texels' axis points, so
    # that a batch's origins share Embree's upper nodes in cache (as the direct light's)
    order = space.morton
    for a in bar(starts, "fibre gather", total=len(starts)):
        b = min(a + FIBRE_BATCH, total)
        pos = np.arange(a, b)
        ray = order[pos // rays] * rays + pos % rays  # the rays' own indices
        if stratified:
            u, psi = direction_at(ray)
        else:  # the draws in their old order: the diffuse fibre's bundles stay the same
            u = rng.random(b - a)
            psi = 2 * np.pi * rng.random(b - a)
        origin, normal, _ = space.surface_points(ray // rays, sample_arc[ray], phi[ray],
                                                 frame_u)
        d = directions_around(normal, np.sqrt(u), psi)
        del normal
        hits = tracer.intersect(origin, d)
        fib = hits.triangle >= mesh_faces
        n_fibre += int(fib.sum())
        n_mesh += int((hits.hit & ~fib).sum())
        if mesh_texels is not None:  # the front of the mesh: its atlas texel receives
            on = np.flatnonzero(hits.hit & ~fib & hits.front)
            mesh_rows.append((ray[on] // rays).astype(np.int32))
            mesh_cols.append(mesh_texels(hits.triangle, hits.barycentric, on, origin, d,
                                         hits.t, index=on).astype(np.int32))
            if all_bounces:
                mesh_po.append(phi[ray[on]].astype(np.float32))
            mesh_tri.append(hits.triangle[on])
            mesh_bary.append(hits.barycentric[on])
            mesh_t.append(hits.t[on])
            if ray_data is not None:
                mesh_rw.append(ray_data(ray[on] // rays, sample_arc[ray[on]],
                                        d[on]).astype(np.float32))
        del origin
        fh = fibre_hits(space, mesh, hits.triangle[fib] - mesh_faces,
                        hits.barycentric[fib], d[fib], rng, frame_u)
        rows_all.append((ray[fib] // rays).astype(np.int32))
        cols_all.append(fh.texel.astype(np.int32))
        cs_all.append(fh.cs.astype(np.float32))
        if ray_data is not None:
            rw_all.append(ray_data(ray[fib] // rays, sample_arc[ray[fib]],
                                   d[fib]).astype(np.float32))
        if all_bounces:
            po_all.append(phi[ray[fib]].astype(np.float32))
    # back in texel order (stable: a texel's rays stay in the order of its samples), as
    # RayBlockProduct and MeshHits' readers expect
    rows, perm = _by_row(rows_all)
    cols = np.concatenate(cols_all)[perm] if cols_all else np.zeros(0, np.int32)
    cs = np.concatenate(cs_all)[perm] if cs_all else np.zeros((0, 2), np.float32)

    def csr(w: np.ndarray) -> sp.csr_matrix:
        m = sp.csr_matrix((w / np.float32(rays), (rows, cols)), shape=(t, t))
        m.sum_duplicates()
        m.sort_indices()
        return m

    psi = np.arctan2(cs[:, 1], cs[:, 0])
    harm = tuple(csr(f((h + 1) * psi).astype(np.float32)) for h in range(harmonics)
                 for f in (np.cos, np.sin))
    block = None
    stats = {"rays": total, "fibre_hits": n_fibre, "mesh_hits": n_mesh,
             "misses": total - n_fibre - n_mesh}
    if all_bounces:
        if callable(harmonic_rows):
            harmonic_rows = harmonic_rows(n_fibre / max(total, 1))
        stats["harmonic_receivers"] = float(np.mean(harmonic_rows))
        po = np.concatenate(po_all)[perm] if po_all else np.zeros(0, np.float32)
        block = harmonic_block(t, rays, rows, cols, po, psi, orders, harmonic_rows)
    to_mesh = mesh_block = mesh_hits = None
    if mesh_texels is not None:
        mr, mperm = _by_row(mesh_rows)
        mc = np.concatenate(mesh_cols)[mperm] if mesh_cols else np.zeros(0, np.int32)
        to_mesh = sp.csr_matrix((np.full(len(mr), 1 / np.float32(rays), np.float32),
                                 (mr, mc)), shape=(t, mesh_columns))
        to_mesh.sum_duplicates()
        to_mesh.sort_indices()
        if all_bounces:
            mpo = np.concatenate(mesh_po)[mperm] if mesh_po else np.zeros(0, np.float32)
            w = fourier_rows(mpo, orders, 2)
            mesh_block = sp.csr_matrix(
                (np.concatenate([w[a] / np.float32(rays) for a in range(len(w))]),
                 (np.concatenate([mr.astype(np.int64) + a * t for a in range(len(w))]),
                  np.tile(mc, len(w)))), shape=(len(w) * t, mesh_columns))
            mesh_block.sum_duplicates()
            mesh_block.sort_indices()
        mesh_hits = MeshHits(row=mr.astype(np.int64), col=mc.astype(np.int64),
                             triangle=np.concatenate(mesh_tri)[mperm] if mesh_tri else
                             np.zeros(0, np.int64),
                             barycentric=np.concatenate(mesh_bary)[mperm] if mesh_bary else
                             np.zeros((0, 3)),
                             t=np.concatenate(mesh_t)[mperm] if mesh_t else np.zeros(0),
                             data=np.concatenate(mesh_rw)[mperm] if mesh_rw else None)
    kept = None
    if ray_data is not None:
        kept = (rows, cols, np.concatenate(rw_all)[perm] if rw_all else
                np.zeros((0, 1), np.float32))
    return FibreTerm(matrix=csr(np.ones(len(rows), np.float32)), harmonics=harm,
                     block=block, mesh=to_mesh, mesh_block=mesh_block, mesh_hits=mesh_hits,
                     rays=kept, stats=stats)


def _by_row(parts: list) -> tuple[np.ndarray, np.ndarray]:
    """The rows of a gather's batches ((n_i,) int32 each) concatenated and sorted, and the
    stable permutation that sorts them ((n,) int64)."""
    if not parts:
        return np.zeros(0, np.int32), np.zeros(0, np.int64)
    rows = np.concatenate(parts)
    perm = np.argsort(rows, kind="stable")
    return rows[perm], perm


class FibreHits(NamedTuple):
    """Rays that hit fibres (:func:`fibre_hits`): the strand texel hit ``texel`` (n,)
    int64, the azimuth ψ of the point hit in the fibre's frame ``cs`` (cos ψ, sin ψ)
    (n, 2) float64 and its arc fraction along the strand ``arc`` (n,) float64 in
    [0, 1]."""

    texel: np.ndarray
    cs: np.ndarray
    arc: np.ndarray


def fibre_hits(space: StrandSpace, mesh: FibreMesh, triangle: np.ndarray,
               barycentric: np.ndarray, direction: np.ndarray, rng: np.random.Generator,
               frame_u: np.ndarray) -> FibreHits:
    """Rays that hit fibres: the tubes' own triangle indices (n,), barycentrics (n, 3) and
    the rays' directions (n, 3) → :class:`FibreHits`, the azimuth of the point hit in the
    fibre's frame with the normal a round fibre
    presents to the ray (:func:`prtcore.core.fibres.cylinder_normal`, impact parameters
    drawn from ``rng``). ``frame_u``: :func:`prtcore.core.fibres.transported_frames`'
    second array, computed once per hair."""
    hair = space.hair
    seg, along = segment_hits(mesh, triangle, barycentric)
    p0 = hair.segment_start[seg]
    arc = hair.arc_length[p0] + along * (hair.arc_length[p0 + 1] - hair.arc_length[p0])
    strand = hair.strand_of_segment[seg]
    a0, b0 = hair.points[p0], hair.points[p0 + 1]
    axis = b0 - a0
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    normal_hit = cylinder_normal(axis, direction, 2 * rng.random(len(p0)) - 1)
    centre = a0 + along[:, None] * (b0 - a0)
    _, _, cs = azimuth_frame(hair, strand, arc, centre + normal_hit, frame_u)
    length = hair.strand_length[strand]
    frac = np.divide(arc, length, out=np.zeros_like(arc), where=length > 0)
    return FibreHits(space.texel_of(strand, arc), cs, np.clip(frac, 0.0, 1.0))


def fourier_rows(angle: np.ndarray, orders: int, scale: float = 1.0) -> np.ndarray:
    """(2H + 1, n): 1, then ``scale`` · (cos hθ, sin hθ) for h = 1 … H (``orders``) of
    ``angle`` (n,)."""
    out = [np.ones_like(angle)]
    for h in range(1, orders + 1):
        x = angle if h == 1 else h * angle
        out += [scale * np.cos(x), scale * np.sin(x)]
    return np.stack(out)


#: the ``hair.harmonics`` variants whose state stacks every strand texel's (mean, cos, sin)
#: and whose operator is :func:`harmonic_block` (mesh_bounces: its mean rows only;
#: turn_bounces: every row of the texels whose fibre turns less than
#: :data:`STRAIGHT_TURN_DEG`, the mean rows of the others; adaptive: all_bounces' or
#: turn_bounces' by how sparse the hair is, :data:`SPARSE_FIBRE_SHARE`)
STACKED_HARMONICS = ("all_bounces", "mesh_bounces", "turn_bounces", "adaptive")

#: ``hair.harmonics = "turn_bounces"``: a texel's harmonics take light from other fibres
#: when its fibre turns less than this along it (:func:`~prtcore.receivers.strands.
#: texel_turn`). Between the 10k heads' medians, straight 11° and curly 60°, where
#: all_bounces and mesh_bounces are the accurate ones (docs/hair.md, "Harmonics by how far
#: the fibre turns")
STRAIGHT_TURN_DEG = 30.0

#: ``hair.harmonics = "adaptive"``: hair whose fibre gather's rays meet another fibre less
#: often than this (sparse hair) is baked with all_bounces' rows, denser hair with
#: turn_bounces'. Between the heads measured: the 2000- and 5000-strand curly heads (0.29,
#: 0.51), where all_bounces is the accurate variant, and the 10k heads 0.63 (straight:
#: both variants within the bounds) and 0.68 (curly), where turn_bounces is (docs/hair.md,
#: "Sparse hair takes every fibre's harmonics", "Transporting each texel in pieces"; 0.5
#: until the 5000-strand head was measured)
SPARSE_FIBRE_SHARE = 0.6


#: strand (and atlas) texels whose gather rays :func:`hair_density` traces before a bake
SHARE_TEXELS = 4096
#: added to each of :class:`HairDensity`'s shares that bound memory: three times the
#: standard error of a share over SHARE_TEXELS texels is at most 0.023
SHARE_MARGIN = 0.05


class HairDensity(NamedTuple):
    """How dense the hair is, seen from the gathers' rays before they are traced. The
    shares that bound memory have :data:`SHARE_MARGIN` added (at most 1)."""

    #: the share of the fibre gather's rays that first meet another fibre (its stats'
    #: ``fibre_hits / rays``)
    fibre_share: float
    #: the share of strand texels with a ray that meets the mesh's front closer than
    #: ``near`` (the texels a near-field correction has rows for)
    near_share: float = 1.0
    #: the share of the fibre gather's rays that meet anything (an operator entry each)
    hit_share: float = 1.0
    #: the share of the atlas's gather rays that meet anything (1 without an atlas)
    atlas_hit_share: float = 1.0
    #: the share of the atlas's gather rays that meet a fibre within ``near_fibres``
    #: footprints (the near fibre hits, :mod:`prtcore.transport.fibre_near`)
    atlas_near_share: float = 1.0
    #: the share of the atlas's gather rays that meet a fibre within ``shaded_fibres``
    #: footprints (the near and the shaded hits, :func:`~prtcore.transport.fibre_near.
    #: shaded_fibre_correction`)
    atlas_shaded_share: float = 1.0


def _bounded(share: float) -> float:
    return min(1.0, share + SHARE_MARGIN)


def hair_density(space: StrandSpace, tracer: RayTracer, mesh_faces: int, rays: int,
                 seed: int, atlas: TexelSpace | None = None, near_field: float = 0.0,
                 texels: int = SHARE_TEXELS, near_fibres: float = 0.0,
                 shaded_fibres: float = 0.0) -> HairDensity:
    """:class:`HairDensity` from ``rays`` cosine gather rays on each of at most
    ``texels`` random strand texels (and as many texels of the mesh's ``atlas``, as its
    gather traces them, :func:`~prtcore.transport.gather.hit_share`), traced before any
    transport: a bake's choices that hang on how dense the hair is, made before the
    memory they cost is spent (``prtcore.hairbake.dense_hair``). ``mesh_faces``: the
    scene triangles before the fibre tubes in ``tracer``; ``near_field``: the transport's
    near-field reach in atlas texel footprints (the largest texel's reach bounds every
    texel's); ``near_fibres``: the atlas's near field on the fibres, in footprints, and
    ``shaded_fibres`` the reach of its shaded hits (at least ``near_fibres``'). On
    the 10k curly head (4096 texels × 64 rays): 0.679 meet a fibre (its
    gather's 0.678), 0.756 anything, 4.3 % of its strand texels have a near mesh hit (its
    gather's 4.4 %), and 0.74 of its atlas's rays meet something (before the margins)."""
    rng = np.random.default_rng([seed, 9])
    pick = np.sort(rng.choice(space.count, min(space.count, texels), replace=False))
    m = max(rays, 1)
    texel = np.repeat(pick, m)
    n = len(texel)
    if not n:
        return HairDensity(0.0, 0.0, 0.0)
    arc = space.arc[texel, 0] + rng.random(n) * (space.arc[texel, 1] - space.arc[texel, 0])
    origin, normal, _ = space.surface_points(texel, arc, 2 * np.pi * rng.random(n))
    d = directions_around(normal, np.sqrt(rng.random(n)), 2 * np.pi * rng.random(n))
    hits = tracer.intersect(origin, d)
    fibre = hits.triangle >= mesh_faces
    near = float(near_field_reach(atlas, near_field).max()) if atlas is not None \
        and atlas.count else 0.0
    close = (hits.hit & ~fibre & hits.front & (hits.t < near)).reshape(len(pick), m)
    atlas_hits = atlas_near = atlas_shaded = 1.0
    if atlas is not None and atlas.count:
        shares = hit_share(atlas, tracer, m, texels, rng, mesh_faces,
                           near_field_reach(atlas, near_fibres),
                           near_field_reach(atlas, max(near_fibres, shaded_fibres)))
        atlas_hits, atlas_near, atlas_shaded = map(_bounded, shares)
    return HairDensity(float(np.mean(fibre)), _bounded(float(close.any(axis=1).mean())),
                       _bounded(float(np.mean(hits.hit))), atlas_hits, atlas_near,
                       atlas_shaded)


def harmonic_receivers(harmonics: str, space: StrandSpace,
                       straight_turn: float = STRAIGHT_TURN_DEG,
                       fibre_share: float | None = None) -> bool | np.ndarray:
    """Which strand texels' harmonic rows take other fibres' light under ``harmonics``
    (:data:`STACKED_HARMONICS`; :func:`harmonic_block`'s ``harmonic_rows``): every
    texel's (all_bounces, True), none (mesh_bounces, False), or those whose fibre turns
    less than ``straight_turn`` degrees along them (turn_bounces, a (T,) bool array).
    adaptive: all_bounces' when ``fibre_share``, the share of the fibre gather's rays
    that met another fibre, is below :data:`SPARSE_FIBRE_SHARE`, turn_bounces' otherwise
    (:func:`fibre_gather` passes it once its rays are traced)."""
    if harmonics == "adaptive":
        if fibre_share is None:
            raise ValueError("adaptive harmonics are chosen from the fibre gather's share "
                             "of rays that met a fibre (fibre_share)")
        if fibre_share < SPARSE_FIBRE_SHARE:
            return True
        harmonics = "turn_bounces"
    if harmonics == "turn_bounces":
        return texel_turn(space) < straight_turn
    return harmonics == "all_bounces"


def harmonic_blocks_bound(harmonics: str, space: StrandSpace) -> float:
    """Before the gather is traced (the memory estimate): an upper bound on the stacked
    operator's entries per gather ray under ``harmonics`` (:data:`STACKED_HARMONICS`),
    every ray counted as a fibre hit. A hit feeds the 3 (mean, cos, sin) columns of its
    receiver's mean row, and 6 more where the receiver's harmonic rows take other fibres'
    light (:func:`harmonic_receivers`). adaptive: turn_bounces' bound, or all_bounces' 9
    over fewer than :data:`SPARSE_FIBRE_SHARE` of the rays, whichever is larger."""
    if harmonics == "adaptive":
        return max(harmonic_blocks_bound("turn_bounces", space), 9 * SPARSE_FIBRE_SHARE)
    return 3 + 6 * float(np.mean(harmonic_receivers(harmonics, space)))


def harmonic_block(t: int, rays: int, rows: np.ndarray, cols: np.ndarray,
                   phi_o: np.ndarray, psi: np.ndarray, orders: int = 1,
                   harmonic_rows: bool | np.ndarray = True) -> sp.csr_matrix:
    """The gather on the azimuthal harmonics of every texel up to order H (``orders``),
    (nT, nT) float32 CSR with n = 2H + 1: row block a ∈ (mean, cos φ, sin φ, cos 2φ, …)
    of the receiving texel, column block b of the source. A ray leaving texel i at
    azimuth φ_o and hitting texel j at azimuth ψ adds ``w_a(φ_o) v_b(ψ) / M`` with
    ``w = (1, 2 cos φ_o, 2 sin φ_o, …)`` (the Fourier coefficients of the irradiance
    around the receiving fibre, whose ray origins are stratified in azimuth) and
    ``v = (1, cos ψ, sin ψ, …)`` (the source's outgoing radiance at the point hit).
    ``harmonic_rows=False`` (``hair.harmonics = "mesh_bounces"``): only the mean rows
    receive, so a texel's harmonics never take light from other fibres (they hold what
    the direct light and the mesh give them); the harmonic row blocks stay, empty. A (T,)
    bool array (``"turn_bounces"``): the harmonic rows of the texels it marks receive,
    the others' stay empty."""
    n = 2 * orders + 1
    w = fourier_rows(phi_o, orders, 2)
    v = fourier_rows(psi, orders)
    if isinstance(harmonic_rows, np.ndarray):  # per receiving texel
        keep = np.asarray(harmonic_rows, bool)[rows]
    else:
        keep = np.full(len(rows), bool(harmonic_rows))
    sel = [slice(None)] + [np.flatnonzero(keep)] * (n - 1)  # the mean rows take every ray
    r = np.concatenate([rows[sel[a]].astype(np.int64) + a * t for a in range(n)
                        for _ in range(n)])
    c = np.concatenate([cols[sel[a]].astype(np.int64) + b * t for a in range(n)
                        for b in range(n)])
    d = np.concatenate([(w[a][sel[a]] * v[b][sel[a]]).astype(np.float32) / np.float32(rays)
                        for a in range(n) for b in range(n)])
    m = sp.csr_matrix((d, (r, c)), shape=(n * t, n * t))
    m.sum_duplicates()
    m.sort_indices()
    return m


def harmonic_first_bounce(term: FibreTerm, direct: FibreDirect, first: int = 1
                          ) -> tuple[np.ndarray, np.ndarray]:
    """The first bounce's correction for the azimuthal variation of the direct light on
    the fibres hit: ``Σ_h G_h · L_h`` over the harmonics h ≥ ``first`` both carry,
    (T, K, 3) float32 for every row, in the units of ``G · L_d``
    (:func:`prtcore.transport.solve.solve_indirect`'s ``first_bounce``). Later bounces
    stay radially constant. ``first = 2`` with ``all_bounces``: the block carries the
    first harmonic through every bounce, the second rides the first bounce only."""
    t, k = direct.mean.shape[:2]
    rows = term.harmonics[0].shape[0] if term.harmonics else t  # (T_m + T) with a mesh
    val = np.zeros((rows, k * 3), dtype=np.float32)
    part = np.empty_like(val)
    skip = 2 * (first - 1)
    for g, l_h in zip(term.harmonics[skip:], direct.harmonics[skip:], strict=False):
        # scipy's rounding on every core (csr_matvecs is single-threaded: 3 s of the 10k
        # hairball's K = 144 dataset)
        val += SparseProduct(g, default_threads())(l_h.reshape(t, -1), out=part)
    return np.arange(rows, dtype=np.int64), val.reshape(rows, k, 3)


#: lights whose direct harmonics are held at once by :func:`direct_and_first_bounce`
FIRST_BOUNCE_LIGHTS = 16


def direct_and_first_bounce(space: StrandSpace, tracer: RayTracer, lights: Sequence[Light],
                            samples: int, seed: int, term: FibreTerm,
                            block: int = FIRST_BOUNCE_LIGHTS, estimator: str = "facing"
                            ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """:func:`fibre_direct`'s mean and :func:`harmonic_first_bounce` of ``term`` with it,
    ``block`` lights at a time, so that the direct light's harmonics ((2, T, K, 3)
    float32: 4.8 GB for 140k strands and 144 lights) are never all held. Every light's
    values are those of one call with all lights (the same surface samples, each light
    and each product column computed on its own). Returns (mean (T, K, 3) float32,
    (rows (T,) int64, first-bounce correction (T, K, 3) float32))."""
    t, k = space.count, len(lights)
    rows = term.harmonics[0].shape[0] if term.harmonics else t  # (T_m + T) with a mesh
    mean = np.empty((t, k, 3), dtype=np.float32)
    val = np.empty((rows, k, 3), dtype=np.float32)
    drawn = draw_direct(space, samples, seed, estimator, lights)  # once for every block
    starts = range(0, k, block)
    for k0 in bar(starts, "direct fibres", total=len(starts)):
        part = direct_of_draw(space, tracer, lights[k0:k0 + block], drawn, HARMONICS,
                              progress=False)
        mean[:, k0:k0 + block] = part.mean
        val[:, k0:k0 + block] = harmonic_first_bounce(term, part)[1]
        del part
    return mean, (np.arange(rows, dtype=np.int64), val)


@register
class FibreGather(TransportOperator):
    """Multiple scattering among diffuse fibres (see the module docstring). ``receiver``
    is a :class:`~prtcore.receivers.strands.StrandSpace`; ``tracer`` is the one
    :func:`hair_tracer` built for it and ``scene`` (None for hair alone)."""

    name = "fibre"
    stage = "fibre gather"
    stats_key = "fibre"

    def build(self, scene: Scene | None, receiver: StrandSpace, tracer: RayTracer,
              spec: TransportSpec, timer: StageTimer | None = None) -> FibreTerm:
        mesh = fibre_tubes(receiver.hair, DEFAULT_SIDES)
        offset = scene.triangle_count if scene is not None else 0
        with timer.stage(self.stage) if timer is not None else nullcontext():
            return fibre_gather(receiver, tracer, mesh, offset, spec.gather_rays, spec.seed)

    def estimate_bytes(self, receivers, configurations, spec):
        return int(receivers) * MEM_PER_TEXEL_RAY * int(spec.gather_rays) \
            + FIBRE_BATCH * MEM_PER_RAY_IN_FLIGHT
