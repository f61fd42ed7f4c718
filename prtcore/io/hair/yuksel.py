"""Cem Yuksel's binary ``.hair`` format (cyHair): reader and writer.

Layout (little-endian): a 128-byte header — ``b"HAIR"``, uint32 strand count, uint32 point
count, uint32 array flags (bit 0 segments, 1 points, 2 thickness, 3 transparency, 4 colour),
uint32 default segment count, float32 default thickness, default transparency, default
colour (3 × float32), 88 bytes of info text — then the arrays present, in that order:
uint16 segments per strand, float32 (p, 3) points, float32 (p,) thickness, float32 (p,)
transparency, float32 (p, 3) colour.

Untrusted input: the header is read alone; counts are checked against the limits and the
arrays' total size against the file's size *before* any array is read. Every refusal is a
one-line :class:`~prtcore.core.errors.AssetError` naming the file and the field
(``header.point_count``, ``points[12]``, …). Transparency is checked and dropped (the
transport treats fibres as opaque). Thickness is the fibre's diameter.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from prtcore.core.errors import AssetError, LimitExceeded, UnsupportedAsset
from prtcore.core.hair import Hair
from prtcore.core.limits import IntakeLimits
from prtcore.io.hair.checks import checked_size, refuse_bad

MAGIC = b"HAIR"
HEADER = struct.Struct("<4sIIII f f 3f 88s")
HAS_SEGMENTS, HAS_POINTS, HAS_THICKNESS, HAS_TRANSPARENCY, HAS_COLOR = (1 << i for i in range(5))
KNOWN_FLAGS = 0b11111
#: the format stores segment counts as uint16
MAX_SEGMENTS = 0xFFFF


def read_hair(path: str | Path, limits: IntakeLimits | None = None) -> Hair:
    """A ``.hair`` file → :class:`~prtcore.core.hair.Hair` (float64, world = file space)."""
    limits = limits or IntakeLimits()
    file, size = checked_size(path, limits)
    if size < HEADER.size:
        raise AssetError(file, "header", f"file is {size} bytes, shorter than the "
                         f"{HEADER.size}-byte header")
    with open(file, "rb") as f:
        head = f.read(HEADER.size)
        (magic, strands, points, flags, d_segments, d_thickness, _d_transparency,
         *d_color, _info) = HEADER.unpack(head)
        if magic != MAGIC:
            raise AssetError(file, "header.signature", f"{magic!r} is not b'HAIR'")
        if flags & ~KNOWN_FLAGS:
            raise UnsupportedAsset(file, "header.arrays",
                                   f"unknown array flags 0x{flags & ~KNOWN_FLAGS:x}")
        if not flags & HAS_POINTS:
            raise AssetError(file, "header.arrays", "the file has no points array")
        if strands == 0:
            raise AssetError(file, "header.hair_count", "the file has no strands")
        if strands > limits.max_strands:
            raise LimitExceeded(file, "header.hair_count", f"{strands} strands",
                                limit=f"max_strands={limits.max_strands}")
        if points > limits.max_hair_points:
            raise LimitExceeded(file, "header.point_count", f"{points} points",
                                limit=f"max_hair_points={limits.max_hair_points}")
        need = HEADER.size + 12 * points
        need += 2 * strands if flags & HAS_SEGMENTS else 0
        need += 4 * points * (bool(flags & HAS_THICKNESS) + bool(flags & HAS_TRANSPARENCY))
        need += 12 * points if flags & HAS_COLOR else 0
        if size != need:
            raise AssetError(file, "header", f"the header's counts and arrays need {need} "
                             f"bytes, the file has {size}")

        def array(dtype: str, count: int, field: str) -> np.ndarray:
            raw = f.read(np.dtype(dtype).itemsize * count)
            if len(raw) != np.dtype(dtype).itemsize * count:  # the file changed under us
                raise AssetError(file, field, "truncated")
            return np.frombuffer(raw, dtype=dtype)

        if flags & HAS_SEGMENTS:
            segments = array("<u2", strands, "segments").astype(np.int64)
        else:
            if not 0 < d_segments <= MAX_SEGMENTS:
                raise AssetError(file, "header.d_segments",
                                 f"{d_segments} default segments per strand")
            segments = np.full(strands, d_segments, dtype=np.int64)
        if (segments == 0).any():
            i = int(np.argmax(segments == 0))
            raise AssetError(file, f"segments[{i}]", "a strand with no segment")
        if int(segments.sum()) + strands != points:
            raise AssetError(file, "header.point_count",
                             f"{points} points, but the strands' segments need "
                             f"{int(segments.sum()) + strands}")
        pos = array("<f4", 3 * points, "points").reshape(points, 3).astype(np.float64)
        refuse_bad(file, "points", pos)
        if flags & HAS_THICKNESS:
            thick = array("<f4", points, "thickness").astype(np.float64)
            refuse_bad(file, "thickness", thick, positive=True)
        else:
            refuse_bad(file, "header.d_thickness", np.array([d_thickness]), positive=True)
            thick = np.full(points, float(d_thickness))
        if flags & HAS_TRANSPARENCY:
            refuse_bad(file, "transparency", array("<f4", points, "transparency"))
        if flags & HAS_COLOR:
            color = array("<f4", 3 * points, "color").reshape(points, 3).astype(np.float64)
            refuse_bad(file, "color", color, nonnegative=True)
        else:
            refuse_bad(file, "header.d_color", np.array([d_color]), nonnegative=True)
            color = np.tile(np.asarray(d_color, dtype=np.float64), (points, 1))
    offsets = np.concatenate([[0], np.cumsum(segments + 1)]).astype(np.int64)
    return Hair(offsets=offsets, points=pos, thickness=thick, color=color,
                name=Path(file).name)


def write_hair(path: str | Path, hair: Hair, info: str = "prtcore") -> Path:
    """Write ``hair`` as a ``.hair`` file with every array (segments, points, thickness,
    colour; no transparency). Raises ValueError for a strand of more than 65535 segments."""
    segments = np.diff(hair.offsets) - 1
    if (segments > MAX_SEGMENTS).any() or (segments < 1).any():
        raise ValueError(f"strand segment counts must lie in [1, {MAX_SEGMENTS}]")
    flags = HAS_SEGMENTS | HAS_POINTS | HAS_THICKNESS | HAS_COLOR
    d_color = hair.color.mean(axis=0) if hair.point_count else np.zeros(3)
    head = HEADER.pack(MAGIC, hair.strand_count, hair.point_count, flags,
                       int(segments.max(initial=1)), float(np.median(hair.thickness)), 0.0,
                       *map(float, d_color), info.encode("utf-8")[:87])
    path = Path(path)
    with open(path, "wb") as f:
        f.write(head)
        f.write(segments.astype("<u2").tobytes())
        f.write(hair.points.astype("<f4").tobytes())
        f.write(hair.thickness.astype("<f4").tobytes())
        f.write(hair.color.astype("<f4").tobytes())
    return path
