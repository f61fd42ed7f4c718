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
from typing import ClassVar

import numpy as np

from prtcore.core.errors import SpecError
from prtcore.core.fibres import FibreMesh, outside_offset, segment_hits, transported_frames
from prtcore.core.geometry import orthonormal_frame
from prtcore.core.hair import Hair

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

    def texel_of(self, strand: np.ndarray, arc: np.ndarray) -> np.ndarray:
        """(n,) int64 element index of the texel holding arc length ``arc`` (metres) of
        ``strand``."""
        n = self.texels_per_strand
        length = self.hair.strand_length[strand]
        j = np.floor(np.divide(arc, length, out=np.zeros_like(arc), where=length > 0) * n)
        return strand * n + np.clip(j, 0, n - 1).astype(np.int64)

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
        phase per texel) and jittered uniformly in arc length within the interval.

        Returns ``origin`` (t, J, 3) on the tube's circumscribed cylinder
        (:func:`prtcore.core.fibres.outside_offset`: rays leaving it along a direction
        with a positive radial part miss their own fibre), ``normal`` (t, J, 3) the unit
        radial directions (the diffuse fibre's surface normals) and ``axis`` (t, J, 3)
        the points on the fibre's axis.
        """
        rng = np.random.default_rng(seed)
        t, j = self.count, per_texel
        frac = rng.random((t, j))
        arc = self.arc[:, :1] + frac * (self.arc[:, 1:] - self.arc[:, :1])
        axis, tangent, u = axis_frame(self.hair, np.repeat(self.strand, j), arc.ravel())
        v = np.cross(tangent, u)
        phase = rng.random((t, 1))
        phi = (2 * np.pi * (np.arange(j)[None, :] + phase) / j).ravel()
        normal = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
        off = interp_points(self.hair, outside_offset(self.hair)[:, None],
                             np.repeat(self.strand, j), arc.ravel())[:, 0]
        origin = axis + off[:, None] * normal
        return (origin.reshape(t, j, 3), normal.reshape(t, j, 3), axis.reshape(t, j, 3),
                phi.reshape(t, j))


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
    transported u ⟂ it (each (n, 3)) at (strand, arc). ``u``: the hair's transported u
    per point, (p, 3) float64 (``transported_frames(hair)[1]``), computed here when None —
    callers that query many batches compute it once (it is a loop over the points of the
    longest strand)."""
    if u is None:
        _, u, _ = transported_frames(hair)
    g = _global_arc(hair)
    q = g[hair.offsets[:-1]][strand] + arc
    first, last = hair.offsets[:-1][strand], hair.offsets[1:][strand] - 2
    k = np.clip(np.searchsorted(g, q, side="right") - 1, first, last)  # segment start
    seg = hair.points[k + 1] - hair.points[k]
    ln = np.linalg.norm(seg, axis=1)
    f = np.clip(np.divide(q - g[k], ln, out=np.zeros_like(q), where=ln > 0), 0.0, 1.0)
    pos = hair.points[k] + f[:, None] * seg
    tan = np.divide(seg, ln[:, None], out=np.tile([0.0, 1.0, 0.0], (len(k), 1)),
                    where=ln[:, None] > 0)
    uu = (1 - f)[:, None] * u[k] + f[:, None] * u[k + 1]
    uu -= np.einsum("ij,ij->i", uu, tan)[:, None] * tan
    n = np.linalg.norm(uu, axis=1, keepdims=True)
    uu = np.where(n > 1e-9, uu / np.maximum(n, 1e-300), orthonormal_frame(tan)[0])
    return pos, tan, uu


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


def texel_of_hit(space: StrandSpace, mesh: FibreMesh, triangle: np.ndarray,
                 barycentric: np.ndarray) -> np.ndarray:
    """(n,) int64 strand texel hit, for hits on ``mesh``'s own triangles (indices local to
    the fibre mesh) with their barycentrics."""
    hair = space.hair
    seg, t = segment_hits(mesh, triangle, barycentric)
    p0 = hair.segment_start[seg]
    arc = hair.arc_length[p0] + t * (hair.arc_length[p0 + 1] - hair.arc_length[p0])
    return space.texel_of(hair.strand_of_segment[seg], arc)
