"""The surface gather: the texel → texel operator G of inter-reflection (paper 4.1).

Every texel shoots M cosine-distributed rays from points jittered over its footprint; each
ray's first front-face hit is mapped to the texel holding that surface point, with weight
1/M. With cosine sampling ``E(x) ≈ π/M Σ_j L(y_j) = 1/M Σ_j ρ_j E_j``, so
``E_ind = G · (ρ ∘ (E_d + E_ind))``. Tracing G also decides where each texel's direct
light is evaluated (:attr:`Gather.direct_position`) and which rays hit so close to their
origin that the first bounce takes the direct light of the hit point
(:attr:`Gather.near`, :func:`prtcore.transport.direct.near_field_correction`).
:class:`prtcore.transport.surface.SurfaceGather` is the transport operator built on it.

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
import threading
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass
from typing import Protocol

import numba
import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from prtcore.core.geometry import directions_around, orthonormal_frame
from prtcore.core.memory import release_free_memory
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Scene
from prtcore.core.spec import TransportSpec
from prtcore.core.tolerances import BARY_EPS, offset_origins
from prtcore.receivers.texels import TexelSpace, sample_texel_regions, texel_regions

#: Gather rays that share one jittered origin (S = M / RAYS_PER_ORIGIN origins per texel);
#: enough rays per origin to tell "inside geometry" (most rays hit back faces) from "sees
#: the back of some open surface" (a few do).
RAYS_PER_ORIGIN = 4
#: How far (in texels) the origins of a texel whose square only touches its triangle are
#: moved from its sample into the triangle.
FALLBACK_NUDGE = 0.05
#: Gather rays traced per batch (bounds memory: ~150 bytes per ray in flight).
GATHER_BATCH = 1 << 19
#: Gather batches traced at once (each one's numpy work is single-threaded; Embree's
#: queries within a batch use the tracer's threads).
GATHER_WORKERS = 2
#: A hit mapped through the UV lookup must lie within this many texel footprints of the
#: texel it lands on; otherwise (overlapping UVs, a texel of another chart) it is re-mapped
#: to the nearest texel in 3-D facing the same way.
MAP_SLACK_FOOTPRINTS = 3.0
#: Texels covered less than 1 − this are "partly covered" (their sample may sit on the
#: chart border; see :class:`Gather`).
PARTIAL_COVERAGE_EPS = 1e-3
#: Texels per chunk of :func:`jittered_origins`' temporaries.
ORIGIN_CHUNK = 1 << 14
#: Golden-ratio conjugate: the rank-1 (Fibonacci) lattice generator.
PHI = 0.6180339887498949


@dataclass(frozen=True)
class NearField:
    """Gather rays that hit close to their origin, where a texel's value (its average)
    stands badly for the light at the hit point: a contact shadow or a lit strip narrower
    than a texel (a block on a floor, a ledge under a step). Each is also in the gather
    matrix; :func:`prtcore.transport.direct.near_field_correction` replaces, for the first
    bounce only, the texel's direct light by the direct light at the hit point.

    row : (n,) int64 receiving texel, sorted; col : (n,) int64 the texel the hit maps to;
    triangle : (n,) int64 and barycentric : (n, 3) float64, the hit point;
    weight : (n,) float32 the ray's weight in the matrix row (1/M_valid), or (n, 3) one per
    colour channel (the Chiang fibre's rays, weighted by its directional albedo), or
    (n, F, 3) one per exitance coefficient a, whose row is ``row + offsets[a]``;
    offsets : (F,) int64 with such weights (None otherwise).
    """

    row: np.ndarray
    col: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    weight: np.ndarray
    offsets: np.ndarray | None = None

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


class ForeignHits(Protocol):
    """Hits of the gather's rays on triangles that are not the scene's: the tracer holds
    the scene's triangles [0, ``first``) and then other geometry (the fibre tubes of a hair
    + mesh bake, :mod:`prtcore.transport.hair_mesh`), whose receivers are ``columns`` more
    columns of the operator after the scene's T texels."""

    first: int
    columns: int

    def __call__(self, batch: int, rows: np.ndarray, triangle: np.ndarray,
                 barycentric: np.ndarray, direction: np.ndarray, distance: np.ndarray
                 ) -> np.ndarray:
        """Front hits of batch ``batch`` (the batch's first row): receiving texel rows
        (n,) int64, tracer triangles (n,) ≥ ``first``, barycentrics (n, 3), ray
        directions (n, 3) float32 and the hits' distances (n,) → (n,) int64 columns in
        [0, ``columns``), counted after the scene's texels. Called from two threads at
        once (one per batch)."""
        ...


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


