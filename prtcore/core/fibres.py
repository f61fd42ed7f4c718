"""Fibres as triangles for the ray tracer (Embree through embreex traces triangles only).

Two representations, measured by ``benchmarks/hair_geometry.py`` (docs/hair.md):

* **tubes** (the default, :func:`fibre_tubes`): each polyline segment is a prism of ``sides``
  quads (2 · sides triangles) around the fibre's axis, rings oriented by a parallel-transported
  frame so the prism does not twist. The polygon's circumradius is chosen so that its
  *mean projected width* equals the fibre's diameter (``R = r · π / (k · sin(π / k))``, the
  Cauchy formula: mean width = perimeter / π), so shadow rays from every direction see on
  average as much fibre as a cylinder blocks. **Joints are mitred** (:func:`miter`): a
  ring lies across the bisector of the two segments it joins, so a circle of radius r
  there would pinch both segments to r · cos(θ/2) across the bend (θ the bend angle); the
  ring is stretched by 1 / cos(θ/2) along the bend, which makes it the section of both
  segments' cylinders. On the 10k hairball (bends of 55° on average, a stretch of 1.11)
  unmitred tubes blocked 43.1 % of 1.2 cm rays from inside the ball against 44.1 % for
  Mitsuba 3's round curves; mitred, 44.2 % (docs/hair.md).
* **ribbons** (:func:`fibre_ribbons`): one quad per segment, flat along the transported
  frame: half the triangles of a 3-sided tube, but a ray travelling in the ribbon's plane
  passes through it — camera-facing ribbons need a camera, which a bake has not.

Ray origins leaving a fibre start on the tube's circumscribed cylinder, widened at each
point by its miter's stretch (:func:`outside_offset`): from there a ray with a positive
radial component never re-enters its own convex prism.

**Each segment is cut into ``pieces`` collinear sub-prisms** (:data:`DEFAULT_PIECES`): the
intermediate rings are the vertex-wise interpolation of the segment's two end rings, so the
surface is the same ruled prism. A segment of the 10k hairball is 9 mm long and 0.1 mm thick,
and its triangles run diagonally through mostly empty bounding boxes. Cut in two, Embree
traces 1.5–1.8× more rays per CPU-second along the Morton curve (``python
benchmarks/hair_rays.py``, row "segments split"; docs/hair.md) for twice the triangles.

A tube's triangles are ordered by segment: triangle ``f`` belongs to segment
``f // (2 · sides · pieces)`` (:attr:`prtcore.core.hair.Hair.segment_start`), then by piece
from the segment's start, and in a piece its first ``sides`` triangles have two vertices on
the piece's start ring. :func:`segment_hits` maps a hit's barycentrics to (segment,
parameter along it). The vertices: every point's ring first (``sides`` each, the point's
index × sides), then the intermediate rings, segment by segment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from prtcore.core.geometry import orthonormal_frame
from prtcore.core.hair import Hair

DEFAULT_SIDES = 3
#: collinear sub-prisms per tube segment (the module docstring)
DEFAULT_PIECES = 2
#: the largest stretch of a mitred ring (:func:`miter`): 1 / cos(60°)
MITER_LIMIT = 2.0


def circumradius_scale(sides: int) -> float:
    """Circumradius / fibre radius of a ``sides``-gon whose mean width is the diameter."""
    return math.pi / (sides * math.sin(math.pi / sides))


def tangents(hair: Hair) -> np.ndarray:
    """(p, 3) float64 unit tangents at every point (central differences inside a strand,
    one-sided at its ends)."""
    p = hair.points
    nxt = np.arange(1, len(p) + 1)
    prv = np.arange(-1, len(p) - 1)
    first, last = hair.offsets[:-1], hair.offsets[1:] - 1
    nxt[last] = last
    prv[first] = first
    t = p[np.minimum(nxt, len(p) - 1)] - p[np.maximum(prv, 0)]
    n = np.linalg.norm(t, axis=1, keepdims=True)
    return np.divide(t, n, out=np.tile([0.0, 1.0, 0.0], (len(p), 1)), where=n > 0)


def miter(hair: Hair) -> tuple[np.ndarray, np.ndarray]:
    """The joints' miters: (bend (p, 3) float64 unit direction of the bend across the
    point's tangent, zero where the strand is straight or ends; stretch (p,) float64
    1 / cos(θ/2), θ the angle between the segments meeting at the point, 1 at a strand's
    ends; at most :data:`MITER_LIMIT`, reached at a bend of 120°: a sharper fold would
    grow a spike no round fibre has)."""
    p = hair.points
    n = len(p)
    inner = np.ones(n, dtype=bool)
    inner[hair.offsets[:-1]] = False
    inner[np.maximum(hair.offsets[1:] - 1, 0)] = False
    i = np.flatnonzero(inner)
    d_in = p[i] - p[i - 1]
    d_out = p[i + 1] - p[i]
    for d in (d_in, d_out):  # coincident points: no bend
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    half_cos = np.linalg.norm(d_in + d_out, axis=1) / 2
    t = tangents(hair)[i]
    b = d_out - d_in
    b -= np.einsum("ij,ij->i", b, t)[:, None] * t
    norm = np.linalg.norm(b, axis=1)
    bend = np.zeros((n, 3))
    stretch = np.ones(n)
    ok = norm > 1e-12
    bend[i[ok]] = b[ok] / norm[ok, None]
    stretch[i[ok]] = np.minimum(1 / np.maximum(half_cos[ok], 1e-3), MITER_LIMIT)
    return bend, stretch


def transported_frames(hair: Hair) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(tangent, u, v), each (p, 3) float64 unit, u and v ⟂ tangent, parallel-transported
    from each strand's root (the root's frame from :func:`orthonormal_frame`)."""
    t = tangents(hair)
    u = np.empty_like(t)
    first = hair.offsets[:-1]
    counts = np.diff(hair.offsets)
    u[first] = orthonormal_frame(t[first])[0]
    for k in range(1, int(counts.max(initial=1))):
        alive = first[counts > k]
        idx = alive + k
        prev = u[idx - 1]
        w = prev - np.einsum("ij,ij->i", prev, t[idx])[:, None] * t[idx]
        n = np.linalg.norm(w, axis=1, keepdims=True)
        fallback = orthonormal_frame(t[idx])[0]
        u[idx] = np.where(n > 1e-9, w / np.maximum(n, 1e-300), fallback)
    v = np.cross(t, u)
    return t, u, v


