"""Texel space: a G-buffer per lightmap texel in TEXCOORD_1 space (docs/bundle.md).

Texel (x, y), y counted from the image's top row, has its centre at
TEXCOORD_1 = ((x + 0.5) / W, (y + 0.5) / H).

:func:`build_texel_space` rasterises TEXCOORD_1 conservatively (exact per-texel coverage),
samples position / normals / albedo / footprint per covered texel, computes the dilation
into the padding and orders texels along a 3-D Morton curve; :func:`texels_to_image` and
:func:`image_to_texels` convert between per-texel arrays and atlas images (row 0 = top).
"""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import ndimage

from prtcore.core.errors import AssetError, SpecError
from prtcore.core.geometry import shading_normals
from prtcore.core.materials import albedo_at
from prtcore.core.progress import StageTimer, bar
from prtcore.core.scene import Scene
from prtcore.core.tolerances import BARY_EPS, DEGENERATE_AREA_REL, UV_TEXEL_EPS
from prtcore.core.uvraster import expand_spans, raster_spans, span_blocks


@dataclass(frozen=True)
class TexelSpace:
    """Covered lightmap texels, in a spatially coherent order.

    width, height : atlas size W × H
    xy : (t, 2) int32 texel coordinates (x, y from the top row)
    position : (t, 3) float64 world position of the texel sample
    normal : (t, 3) float64 unit shading normal (interpolated vertex normals)
    geometric_normal : (t, 3) float64 unit face normal
    albedo : (t, 3) float64 raw linear albedo (clamp for transport with
        :func:`prtcore.core.materials.clamp_albedo`)
    triangle : (t,) int64 face index into the scene
    barycentric : (t, 3) float64 weights of the face's vertices at the sample
    coverage : (t,) float32 fraction of the texel's area covered by geometry, in (0, 1]
    footprint : (t, 2, 3) float64 world-space extent of one texel step in x and in y
        (dP/dx, dP/dy) at the sample, for jittering within the texel
    dilate_xy : (d, 2) int32 padding texels filled by dilation, and
    dilate_src : (d,) int64 the covered texel (index into the arrays above) each copies
    """

    width: int
    height: int
    xy: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    geometric_normal: np.ndarray
    albedo: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    coverage: np.ndarray
    footprint: np.ndarray
    dilate_xy: np.ndarray
    dilate_src: np.ndarray

    #: the receiver kind (prtcore.receivers.base.Receiver)
    kind: ClassVar[str] = "texels"

    @property
    def count(self) -> int:
        return len(self.xy)

    def to_image(self, values: np.ndarray, dilate: bool = True) -> np.ndarray:
        """:func:`texels_to_image` of this texel space (the Receiver protocol)."""
        return texels_to_image(self, values, dilate=dilate)


# ---------------------------------------------------------------------------------------
# Building the texel space
# ---------------------------------------------------------------------------------------
#
# Conventions used below (all documented in :func:`build_texel_space`):
#
# * "pixel space": TEXCOORD_1 scaled by (W, H); texel (x, y) is the square
#   [x, x+1] × [y, y+1] and its centre is (x + 0.5, y + 0.5). Distances are in texels.
# * Triangles are re-oriented in pixel space so that their doubled signed area ``det`` is
#   positive; barycentrics are mapped back to the face's own vertex order at the end.
# * Edge k of an oriented triangle runs from vertex k to vertex k+1 (mod 3); its edge
#   function E_k(q) = cross(p[k+1] - p[k], q - p[k]) is ≥ 0 inside, and the barycentric of
#   the vertex opposite the edge, (k + 2) mod 3, is E_k / det.

#: Smallest coverage stored for a texel that a triangle touches with (almost) no area.
MIN_COVERAGE = 1.0 / 64.0
#: A texel region (its square ∩ its triangle, in barycentric units: the triangle has
#: area 1/2) at or below this area only touches its triangle (:func:`texel_regions`).
REGION_MIN_AREA = 1e-14
#: Candidate (triangle, texel) pairs evaluated per vectorised chunk.
_PAIR_CHUNK = 1 << 18
#: Covered texels turned into G-buffer samples per block.
_SAMPLE_BLOCK = 1 << 20
#: Atlas rows per distance-transform band (bounded memory for 4096² atlases).
_DILATE_BAND_TEXELS = 1 << 21
#: Key of a (triangle, texel) pair whose texel centre lies inside the triangle; pairs that
#: only overlap the texel square use their overlap area (≤ 1) as key.
_CENTRE_KEY = np.float32(2.0)


def _require_uv1(scene: Scene) -> np.ndarray:
    if scene.uv1 is None:
        raise AssetError(scene.source, "attributes.TEXCOORD_1",
                         "the scene has no lightmap UVs (run the UV stage first)")
    return np.asarray(scene.uv1, dtype=np.float64)