def jittered_origins(scene: Scene, texels: TexelSpace, per_texel: int,
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
    centre = texels.xy.astype(np.float64) + 0.5
    shift = rng.random((t, 2))
    # the lattice points' barycentrics, texels in chunks (bounds the temporaries: the
    # lattice, its pixel positions and the frames per point cost ~6× the result)
    bary = np.empty((t * per_texel, 3))

    def lattice_bary(a: int) -> None:
        b = min(t, a + ORIGIN_CHUNK)
        corner, inv = _uv_frames(scene.uv1[scene.faces[texels.triangle[a:b]]] * size)
        q = fibonacci_lattice(per_texel, shift[a:b]) - 0.5 + centre[a:b, None, :]
        bary[a * per_texel:b * per_texel] = _uv_barycentric(
            corner[:, None], inv[:, None], q).reshape(-1, 3)

    _over_chunks(lattice_bary, t)
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
    del owner
    np.clip(bary, 0.0, None, out=bary)
    bary /= bary.sum(axis=1, keepdims=True)
    pos = bary.reshape(t, per_texel, 3)  # the positions overwrite the barycentrics

    def to_world(a: int) -> None:
        b = min(t, a + ORIGIN_CHUNK)
        verts = scene.positions[scene.faces[texels.triangle[a:b]]]  # (n, 3, 3)
        pos[a:b] = np.einsum("tsk,tkj->tsj", pos[a:b], verts)

    _over_chunks(to_world, t)
    return pos, inside.reshape(t, per_texel)


def _over_chunks(fn, t: int) -> None:
    """fn(a) for a = 0, ORIGIN_CHUNK, … < t, on GATHER_WORKERS threads (each chunk writes
    its own rows, so the result does not depend on the order; numpy releases the GIL)."""
    starts = range(0, t, ORIGIN_CHUNK)
    if len(starts) == 1:
        fn(0)
        return
    with ThreadPoolExecutor(GATHER_WORKERS) as ex:
        for _ in ex.map(fn, starts):
            pass


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


@numba.njit(parallel=True, cache=True, nogil=True)
def _uv_texels(index, tri, bary, x0, x1, x2, y0, y1, y2, width, height, lut, texel_triangle,
               tex, own):  # pragma: no cover - compiled
    """Each hit's atlas texel: (⌊x⌋, ⌊y⌋) of its TEXCOORD_1 point in pixels (corner 0 plus
    the barycentric-weighted edges, summed in that order, as numpy would), looked up in
    ``lut`` (H·W,) int64. Hit i is row index[i] of tri (·,) int64 and bary (·, 3) float64;
    x0 … y2 : (F,) float64 per face (:class:`HitMapper`); writes tex (n,) int64 (−1 off
    the atlas or on an empty texel) and own (n,) bool: the texel was sampled on the hit's
    own face."""
    for i in numba.prange(len(index)):
        h = index[i]
        f = tri[h]
        b1 = bary[h, 1]
        b2 = bary[h, 2]
        x = np.floor(x0[f] + b1 * x1[f] + b2 * x2[f])
        y = np.floor(y0[f] + b1 * y1[f] + b2 * y2[f])
        k = -1
        if x >= 0 and x < width and y >= 0 and y < height:
            k = lut[np.int64(y) * width + np.int64(x)]
        tex[i] = k
        own[i] = k >= 0 and texel_triangle[k] == f


class HitMapper:
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
        self.triangle = np.ascontiguousarray(texels.triangle, dtype=np.int64)
        self.position32 = texels.position.astype(np.float32)
        fp = np.linalg.norm(texels.footprint, axis=2).sum(axis=1)  # |dP/dx| + |dP/dy|
        self.reach2 = ((MAP_SLACK_FOOTPRINTS * fp + 2.0 * tracer.offset) ** 2).astype(
            np.float32)
        self._tree: cKDTree | None = None
        self._lock = threading.Lock()  # the gather maps two batches at once
        self.remapped = 0

    def __call__(self, tri: np.ndarray, bary: np.ndarray, ray: np.ndarray,
                 origin: np.ndarray, direction: np.ndarray, t: np.ndarray,
                 index: np.ndarray | None = None) -> np.ndarray:
        """tri : (n,) faces, bary : (n, 3) barycentrics, t : (n,) float64 distances of n
        front hits of rays ``ray`` (n,) int64 into origin, direction ((r, 3) float32);
        with ``index`` (n,) int64 the hits are rows ``index`` of tri, bary and t (a
        :class:`~prtcore.core.raytrace.Hits`' arrays, not gathered first).
        Returns (n,) int64 texel indices."""
        if index is None:
            index = np.arange(len(tri))
        tex = np.empty(len(index), dtype=np.int64)
        own = np.empty(len(index), dtype=bool)
        _uv_texels(index, tri, bary, *self.px, self.texels.width, self.texels.height,
                   self.lut_flat, self.triangle, tex, own)
        # A texel sampled on the hit's own face is right by construction; others must be
        # near the hit point (a texel of another chart means overlapping UVs).
        other = np.flatnonzero(~own)
        tk = tex[other]
        ro = ray[other]
        point = origin[ro] + direction[ro] * t[index[other]].astype(np.float32)[:, None]
        diff = point - self.position32[tk]
        far = (tk < 0) | (np.einsum("ij,ij->i", diff, diff) > self.reach2[tk])
        bad = other[far]
        if len(bad):
            hit = index[bad]
            p64 = self.tracer.surface_point(tri[hit], bary[hit])
            tex[bad] = self._nearest(p64, self.tracer.face_normals[tri[hit]])
            with self._lock:
                self.remapped += len(bad)
        return tex

    def _nearest(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Nearest texel in 3-D whose geometric normal faces the same way (of the 8
        nearest), else the nearest."""
        with self._lock:
            if self._tree is None:
                self._tree = cKDTree(self.texels.position)
        k = min(8, self.texels.count)
        _, idx = self._tree.query(points, k=k)
        idx = idx.reshape(len(points), k)
        facing = np.einsum("nkj,nj->nk", self.texels.geometric_normal[idx], normals) > 0.5
        first = np.where(facing.any(axis=1), facing.argmax(axis=1), 0)
        return idx[np.arange(len(points)), first]


def near_field_reach(texels: TexelSpace, near_field: float) -> np.ndarray:
    """(T,) float64: how far from texel i a gather hit counts as near field —
    ``near_field`` × its footprint (|dP/dx| + |dP/dy|)/2, in world units."""
    return near_field * 0.5 * np.linalg.norm(texels.footprint, axis=2).sum(axis=1)


def gather_operator(scene: Scene, texels: TexelSpace, tracer: RayTracer, rays: int,
                    seed: int, timer: StageTimer | None = None, near_field: float = 0.0,
                    direct_samples: int = 1, foreign: ForeignHits | None = None) -> Gather:
    """Trace the texel → texel gather operator G (see the module docstring).

    rays : M gather rays per texel (≥ 1); seed : every random choice (same inputs + seed
    → bit-identical operator).

    Per texel: S = max(1, M // RAYS_PER_ORIGIN) origins on a shifted Fibonacci lattice
    over the texel square, kept on the texel's triangle (:func:`jittered_origins`),
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

    foreign : the tracer holds more than the scene's triangles (:class:`ForeignHits`):
    hits on the others go to the columns it names after the T texels, and ``matrix`` is
    (T, T + foreign.columns); they are never near-field hits.

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
                       float(near_field), int(direct_samples), foreign)


def build_gather_operator(scene: Scene, texels: TexelSpace, tracer: RayTracer, rays: int,
                          seed: int, timer: StageTimer | None = None) -> sp.csr_matrix:
    """(T, T) float32 CSR gather operator, rows = receiving texel, weights 1/M (1/M_valid
    for partly buried texels; see :func:`gather_operator`, which also returns the
    buried-texel handling)."""
    return gather_operator(scene, texels, tracer, rays, seed, timer).matrix


def side_normals(shading: np.ndarray, geometric: np.ndarray) -> np.ndarray:
    """The geometric normals (n, 3) float64 turned to their shading normals' side (n, 3):
    the side a texel's gather rays leave from, and its origins' offset direction."""
    geo = np.asarray(geometric, dtype=np.float64)
    return geo * np.where(np.einsum("ij,ij->i", shading, geo) < 0, -1.0, 1.0)[:, None]


def hit_share(texels: TexelSpace, tracer: RayTracer, rays: int, count: int,
              rng: np.random.Generator, first: int | None = None,
              *reach: np.ndarray) -> tuple[float, ...]:
    """The share of ``rays`` cosine gather rays from each of at most ``count`` random
    texels (from their sample points, offset as the gather offsets) that hit anything:
    before the gather, a bound on the entries it keeps (at most one per ray that hits;
    rays below the surface, which the gather drops, count as hits here); and for each
    ``reach`` (T,) world units, the share that hit a triangle ≥ ``first`` (another
    receiver's: the fibre tubes) closer than that to its texel (0 without ``first``).
    Draws from ``rng``."""
    at = np.repeat(np.sort(rng.choice(texels.count, min(texels.count, count),
                                      replace=False)), max(rays, 1))
    if not len(at):
        return 0.0, 0.0
    shade = np.asarray(texels.normal[at], dtype=np.float64)
    o = offset_origins(texels.position[at], side_normals(shade, texels.geometric_normal[at]),
                       tracer.scale)
    d = directions_around(shade, np.sqrt(rng.random(len(at))), 2 * np.pi * rng.random(len(at)))
    hits = tracer.intersect(o, d)
    foreign = hits.triangle >= first if first is not None else np.zeros(len(at), bool)
    return float(np.mean(hits.hit)), *(float(np.mean(foreign & (hits.t < r[at])))
                                       for r in reach)


def _gather(scene: Scene, texels: TexelSpace, tracer: RayTracer, m: int, seed: int,
            timer: StageTimer | None, near_field: float = 0.0, direct_samples: int = 1,
            foreign: ForeignHits | None = None) -> Gather:
    t = texels.count
    # columns: the texels, then the foreign receivers; the sentinel after them all
    n_cols = t + (foreign.columns if foreign is not None else 0)
    s = max(1, m // RAYS_PER_ORIGIN)
    rng = np.random.default_rng(seed)
    origins, jittered = jittered_origins(scene, texels, s, rng)
    dir_shift = rng.random((t, 2), dtype=np.float32)
    shade = np.asarray(texels.normal, dtype=np.float64)
    geo = side_normals(shade, texels.geometric_normal)
    tan, bit = orthonormal_frame(shade)
    # frame rows (tangent, bitangent, normal) in float32 for the Embree-bound directions
    frame = np.stack([tan, bit, shade], axis=1).astype(np.float32)  # (T, 3, 3)
    up = np.einsum("tij,tj->ti", np.stack([tan, bit, shade], axis=1), geo)  # (T, 3)
    flat = bool((np.abs(up[:, :2]).max(initial=0.0) < 1e-12) and (up[:, 2].min(
        initial=1.0) > 0))
    mapper = HitMapper(scene, texels, tracer)
    # near-field reach of each texel: near_field × its footprint, in world units
    reach = near_field_reach(texels, near_field)
    near_parts: list[tuple[np.ndarray, ...]] = []

    i = np.arange(m, dtype=np.float64)
    lattice = np.stack([(i + 0.5) / m, np.mod(i * PHI, 1.0)], axis=1).astype(np.float32)
    ray_o = np.arange(m) % s  # origin of each ray within its texel
    per_batch = max(1, GATHER_BATCH // m)
    valid_rays = np.zeros(t, dtype=np.int32)
    inside_origin = np.zeros((t, s), dtype=bool)
    # per batch: the row lengths, columns and weights (8 bytes per non-zero, not the 20 of
    # rows, columns and counts), one list each so that each is joined and dropped in turn
    row_lens: list[np.ndarray] = []
    col_parts: list[np.ndarray] = []
    weight_parts: list[np.ndarray] = []

    def one(b0: int) -> tuple:
        """Trace texels b0 … b0 + per_batch − 1; returns their CSR parts, near-field hits
        and counts (batches are independent: two run at once, joined in order)."""
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
        # the batch's origins off their surface (float32), each texel's S of them per ray
        o = offset_origins(origins[b0:b1].reshape(-1, 3), np.repeat(geo[b0:b1], s, axis=0),
                           tracer.scale).reshape(nt, s, 3)[:, ray_o]  # (nt, m, 3)
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
        counts = (len(sel), int(back.sum()), len(sel) - int(hit.sum()), nt * m - len(sel))
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
        cols = np.full(nt * m, n_cols, dtype=np.int64)  # sentinel: ray brings nothing
        if foreign is None:
            cols[use] = mapper(hits.triangle, hits.barycentric, use, o, d, hits.t,
                               index=pos)
        else:
            own = hits.triangle[pos] < foreign.first
            cols[use[own]] = mapper(hits.triangle, hits.barycentric, use[own], o, d,
                                    hits.t, index=pos[own])
            fu, fp = use[~own], pos[~own]
            cols[fu] = t + foreign(b0, b0 + fu // m, hits.triangle[fp],
                                   hits.barycentric[fp], d[fu], hits.t[fp])
            # foreign hits are not near-field hits (the correction shades scene faces)
            use, pos = use[own], pos[own]
        r, c, cnt = _row_counts(cols.reshape(nt, m), b0, n_cols)
        parts = (np.bincount(r - b0, minlength=nt), c,
                 (cnt / valid_rays[r]).astype(np.float32))
        near_part = None
        if near_field > 0:
            r_use = use // m  # receiving texel - b0
            close = hits.t[pos] < reach[b0 + r_use]
            nu, npos, nr = use[close], pos[close], r_use[close]
            near_part = (b0 + nr, cols[nu], hits.triangle[npos], hits.barycentric[npos],
                         (1.0 / ray_ok.sum(axis=1)[nr]).astype(np.float32))
        return parts, near_part, counts

    totals = np.zeros(4, dtype=np.int64)  # traced, back-face hits, misses, below surface
    starts = range(0, t, per_batch)
    with ThreadPoolExecutor(GATHER_WORKERS if len(starts) > 1 else 1) as ex:
        done = ex.map(one, starts)
        if timer is not None:
            done = timer.bar(done, "gather", total=len(starts))
        for (lens, c, w), near_part, counts in done:
            row_lens.append(lens)
            col_parts.append(c)
            weight_parts.append(w)
            if near_part is not None:
                near_parts.append(near_part)
            totals += counts
    n_traced, n_back, n_miss, n_below = (int(n) for n in totals)
    frame = up = dir_shift = None  # the rays' inputs: freed before the matrix is joined
    release_free_memory()  # the batches' arenas (prtcore/core/memory.py)

    indptr = np.zeros(t + 1, dtype=np.int64)
    if row_lens:
        np.cumsum(np.concatenate(row_lens), out=indptr[1:])
    # each kind joined and its parts dropped before the next (one copy in flight, not two)
    col = np.concatenate(col_parts) if col_parts else np.zeros(0, np.int32)
    col_parts.clear()
    weight = np.concatenate(weight_parts) if weight_parts else np.zeros(0, np.float32)
    weight_parts.clear()
    matrix = sp.csr_matrix((weight, col, indptr), shape=(t, n_cols))
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

def spec_gather(scene: Scene, texels: TexelSpace, tracer: RayTracer, spec: TransportSpec,
                timer: StageTimer | None = None) -> Gather:
    """:func:`gather_operator` with the spec's rays, seed, near field and direct samples."""
    return gather_operator(scene, texels, tracer, spec.gather_rays, spec.seed, timer,
                           near_field=spec.near_field, direct_samples=spec.direct_samples)