@dataclass(frozen=True)
class FibreMesh:
    """Triangles standing for the fibres.

    positions : (v, 3) float64; faces : (f, 3) int64;
    kind : "tubes" | "ribbons"; sides : quads around a segment (1 for ribbons);
    pieces : collinear sub-prisms per segment (1 for ribbons)
    """

    positions: np.ndarray
    faces: np.ndarray
    kind: str
    sides: int
    pieces: int = 1

    @property
    def triangles_per_segment(self) -> int:
        return 2 * self.sides * self.pieces


def fibre_tubes(hair: Hair, sides: int = DEFAULT_SIDES,
                pieces: int = DEFAULT_PIECES) -> FibreMesh:
    """Prisms of ``sides`` (≥ 3) faces around every segment, each cut into ``pieces`` (≥ 1)
    collinear sub-prisms (see the module docstring)."""
    if sides < 3:
        raise ValueError(f"fibre tubes need at least 3 sides, got {sides}")
    if pieces < 1:
        raise ValueError(f"fibre tubes need at least 1 piece per segment, got {pieces}")
    _, u, v = transported_frames(hair)
    radius = hair.thickness / 2 * circumradius_scale(sides)
    ang = 2 * np.pi * np.arange(sides) / sides
    ring = (np.cos(ang)[None, :, None] * u[:, None, :] + np.sin(ang)[None, :, None]
            * v[:, None, :])
    bend, stretch = miter(hair)  # each ring stretched along its bend (mitred joints)
    along = np.einsum("psj,pj->ps", ring, bend)
    ring += ((stretch - 1)[:, None] * along)[:, :, None] * bend[:, None, :]
    rings = hair.points[:, None, :] + radius[:, None, None] * ring  # (p, sides, 3)
    start = hair.segment_start
    g = len(start)
    frac = np.arange(1, pieces)[None, :, None, None] / pieces  # (1, P − 1, 1, 1)
    inner = (1 - frac) * rings[start][:, None] + frac * rings[start + 1][:, None]
    positions = np.concatenate([rings.reshape(-1, 3), inner.reshape(-1, 3)])
    # first vertex of ring j = 0 … P of every segment (g, P + 1)
    first = np.empty((g, pieces + 1), dtype=np.int64)
    first[:, 0] = start * sides
    first[:, pieces] = (start + 1) * sides
    first[:, 1:pieces] = len(hair.points) * sides + (
        np.arange(g)[:, None] * (pieces - 1) + np.arange(pieces - 1)[None, :]) * sides
    k = np.arange(sides)
    a = first[:, :-1, None] + k  # (g, P, sides) the piece's start ring
    b = first[:, :-1, None] + (k + 1) % sides
    a1 = first[:, 1:, None] + k  # its end ring
    b1 = first[:, 1:, None] + (k + 1) % sides
    # per piece: first the `sides` triangles with two start-ring vertices, then the others
    lower = np.stack([a, b, b1], axis=3)
    upper = np.stack([a, b1, a1], axis=3)
    faces = np.concatenate([lower, upper], axis=2).reshape(-1, 3)
    return FibreMesh(positions=positions, faces=faces, kind="tubes", sides=sides,
                     pieces=pieces)