def uv_degenerate_faces(scene: Scene) -> np.ndarray:
    """Faces whose TEXCOORD_1 triangle has (numerically) zero area: they get no texels.

    A face is UV-degenerate when a UV is not finite or when its doubled UV area is at most
    ``BARY_EPS`` times its longest UV edge squared (collinear to 1e-9, scale-free).

    Returns (k,) int64 ascending face indices.
    """
    uv = _require_uv1(scene)
    if len(scene.faces) == 0:
        return np.zeros(0, dtype=np.int64)
    t = uv[scene.faces]  # (f, 3, 2)
    e1 = t[:, 1] - t[:, 0]
    e2 = t[:, 2] - t[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    longest = np.max(((t - np.roll(t, 1, axis=1)) ** 2).sum(axis=2), axis=1)
    finite = np.isfinite(t).all(axis=(1, 2))
    with np.errstate(invalid="ignore"):
        bad = ~finite | ~(np.abs(det) > BARY_EPS * longest)
    return np.flatnonzero(bad).astype(np.int64)


def world_degenerate_faces(scene: Scene) -> np.ndarray:
    """Faces whose world-space area is at most ``DEGENERATE_AREA_REL`` × radius².

    They have no geometric normal, so :func:`build_texel_space` does not rasterise them
    either (their texels stay uncovered and are filled by dilation when in the padding).

    Returns (k,) int64 ascending face indices.
    """
    if len(scene.faces) == 0:
        return np.zeros(0, dtype=np.int64)
    limit = DEGENERATE_AREA_REL * scene.radius ** 2
    area = scene.face_areas()
    return np.flatnonzero(~(area > limit)).astype(np.int64)


def _part1by2(v: np.ndarray) -> np.ndarray:
    """Spread the low 21 bits of uint64 ``v`` so that bit i lands on bit 3i."""
    v = v & np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


def morton_codes(points: np.ndarray, bounds: np.ndarray, bits: int = 21) -> np.ndarray:
    """3-D Morton (Z-order) codes of points quantised on an axis-aligned box.

    points : (n, 3) float; bounds : (2, 3) float (min row, max row); bits : 1..21 per axis.
    Each axis is quantised to ``floor((p - min) / (max - min) * 2**bits)`` clamped to
    [0, 2**bits - 1] (0 on an axis of zero extent); bit i of x, y, z goes to bit 3i, 3i+1,
    3i+2 of the code. Returns (n,) uint64.
    """
    if not 1 <= bits <= 21:
        raise ValueError(f"morton_codes: bits must be in 1..21, got {bits}")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    bounds = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    lo, ext = bounds[0], bounds[1] - bounds[0]
    cells = float(1 << bits)
    rel = np.divide(points - lo, ext, out=np.zeros_like(points), where=ext > 0)
    q = np.clip(np.floor(np.nan_to_num(rel) * cells), 0, cells - 1).astype(np.uint64)
    return (_part1by2(q[:, 0]) | (_part1by2(q[:, 1]) << np.uint64(1))
            | (_part1by2(q[:, 2]) << np.uint64(2)))


def morton_order(points: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Permutation sorting points along the 3-D Morton curve of ``bounds``.

    points : (n, 3) float; bounds : (2, 3) float. 21 bits per axis (see
    :func:`morton_codes`); the sort is stable, so points in the same cell keep their input
    order. Returns (n,) int64 indices: ``points[order]`` is Z-ordered.
    """
    return np.argsort(morton_codes(points, bounds), kind="stable").astype(np.int64)


def _mean_clamped(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean of clip(t, 0, 1) for t uniform between a and b (elementwise, any order)."""
    lo = np.minimum(a, b)
    hi = np.maximum(a, b)
    lo01 = np.clip(lo, 0.0, 1.0)
    hi01 = np.clip(hi, 0.0, 1.0)
    span = hi - lo
    integral = 0.5 * (hi01 - lo01) * (hi01 + lo01) + np.maximum(hi - np.maximum(lo, 1.0), 0.0)
    return np.divide(integral, span, out=np.clip(0.5 * (lo + hi), 0.0, 1.0), where=span > 0)


def _square_overlap(vx: np.ndarray, vy: np.ndarray) -> np.ndarray:
    """Exact area of a positively oriented triangle ∩ the unit square [0, 1]².

    vx, vy : (3, n) float64 vertex coordinates relative to the square's corner.
    Signed-area decomposition: area(T ∩ S) = Σ_edges −sign(dx) ∫ clip(y(x), 0, 1) dx over the
    edge's x-range clipped to [0, 1] (exact, no polygon clipping). Returns (n,) float64.
    """
    area = np.zeros(vx.shape[1])
    for k in range(3):
        ax, ay = vx[k], vy[k]
        bx, by = vx[(k + 1) % 3], vy[(k + 1) % 3]
        dx = bx - ax
        lo = np.clip(np.minimum(ax, bx), 0.0, 1.0)
        hi = np.clip(np.maximum(ax, bx), 0.0, 1.0)
        slope = np.divide(by - ay, dx, out=np.zeros_like(dx), where=dx != 0)
        mean = _mean_clamped(ay + slope * (lo - ax), ay + slope * (hi - ax))
        area -= np.sign(dx) * (hi - lo) * mean
    return np.clip(area, 0.0, 1.0)


class _Raster:
    """Dense per-atlas-texel reduction state (one float32 key, int32 triangle, f64 area)."""

    def __init__(self, width: int, height: int):
        n = width * height
        self.key = np.full(n, -1.0, dtype=np.float32)
        self.tri = np.full(n, -1, dtype=np.int32)
        self.area = np.zeros(n, dtype=np.float64)

    def merge(self, tid: np.ndarray, key: np.ndarray, tri: np.ndarray, area: np.ndarray):
        """Accumulate pair areas; keep per texel the pair with the largest (key, −tri)."""
        if len(tid) == 0:
            return
        order = np.lexsort((tri, -key, tid))
        tid_s = tid[order]
        first = np.flatnonzero(np.r_[True, tid_s[1:] != tid_s[:-1]])
        u = tid_s[first]
        self.area[u] += np.add.reduceat(area[order], first)
        best = order[first]
        k, t = key[best], tri[best]
        ok, ot = self.key[u], self.tri[u]
        better = (k > ok) | ((k == ok) & (t < ot))
        self.key[u[better]] = k[better]
        self.tri[u[better]] = t[better]


def _rasterise(px: np.ndarray, py: np.ndarray, faces: np.ndarray, width: int, height: int,
               timer: StageTimer | None) -> _Raster:
    """Conservative rasterisation of oriented pixel-space triangles.

    px, py : (m, 3) float64 pixel-space vertices (det > 0); faces : (m,) int64 their face
    indices. The (triangle, texel) pairs are those of :func:`prtcore.core.uvraster.raster_spans`
    (the texel square shrunk by ``UV_TEXEL_EPS`` texels meets the triangle); each
    contributes its exact overlap area and a key (centre inside → 2, else the overlap
    area).
    """
    r = _Raster(width, height)
    m = len(faces)
    if m == 0:
        return r
    ex = np.roll(px, -1, axis=1) - px  # edge k: vertex k → k+1
    ey = np.roll(py, -1, axis=1) - py
    det = ex[:, 0] * (py[:, 2] - py[:, 0]) - ey[:, 0] * (px[:, 2] - px[:, 0])
    half = 0.5 - UV_TEXEL_EPS
    # one row per quantity: gathering columns table[:, ti] gives contiguous rows
    table = np.concatenate([px.T, py.T, ex.T, ey.T, (np.abs(ex) + np.abs(ey)).T * half,
                            -BARY_EPS * det[None]])
    hit = np.zeros(m, dtype=bool)

    def evaluate(ti: np.ndarray, x: np.ndarray, y: np.ndarray):
        g = table[:, ti]
        vx, vy, gx, gy, reach, lim = g[0:3], g[3:6], g[6:9], g[9:12], g[12:15], g[15]
        fx = x.astype(np.float64)
        fy = y.astype(np.float64)
        cx = fx + 0.5
        cy = fy + 0.5
        e0, e1, e2 = (gx[k] * (cy - vy[k]) - gy[k] * (cx - vx[k]) for k in range(3))
        inside = (e0 >= lim) & (e1 >= lim) & (e2 >= lim)
        # squares wholly inside the triangle have area 1; clip only the others
        r_sel = reach * (0.5 / half)
        cut = np.flatnonzero((e0 < r_sel[0]) | (e1 < r_sel[1]) | (e2 < r_sel[2]))
        area = np.ones(len(ti))
        area[cut] = _square_overlap(vx[:, cut] - fx[cut], vy[:, cut] - fy[cut])
        key = np.where(inside, _CENTRE_KEY, area.astype(np.float32))
        r.merge(y * width + x, key, faces[ti].astype(np.int32), area)

    spans = list(raster_spans(np.stack([px, py], axis=2), width, height, 0.5))
    f, y, x0, x1 = (np.concatenate(a) for a in zip(*spans, strict=True)) if spans else \
        (np.zeros(0, np.int64),) * 4
    blocks = list(span_blocks(x0, x1, _PAIR_CHUNK))
    # without a timer of its own: a bar on the timer of the stage running (the pipeline's)
    blocks = (timer.bar if timer is not None else bar)(blocks, "texels", total=len(blocks))
    for sl in blocks:
        ti, tid = expand_spans(f[sl], y[sl], x0[sl], x1[sl], width)
        evaluate(ti, tid % width, tid // width)
        hit[ti] = True
    # Triangles thinner than the tolerance that hug a texel border still get the texel
    # holding their centroid, so every rasterisable triangle inside the atlas has a sample.
    cxs = px.mean(axis=1)
    cys = py.mean(axis=1)
    lost = np.flatnonzero(~hit & (cxs >= 0) & (cxs < width) & (cys >= 0)
                          & (cys < height))
    if len(lost):
        evaluate(lost, np.floor(cxs[lost]).astype(np.int64),
                 np.floor(cys[lost]).astype(np.int64))
    return r


def _closest_on_triangle(px: np.ndarray, py: np.ndarray, cx: np.ndarray, cy: np.ndarray,
                         det: np.ndarray) -> np.ndarray:
    """Barycentrics (oriented vertex order) of the point of each triangle closest to (cx, cy).

    px, py : (3, n) float64 pixel-space vertices (det > 0); cx, cy, det : (n,) float64.
    Inside points (all barycentrics ≥ −BARY_EPS) keep their barycentrics (clipped to ≥ 0 and
    renormalised); outside points take the nearest of the three clamped edge projections,
    which is the exact closest point of the (closed) triangle. Returns (n, 3) float64.
    """
    n = len(cx)
    bary = np.empty((n, 3))
    for k in range(3):  # barycentric of the vertex opposite edge k, from the edge function
        k1 = (k + 1) % 3
        bary[:, (k + 2) % 3] = ((px[k1] - px[k]) * (cy - py[k])
                                - (py[k1] - py[k]) * (cx - px[k])) / det
    outside = np.flatnonzero((bary < -BARY_EPS).any(axis=1))
    np.clip(bary, 0.0, None, out=bary)
    bary /= np.maximum(bary.sum(axis=1), np.finfo(float).tiny)[:, None]
    if len(outside) == 0:
        return bary
    px, py, cx, cy = px[:, outside], py[:, outside], cx[outside], cy[outside]
    m = len(outside)
    edge_bary = np.zeros((m, 3))
    best_d = np.full(m, np.inf)
    for k in range(3):
        k1 = (k + 1) % 3
        ax, ay = px[k], py[k]
        dx, dy = px[k1] - ax, py[k1] - ay
        ln2 = dx * dx + dy * dy
        t = np.clip(np.divide((cx - ax) * dx + (cy - ay) * dy, ln2, out=np.zeros(m),
                              where=ln2 > 0), 0.0, 1.0)
        d = (ax + t * dx - cx) ** 2 + (ay + t * dy - cy) ** 2
        closer = np.flatnonzero(d < best_d)
        best_d[closer] = d[closer]
        edge_bary[closer] = 0.0
        edge_bary[closer, k] = 1.0 - t[closer]
        edge_bary[closer, k1] = t[closer]
    bary[outside] = edge_bary
    return bary


def face_frames(scene: Scene, faces: np.ndarray, width: int, height: int):
    """Unit geometric normals (k, 3) and texel-step footprints (k, 2, 3) of faces (k,).

    footprint[:, 0] = dP/dx, footprint[:, 1] = dP/dy for one texel step, from the face's
    UV→world Jacobian [E1 E2] · inv([t1 t2]) (zero for UV-degenerate faces).
    """
    f = scene.faces[faces]
    pv = scene.positions[f]
    e1 = pv[:, 1] - pv[:, 0]
    e2 = pv[:, 2] - pv[:, 0]
    gn = np.cross(e1, e2)
    gl = np.linalg.norm(gn, axis=1, keepdims=True)
    gn = np.divide(gn, gl, out=np.zeros_like(gn), where=gl > 0)
    t = scene.uv1[f] * np.array([width, height], dtype=np.float64)
    t1 = t[:, 1] - t[:, 0]
    t2 = t[:, 2] - t[:, 0]
    tdet = t1[:, 0] * t2[:, 1] - t1[:, 1] * t2[:, 0]
    inv = np.divide(1.0, tdet, out=np.zeros_like(tdet), where=np.abs(tdet) > 0)[:, None]
    footprint = np.empty((len(faces), 2, 3))
    footprint[:, 0] = (e1 * t2[:, 1:2] - e2 * t1[:, 1:2]) * inv
    footprint[:, 1] = (e2 * t1[:, 0:1] - e1 * t2[:, 0:1]) * inv
    return gn, footprint


def _dilation(covered: np.ndarray, padding: int) -> tuple[np.ndarray, np.ndarray]:
    """Padding texels and the covered texel each copies.

    covered : (H, W) bool. A padding texel is an uncovered texel within Chebyshev distance
    ``padding`` of a covered one; its source is the Euclidean-nearest covered texel
    (scipy's exact EDT, computed in row bands with a halo so memory stays bounded).
    Returns dilate_xy (d, 2) int32 in row-major order and src_flat (d,) int64 flat index
    ``y * W + x`` of the sources.
    """
    h, w = covered.shape
    if padding <= 0 or not covered.any():
        return np.zeros((0, 2), dtype=np.int32), np.zeros(0, dtype=np.int64)
    size = 2 * padding + 1
    near = ndimage.maximum_filter(covered.view(np.uint8), size=size, mode="constant") > 0
    pad = near & ~covered
    halo = int(np.ceil(np.sqrt(2.0) * padding)) + 1
    band = max(1, _DILATE_BAND_TEXELS // w)
    xs, srcs = [], []
    for r0 in range(0, h, band):
        r1 = min(h, r0 + band)
        py, px_ = np.nonzero(pad[r0:r1])
        if len(py) == 0:
            continue
        a0, a1 = max(0, r0 - halo), min(h, r1 + halo)
        idx = ndimage.distance_transform_edt(~covered[a0:a1], return_distances=False,
                                             return_indices=True)
        ly = py + (r0 - a0)
        sy = idx[0][ly, px_].astype(np.int64) + a0
        sx = idx[1][ly, px_].astype(np.int64)
        xs.append(np.stack([px_, py + r0], axis=1))
        srcs.append(sy * w + sx)
    if not xs:  # every texel within reach is covered: nothing to dilate
        return np.zeros((0, 2), dtype=np.int32), np.zeros(0, dtype=np.int64)
    return (np.concatenate(xs).astype(np.int32), np.concatenate(srcs))


def build_texel_space(scene: Scene, width: int, height: int | None = None, padding: int = 4,
                      timer: StageTimer | None = None) -> TexelSpace:
    """Rasterise TEXCOORD_1 into a W × H atlas and sample the surface at every covered texel.

    scene : the flattened scene (``scene.uv1`` required); width, height : atlas size
    (height defaults to width); padding : dilation radius in texels.

    Rasterisation (vectorised over (triangle, texel) pairs of each triangle's bounding box,
    in chunks of bounded memory):

    * A texel is *covered* when some triangle reaches more than ``UV_TEXEL_EPS`` texels into
      its square (separating-axis test, i.e. conservative rasterisation; touching the square's
      border does not count). Triangles outside [0, 1]² are clipped to the atlas.
    * Its sample: if the texel centre lies in a triangle (barycentrics ≥ −BARY_EPS) the
      sample is the centre, on the lowest-index such triangle (so a centre on a shared edge
      is claimed exactly once). Otherwise the sample is the point of the triangle with the
      largest overlap with the square (ties: lowest index) closest to the centre in texel
      units (exact closest point on the triangle, not clamped barycentrics).
    * coverage : exact area of each triangle ∩ texel square (closed-form clipping), summed
      over triangles and clamped to [MIN_COVERAGE = 1/64, 1]. The sum equals the union for
      non-overlapping charts (lightmap UVs must not overlap; overlaps are over-counted up to
      the clamp). A triangle touching a texel with ~0 area gets MIN_COVERAGE.
    * Faces from :func:`uv_degenerate_faces` and :func:`world_degenerate_faces` are not
      rasterised. A rasterisable triangle thinner than the tolerance along a texel border
      still gets the texel holding its centroid.

    Samples: position = Σ bary × vertex positions; geometric_normal = face normal;
    normal = normalised interpolated vertex normal (the geometric normal where it vanishes),
    negated when it points into the geometric normal's opposite hemisphere; albedo =
    :func:`prtcore.core.materials.albedo_at` (raw, through the material's TEXCOORD_n);
    footprint = (dP/dx, dP/dy) for one texel step, from the face's UV→world Jacobian.

    Dilation: uncovered texels within Chebyshev distance ``padding`` of a covered texel copy
    their Euclidean-nearest covered texel (``dilate_xy``, ``dilate_src``, row-major order).

    Order: covered texels are sorted by the 3-D Morton code (21 bits/axis) of their position
    quantised on ``scene.bounds``, ties by (y, x); every per-texel array uses that order and
    ``dilate_src`` indexes it.

    Raises AssetError when the scene has no TEXCOORD_1 or covers no texel, SpecError for a
    non-positive atlas size or a negative padding.
    """
    height = width if height is None else height
    for key, val, low in (("atlas.resolution", width, 1), ("atlas.resolution", height, 1),
                          ("atlas.padding", padding, 0)):
        if int(val) != val or val < low:
            raise SpecError(key, f"must be an integer ≥ {low}, got {val!r}")
    width, height, padding = int(width), int(height), int(padding)
    ctx = timer.stage("texels") if timer is not None else nullcontext()
    with ctx:
        return _build(scene, width, height, padding, timer)


def _build(scene: Scene, width: int, height: int, padding: int,
           timer: StageTimer | None) -> TexelSpace:
    uv = _require_uv1(scene)
    faces = np.asarray(scene.faces, dtype=np.int64)
    skip = np.zeros(len(faces), dtype=bool)
    skip[uv_degenerate_faces(scene)] = True
    skip[world_degenerate_faces(scene)] = True
    use = np.flatnonzero(~skip)
    scale = np.array([width, height], dtype=np.float64)
    t = uv[faces[use]] * scale  # (m, 3, 2) pixel space
    det = ((t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1])
           - (t[:, 1, 1] - t[:, 0, 1]) * (t[:, 2, 0] - t[:, 0, 0]))
    flip = det < 0
    t[flip] = t[flip][:, [0, 2, 1]]
    r = _rasterise(t[:, :, 0].copy(), t[:, :, 1].copy(), use, width, height, timer)

    tid = np.flatnonzero(r.tri >= 0)  # row-major (y, x)
    if len(tid) == 0:
        raise AssetError(scene.source, "attributes.TEXCOORD_1",
                         f"TEXCOORD_1 covers no texel of the {width}×{height} atlas "
                         f"({int(skip.sum())} of {len(faces)} faces degenerate)")
    n = len(tid)
    tri = r.tri[tid].astype(np.int64)
    coverage = np.clip(r.area[tid], MIN_COVERAGE, 1.0).astype(np.float32)
    del r

    # samples (barycentric, position) in row-major texel order
    local = np.full(len(faces), -1, dtype=np.int64)  # face → row of the oriented arrays
    local[use] = np.arange(len(use))
    odet = np.abs(det)
    tx = np.ascontiguousarray(t[:, :, 0].T)
    ty = np.ascontiguousarray(t[:, :, 1].T)
    del t
    bary = np.empty((n, 3))
    position = np.empty((n, 3))
    for s in _blocks(n):
        li = local[tri[s]]
        b = _closest_on_triangle(tx[:, li], ty[:, li], tid[s] % width + 0.5,
                                 tid[s] // width + 0.5, odet[li])
        sw = flip[li]
        b[sw] = b[sw][:, [0, 2, 1]]  # back to the face's own vertex order
        bary[s] = b
        position[s] = np.einsum("nk,nkj->nj", b, scene.positions[faces[tri[s]]])
    del tx, ty

    # Morton order, then everything else computed directly in that order
    order = morton_order(position, scene.bounds)
    inverse = np.empty(n, dtype=np.int64)
    inverse[order] = np.arange(n)
    dilate_xy, src_flat = _dilation(_covered_mask(tid, width, height), padding)
    dilate_src = inverse[np.searchsorted(tid, src_flat)]
    del inverse, src_flat
    tid = tid[order]
    tri = tri[order]
    coverage = coverage[order]
    bary = bary[order]
    position = position[order]
    del order
    xy = np.stack([tid % width, tid // width], axis=1).astype(np.int32)
    del tid
    # per-face frames for the faces that own texels, gathered per texel
    row = np.zeros(len(faces), dtype=np.int64)
    row[tri] = 1
    owners = np.flatnonzero(row)
    row[owners] = np.arange(len(owners))
    face_gn, face_fp = face_frames(scene, owners, width, height)
    gnormal = face_gn[row[tri]]
    footprint = face_fp[row[tri]]
    del face_gn, face_fp, row
    normal = np.empty((n, 3))
    albedo = np.empty((n, 3))
    for s in _blocks(n):
        normal[s] = shading_normals(scene, tri[s], bary[s], gnormal[s])
        albedo[s] = albedo_at(scene, tri[s], bary[s])
    return TexelSpace(
        width=width, height=height, xy=xy, position=position, normal=normal,
        geometric_normal=gnormal, albedo=albedo, triangle=tri, barycentric=bary,
        coverage=coverage, footprint=footprint, dilate_xy=dilate_xy, dilate_src=dilate_src)


def texel_centres(scene: Scene, texels: TexelSpace) -> np.ndarray:
    """World position of each texel's centre on its triangle's plane, (t, 3) float64.

    The texel sample is the centre when the centre lies on the texel's triangle, else the
    triangle point closest to it; the centre is found by stepping back from the sample
    with the footprint (the UV→world Jacobian). Without TEXCOORD_1 (hand-built texel
    spaces) the sample is taken as the centre.
    """
    pos = np.asarray(texels.position, dtype=np.float64)
    if scene.uv1 is None or texels.count == 0:
        return pos.copy()
    uv = np.einsum("nk,nkj->nj", texels.barycentric, scene.uv1[scene.faces[texels.triangle]])
    delta = texels.xy + 0.5 - uv * np.array([texels.width, texels.height], dtype=np.float64)
    return pos + delta[:, :1] * texels.footprint[:, 0] + delta[:, 1:] * texels.footprint[:, 1]


def _barycentric(tri: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Barycentrics of points p (m, d) in the planes of triangles tri (m, 3, d), d = 2
    (UV) or 3 (world); rows of degenerate triangles are NaN (rejected by every inside
    test)."""
    a = tri[:, 0]
    e1, e2, d = tri[:, 1] - a, tri[:, 2] - a, p - a
    d00 = np.einsum("ij,ij->i", e1, e1)
    d01 = np.einsum("ij,ij->i", e1, e2)
    d11 = np.einsum("ij,ij->i", e2, e2)
    d20 = np.einsum("ij,ij->i", d, e1)
    d21 = np.einsum("ij,ij->i", d, e2)
    den = d00 * d11 - d01 * d01
    inv = np.divide(1.0, den, out=np.full_like(den, np.nan), where=den > 0)
    v = (d11 * d20 - d01 * d21) * inv
    w = (d00 * d21 - d01 * d20) * inv
    return np.stack([1.0 - v - w, v, w], axis=1)


@dataclass(frozen=True)
class TexelRegions:
    """Each texel's square intersected with its own triangle, as a fan of triangles in
    barycentric coordinates of that triangle (the region path origins are drawn from).

    corners : (t, 5, 3, 3) float64 — fan triangle f of texel i has corners
    ``corners[i, f, c]`` (barycentrics on ``texels.triangle[i]``; a square clipped by a
    triangle has at most 7 corners, so 5 fan triangles); cdf : (t, 5)
    float64 cumulative area fractions (last column 1); unused fan slots have zero area.
    A texel whose square only touches its triangle (zero area) has every corner at its
    own sample (``texels.barycentric``) and is ``empty``; so is a texel of zero footprint
    (a point, e.g. a pixel's hit point in :func:`prtcore.reference.camera.reference_image`).
    empty : (t,) bool — the square only touches the triangle (zero area), or is a point
    """

    corners: np.ndarray
    cdf: np.ndarray
    empty: np.ndarray


def _clip_half_plane(poly: np.ndarray, count: np.ndarray, a: np.ndarray, c: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Sutherland–Hodgman step for t convex polygons at once: keep ``a·p + c ≥ 0``.
    poly : (t, V, 2), count : (t,) vertices in use. Returns (t, V + 1, 2) and counts."""
    t, v = poly.shape[:2]
    out = np.zeros((t, v + 1, 2))
    n_out = np.zeros(t, dtype=np.int64)
    rows = np.arange(t)

    def emit(mask: np.ndarray, pts: np.ndarray) -> None:
        r = rows[mask]
        out[r, n_out[r]] = pts[r]
        n_out[r] += 1

    for i in range(v):
        active = i < count
        j = np.where(i + 1 < count, i + 1, 0)
        p, q = poly[:, i], poly[rows, j]
        fp, fq = p @ a + c, q @ a + c
        emit(active & (fp >= 0), p)
        crosses = active & ((fp >= 0) != (fq >= 0))
        s = np.divide(fp, fp - fq, out=np.zeros_like(fp), where=crosses)
        emit(crosses, p + s[:, None] * (q - p))
    return out, n_out


def texel_regions(scene: Scene, texels: TexelSpace, index: np.ndarray | None = None
                  ) -> TexelRegions:
    """:class:`TexelRegions` of every texel (or of the texels ``index``, (t,) int64, in
    that order): its square (in TEXCOORD_1; without it, the footprint around its centre,
    :func:`texel_centres`) clipped exactly against its triangle in barycentric space,
    where uniform area on the triangle is uniform area (the map is affine)."""
    sel = slice(None) if index is None else np.asarray(index, dtype=np.int64)
    triangle = texels.triangle[sel]
    t = len(triangle)
    signs = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    if scene.uv1 is not None:  # in atlas pixels: exact, and the same at any scene scale
        tri = scene.uv1[scene.faces[triangle]].astype(np.float64) * np.array(
            [texels.width, texels.height], dtype=np.float64)
        centre = texels.xy[sel].astype(np.float64) + 0.5
        corners = [centre + sign for sign in signs]
    else:  # hand-built texel spaces: the footprint around the sample
        tri = scene.positions[scene.faces[triangle]].astype(np.float64)
        fp = np.asarray(texels.footprint[sel], dtype=np.float64)
        centres = texel_centres(scene, texels)[sel]
        corners = [centres + sx * fp[:, 0] + sy * fp[:, 1] for sx, sy in signs]
    quad = np.stack([_barycentric(tri, c) for c in corners], axis=1)[:, :, 1:]  # (b1, b2)
    # a texel of zero footprint is a point (a camera reference's pixel hit): no region
    point = ~(np.abs(np.asarray(texels.footprint[sel])).sum(axis=(1, 2)) > 0)
    ok = np.isfinite(quad).all(axis=(1, 2)) & ~point
    poly, count = np.where(ok[:, None, None], quad, 0.0), np.full(t, 4, dtype=np.int64)
    for a, c in (((1.0, 0.0), 0.0), ((0.0, 1.0), 0.0), ((-1.0, -1.0), 1.0)):
        poly, count = _clip_half_plane(poly, count, np.array(a), c)
    count[~ok] = 0
    fan = poly.shape[1] - 2
    k = np.arange(1, fan + 1)
    valid = k[None, :] < count[:, None] - 1  # fan triangle (P0, Pk, Pk+1)
    p0 = poly[:, :1]
    pk = poly[:, 1:fan + 1]
    pk1 = poly[:, 2:fan + 2]
    e1, e2 = pk - p0, pk1 - p0
    area = np.where(valid, 0.5 * np.abs(e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]),
                    0.0)
    total = area.sum(axis=1)
    own = np.asarray(texels.barycentric[sel], dtype=np.float64)[:, 1:]
    flat = ~(total > REGION_MIN_AREA)
    corners2 = np.stack([np.broadcast_to(p0, pk.shape), pk, pk1], axis=2)  # (t, F, 3, 2)
    corners2[flat] = own[flat][:, None, None, :]
    area[flat] = 0.0
    area[flat, 0] = 1.0
    cdf = np.cumsum(area, axis=1) / area.sum(axis=1, keepdims=True)
    cdf[:, -1] = 1.0
    corners = np.concatenate([1.0 - corners2.sum(axis=3, keepdims=True), corners2], axis=3)
    return TexelRegions(corners=corners, cdf=cdf, empty=flat)


def sample_texel_regions(regions: TexelRegions, tex: np.ndarray,
                         rng: np.random.Generator | None = None, u: np.ndarray | None = None
                         ) -> np.ndarray:
    """Points uniform over each texel's square ∩ its own triangle (exact: no rejection,
    no fallback). tex : (m,) int64 texel of each point; u : (m, 3) uniforms in [0, 1)
    (drawn from ``rng`` when None). Returns (m, 3) float64 barycentrics on
    ``texels.triangle[tex]``."""
    if u is None:
        u = rng.random((len(tex), 3))
    f = (regions.cdf[tex] <= u[:, :1]).sum(axis=1)
    f = np.minimum(f, regions.cdf.shape[1] - 1)
    c = regions.corners[tex, f]  # (m, 3 corners, 3)
    r = np.sqrt(u[:, 1])
    w = np.stack([1.0 - r, r * (1.0 - u[:, 2]), r * u[:, 2]], axis=1)
    bary = np.clip(np.einsum("mc,mcj->mj", w, c), 0.0, None)
    return bary / bary.sum(axis=1, keepdims=True)


def _blocks(n: int):
    """Slices of at most ``_SAMPLE_BLOCK`` covering range(n)."""
    return [slice(b, min(n, b + _SAMPLE_BLOCK)) for b in range(0, n, _SAMPLE_BLOCK)]


def _covered_mask(tid: np.ndarray, width: int, height: int) -> np.ndarray:
    mask = np.zeros(width * height, dtype=bool)
    mask[tid] = True
    return mask.reshape(height, width)


def texels_to_image(ts: TexelSpace, values: np.ndarray, dilate: bool = True) -> np.ndarray:
    """Scatter per-texel values into an atlas image.

    values : (t, c) (or (t,), read as c = 1) in ``ts`` order. Returns (H, W, c + 1) float32,
    row 0 = top (texel y = 0): channels :c hold the values, the last channel is 1 on covered
    texels and 0 elsewhere. With ``dilate``, padding texels receive their source texel's
    values (alpha stays 0); all other texels are 0.
    """
    values = np.asarray(values)
    if values.ndim == 1:
        values = values[:, None]
    if values.ndim != 2 or values.shape[0] != ts.count:
        raise ValueError(f"texels_to_image: values must be ({ts.count}, c), got {values.shape}")
    c = values.shape[1]
    img = np.zeros((ts.height, ts.width, c + 1), dtype=np.float32)
    img[ts.xy[:, 1], ts.xy[:, 0], :c] = values
    img[ts.xy[:, 1], ts.xy[:, 0], c] = 1.0
    if dilate and len(ts.dilate_xy):
        img[ts.dilate_xy[:, 1], ts.dilate_xy[:, 0], :c] = values[ts.dilate_src]
    return img


def image_to_texels(ts: TexelSpace, image: np.ndarray) -> np.ndarray:
    """Gather an atlas image (H, W, c) (or (H, W)) at the covered texels → (t, c), ts order.

    The dtype of ``image`` is kept; all its channels are returned (alpha included).
    """
    image = np.asarray(image)
    if image.shape[:2] != (ts.height, ts.width):
        raise ValueError(f"image_to_texels: image is {image.shape[:2]}, atlas is "
                         f"({ts.height}, {ts.width})")
    if image.ndim == 2:
        image = image[:, :, None]
    return image[ts.xy[:, 1], ts.xy[:, 0]]
