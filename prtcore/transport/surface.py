"""Fast transport: the dataset of the bake (DESIGN 4, paper 4.1).

Light transport is linear and all K lighting configurations share one geometry, so the
geometry is traced once:

1. **Gather operator** G (T × T, rows = receiving texel): every texel shoots M
   cosine-distributed rays from points jittered over its footprint; each ray's first
   front-face hit is mapped to the texel holding that surface point, with weight 1/M.
   With cosine sampling ``E(x) ≈ π/M Σ_j L(y_j) = 1/M Σ_j ρ_j E_j``, so
   ``E_ind = G · (ρ ∘ (E_d + E_ind))``.
2. **Direct light** for every configuration at texels and measurement points with
   shadow rays (:func:`prtcore.emitters.punctual.irradiance`, the one light evaluation). A texel's
   direct light is the mean over J points spread over it (``transport.direct_samples``):
   one point aliases where a shadow edge runs along a texel column.
3. **Near field**: a texel's value stands badly for the light at a point closer than
   about a texel — a contact shadow narrower than a texel under a block's foot — so the
   first bounce of a gather ray that hits within ``transport.near_field`` footprints of
   its origin takes the direct light at the hit point itself
   (:func:`near_field_correction`; one shadow ray per near hit and light).
4. **All bounces for all configurations at once**: ``(I − Gρ)⁻¹ Gρ E_d`` for all K × 3
   right-hand sides together, one sparse × dense product per step: the Neumann series
   (one bounce per product) or, by default, a Chebyshev iteration on the spectrum of Gρ
   that needs about half the products (:func:`solve_indirect`).

Radiometry (DESIGN 3.1): every stored value is outgoing radiance ``L = ρ/π · E``;
the indirect counts light that bounced at least once (all bounces).

Sampling conventions of the gather (kept identical in spirit to the reference path
tracer, :mod:`prtcore.reference.pathtracer`, where they are about the physics):

* a ray that hits the *back* of a face is inside geometry: it brings no light;
* a ray that misses brings nothing (no environment light);
* a direction below the geometric plane of its texel (possible with interpolated shading
  normals) brings nothing; it still counts in the 1/M weight;
* **buried samples**: each texel shoots its M rays from S = M / RAYS_PER_ORIGIN jittered
  origins; an origin whose rays mostly hit back faces lies inside other geometry (a floor
  texel under a block). Its rays are dropped and the row is renormalised over the rays of
  the texel's *visible* origins (the lightmap value of a partly buried texel is the average
  over its visible part), and the texel's direct light is evaluated at a visible origin
  (:class:`Gather`). A texel with no visible origin is *buried*: its row is zero.
* origins are uniform over the texel's square ∩ its own triangle, the region the
  reference integrates (:func:`prtcore.receivers.texels.texel_regions`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from prtcore.core.geometry import orthonormal_frame, shading_normals
from prtcore.core.materials import clamp_albedo
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Scene
from prtcore.core.spec import TransportSpec
from prtcore.core.tolerances import BARY_EPS, offset_origins
from prtcore.emitters.punctual import irradiance
from prtcore.intake.points import MeasurementPoints
from prtcore.receivers.texels import TexelSpace, sample_texel_regions, texel_regions

#: Gather rays that share one jittered origin (S = M / RAYS_PER_ORIGIN origins per texel);
#: enough rays per origin to tell "inside geometry" (most rays hit back faces) from "sees
#: the back of some open surface" (a few do).
#: the timed stages of :func:`bake_dataset`, in the order they run
STAGES = ("gather operator", "direct points", "direct texels", "near field", "indirect solve")

RAYS_PER_ORIGIN = 4
#: How far (in texels) the origins of a texel whose square only touches its triangle are
#: moved from its sample into the triangle.
FALLBACK_NUDGE = 0.05
#: Near hits per chunk in :func:`near_field_correction` (bounds its (chunk, K, 3) array).
NEAR_CHUNK = 1 << 15
#: Points per light evaluation in :func:`direct_radiance` (bounds its temporaries).
DIRECT_CHUNK = 1 << 19
#: Gather rays traced per batch (bounds memory: ~150 bytes per ray in flight).
GATHER_BATCH = 1 << 20
#: A hit mapped through the UV lookup must lie within this many texel footprints of the
#: texel it lands on; otherwise (overlapping UVs, a texel of another chart) it is re-mapped
#: to the nearest texel in 3-D facing the same way.
MAP_SLACK_FOOTPRINTS = 3.0
#: Texels covered less than 1 − this are "partly covered" (their sample may sit on the
#: chart border; see :class:`Gather`).
PARTIAL_COVERAGE_EPS = 1e-3
#: Golden-ratio conjugate: the rank-1 (Fibonacci) lattice generator.
PHI = 0.6180339887498949
#: Rows per float32 partial sum of column norms (the partial sums add up in float64).
NORM_BLOCK = 1 << 12
#: Arnoldi steps estimating the spectrum of Gρ for the Chebyshev iteration.
ARNOLDI_STEPS = 12
#: Relative widening of the Arnoldi interval (Ritz values lie inside the spectrum's hull).
SPECTRUM_MARGIN = 0.05
#: The Chebyshev iteration is abandoned for the plain series if the relative change grows
#: beyond this factor of the smallest one seen (a spectrum outside the interval).
CHEBYSHEV_DIVERGENCE = 4.0
#: Bytes for the solver's working arrays (five of T × block × 3 float32 for "chebyshev":
#: solution, residual, step, source and product, allocated once per block); the K
#: configurations are solved in column blocks that fit. Fewer, wider blocks are faster:
#: scipy's sparse × dense kernel amortises each non-zero over all columns of a product.
SOLVE_BLOCK_BYTES = 2 << 30
#: Solver methods (see :func:`solve_indirect`).
SOLVE_METHODS = ("chebyshev", "neumann")
#: Memory model of a bake (bytes; :func:`estimate_bake_bytes`), measured as peak RSS on the
#: Cornell box at 512² and 1024² with 4–16 gather rays and 30–96 configurations
#: (tests/stability) and rounded up, so that it overestimates by 10–30 %: per covered
#: texel (texel space, gather bookkeeping, interpreter), per texel and gather ray, per
#: texel and configuration (texel direct and indirect, (T, K, 3) float32 each, and at most
#: as much again for the near field's first-bounce correction), plus the solver's working
#: arrays (five more per configuration, up to SOLVE_BLOCK_BYTES).
MEM_PER_TEXEL = 1536
MEM_PER_TEXEL_RAY = 64
MEM_PER_TEXEL_CONFIG = 36
MEM_PER_GATHER_RAY_IN_FLIGHT = 150


# ---------------------------------------------------------------------------------------
# Data


@dataclass(frozen=True)
class Dataset:
    """The lighting database of a bake (paper 4.1), one column per configuration.

    lights : (K,) the configurations, training first, then held-out (``stats["train"]``
        says how many are training; the caller splits)
    direct_points : (P, K, 3) float32 direct outgoing radiance ρ/π·E_d at the measurement
        points, each the average of its supersample cluster
    direct_texels : (T, K, 3) float32 direct outgoing radiance at the texels
    indirect : (T, K, 3) float32 indirect outgoing radiance ρ/π·E_ind at the texels (light
        that bounced at least once, all bounces)
    iterations : bounces computed (1 = single bounce)
    residual : relative change of the last bounce, max over configurations and channels
        (``‖ΔE_k‖ / ‖E_k‖``); below ``spec.tolerance`` when ``stats["converged"]``
    stats : rays traced, seconds per sub-stage, buried/moved texels, back-face fraction, …
    """

    lights: tuple[Light, ...]
    direct_points: np.ndarray
    direct_texels: np.ndarray
    indirect: np.ndarray
    iterations: int
    residual: float
    stats: dict = field(default_factory=dict)


@dataclass(frozen=True)
class NearField:
    """Gather rays that hit close to their origin, where a texel's value (its average)
    stands badly for the light at the hit point: a contact shadow or a lit strip narrower
    than a texel (a block on a floor, a ledge under a step). Each is also in the gather
    matrix; :func:`near_field_correction` replaces, for the first bounce only, the
    texel's direct light by the direct light at the hit point.

    row : (n,) int64 receiving texel, sorted; col : (n,) int64 the texel the hit maps to;
    triangle : (n,) int64 and barycentric : (n, 3) float64, the hit point;
    weight : (n,) float32 the ray's weight in the matrix row (1/M_valid).
    """

    row: np.ndarray
    col: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    weight: np.ndarray

    @property
    def count(self) -> int:
        return len(self.row)


@dataclass(frozen=True)
class Gather:
    """The gather operator and what tracing it learnt about the texels.

    matrix : (T, T) float32 CSR, rows = receiving texel, weights 1/M_valid, columns sorted
    sample_position : (T, 3) float64 where the texel's direct light is evaluated: the
        texel sample, or — for a partly covered or partly buried texel — its visible
        jittered origin nearest to the centroid of those origins (a point strictly inside
        the texel's visible part: a sample on a concave chart border would be shadowed by
        the neighbouring face, one inside geometry by that geometry)
    valid_rays : (T,) int32 rays from visible origins (the row's 1/M_valid); 0 = buried
    moved : (T,) bool texels whose sample_position is not the texel sample
    stats : counts (rays, back-face hits, misses, re-mapped hits, …)
    direct_position : (T, J, 3) float64 the points whose direct light, averaged, is the
        texel's: J visible origins spread over the texel (J = 1: ``sample_position``)
    near : the rays that hit within ``near_field`` texel footprints of their origin
        (:class:`NearField`; None when the near field is off)
    """

    matrix: sp.csr_matrix
    sample_position: np.ndarray
    valid_rays: np.ndarray
    moved: np.ndarray
    stats: dict
    direct_position: np.ndarray
    near: NearField | None = None

    @property
    def buried(self) -> np.ndarray:
        """(T,) bool texels with no visible origin (zero rows)."""
        return self.valid_rays == 0


# ---------------------------------------------------------------------------------------
# Sampling helpers


def fibonacci_lattice(count: int, shift: np.ndarray) -> np.ndarray:
    """Randomly shifted rank-1 Fibonacci lattices in [0, 1)².

    Point i of lattice r is ``frac((i + ½)/count + shift[r, 0], i·φ + shift[r, 1])``, φ the
    golden-ratio conjugate: well stratified in 2-D for any count, and unbiased under the
    uniform Cranley–Patterson shift. shift : (m, 2) float64. Returns (m, count, 2).
    """
    i = np.arange(count, dtype=np.float64)
    base = np.stack([(i + 0.5) / count, np.mod(i * PHI, 1.0)], axis=1)
    return np.mod(base[None, :, :] + shift[:, None, :], 1.0)


def _uv_barycentric(a: np.ndarray, inv: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Barycentrics of pixel-space points q (..., 2) in triangles given by their corner 0
    ``a`` (..., 2) and the inverse edge matrix ``inv`` (..., 2, 2) (see :func:`_uv_frames`).
    Returns (..., 3); NaN for degenerate triangles (rejected by every inside test)."""
    d = q - a
    v = inv[..., 0, 0] * d[..., 0] + inv[..., 0, 1] * d[..., 1]
    w = inv[..., 1, 0] * d[..., 0] + inv[..., 1, 1] * d[..., 1]
    return np.stack([1.0 - v - w, v, w], axis=-1)


def _uv_frames(tri_uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Corner 0 (n, 2) and the inverse of the edge matrix [e1 e2] (n, 2, 2) of pixel-space
    triangles (n, 3, 2); NaN rows for degenerate ones."""
    e1 = tri_uv[:, 1] - tri_uv[:, 0]
    e2 = tri_uv[:, 2] - tri_uv[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    inv_det = np.divide(1.0, det, out=np.full_like(det, np.nan), where=det != 0)
    inv = np.stack([np.stack([e2[:, 1], -e2[:, 0]], 1), np.stack([-e1[:, 1], e1[:, 0]], 1)],
                   axis=1) * inv_det[:, None, None]
    return tri_uv[:, 0], inv


def _jittered_origins(scene: Scene, texels: TexelSpace, per_texel: int,
                      rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Origins jittered over each texel's region: its square ∩ its own triangle
    (:func:`~prtcore.receivers.texels.texel_regions`), the region the reference integrates.

    A stratified (shifted Fibonacci) set of ``per_texel`` offsets in the texel square
    [x, x+1] × [y, y+1]; an offset outside the texel's triangle (in TEXCOORD_1) is replaced
    by a point drawn uniformly over the region, exactly, so the origins are uniform over the
    region however little of the square it covers. A texel whose square only touches its
    triangle has no region: its origins are its sample moved FALLBACK_NUDGE texels toward
    the triangle's centroid.
    Returns positions (T, S, 3) float64 on the triangle, and (T, S) bool "in the region".
    """
    t = texels.count
    size = np.array([texels.width, texels.height], dtype=np.float64)
    corner, inv = _uv_frames(scene.uv1[scene.faces[texels.triangle]] * size)
    centre = texels.xy.astype(np.float64) + 0.5
    q = fibonacci_lattice(per_texel, rng.random((t, 2))) - 0.5 + centre[:, None, :]
    bary = _uv_barycentric(corner[:, None], inv[:, None], q).reshape(-1, 3)  # (T·S, 3)
    owner = np.repeat(np.arange(t), per_texel)
    inside = (bary >= -BARY_EPS).all(axis=1)
    part = np.unique(owner[~inside])  # texels with a lattice point off their triangle
    regions = texel_regions(scene, texels, part)
    redo = np.flatnonzero(~inside)
    slot = np.searchsorted(part, owner[redo])
    redo, slot = redo[~regions.empty[slot]], slot[~regions.empty[slot]]
    if len(redo):
        bary[redo] = sample_texel_regions(regions, slot, rng)
        inside[redo] = True
    # Fallback: the texel sample nudged toward its triangle's centroid by about
    # FALLBACK_NUDGE texels, so that it is strictly inside (a sample on a concave chart
    # border lies on the neighbouring face's plane, where rays hit that face at t ≈ 0).
    lost = np.flatnonzero(~inside)
    if len(lost):
        tex = owner[lost]
        b0 = np.clip(texels.barycentric[tex], 0.0, None)
        b0 /= b0.sum(axis=1, keepdims=True)
        verts = scene.positions[scene.faces[texels.triangle[tex]]]
        to_mid = verts.mean(axis=1) - np.einsum("nk,nkj->nj", b0, verts)
        step = FALLBACK_NUDGE * np.linalg.norm(texels.footprint[tex], axis=2).mean(axis=1)
        dist = np.linalg.norm(to_mid, axis=1)
        eps = np.minimum(1.0, np.divide(step, dist, out=np.ones_like(dist), where=dist > 0))
        bary[lost] = (1.0 - eps)[:, None] * b0 + (eps / 3.0)[:, None]
    bary = np.clip(bary, 0.0, None)
    bary /= bary.sum(axis=1, keepdims=True)
    verts = scene.positions[scene.faces[texels.triangle]]  # (T, 3, 3)
    pos = np.einsum("tsk,tkj->tsj", bary.reshape(t, per_texel, 3), verts)
    return pos, inside.reshape(t, per_texel)


# ---------------------------------------------------------------------------------------
# Gather operator


def _texel_lookup(texels: TexelSpace) -> np.ndarray:
    """(H, W) int64 texel index per atlas texel: covered texels, padding texels through
    their dilation source, −1 elsewhere."""
    lut = np.full((texels.height, texels.width), -1, dtype=np.int64)
    if len(texels.dilate_xy):
        lut[texels.dilate_xy[:, 1], texels.dilate_xy[:, 0]] = texels.dilate_src
    lut[texels.xy[:, 1], texels.xy[:, 0]] = np.arange(texels.count)
    return lut


class _HitMapper:
    """Surface hit (triangle, barycentric) → texel index (see :func:`gather_operator`)."""

    def __init__(self, scene: Scene, texels: TexelSpace, tracer: RayTracer):
        self.scene = scene
        self.texels = texels
        self.tracer = tracer
        self.lut = _texel_lookup(texels)
        # per face: pixel-space corner 0 and edges 0→1, 0→2, one 1-D array each (fast gathers)
        fuv = scene.uv1[scene.faces] * np.array([texels.width, texels.height], np.float64)
        self.px = [np.ascontiguousarray(a) for a in (
            fuv[:, 0, 0], fuv[:, 1, 0] - fuv[:, 0, 0], fuv[:, 2, 0] - fuv[:, 0, 0],
            fuv[:, 0, 1], fuv[:, 1, 1] - fuv[:, 0, 1], fuv[:, 2, 1] - fuv[:, 0, 1])]
        self.lut_flat = self.lut.reshape(-1)
        self.position32 = texels.position.astype(np.float32)
        fp = np.linalg.norm(texels.footprint, axis=2).sum(axis=1)  # |dP/dx| + |dP/dy|
        self.reach2 = ((MAP_SLACK_FOOTPRINTS * fp + 2.0 * tracer.offset) ** 2).astype(
            np.float32)
        self._tree: cKDTree | None = None
        self.remapped = 0

    def __call__(self, tri: np.ndarray, bary: np.ndarray, ray: np.ndarray,
                 origin: np.ndarray, direction: np.ndarray, t: np.ndarray) -> np.ndarray:
        """tri : (n,) faces, bary : (n, 3) barycentrics, t : (n,) float64 distances of n
        front hits of rays ``ray`` (n,) int64 into origin, direction ((r, 3) float32).
        Returns (n,) int64 texel indices."""
        b1, b2 = bary[:, 1], bary[:, 2]
        x0, x1, x2, y0, y1, y2 = self.px
        x = np.floor(x0[tri] + b1 * x1[tri] + b2 * x2[tri])
        y = np.floor(y0[tri] + b1 * y1[tri] + b2 * y2[tri])
        w, h = self.texels.width, self.texels.height
        inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
        flat = np.clip(y, 0, h - 1).astype(np.int64) * w + np.clip(x, 0, w - 1).astype(np.int64)
        tex = np.where(inside, self.lut_flat[flat], -1)
        # A texel sampled on the hit's own face is right by construction; others must be
        # near the hit point (a texel of another chart means overlapping UVs).
        other = np.flatnonzero((tex < 0) | (self.texels.triangle[tex] != tri))
        tk = tex[other]
        ro = ray[other]
        point = origin[ro] + direction[ro] * t[other].astype(np.float32)[:, None]
        diff = point - self.position32[tk]
        far = (tk < 0) | (np.einsum("ij,ij->i", diff, diff) > self.reach2[tk])
        bad = other[far]
        if len(bad):
            p64 = self.tracer.surface_point(tri[bad], bary[bad])
            tex[bad] = self._nearest(p64, self.tracer.face_normals[tri[bad]])
            self.remapped += len(bad)
        return tex

    def _nearest(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Nearest texel in 3-D whose geometric normal faces the same way (of the 8
        nearest), else the nearest."""
        if self._tree is None:
            self._tree = cKDTree(self.texels.position)
        k = min(8, self.texels.count)
        _, idx = self._tree.query(points, k=k)
        idx = idx.reshape(len(points), k)
        facing = np.einsum("nkj,nj->nk", self.texels.geometric_normal[idx], normals) > 0.5
        first = np.where(facing.any(axis=1), facing.argmax(axis=1), 0)
        return idx[np.arange(len(points)), first]


def gather_operator(scene: Scene, texels: TexelSpace, tracer: RayTracer, rays: int,
                    seed: int, timer: StageTimer | None = None, near_field: float = 0.0,
                    direct_samples: int = 1) -> Gather:
    """Trace the texel → texel gather operator G (see the module docstring).

    rays : M gather rays per texel (≥ 1); seed : every random choice (same inputs + seed
    → bit-identical operator).

    Per texel: S = max(1, M // RAYS_PER_ORIGIN) origins on a shifted Fibonacci lattice
    over the texel square, kept on the texel's triangle (:func:`_jittered_origins`),
    offset along the geometric normal turned to the shading side
    (:func:`prtcore.core.tolerances.offset_origins`); ray i leaves origin i mod S along point i
    of a shifted Fibonacci lattice mapped to the cosine hemisphere about the shading
    normal. A front-face hit at (triangle, barycentric) → TEXCOORD_1 → texel
    (⌊u·W⌋, ⌊v·H⌋) → covered texel, or the dilation source of a padding texel; a lookup
    that fails or lands more than MAP_SLACK_FOOTPRINTS footprints away goes to the
    nearest same-facing texel in 3-D (counted in ``stats["remapped_hits"]``).

    near_field : rays whose hit lies within this many footprints of their origin texel
    (|dP/dx| + |dP/dy|)/2 are also listed in ``Gather.near`` (0: none).
    direct_samples : J, the points per texel in ``Gather.direct_position`` (1: the
    sample; J > 1: J of the texel's S origins, evenly spaced along its lattice).

    Returns a :class:`Gather`; ``matrix`` is (T, T) float32 CSR with duplicate entries
    summed, row sums ≤ 1.
    """
    if rays < 1:
        raise ValueError(f"gather_operator: rays must be ≥ 1, got {rays}")
    if scene.uv1 is None:
        raise ValueError("gather_operator: the scene has no TEXCOORD_1")
    ctx = timer.stage("gather operator") if timer is not None else nullcontext()
    with ctx:
        return _gather(scene, texels, tracer, int(rays), int(seed), timer,
                       float(near_field), int(direct_samples))


def build_gather_operator(scene: Scene, texels: TexelSpace, tracer: RayTracer, rays: int,
                          seed: int, timer: StageTimer | None = None) -> sp.csr_matrix:
    """(T, T) float32 CSR gather operator, rows = receiving texel, weights 1/M (1/M_valid
    for partly buried texels; see :func:`gather_operator`, which also returns the
    buried-texel handling)."""
    return gather_operator(scene, texels, tracer, rays, seed, timer).matrix


def _gather(scene: Scene, texels: TexelSpace, tracer: RayTracer, m: int, seed: int,
            timer: StageTimer | None, near_field: float = 0.0, direct_samples: int = 1
            ) -> Gather:
    t = texels.count
    s = max(1, m // RAYS_PER_ORIGIN)
    rng = np.random.default_rng(seed)
    origins, jittered = _jittered_origins(scene, texels, s, rng)
    dir_shift = rng.random((t, 2), dtype=np.float32)
    shade = np.asarray(texels.normal, dtype=np.float64)
    geo = np.asarray(texels.geometric_normal, dtype=np.float64)
    geo = geo * np.where(np.einsum("ij,ij->i", shade, geo) < 0, -1.0, 1.0)[:, None]
    start = offset_origins(origins.reshape(-1, 3), np.repeat(geo, s, axis=0),
                           tracer.scale).reshape(t, s, 3)
    tan, bit = orthonormal_frame(shade)
    # frame rows (tangent, bitangent, normal) in float32 for the Embree-bound directions
    frame = np.stack([tan, bit, shade], axis=1).astype(np.float32)  # (T, 3, 3)
    up = np.einsum("tij,tj->ti", np.stack([tan, bit, shade], axis=1), geo)  # (T, 3)
    flat = bool((np.abs(up[:, :2]).max(initial=0.0) < 1e-12) and (up[:, 2].min(
        initial=1.0) > 0))
    mapper = _HitMapper(scene, texels, tracer)
    # near-field reach of each texel: near_field × its footprint, in world units
    reach = near_field * 0.5 * np.linalg.norm(texels.footprint, axis=2).sum(axis=1)
    near_parts: list[tuple[np.ndarray, ...]] = []

    i = np.arange(m, dtype=np.float64)
    lattice = np.stack([(i + 0.5) / m, np.mod(i * PHI, 1.0)], axis=1).astype(np.float32)
    ray_o = np.arange(m) % s  # origin of each ray within its texel
    per_batch = max(1, GATHER_BATCH // m)
    valid_rays = np.zeros(t, dtype=np.int32)
    inside_origin = np.zeros((t, s), dtype=bool)
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    n_traced = n_back = n_miss = n_below = 0
    starts = range(0, t, per_batch)
    if timer is not None:
        starts = timer.bar(starts, "gather", total=len(starts))
    for b0 in starts:
        b1 = min(t, b0 + per_batch)
        nt = b1 - b0
        # shifted lattice in float32 (the directions go to Embree as float32 anyway)
        u = lattice[None, :, :] + dir_shift[b0:b1, None, :]  # (nt, m, 2) in [0, 2)
        u -= (u >= 1.0).astype(np.float32)
        rr = np.sqrt(u[..., 0])
        phi = np.float32(2.0 * math.pi) * u[..., 1]
        local = np.stack([rr * np.cos(phi), rr * np.sin(phi),
                          np.sqrt(np.clip(1.0 - u[..., 0], 0.0, None))], axis=2)
        del u, rr, phi
        d = np.matmul(local, frame[b0:b1])  # (nt, m, 3) float32 world
        if flat:
            above = np.ones((nt, m), dtype=bool)
        else:
            above = np.einsum("tmk,tk->tm", local, up[b0:b1].astype(np.float32)) > 0
        del local
        o = start[b0:b1][:, ray_o]  # (nt, m, 3) float32
        sel = np.flatnonzero(above.reshape(-1))
        traced_all = len(sel) == nt * m
        d = d.reshape(-1, 3)
        o = o.reshape(-1, 3)
        hits = tracer.intersect(o, d) if traced_all else tracer.intersect(o[sel], d[sel])
        hit = np.zeros(nt * m, dtype=bool)
        front = np.zeros(nt * m, dtype=bool)
        hit[sel] = hits.hit
        front[sel] = hits.front
        back = hit & ~front
        n_traced += len(sel)
        n_back += int(back.sum())
        n_miss += len(sel) - int(hit.sum())
        n_below += nt * m - len(sel)
        # An origin is inside geometry when most of its traced rays hit back faces.
        key_o = (np.arange(nt)[:, None] * s + ray_o[None, :]).reshape(-1)
        traced_o = np.bincount(key_o, weights=above.reshape(-1), minlength=nt * s)
        back_o = np.bincount(key_o, weights=back, minlength=nt * s)
        inside = (2 * back_o > traced_o).reshape(nt, s)
        inside_origin[b0:b1] = inside
        ray_ok = ~inside[:, ray_o]  # (nt, m)
        valid_rays[b0:b1] = ray_ok.sum(axis=1)
        use = np.flatnonzero(front & ray_ok.reshape(-1))
        pos = use if traced_all else np.searchsorted(sel, use)  # among the traced rays
        cols = np.full(nt * m, t, dtype=np.int64)  # sentinel t: ray brings nothing
        cols[use] = mapper(hits.triangle[pos], hits.barycentric[pos], use, o, d, hits.t[pos])
        parts.append(_row_counts(cols.reshape(nt, m), b0, t))
        if near_field > 0:
            r_use = use // m  # receiving texel - b0
            close = hits.t[pos] < reach[b0 + r_use]
            nu, npos, nr = use[close], pos[close], r_use[close]
            near_parts.append((b0 + nr, cols[nu], hits.triangle[npos],
                               hits.barycentric[npos],
                               (1.0 / ray_ok.sum(axis=1)[nr]).astype(np.float32)))
        del hits, d, o, cols

    row = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.int64)
    col = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0, np.int32)
    cnt = np.concatenate([p[2] for p in parts]) if parts else np.zeros(0, np.int64)
    weight = (cnt / valid_rays[row]).astype(np.float32)
    indptr = np.zeros(t + 1, dtype=np.int64)
    np.cumsum(np.bincount(row, minlength=t), out=indptr[1:])
    matrix = sp.csr_matrix((weight, col, indptr), shape=(t, t))
    matrix.has_sorted_indices = True
    matrix.has_canonical_format = True

    # Where the texel's direct light is evaluated. A partly covered texel's sample may lie
    # on its chart's border — on a concave edge that is also the neighbouring face's
    # plane, where shadow rays hit that face at t ≈ 0 — and a partly buried texel's
    # sample may be inside geometry: both use their visible jittered origin (strictly
    # inside the triangle) nearest to the centroid of those origins.
    sample = np.asarray(texels.position, dtype=np.float64).copy()
    partial = np.asarray(texels.coverage) < 1.0 - PARTIAL_COVERAGE_EPS
    moved = (partial | inside_origin.any(axis=1)) & (valid_rays > 0)
    mv = np.flatnonzero(moved)
    if len(mv):
        good = ~inside_origin[mv] & jittered[mv]
        good[~good.any(axis=1)] = ~inside_origin[mv][~good.any(axis=1)]
        w = good[:, :, None].astype(np.float64)
        centroid = (origins[mv] * w).sum(axis=1) / w.sum(axis=1)
        dist = np.linalg.norm(origins[mv] - centroid[:, None, :], axis=2)
        dist[~good] = np.inf
        # Symmetric origin sets have exactly tied distances; rounding decided the tie,
        # differently at another scene scale (tests/stability). Ties within 1e-6 of the
        # texel's footprint go to the first origin.
        tie = 1e-6 * np.linalg.norm(texels.footprint[mv], axis=2).mean(axis=1)
        near = dist <= dist.min(axis=1, keepdims=True) + tie[:, None]
        sample[mv] = origins[mv, near.argmax(axis=1)]
    # Where the texel's direct light is evaluated and averaged: J origins spread over the
    # texel (every S/J-th point of its lattice), each buried one replaced by the sample.
    # One point aliases: a shadow edge along a texel column leaves every centre lit.
    j = max(1, min(int(direct_samples), s))
    if j == 1:
        direct_position = sample[:, None, :].copy()
    else:
        pick = (np.arange(j) * s) // j
        direct_position = origins[:, pick].copy()
        off = inside_origin[:, pick] | ~jittered[:, pick] | (valid_rays == 0)[:, None]
        direct_position[off] = np.broadcast_to(sample[:, None, :], direct_position.shape)[off]
    stats = {
        "gather_rays": m, "origins_per_texel": s, "rays_traced": n_traced,
        "rays_below_surface": n_below, "back_face_hits": n_back, "misses": n_miss,
        "back_face_fraction": n_back / max(n_traced, 1),
        "remapped_hits": mapper.remapped, "jitter_fallbacks": int((~jittered).sum()),
        "buried_texels": int((valid_rays == 0).sum()), "moved_texels": int(moved.sum()),
        "nnz": int(matrix.nnz),
    }
    near = None
    if near_field > 0:
        empty = (np.zeros(0, np.int64),) * 3 + (np.zeros((0, 3)), np.zeros(0, np.float32))
        near = NearField(*(np.concatenate(a) for a in zip(empty, *near_parts, strict=True)))
        stats["near_field_hits"] = near.count
    return Gather(matrix=matrix, sample_position=sample, valid_rays=valid_rays, moved=moved,
                  stats=stats, direct_position=direct_position, near=near)


def _row_counts(cols: np.ndarray, row0: int, sentinel: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct column indices per row and how often each occurs.

    cols : (n, m) int64 column of each ray of rows row0 … row0 + n − 1, ``sentinel`` for
    rays that bring nothing. Returns rows (k,) int64, columns (k,) int32 (ascending within a
    row) and counts (k,) int64, rows ascending.
    """
    n, m = cols.shape
    c = np.sort(cols, axis=1).reshape(-1)
    new = np.ones(n * m, dtype=bool)
    new[1:] = c[1:] != c[:-1]
    new[::m] = True  # every row starts a run
    run = np.flatnonzero(new)
    length = np.diff(np.append(run, n * m))
    value = c[run]
    keep = value != sentinel
    return (run[keep] // m + row0).astype(np.int64), value[keep].astype(np.int32), \
        length[keep]


# ---------------------------------------------------------------------------------------
# Direct light


def direct_radiance(scene: Scene, tracer: RayTracer, lights: Sequence[Light],
                    positions: np.ndarray, normals: np.ndarray, albedo: np.ndarray,
                    timer: StageTimer | None = None, desc: str = "direct") -> np.ndarray:
    """Direct outgoing radiance ``L = clamp(ρ)/π · E`` for every light.

    positions : (n, 3) float64 surface points, or (n, J, 3): J points per row whose
    irradiance is averaged (a texel's direct samples, :attr:`Gather.direct_position`);
    normals : (n, 3) float64 unit shading normals; albedo : (n, 3) raw albedo (clamped
    here with :func:`prtcore.core.materials.clamp_albedo`).
    E is :func:`prtcore.emitters.punctual.irradiance` with shadow rays. Lights are evaluated on
    ``tracer.threads`` threads (embreex and numpy release the GIL), one light per task,
    points in chunks of DIRECT_CHUNK, so memory stays at the (n, K, 3) float32 result
    plus O(DIRECT_CHUNK) per thread.
    Returns (n, K, 3) float32.
    """
    del scene  # the tracer holds the geometry; kept for a uniform stage signature
    positions = np.asarray(positions, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    if positions.ndim == 3 and positions.shape[1] == 1:
        positions = positions[:, 0]
    per = 1 if positions.ndim == 2 else positions.shape[1]
    rho, _ = clamp_albedo(np.asarray(albedo, dtype=np.float64))
    scale = rho / math.pi
    out = np.empty((len(positions), len(lights), 3), dtype=np.float32)
    step = max(1, DIRECT_CHUNK // per)

    def one(k: int) -> None:
        for a in range(0, len(positions), step):
            b = a + step
            if per == 1:
                e = irradiance(lights[k], positions[a:b], normals[a:b], tracer)
            else:
                e = irradiance(lights[k], positions[a:b].reshape(-1, 3),
                               np.repeat(normals[a:b], per, axis=0), tracer)
                # the mean over each row's J points, by slices: numpy's mean over a short
                # middle axis is slow, and a BLAS product would oversubscribe the threads
                e = e.reshape(-1, per, 3)
                acc = e[:, 0].copy()
                for j in range(1, per):
                    acc += e[:, j]
                e = acc / per
            out[a:b, k, :] = e * scale[a:b]

    ks = range(len(lights))
    if tracer.threads > 1 and len(lights) > 1:
        with ThreadPoolExecutor(tracer.threads) as ex:
            it = ex.map(one, ks)
            if timer is not None:
                it = timer.bar(it, desc, total=len(lights))
            for _ in it:
                pass
    else:
        for k in timer.bar(ks, desc, total=len(lights)) if timer is not None else ks:
            one(k)
    return out


def near_field_correction(scene: Scene, tracer: RayTracer, near: NearField,
                          lights: Sequence[Light], direct_texels: np.ndarray,
                          timer: StageTimer | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """The first bounce of the near field at the hit points instead of their texels.

    For every near hit (:class:`NearField`) the direct outgoing radiance at the hit point
    (:func:`direct_radiance`, shadow rays included) replaces the value of the texel it maps
    to, ``direct_texels`` (T, K, 3): a receiving texel's first bounce changes by
    ``Σ_hits w · (L_d(hit) − L_d[col])``. Costs one shadow ray per near hit and light.
    Returns rows (r,) int64, the receiving texels (sorted, unique), and their changes
    (r, K, 3) float32; :func:`solve_indirect` adds them to the first bounce.
    """
    from prtcore.core.materials import albedo_at

    k = direct_texels.shape[1]
    rows = np.unique(near.row)
    out = np.zeros((len(rows), k, 3), dtype=np.float32)
    slot = np.searchsorted(rows, near.row)
    starts = range(0, near.count, NEAR_CHUNK)
    if timer is not None:
        starts = timer.bar(starts, "near field", total=len(starts))
    for a in starts:
        sl = slice(a, a + NEAR_CHUNK)
        tri, bary = near.triangle[sl], near.barycentric[sl]
        point = tracer.surface_point(tri, bary)
        normal = shading_normals(scene, tri, bary, tracer.face_normals[tri])
        ld = direct_radiance(scene, tracer, lights, point, normal, albedo_at(scene, tri, bary))
        ld -= direct_texels[near.col[sl]]
        ld *= near.weight[sl, None, None]
        # rows are sorted: sum each run of equal rows, then add the runs (unique slots)
        sk = slot[sl]
        run = np.flatnonzero(np.r_[True, sk[1:] != sk[:-1]])
        out[sk[run]] += np.add.reduceat(ld, run, axis=0)
    return rows, out


# ---------------------------------------------------------------------------------------
# Indirect solve


class SparseProduct:
    """``matrix @ x`` for a CSR matrix and dense (n, c) arrays, rows split over threads.

    scipy releases the GIL in its sparse × dense kernel, so the row blocks (cut once, not
    per product) run in parallel. Output dtype = x's dtype (float32 here).
    """

    def __init__(self, matrix: sp.csr_matrix, threads: int = 2):
        self.matrix = matrix
        self.shape = matrix.shape
        m = matrix.shape[0]
        parts = max(1, threads) if m >= 2 * 4096 else 1
        bounds = np.linspace(0, m, parts + 1).astype(np.int64)
        self.blocks = [(int(bounds[i]), int(bounds[i + 1]), matrix[bounds[i]:bounds[i + 1]])
                       for i in range(parts)]

    def __call__(self, x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """x : (n, c); out : optional (m, c) C-contiguous array of x's dtype to fill."""
        x = np.ascontiguousarray(x)
        if out is None:
            out = np.empty((self.shape[0], x.shape[1]), dtype=x.dtype)
        if len(self.blocks) == 1:
            out[...] = self.matrix @ x
            return out

        def part(block) -> None:
            a, b, mat = block
            out[a:b] = mat @ x

        with ThreadPoolExecutor(len(self.blocks)) as ex:
            list(ex.map(part, self.blocks))
        return out


def _col_norms(x: np.ndarray) -> np.ndarray:
    """‖x[:, j]‖ over rows for x (T, ...) float32 → x.shape[1:] float64 (float32 sums over
    row blocks of NORM_BLOCK, accumulated in float64)."""
    x2 = x.reshape(len(x), -1)
    out = np.zeros(x2.shape[1])
    for i in range(0, len(x2), NORM_BLOCK):
        xi = x2[i:i + NORM_BLOCK]
        out += np.einsum("ij,ij->j", xi, xi)
    return np.sqrt(out).reshape(x.shape[1:])


def _relative(change: np.ndarray, total: np.ndarray) -> float:
    """max over columns of change / total, columns with total 0 skipped."""
    live = total > 0
    return float((change[live] / total[live]).max()) if live.any() else 0.0


def spectrum_interval(product: SparseProduct, rho: np.ndarray, steps: int = ARNOLDI_STEPS
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Interval [lo, hi] per channel holding the (real parts of the) eigenvalues of
    ``A_c = G·diag(ρ_c)``.

    product : G as a :class:`SparseProduct`; rho : (T, 3) clamped albedo. Arnoldi with
    ``steps`` steps per channel from a fixed positive start vector (the three channels
    share each sparse product); the extreme real parts of the Ritz values, widened by
    SPECTRUM_MARGIN because Ritz values approach the spectrum from inside. A_c is
    non-negative, so its spectral radius is its largest real eigenvalue (Perron–Frobenius)
    and ``lo ≥ −hi``. Returns lo, hi : (3,) float64 with −1 < lo < hi < 1.
    """
    t = product.shape[0]
    m = max(1, min(steps, t))
    rho = np.asarray(rho, dtype=np.float64)
    basis = np.zeros((3, m + 1, t))
    h = np.zeros((3, m + 1, m))
    v = np.random.default_rng(0).random((3, t)) + 0.5
    basis[:, 0] = v / np.linalg.norm(v, axis=1, keepdims=True)
    size = [m, m, m]
    active = np.ones(3, dtype=bool)
    for j in range(m):
        src = (basis[:, j].T * rho).astype(np.float32)  # (T, 3)
        w = product(src).astype(np.float64).T  # (3, T)
        for c in np.flatnonzero(active):
            wc = w[c]
            scale = np.linalg.norm(wc)
            for _ in range(2):  # Gram–Schmidt, twice for stability
                coef = basis[c, :j + 1] @ wc
                wc = wc - coef @ basis[c, :j + 1]
                h[c, :j + 1, j] += coef
            nrm = np.linalg.norm(wc)
            h[c, j + 1, j] = nrm
            if nrm <= 1e-9 * max(scale, 1e-300):
                size[c] = j + 1
                active[c] = False
            else:
                basis[c, j + 1] = wc / nrm
        if not active.any():
            break
    lo, hi = np.zeros(3), np.zeros(3)
    for c in range(3):
        ritz = np.linalg.eigvals(h[c, :size[c], :size[c]]).real
        top = float(ritz.max(initial=0.0))
        bottom = float(ritz.min(initial=0.0))
        hi[c] = min(top + SPECTRUM_MARGIN * max(top, 0.0) + 0.01, 0.999)
        lo[c] = max(min(bottom, 0.0) - SPECTRUM_MARGIN * (top - bottom) - 0.01, -hi[c])
    return lo, hi


def solve_indirect(matrix: sp.csr_matrix, albedo: np.ndarray, direct: np.ndarray,
                   max_bounces: int, tolerance: float, timer: StageTimer | None = None,
                   method: str = "chebyshev", threads: int = 2,
                   first_bounce: tuple[np.ndarray, np.ndarray] | None = None
                   ) -> tuple[np.ndarray, int, float, dict]:
    """All bounces of indirect light for every configuration and channel at once.

    matrix : (T, T) gather operator G (CSR, used as float32); albedo : (T, 3) raw texel
    albedo (clamped here); direct : (T, K, 3) direct outgoing radiance L_d = ρ/π·E_d.
    Solves ``E_ind = G·(ρ∘(E_d + E_ind))``, i.e. ``(I − A) E_ind = b`` with ``A = Gρ``
    and the first bounce ``b = A E_d = π G L_d``. Every product is a sparse × dense
    product with all 3K columns (float32 data; norms accumulate in float64). The solution
    is the Neumann series ``Σ_{n≥0} Aⁿ b``, convergent because rows of G sum to ≤ 1 and
    ρ ≤ 0.99.

    method "neumann": one bounce per product, ``term ← A·term``; after n products the
    result is exactly the light of bounces 1 … n.
    method "chebyshev" (default): Chebyshev iteration (Saad, *Iterative Methods for Sparse
    Linear Systems*, alg. 12.1) on the interval from :func:`spectrum_interval`: the
    spectrum of A is real up to Monte Carlo noise (form factors are reciprocal), so the
    error falls by ≈ (√κ − 1)/(√κ + 1) per product, κ = (1 − lo)/(1 − hi), instead of by
    the spectral radius hi — for the Cornell box 0.3 instead of 0.6, about half the
    products. Should the change grow (a spectrum outside the interval) the block is
    solved again with "neumann" (``stats["fallback"]``).

    Both stop when the relative change ``‖ΔE_k‖/‖E_k‖`` of every configuration k and
    channel is below ``tolerance`` (``stats["converged"]``), or after ``max_bounces``
    products counting the first bounce. max_bounces = 1 gives exactly the single-bounce
    light; an unconverged "chebyshev" result is the Chebyshev approximant of that degree.
    Configurations are solved in column blocks so that the working arrays (5 of
    T × block × 3 float32) stay within SOLVE_BLOCK_BYTES.

    first_bounce : (rows, values (r, K, 3)) added to ``G L_d`` at those rows — the near
    field's correction (:func:`near_field_correction`).

    Returns the indirect outgoing radiance ρ/π·E_ind (T, K, 3) float32, the number of
    products (bounces), the residual (the largest last relative change; 1.0 after a single
    bounce) and stats.
    """
    if method not in SOLVE_METHODS:
        raise ValueError(f"solve_indirect: method must be one of {SOLVE_METHODS}, got "
                         f"{method!r}")
    ctx = timer.stage("indirect solve") if timer is not None else nullcontext()
    with ctx:
        return _solve(matrix, albedo, direct, int(max_bounces), float(tolerance), method,
                      threads, first_bounce)


def _solve(matrix, albedo, direct, max_bounces, tolerance, method, threads, extra=None):
    t, k = direct.shape[:2]
    rho, _ = clamp_albedo(np.asarray(albedo, dtype=np.float64))
    rho32 = rho.astype(np.float32)
    g = matrix if matrix.dtype == np.float32 else matrix.astype(np.float32)
    out = np.zeros((t, k, 3), dtype=np.float32)
    stats: dict = {"method": method, "converged": True, "blocks": []}
    if max_bounces < 1 or t == 0 or k == 0:
        return out, 0, 0.0, stats
    product = SparseProduct(g, threads)
    t0 = time.perf_counter()
    lo = hi = None
    if method == "chebyshev" and max_bounces > 1:
        lo, hi = spectrum_interval(product, rho)
        stats["interval"] = {"lo": lo.tolist(), "hi": hi.tolist()}
    stats["seconds_interval"] = time.perf_counter() - t0
    per_block = max(1, min(k, int(SOLVE_BLOCK_BYTES // max(1, 5 * t * 3 * 4))))
    bounces_all, resid_all = 0, 0.0

    def first_bounce(k0: int, k1: int) -> np.ndarray:
        ld = np.ascontiguousarray(direct[:, k0:k1], dtype=np.float32)
        b = product(ld.reshape(t, -1)).reshape(t, k1 - k0, 3)
        if extra is not None:  # ≥ 0 exactly; float32 round-off must not make it negative
            rows = extra[0]
            b[rows] = np.maximum(b[rows] + extra[1][:, k0:k1], np.float32(0))
        b *= np.float32(math.pi)
        return b

    for k0 in range(0, k, per_block):
        k1 = min(k, k0 + per_block)
        t1 = time.perf_counter()
        b = first_bounce(k0, k1)
        if max_bounces == 1:
            x, n, resid, conv = b, 1, 1.0, tolerance >= 1.0
        elif method == "neumann":
            x, n, resid, conv = _neumann(product, rho32, b, max_bounces, tolerance)
        else:
            x, n, resid, conv = _chebyshev(product, rho32, b, lo, hi, max_bounces, tolerance)
            if x is None:  # diverged (b was overwritten): plain series from scratch
                stats["fallback"] = stats.get("fallback", 0) + 1
                x, n2, resid, conv = _neumann(product, rho32, first_bounce(k0, k1),
                                              max_bounces, tolerance)
                n += n2
        x *= (rho32 / np.float32(math.pi))[:, None, :]
        out[:, k0:k1] = x
        del x, b
        stats["blocks"].append({"configurations": [k0, k1], "bounces": n, "residual": resid,
                                "converged": conv, "seconds": time.perf_counter() - t1})
        stats["converged"] = stats["converged"] and conv
        bounces_all = max(bounces_all, n)
        resid_all = max(resid_all, resid)
    return out, bounces_all, resid_all, stats


def _apply(product: SparseProduct, rho32: np.ndarray, x: np.ndarray,
           src: np.ndarray | None = None, out: np.ndarray | None = None) -> np.ndarray:
    """A·x = G (ρ ∘ x) for x (T, k, 3) float32; ``src`` and ``out`` (same shape) are
    optional work arrays (the product lands in ``out``)."""
    t = len(x)
    src = np.multiply(x, rho32[:, None, :], out=src)
    res = product(src.reshape(t, -1), None if out is None else out.reshape(t, -1))
    return res.reshape(x.shape)


def _neumann(product, rho32, b, max_bounces, tolerance):
    """x = Σ_{n<N} Aⁿ b, one product per bounce, until the relative change < tolerance."""
    x = b.copy()
    term = b
    n, resid, conv = 1, 1.0, False
    while n < max_bounces:
        term = _apply(product, rho32, term)
        n += 1
        x += term
        resid = _relative(_col_norms(term), _col_norms(x))
        if resid < tolerance:
            conv = True
            break
    return x, n, resid, conv


def _chebyshev(product, rho32, b, lo, hi, max_bounces, tolerance):
    """Chebyshev iteration for (I − A) x = b, A's spectrum in [lo, hi] per channel.
    Overwrites b. Returns (None, n, resid, False) when the change grows (divergence)."""
    alpha, beta = 1.0 - hi, 1.0 - lo  # spectrum of I − A
    theta = (beta + alpha) / 2.0
    delta = np.maximum((beta - alpha) / 2.0, 1e-6)
    sigma = theta / delta
    rho_k = 1.0 / sigma
    r = b  # residual b − (I − A)·0
    d = r / theta.astype(np.float32)
    x = np.zeros_like(b)
    src = np.empty_like(b)  # work arrays, reused by every product
    ad = np.empty_like(b)
    n, resid, conv = 1, 1.0, False
    best = np.inf
    while True:
        x += d  # x now holds bounces 1 … n
        if n > 1:
            resid = _relative(_col_norms(d), _col_norms(x))
            best = min(best, resid)
            if resid < tolerance:
                conv = True
                break
            if resid > CHEBYSHEV_DIVERGENCE * best:
                return None, n, resid, False
        if n >= max_bounces:
            break
        _apply(product, rho32, d, src, ad)
        n += 1
        ad -= d
        r += ad  # r ← r − (I − A) d
        rho_new = 1.0 / (2.0 * sigma - rho_k)
        np.multiply(r, (2.0 * rho_new / delta).astype(np.float32), out=ad)
        d *= (rho_new * rho_k).astype(np.float32)
        d += ad
        rho_k = rho_new
    return x, n, resid, conv


# ---------------------------------------------------------------------------------------
# The stage


def estimate_bake_bytes(texels: int, configurations: int, gather_rays: int) -> int:
    """Peak memory of a bake with ``texels`` covered texels and ``configurations`` lights
    (training + held-out), from the measured model above (transport is the peak stage)."""
    t, k = int(texels), int(configurations)
    return int(t * (MEM_PER_TEXEL + MEM_PER_TEXEL_RAY * int(gather_rays))
               + GATHER_BATCH * MEM_PER_GATHER_RAY_IN_FLIGHT + t * k * MEM_PER_TEXEL_CONFIG
               + min(5 * t * k * 12, SOLVE_BLOCK_BYTES))


def check_bake_memory(source: str, texels: TexelSpace, spec, limit_bytes: int) -> int:
    """Refuse (:class:`~prtcore.core.errors.LimitExceeded`) a bake whose estimated peak memory
    exceeds ``limit_bytes`` (``IntakeLimits.max_bake_bytes``), before transport allocates.
    spec : the :class:`~prtcore.core.spec.BakeSpec`. Returns the estimate."""
    from prtcore.core.errors import LimitExceeded

    k = spec.lights.count + spec.lights.holdout
    need = estimate_bake_bytes(texels.count, k, spec.transport.gather_rays)
    if need > limit_bytes:
        gib = 1 << 30
        raise LimitExceeded(
            str(source), "", f"the bake would need about {need / gib:.1f} GiB "
            f"({texels.count} covered texels of a {texels.width}×{texels.height} atlas, {k} "
            f"lighting configurations, {spec.transport.gather_rays} gather rays); lower "
            "atlas.resolution, lights.count or transport.gather_rays",
            limit=f"max_bake_bytes={limit_bytes} ({limit_bytes / gib:.1f} GiB)")
    return need


def spec_gather(scene: Scene, texels: TexelSpace, tracer: RayTracer, spec: TransportSpec,
                timer: StageTimer | None = None) -> Gather:
    """:func:`gather_operator` with the spec's rays, seed, near field and direct samples."""
    return gather_operator(scene, texels, tracer, spec.gather_rays, spec.seed, timer,
                           near_field=spec.near_field, direct_samples=spec.direct_samples)


@dataclass(frozen=True)
class TexelLighting:
    """Direct and indirect outgoing radiance at the texels for K lights.

    direct, indirect : (T, K, 3) float32; iterations, residual : as :class:`Dataset`;
    stats : "rays" (direct texels, near field), "solve", "direct_samples".
    """

    direct: np.ndarray
    indirect: np.ndarray
    iterations: int
    residual: float
    stats: dict


def light_texels(scene: Scene, texels: TexelSpace, tracer: RayTracer, gather: Gather,
                 lights: Sequence[Light], spec: TransportSpec,
                 timer: StageTimer | None = None) -> TexelLighting:
    """Direct light at the texels (averaged over ``gather.direct_position``), the near
    field's first bounce (:func:`near_field_correction`) and all bounces
    (:func:`solve_indirect`) for ``lights``, on a gather traced once
    (:func:`spec_gather`). Sub-stages "direct texels", "near field", "indirect solve"."""
    timer = timer or StageTimer(quiet=True)
    rays0 = tracer.rays_traced
    with timer.stage("direct texels"):
        direct = direct_radiance(scene, tracer, lights, gather.direct_position,
                                 texels.normal, texels.albedo, timer, "direct texels")
    rays1 = tracer.rays_traced
    first = None
    if gather.near is not None and gather.near.count:
        with timer.stage("near field"):
            first = near_field_correction(scene, tracer, gather.near, lights, direct, timer)
    rays2 = tracer.rays_traced
    indirect, bounces, resid, solve_stats = solve_indirect(
        gather.matrix, texels.albedo, direct, spec.max_bounces, spec.tolerance, timer,
        threads=tracer.threads, first_bounce=first)
    stats = {"rays": {"direct_texels": rays1 - rays0, "near_field": rays2 - rays1},
             "solve": solve_stats, "direct_samples": int(gather.direct_position.shape[1])}
    return TexelLighting(direct=direct, indirect=indirect, iterations=bounces,
                         residual=resid, stats=stats)


def bake_dataset(scene: Scene, texels: TexelSpace, points: MeasurementPoints,
                 lights_train: Sequence[Light], lights_holdout: Sequence[Light] = (),
                 spec: TransportSpec | None = None, timer: StageTimer | None = None,
                 tracer: RayTracer | None = None) -> Dataset:
    """The transport stage: gather operator, direct light, all bounces.

    Training and held-out configurations are computed in one pass: ``Dataset.lights`` is
    ``(*lights_train, *lights_holdout)`` and every (…, K, 3) array follows that order;
    ``stats["train"]`` is ``len(lights_train)`` (the caller splits at it).
    Sub-stages are timed on ``timer`` as "gather operator", "direct points",
    "direct texels", "near field", "indirect solve".
    """
    spec = spec or TransportSpec()
    timer = timer or StageTimer(quiet=True)
    tracer = tracer or RayTracer(scene.positions, scene.faces, scene.radius)
    lights = (*tuple(lights_train), *tuple(lights_holdout))
    rays0 = tracer.rays_traced
    before = dict(timer.seconds)

    gather = spec_gather(scene, texels, tracer, spec, timer)
    rays1 = tracer.rays_traced
    with timer.stage("direct points"):
        cl = direct_radiance(scene, tracer, lights, points.cluster_position,
                             points.cluster_normal, points.cluster_albedo, timer,
                             "direct points")
        k = len(lights)
        direct_p = points.average_clusters(cl.reshape(len(cl), 3 * k).astype(np.float64))
        direct_p = direct_p.reshape(points.count, k, 3).astype(np.float32)
        del cl
    rays2 = tracer.rays_traced
    lit = light_texels(scene, texels, tracer, gather, lights, spec, timer)
    _, clamped = clamp_albedo(np.asarray(texels.albedo, dtype=np.float64))
    stats = {
        "train": len(lights_train), "holdout": len(lights_holdout),
        "texels": texels.count, "points": points.count,
        "rays": {"gather": rays1 - rays0, "direct_points": rays2 - rays1,
                 **lit.stats["rays"], "total": tracer.rays_traced - rays0},
        "direct_samples": lit.stats["direct_samples"],
        "gather": gather.stats, "solve": lit.stats["solve"],
        "albedo_clamped_values": clamped,
        "seconds": {name: timer.seconds[name] - before.get(name, 0.0)
                    for name in ("gather operator", "direct points", "direct texels",
                                 "near field", "indirect solve") if name in timer.seconds},
    }
    return Dataset(lights=lights, direct_points=direct_p, direct_texels=lit.direct,
                   indirect=lit.indirect, iterations=lit.iterations, residual=lit.residual,
                   stats=stats)