def fibre_ribbons(hair: Hair) -> FibreMesh:
    """One quad per segment, width = the diameter, across the transported frame's u."""
    _, u, _ = transported_frames(hair)
    half = (hair.thickness / 2)[:, None] * u
    positions = np.stack([hair.points - half, hair.points + half], axis=1).reshape(-1, 3)
    s0 = hair.segment_start * 2
    faces = np.stack([np.stack([s0, s0 + 1, s0 + 3], axis=1),
                      np.stack([s0, s0 + 3, s0 + 2], axis=1)], axis=1).reshape(-1, 3)
    return FibreMesh(positions=positions, faces=faces.astype(np.int64), kind="ribbons",
                     sides=1)


def segment_hits(mesh: FibreMesh, triangle: np.ndarray, barycentric: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Hits on ``mesh``'s own triangle indices → (segment (n,) int64, parameter along the
    segment (n,) float64 in [0, 1]: the barycentric weight of the end ring's vertices)."""
    per = mesh.triangles_per_segment
    seg = triangle // per
    local = triangle % per
    if mesh.kind == "tubes":
        piece, local = np.divmod(local, 2 * mesh.sides)
        # lower triangles (a, b, b1): vertex 2 on the piece's end ring; upper (a, b1, a1):
        # 1 and 2
        lower = local < mesh.sides
        t = (piece + np.where(lower, barycentric[:, 2], barycentric[:, 1] + barycentric[:, 2])
             ) / mesh.pieces
    else:
        # (s0, s0+1, s0+3) then (s0, s0+3, s0+2): end-ring vertices are 3 and 2
        first = local == 0
        t = np.where(first, barycentric[:, 2], barycentric[:, 1] + barycentric[:, 2])
    return seg.astype(np.int64), np.clip(t, 0.0, 1.0)


def outside_offset(hair: Hair, sides: int = DEFAULT_SIDES) -> np.ndarray:
    """(p,) float64: the radius at each point from which rays leave the fibre — the tube's
    circumradius times the point's miter stretch (:func:`miter`), plus a relative margin
    of 1e-3."""
    return hair.thickness / 2 * circumradius_scale(sides) * miter(hair)[1] * (1 + 1e-3)


def cylinder_normal(tangent: np.ndarray, direction: np.ndarray, impact: np.ndarray
                    ) -> np.ndarray:
    """(n, 3) unit normals of a round fibre hit by rays along ``direction`` (n, 3) at
    impact parameter ``impact`` (n,) in [−1, 1] (signed offset from the axis in radii,
    across the ray), ``tangent`` (n, 3) the fibre's unit axis.

    The tubes are an occlusion proxy whose mean projected width is the cylinder's; where
    a ray hits them, shading uses the cylinder's normal for a uniformly random impact
    parameter — the distribution of normals a round fibre presents to that ray — not the
    flat face's, which would bias light reflected back toward the ray."""
    d = direction - np.einsum("ij,ij->i", direction, tangent)[:, None] * tangent
    ln = np.linalg.norm(d, axis=1, keepdims=True)
    d = np.where(ln > 1e-12, d / np.maximum(ln, 1e-300), orthonormal_frame(tangent)[0])
    side = np.cross(tangent, d)
    h = np.clip(impact, -1.0, 1.0)[:, None]
    return -np.sqrt(1.0 - h * h) * d + h * side


def facing(tangent: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """(n, 3) unit radial directions of fibres (tangents (n, 3)) toward ``direction``
    (n, 3): its component across the fibre, normalised (any radial one where it is
    along the fibre)."""
    w = direction - np.einsum("ij,ij->i", direction, tangent)[:, None] * tangent
    n = np.linalg.norm(w, axis=1, keepdims=True)
    fallback = np.cross(tangent, np.where(np.abs(tangent[:, :1]) < 0.9, [[1.0, 0, 0]],
                                          [[0, 1.0, 0]]))
    fallback /= np.linalg.norm(fallback, axis=1, keepdims=True)
    return np.where(n > 1e-9, w / np.maximum(n, 1e-300), fallback)


def fibre_at_hits(hair: Hair, mesh: FibreMesh, off: np.ndarray, sigma_points: np.ndarray,
                  triangle: np.ndarray, barycentric: np.ndarray) -> tuple:
    """The fibre vertices of hits on the tubes (their own triangle indices (n,) and
    barycentrics (n, 3)): the segment's unit tangent, the axis point, the outside radius
    and σ_a, interpolated along the segment. Returns (tangent, centre, radius, sigma)."""
    seg, t = segment_hits(mesh, triangle, barycentric)
    p0 = hair.segment_start[seg]
    a0, b0 = hair.points[p0], hair.points[p0 + 1]
    ax = b0 - a0
    return (ax / np.linalg.norm(ax, axis=1, keepdims=True), a0 + t[:, None] * ax,
            (1 - t) * off[p0] + t * off[p0 + 1],
            (1 - t)[:, None] * sigma_points[p0] + t[:, None] * sigma_points[p0 + 1])
