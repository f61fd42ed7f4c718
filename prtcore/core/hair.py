"""Plain data for loaded hair: strands as polylines in world space (metres, +Y up).

Produced by the readers of :mod:`prtcore.io.hair` (cyHair ``.hair``, USD ``BasisCurves``) and
by the procedural assets of :mod:`prtcore.scenes.hair`; consumed by the strand receiver
(:mod:`prtcore.receivers.strands`) and the fibre geometry. Cubic curves are already
tessellated into polylines by the reader.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class Hair:
    """Strands as polylines.

    offsets : (s + 1,) int64, strand i owns points ``offsets[i]:offsets[i + 1]`` (≥ 2 each)
    points : (p, 3) float64 world positions
    thickness : (p,) float64 fibre *diameter* at each point (metres)
    color : (p, 3) float64 linear albedo at each point (per-strand or per-file colour is
        repeated over the strand's points)
    name : where the hair came from (file name or generator)
    """

    offsets: np.ndarray
    points: np.ndarray
    thickness: np.ndarray
    color: np.ndarray
    name: str = ""

    @property
    def strand_count(self) -> int:
        return len(self.offsets) - 1

    @property
    def point_count(self) -> int:
        return len(self.points)

    @cached_property
    def strand_of_segment(self) -> np.ndarray:
        """(g,) int64 strand index of each segment (segment j joins points j and j + 1 of
        the flattened arrays, for j not the last point of a strand)."""
        counts = np.diff(self.offsets) - 1
        return np.repeat(np.arange(self.strand_count, dtype=np.int64), counts)

    @cached_property
    def segment_start(self) -> np.ndarray:
        """(g,) int64 index of each segment's first point in ``points``."""
        last = np.zeros(self.point_count, dtype=bool)
        last[self.offsets[1:] - 1] = True
        return np.flatnonzero(~last).astype(np.int64)

    @cached_property
    def arc_length(self) -> np.ndarray:
        """(p,) float64 arc length from the strand's root to each point."""
        seg = np.zeros(self.point_count)
        d = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        seg[1:] = d
        seg[self.offsets[:-1]] = 0.0
        cum = np.cumsum(seg)
        return cum - np.repeat(cum[self.offsets[:-1]], np.diff(self.offsets))

    @cached_property
    def strand_length(self) -> np.ndarray:
        """(s,) float64 total arc length of each strand."""
        return self.arc_length[self.offsets[1:] - 1]

    def bounds(self) -> np.ndarray:
        """(2, 3) float64 axis-aligned bounds of the points, widened by the thickest fibre's
        radius."""
        r = float(self.thickness.max(initial=0.0)) / 2
        return np.stack([self.points.min(axis=0) - r, self.points.max(axis=0) + r])


def make_hair(strands: list[np.ndarray] | tuple[np.ndarray, ...], thickness: float | list,
              color=(0.5, 0.5, 0.5), name: str = "") -> Hair:
    """A :class:`Hair` from a list of (n_i, 3) polylines; ``thickness`` one diameter for every
    point or one array per strand; ``color`` one (3,) for the file or (s, 3) per strand."""
    counts = np.array([len(s) for s in strands], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    points = np.concatenate([np.asarray(s, dtype=np.float64) for s in strands])
    if np.isscalar(thickness):
        th = np.full(len(points), float(thickness))
    else:
        th = np.concatenate([np.broadcast_to(np.asarray(t, dtype=np.float64), (c,))
                             for t, c in zip(thickness, counts, strict=True)])
    col = np.asarray(color, dtype=np.float64)
    col = np.repeat(col, counts, axis=0) if col.ndim == 2 else np.tile(col, (len(points), 1))
    return Hair(offsets=offsets, points=points, thickness=th, color=col, name=name)
