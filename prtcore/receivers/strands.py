"""Strand space: the hair receiver (paper 6.3, Fig. 11) — strand index × arc length.

Each strand is cut into ``texels_per_strand`` (n, default 10) equal arc-length intervals;
texel j of strand s stands for the interval ``[j, j + 1] · L_s / n`` of its arc length L_s,
its value is the outgoing radiance averaged over the fibre's azimuth and over that
interval (radially constant, as the paper stores it). Strands are packed row by row,
``strands_per_row`` (r) to a row:

    x = (s mod r) · n + j,   y = s div r   (y from the image's top row)

so 100k strands at n = 10 fill a 1000 × 1000 image (r = 100); the tail of the last row is
empty (coverage 0).

**Sampling without mixing strands** (the rule written to the manifest, :meth:`layout`):
for strand s at arc fraction a ∈ [0, 1] (arc length from the root / L_s) sample at pixel
coordinates

    px = (s mod r) · n + clamp(a · n, 0.5, n − 0.5),   py = (s div r) + 0.5

i.e. ``uv = (px / W, py / H)``. The vertical coordinate sits on the row's texel centres, so
bilinear filtering never reaches the rows above or below; the horizontal clamp keeps it
between the strand's first and last texel centres, so it never reaches the neighbouring
strand in the row. No padding texels are needed; mip-maps would mix strands and must not
be used (the texture has one level).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar

import numba
import numpy as np

from prtcore.core.errors import SpecError
from prtcore.core.fibres import FibreMesh, outside_offset, segment_hits, transported_frames
from prtcore.core.hair import Hair
from prtcore.receivers.texels import morton_order

DEFAULT_TEXELS_PER_STRAND = 10
#: widest strand texture built (texels); more strands make it taller, not wider
MAX_WIDTH = 4096


@dataclass(frozen=True)
class StrandSpace:
    """Strand texels, element i = strand ``strand[i]``, texel ``slot[i]`` along it
    (elements ordered by strand, then slot: i = strand · n + slot).

    hair : the strands (world space)
    texels_per_strand : n; strands_per_row : r; width = r · n, height = ⌈S / r⌉
    xy : (t, 2) int32 texel coordinates (x, y from the top row)
    strand : (t,) int64; slot : (t,) int64
    arc : (t, 2) float64 arc-length interval [a0, a1] (metres from the root)
    position : (t, 3) float64 fibre axis at the interval's middle
    tangent : (t, 3) float64 unit fibre direction there
    normal : (t, 3) float64 unit vector ⟂ tangent (the transported frame's u): fibres have
        no single normal; this one orients the footprint
    radius : (t,) float64 fibre radius at the middle
    albedo : (t, 3) float64 raw linear fibre colour at the middle
    footprint : (t, 2, 3) float64: the interval along the fibre, and the diameter across
    """

    hair: Hair
    texels_per_strand: int
    strands_per_row: int
    width: int
    height: int
    xy: np.ndarray
    strand: np.ndarray
    slot: np.ndarray
    arc: np.ndarray
    position: np.ndarray
    tangent: np.ndarray
    normal: np.ndarray
    radius: np.ndarray
    albedo: np.ndarray
    footprint: np.ndarray

    #: the receiver kind (prtcore.receivers.base.Receiver)
    kind: ClassVar[str] = "strands"

    @cached_property
    def ray_offset(self) -> np.ndarray:
        """(p,) float64 :func:`prtcore.core.fibres.outside_offset` of the hair's points,
        computed once (it mitres every joint: 57 ms for the 10k hairball, which
        :meth:`surface_points` would pay per gather batch)."""
        return outside_offset(self.hair)

    @cached_property
    def morton(self) -> np.ndarray:
        """(t,) int64: the texels in the 3-D Morton order of their axis points
        (:func:`prtcore.receivers.texels.morton_order`). Work done in this order — a
        light's shadow rays, the gather's rays, the solve's rows — keeps neighbouring
        texels together in cache (docs/hair.md, "Speed and memory")."""
        return morton_order(self.position, np.stack([self.position.min(axis=0),
                                                     self.position.max(axis=0)]))

    @property
    def count(self) -> int:
        return len(self.strand)

    def to_image(self, values: np.ndarray, dilate: bool = True) -> np.ndarray:
        """Per-texel values (t, c) → (H, W, c + 1) float32, last channel 1 on strand texels.
        Nothing to dilate (the sampling rule never reads an empty texel); ``dilate`` is
        accepted for the Receiver protocol."""
        del dilate
        values = np.asarray(values)
        if values.ndim == 1:
            values = values[:, None]
        if values.shape[0] != self.count:
            raise ValueError(f"StrandSpace.to_image: values must be ({self.count}, c), got "
                             f"{values.shape}")
        c = values.shape[1]
        img = np.zeros((self.height, self.width, c + 1), dtype=np.float32)
        img[self.xy[:, 1], self.xy[:, 0], :c] = values
        img[self.xy[:, 1], self.xy[:, 0], c] = 1.0
        return img

    def subdivided(self, pieces: int) -> StrandSpace:
        """The same hair with every texel cut into ``pieces`` (S) equal arc intervals:
        texel i's pieces are the fine space's texels S·i … S·i + S − 1 (the layout is
        strand-major), so :meth:`coarsen` averages them back. S = 1: ``self``."""
        if pieces == 1:
            return self
        return build_strand_space(self.hair, self.texels_per_strand * int(pieces))

    @staticmethod
    def coarsen(values: np.ndarray, pieces: int) -> np.ndarray:
        """Per-piece values (S·t, …) of :meth:`subdivided` → (t, …), each texel the
        mean of its S pieces (equal arc lengths), in ``values``' dtype."""
        if pieces == 1:
            return values
        n = values.shape[0] // pieces
        if n * pieces != values.shape[0]:
            raise ValueError(f"StrandSpace.coarsen: {values.shape[0]} rows are not "
                             f"{pieces} pieces per texel")
        v = values.reshape(n, pieces, *values.shape[1:])
        out = v[:, 0].copy()  # summed in place: no (t, …) float64 temporary
        for i in range(1, pieces):
            out += v[:, i]
        out /= pieces
        return out

    def texel_of(self, strand: np.ndarray, arc: np.ndarray) -> np.ndarray:
        """(n,) int64 element index of the texel holding arc length ``arc`` (metres) of
        ``strand``."""
        n = self.texels_per_strand
        length = self.hair.strand_length[strand]
        j = np.floor(np.divide(arc, length, out=np.zeros_like(arc), where=length > 0) * n)
        return strand * n + np.clip(j, 0, n - 1).astype(np.int64)

    def arc_weights(self, texel: np.ndarray, frac: np.ndarray, root: str = "extrapolate"
                    ) -> tuple[np.ndarray, np.ndarray]:
        """A point at arc fraction ``frac`` (n,) of the strand of ``texel`` (n,) as a linear
        combination of the two texel centres about it: columns (n, 2) int64, weights (n, 2)
        float64 summing to 1. Beyond the last centre the value is held (the manifest's
        sampling rule); before the root's centre it is held too (``root="clamp"``) or
        extrapolated along the first two centres (``"extrapolate"``: weights down to
        −1/2), so that a hit just above the root reads the radiance's slope there."""
        n = self.texels_per_strand
        texel = np.asarray(texel, np.int64)
        base = texel - texel % n
        if n == 1:
            return (np.stack([texel, texel], axis=1),
                    np.stack([np.ones(len(texel)), np.zeros(len(texel))], axis=1))
        x = np.asarray(frac, np.float64) * n - 0.5
        j0 = np.clip(np.floor(x), 0, n - 2)
        f = np.minimum(x - j0, 1.0)
        if root == "clamp":
            f = np.maximum(f, 0.0)
        cols = base[:, None] + np.stack([j0, j0 + 1], axis=1).astype(np.int64)
        return cols, np.stack([1.0 - f, f], axis=1)

    def layout(self) -> dict:
        """The manifest's description of the layout and of the sampling rule."""
        n, r = self.texels_per_strand, self.strands_per_row
        return {
            "kind": self.kind, "strand_count": self.hair.strand_count,
            "texels_per_strand": n, "strands_per_row": r,
            "width": self.width, "height": self.height, "row_order": "top_down",
            "texel": "strand s, texel j (0 at the root) ↔ x = (s % strands_per_row) * "
                     "texels_per_strand + j, y = s // strands_per_row; it covers arc "
                     "lengths [j, j + 1] * L_s / texels_per_strand",
            "sample": "strand s at arc fraction a in [0, 1]: px = (s % strands_per_row) * "
                      "texels_per_strand + clamp(a * texels_per_strand, 0.5, "
                      "texels_per_strand - 0.5), py = s // strands_per_row + 0.5, "
                      "uv = (px / width, py / height), bilinear, no mip-maps",
        }

    def surface_samples(self, per_texel: int, seed: int
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Stratified points on every texel's fibre surface, for direct light and gather
        origins: ``per_texel`` (J) samples, stratified in azimuth (J strata, a random
        phase per texel) and jittered uniformly in arc length within the interval
        (:meth:`surface_sample_params`, then :meth:`surface_points`).

        Returns ``origin`` (t, J, 3) on the tube's circumscribed cylinder
        (:func:`prtcore.core.fibres.outside_offset`: rays leaving it along a direction
        with a positive radial part miss their own fibre), ``normal`` (t, J, 3) the unit
        radial directions (the diffuse fibre's surface normals), ``axis`` (t, J, 3)
        the points on the fibre's axis, all float64, and ``phi`` (t, J) the azimuths.
        """
        t, j = self.count, per_texel
        arc, phi = self.surface_sample_params(per_texel, seed)
        origin, normal, axis = self.surface_points(np.repeat(np.arange(t), j), arc.ravel(),
                                                   phi.ravel())
        return (origin.reshape(t, j, 3), normal.reshape(t, j, 3), axis.reshape(t, j, 3),
                phi)

    def surface_sample_params(self, per_texel: int, seed: int
                              ) -> tuple[np.ndarray, np.ndarray]:
        """Where :meth:`surface_samples` puts its points: ``arc`` (t, J) float64 metres
        from the root (uniform in each texel's interval) and ``phi`` (t, J) float64
        azimuths (J strata, one random phase per texel), drawn from ``seed``. 16 bytes a
        sample: the fibre gather keeps these and makes the points batch by batch."""
        rng = np.random.default_rng(seed)
        t, j = self.count, per_texel
        frac = rng.random((t, j))
        arc = self.arc[:, :1] + frac * (self.arc[:, 1:] - self.arc[:, :1])
        phase = rng.random((t, 1))
        phi = 2 * np.pi * (np.arange(j)[None, :] + phase) / j
        return arc, phi

    def surface_points(self, texel: np.ndarray, arc: np.ndarray, phi: np.ndarray,
                       u: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``origin``, ``normal``, ``axis`` (n, 3) float64 of :meth:`surface_samples` at
        the samples (texel (n,) int, arc (n,) metres, phi (n,) radians); ``u`` as for
        :func:`axis_frame`."""
        strand = self.strand[texel]
        axis, tangent, uu = axis_frame(self.hair, strand, arc, u)
        off = interp_points(self.hair, self.ray_offset[:, None], strand, arc)[:, 0]
        normal, origin = tangent, uu  # overwritten row by row (no (n, 3) temporaries)
        _radial_points(axis, tangent, uu, np.cos(phi), np.sin(phi), off, normal, origin)
        return origin, normal, axis


@numba.njit(parallel=True, cache=True, nogil=True)
def _radial_points(axis, tan, u, c, s, off, normal, origin):  # pragma: no cover
    """Rows i: ``normal = c·u + s·(tan × u)`` (the unit radial direction at azimuth φ,
    c = cos φ, s = sin φ, in the frame (u, tan × u)) and ``origin = axis + off·normal``,
    each (n, 3); numpy's rounding (products, then sums; no fused multiply-add). ``normal``
    and ``origin`` may be ``tan`` and ``u`` themselves: a row is read before it is
    written."""
    for i in numba.prange(len(c)):
        t0, t1, t2 = tan[i, 0], tan[i, 1], tan[i, 2]
        u0, u1, u2 = u[i, 0], u[i, 1], u[i, 2]
        v0 = t1 * u2 - t2 * u1
        v1 = t2 * u0 - t0 * u2
        v2 = t0 * u1 - t1 * u0
        n0 = c[i] * u0 + s[i] * v0
        n1 = c[i] * u1 + s[i] * v1
        n2 = c[i] * u2 + s[i] * v2
        normal[i, 0], normal[i, 1], normal[i, 2] = n0, n1, n2
        origin[i, 0] = axis[i, 0] + off[i] * n0
        origin[i, 1] = axis[i, 1] + off[i] * n1
        origin[i, 2] = axis[i, 2] + off[i] * n2


def _global_arc(hair: Hair) -> np.ndarray:
    """(p,) increasing arc coordinate over all strands (each strand's arc length plus the
    total length of the strands before it, plus one metre per strand as a gap)."""
    start = np.concatenate([[0.0], np.cumsum(hair.strand_length + 1.0)[:-1]])
    return hair.arc_length + np.repeat(start, np.diff(hair.offsets))


def interp_points(hair: Hair, values: np.ndarray, strand: np.ndarray, arc: np.ndarray
                   ) -> np.ndarray:
    """Per-point ``values`` (p, c) interpolated linearly in arc length at (strand, arc)."""
    g = _global_arc(hair)
    start = g[hair.offsets[:-1]]
    q = start[strand] + arc
    return np.stack([np.interp(q, g, values[:, c]) for c in range(values.shape[1])], axis=1)


def axis_frame(hair: Hair, strand: np.ndarray, arc: np.ndarray,
               u: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Axis point, unit tangent (the direction of the segment holding the point) and unit
    transported u ⟂ it (each (n, 3) float64) at (strand, arc) (``strand`` (n,) int, ``arc``
    (n,) metres from the root, clamped to the strand). ``u``: the hair's transported u per
    point, (p, 3) float64 (``transported_frames(hair)[1]``), computed here when None —
    callers that query many batches compute it once (it is a loop over the points of the
    longest strand). Compiled (:func:`_axis_frame_rows`): the gather asks for millions."""
    if u is None:
        _, u, _ = transported_frames(hair)
    strand = np.ascontiguousarray(strand, dtype=np.int64).reshape(-1)
    arc = np.ascontiguousarray(arc, dtype=np.float64).reshape(-1)
    n = len(strand)
    pos, tan, uu = (np.empty((n, 3)) for _ in range(3))
    _axis_frame_rows(np.ascontiguousarray(hair.points, dtype=np.float64),
                     np.ascontiguousarray(u, dtype=np.float64), _global_arc(hair),
                     np.ascontiguousarray(hair.offsets, dtype=np.int64), strand, arc,
                     pos, tan, uu)
    return pos, tan, uu


@numba.njit(parallel=True, cache=True, nogil=True)
def _axis_frame_rows(points, u, g, offsets, strand, arc, pos, tan, uu):  # pragma: no cover
    """:func:`axis_frame`'s rows, written into pos, tan, uu (n, 3). The rule: the segment
    [k, k + 1] of the strand's points whose global arc (:func:`_global_arc`) interval holds
    the query (the last one starting at or before it; the first or last segment for a
    query off the strand's ends), f its fraction along the segment clamped to [0, 1]; the
    axis point interpolated at f, the tangent the segment's direction ((0, 1, 0) for a
    zero-length one), u interpolated at f from the points' transported u, made ⟂ the
    tangent and unit (where that fails, the first vector of
    :func:`~prtcore.core.geometry.orthonormal_frame` of the tangent)."""
    for i in numba.prange(len(strand)):
        s = strand[i]
        lo = offsets[s]
        hi = offsets[s + 1] - 2
        q = g[lo] + arc[i]
        k = lo  # the last k in [lo, hi] with g[k] <= q, else lo
        a, b = lo, hi
        while a <= b:
            m = (a + b) // 2
            if g[m] <= q:
                k = m
                a = m + 1
            else:
                b = m - 1
        s0 = points[k + 1, 0] - points[k, 0]
        s1 = points[k + 1, 1] - points[k, 1]
        s2 = points[k + 1, 2] - points[k, 2]
        ln = np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        f = (q - g[k]) / ln if ln > 0 else 0.0
        f = min(max(f, 0.0), 1.0)
        pos[i, 0] = points[k, 0] + f * s0
        pos[i, 1] = points[k, 1] + f * s1
        pos[i, 2] = points[k, 2] + f * s2
        if ln > 0:
            t0, t1, t2 = s0 / ln, s1 / ln, s2 / ln
        else:
            t0, t1, t2 = 0.0, 1.0, 0.0
        tan[i, 0], tan[i, 1], tan[i, 2] = t0, t1, t2
        w0 = (1 - f) * u[k, 0] + f * u[k + 1, 0]
        w1 = (1 - f) * u[k, 1] + f * u[k + 1, 1]
        w2 = (1 - f) * u[k, 2] + f * u[k + 1, 2]
        d = w0 * t0 + w1 * t1 + w2 * t2
        w0 -= d * t0
        w1 -= d * t1
        w2 -= d * t2
        nw = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        if nw > 1e-9:
            uu[i, 0], uu[i, 1], uu[i, 2] = w0 / nw, w1 / nw, w2 / nw
        else:  # orthonormal_frame's first tangent (Duff et al. 2017)
            sign = 1.0 if t2 >= 0.0 else -1.0
            c = -1.0 / (sign + t2)
            uu[i, 0] = 1.0 + sign * t0 * t0 * c
            uu[i, 1] = sign * t0 * t1 * c
            uu[i, 2] = -sign * t0


def azimuth_frame(hair: Hair, strand: np.ndarray, arc: np.ndarray, points: np.ndarray,
                  u: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For points near the fibre at (strand, arc): the axis point (n, 3), the unit radial
    direction to each point (n, 3) and its azimuth's (cos φ, sin φ) (n, 2) in the fibre's
    transported frame (u, v = tangent × u) — the convention of
    :meth:`StrandSpace.surface_samples`. ``u`` as for :func:`axis_frame`."""
    axis, tan, u = axis_frame(hair, strand, arc, u)
    radial = points - axis
    radial -= np.einsum("ij,ij->i", radial, tan)[:, None] * tan
    n = np.linalg.norm(radial, axis=1, keepdims=True)
    radial = np.where(n > 0, radial / np.maximum(n, 1e-300), u)
    cs = np.stack([np.einsum("ij,ij->i", radial, u),
                   np.einsum("ij,ij->i", radial, np.cross(tan, u))], axis=1)
    return axis, radial, cs


def texel_turn(space: StrandSpace) -> np.ndarray:
    """How far each texel's fibre turns along it: the angle between its unit tangents at
    the texel's two ends, (T,) float64 degrees (0 on a straight piece; the 10k curly
    head's median is 60°, the straight head's 11°)."""
    _, t0, _ = axis_frame(space.hair, space.strand, space.arc[:, 0])
    _, t1, _ = axis_frame(space.hair, space.strand, space.arc[:, 1])
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", t0, t1), -1.0, 1.0)))


def strands_per_row(strands: int, texels_per_strand: int) -> int:
    """Strands per row for a near-square texture no wider than MAX_WIDTH."""
    r = max(1, math.ceil(math.sqrt(strands / texels_per_strand)))
    return min(r, max(1, MAX_WIDTH // texels_per_strand))


def build_strand_space(hair: Hair, texels_per_strand: int = DEFAULT_TEXELS_PER_STRAND
                       ) -> StrandSpace:
    """The strand texels of ``hair`` (see the module docstring for the layout)."""
    n = int(texels_per_strand)
    if not 1 <= n <= MAX_WIDTH:
        raise SpecError("hair.texels_per_strand", f"{n} is outside [1, {MAX_WIDTH}]")
    s = hair.strand_count
    r = strands_per_row(s, n)
    strand = np.repeat(np.arange(s, dtype=np.int64), n)
    slot = np.tile(np.arange(n, dtype=np.int64), s)
    xy = np.stack([(strand % r) * n + slot, strand // r], axis=1).astype(np.int32)
    length = hair.strand_length[strand]
    arc = np.stack([slot * length / n, (slot + 1) * length / n], axis=1)
    mid = arc.mean(axis=1)
    position, tangent, u = axis_frame(hair, strand, mid)
    extra = interp_points(hair, np.concatenate([hair.thickness[:, None] / 2, hair.color],
                                                axis=1), strand, mid)
    radius, albedo = extra[:, 0], extra[:, 1:]
    footprint = np.stack([tangent * (length / n)[:, None], u * (2 * radius)[:, None]], axis=1)
    return StrandSpace(hair=hair, texels_per_strand=n, strands_per_row=r, width=r * n,
                       height=math.ceil(s / r), xy=xy, strand=strand, slot=slot, arc=arc,
                       position=position, tangent=tangent, normal=u, radius=radius,
                       albedo=albedo, footprint=footprint)


def arc_of_hit(hair: Hair, mesh: FibreMesh, triangle: np.ndarray, barycentric: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Where hits on ``mesh``'s own triangles (indices local to the fibre mesh, (n,)) with
    their barycentrics (n, 3) lie on the hair: the strand (n,) int64 and the arc length
    (n,) float64, metres from its root."""
    seg, t = segment_hits(mesh, triangle, barycentric)
    p0 = hair.segment_start[seg]
    arc = hair.arc_length[p0] + t * (hair.arc_length[p0 + 1] - hair.arc_length[p0])
    return hair.strand_of_segment[seg], arc


def texel_of_hit(space: StrandSpace, mesh: FibreMesh, triangle: np.ndarray,
                 barycentric: np.ndarray) -> np.ndarray:
    """(n,) int64 strand texel hit, for hits on ``mesh``'s own triangles (indices local to
    the fibre mesh) with their barycentrics."""
    return space.texel_of(*arc_of_hit(space.hair, mesh, triangle, barycentric))
