"""Conservative rasterisation of lightmap triangles: the one rule for which texels a
triangle touches, shared by the UV checks (:mod:`prtcore.intake.uv`) and the texel space
(:mod:`prtcore.receivers.texels`).

Texel (x, y) of a W × H atlas is the square [x, x+1] × [y, y+1] in *texel units*
(TEXCOORD_1 × (W, H), row y = 0 the image's top row). A triangle touches the texel when the
square of half-size ``half − UV_TEXEL_EPS`` about the texel's centre meets it: ``half`` =
0.5 is conservative rasterisation (the texel's square, shrunk so that touching its border
does not count), 1.0 the bilinear footprint. :func:`raster_spans` gives the touched texels
as row spans, exactly (no sampling), for any triangle, degenerate ones included.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from prtcore.core.tolerances import UV_TEXEL_EPS


def raster_spans(tri: np.ndarray, width: int, height: int, half: float,
                 chunk: int = 1 << 20):
    """Yield texel row spans (face, y, x0, x1) hit by triangles, chunk by chunk.

    A texel (x, y) is hit when the square of half-size ``half − UV_TEXEL_EPS`` around its
    centre (x + ½, y + ½) meets the triangle, i.e. when the centre lies in the triangle
    dilated by that square. Per (triangle, row) the dilated triangle's x-interval is exact:
    the x-extent of the triangle inside the band |v − cy| ≤ h (corners inside the band and
    edge crossings of its two borders), widened by h. Degenerate triangles (segments,
    points) work the same way.
    """
    tri = np.asarray(tri, dtype=np.float64).reshape(-1, 3, 2)
    h = float(half) - UV_TEXEL_EPS
    ys_all = tri[:, :, 1]
    y_first = np.ceil(ys_all.min(axis=1) - h - 0.5)
    y_last = np.floor(ys_all.max(axis=1) + h - 0.5)
    y_first = np.clip(y_first, 0, height).astype(np.int64)
    y_last = np.clip(y_last, -1, height - 1).astype(np.int64)
    rows = np.maximum(y_last - y_first + 1, 0)
    ends = np.cumsum(rows)
    total = int(ends[-1]) if len(ends) else 0
    edges = ((0, 1), (1, 2), (2, 0))
    for g0 in range(0, total, chunk):
        g = np.arange(g0, min(g0 + chunk, total), dtype=np.int64)
        f = np.searchsorted(ends, g, side="right")
        y = y_first[f] + (g - (ends[f] - rows[f]))
        ya, yb = y + 0.5 - h, y + 0.5 + h
        xs, ys = tri[f, :, 0], tri[f, :, 1]                      # (n, 3)
        inb = (ys >= ya[:, None]) & (ys <= yb[:, None])
        xmin = np.where(inb, xs, np.inf).min(axis=1)
        xmax = np.where(inb, xs, -np.inf).max(axis=1)
        for i, j in edges:
            yi, yj, xi, xj = ys[:, i], ys[:, j], xs[:, i], xs[:, j]
            dy = yj - yi
            for lev in (ya, yb):
                cross = ((yi - lev) * (yj - lev) <= 0) & (dy != 0)
                t = np.divide(lev - yi, dy, out=np.zeros_like(dy), where=cross)
                x = xi + t * (xj - xi)
                xmin = np.where(cross, np.minimum(xmin, x), xmin)
                xmax = np.where(cross, np.maximum(xmax, x), xmax)
        ok = xmin <= xmax
        x0 = np.ceil(np.where(ok, xmin, 0.0) - h - 0.5)
        x1 = np.floor(np.where(ok, xmax, -1.0) + h - 0.5)
        x0 = np.clip(x0, 0, width).astype(np.int64)
        x1 = np.clip(x1, -1, width - 1).astype(np.int64)
        ok &= x1 >= x0
        yield f[ok], y[ok], x0[ok], x1[ok]


def expand_spans(f, y, x0, x1, width: int):
    """(face, texel = y × width + x) pairs of row spans."""
    cnt = x1 - x0 + 1
    total = int(cnt.sum())
    rep = np.repeat(np.arange(len(cnt)), cnt)
    x = x0[rep] + (np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt))
    return f[rep], y[rep] * width + x


def rasterise_uv(tri: np.ndarray, width: int, height: int, half: float = 0.5):
    """Texels a triangle reaches into, vectorised, as (face, texel) pairs.

    tri : (f, 3, 2) float64 corners in texel units (u × W, v × H; row y = 0 is the image's
        top row, texel (x, y) is the square [x, x+1] × [y, y+1])
    half : half-size of the square tested around each texel centre: 0.5 is conservative
        rasterisation (the texel square itself), 1.0 the bilinear footprint (every texel a
        bilinear lookup inside the triangle may read). The square is shrunk by
        UV_TEXEL_EPS so that merely touching its border does not count.
    Returns (face (n,) int64, texel (n,) int64 = y × width + x), one row per pair.
    """
    fs, ts = [], []
    for span in raster_spans(tri, width, height, half):
        f, t = expand_spans(*span, width)
        fs.append(f)
        ts.append(t)
    if not fs:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(fs), np.concatenate(ts)


def span_blocks(x0: np.ndarray, x1: np.ndarray, block: int) -> Iterator[slice]:
    """Consecutive slices of spans (x0, x1 inclusive) holding at most ``block`` texels each
    (a single longer span is a slice of its own), to expand in bounded memory."""
    cnt = x1 - x0 + 1
    ends = np.cumsum(cnt)
    s = 0
    while s < len(cnt):
        base = ends[s - 1] if s else 0
        e = max(int(np.searchsorted(ends, base + block, side="right")), s + 1)
        yield slice(s, e)
        s = e
