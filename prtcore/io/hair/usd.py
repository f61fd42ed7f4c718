"""USD ``BasisCurves`` → :class:`~prtcore.core.hair.Hair`, through ``usd-core`` (``pxr``).

Every ``BasisCurves`` prim of the stage's default time is read and transformed to world
space (its local-to-world transform; the stage's ``metersPerUnit`` scales to metres;
``upAxis = Z`` is rotated to +Y up). Attributes: ``curveVertexCounts``, ``points``,
``widths`` (diameters; ``constant``, ``uniform``, ``varying`` or ``vertex`` interpolation;
absent: the spec's or 1 mm), ``primvars:displayColor`` (``constant``, ``uniform``,
``varying`` or ``vertex``; absent: the default colour). ``type = linear`` is read as is;
``type = cubic`` with ``basis`` ``bezier``, ``bspline`` or ``catmullRom`` and
``wrap = nonperiodic`` is tessellated into ``CUBIC_STEPS`` line segments per cubic segment
(``periodic`` and ``pinned`` wraps are refused).

Hardening as the ``.hair`` reader: the file size is checked before the stage is opened,
a layer that composes other files (sublayers, references, payloads) is refused before
USD would open them, counts before arrays are converted, NaN points are refused, every
refusal names the file and the prim's attribute (``/Hair/curves.points[3]``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from prtcore.core.errors import AssetError, LimitExceeded, UnsupportedAsset
from prtcore.core.hair import Hair
from prtcore.core.limits import IntakeLimits
from prtcore.io.hair.checks import checked_size, refuse_bad

#: line segments each cubic segment is tessellated into
CUBIC_STEPS = 4
DEFAULT_WIDTH = 1e-3
DEFAULT_COLOR = (0.5, 0.5, 0.5)

# Cubic bases as 4 × 4 matrices M: point(t) = [1, t, t², t³] · M · [P0 P1 P2 P3].
_BASIS = {
    "bezier": (np.array([[1, 0, 0, 0], [-3, 3, 0, 0], [3, -6, 3, 0], [-1, 3, -3, 1]], float), 3),
    "bspline": (np.array([[1, 4, 1, 0], [-3, 0, 3, 0], [3, -6, 3, 0], [-1, 3, -3, 1]],
                         float) / 6, 1),
    "catmullRom": (np.array([[0, 2, 0, 0], [-1, 0, 1, 0], [2, -5, 4, -1], [-1, 3, -3, 1]],
                            float) / 2, 1),
}


def _pxr():
    try:
        from pxr import Usd, UsdGeom
    except ImportError as e:  # pragma: no cover - usd-core is a pinned dependency
        raise UnsupportedAsset("", "", f"reading USD needs usd-core ({e})") from None
    return Usd, UsdGeom


def _cubic_segments(n: int, basis: str) -> int:
    step = _BASIS[basis][1]
    return (n - 4) // step + 1 if n >= 4 and (n - 4) % step == 0 else -1


def _tessellate(cv: np.ndarray, basis: str) -> tuple[np.ndarray, np.ndarray]:
    """Control vertices (n, c) of one nonperiodic cubic curve → (polyline (m, c), the
    (m,) parameter of each point as (segment index + t))."""
    m, step = _BASIS[basis]
    segs = _cubic_segments(len(cv), basis)
    t = np.linspace(0.0, 1.0, CUBIC_STEPS + 1)
    powers = np.stack([np.ones_like(t), t, t * t, t ** 3], axis=1) @ m  # (steps+1, 4)
    out = []
    params = []
    for s in range(segs):
        ctrl = cv[s * step:s * step + 4]
        pts = powers @ ctrl
        out.append(pts if s == 0 else pts[1:])
        params.append(s + t if s == 0 else s + t[1:])
    return np.concatenate(out), np.concatenate(params)


def read_usd_hair(path: str | Path, limits: IntakeLimits | None = None,
                  default_width: float = DEFAULT_WIDTH,
                  default_color=DEFAULT_COLOR) -> Hair:
    """Every BasisCurves prim of a ``.usd``/``.usda``/``.usdc`` file → one Hair."""
    limits = limits or IntakeLimits()
    file, _ = checked_size(path, limits)
    Usd, UsdGeom = _pxr()
    _refuse_external_layers(file)
    stage = _opened(file, Usd.Stage.Open, "stage")
    meters = float(UsdGeom.GetStageMetersPerUnit(stage))
    up = UsdGeom.GetStageUpAxis(stage)
    to_y_up = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float) if up == "Z" else np.eye(3)
    cache = UsdGeom.XformCache()
    strands_total = points_total = 0
    parts: list[tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]] = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.BasisCurves):
            continue
        where = str(prim.GetPath())
        curves = UsdGeom.BasisCurves(prim)
        counts = curves.GetCurveVertexCountsAttr().Get()
        counts = np.asarray(counts if counts is not None else [], dtype=np.int64)
        strands_total += len(counts)
        if strands_total > limits.max_strands:
            raise LimitExceeded(file, f"{where}.curveVertexCounts", f"{strands_total} strands",
                                limit=f"max_strands={limits.max_strands}")
        kind = curves.GetTypeAttr().Get() or "cubic"
        basis = curves.GetBasisAttr().Get() or "bezier"
        wrap = curves.GetWrapAttr().Get() or "nonperiodic"
        if wrap != "nonperiodic":
            raise UnsupportedAsset(file, f"{where}.wrap", f"{wrap!r} curves (only nonperiodic)")
        if kind == "cubic" and basis not in _BASIS:
            raise UnsupportedAsset(file, f"{where}.basis", f"cubic basis {basis!r}")
        if kind not in ("linear", "cubic"):
            raise AssetError(file, f"{where}.type", f"unknown curve type {kind!r}")
        if (counts < (2 if kind == "linear" else 4)).any():
            i = int(np.argmax(counts < (2 if kind == "linear" else 4)))
            raise AssetError(file, f"{where}.curveVertexCounts[{i}]",
                             f"{counts[i]} vertices are too few for a {kind} curve")
        nverts = int(counts.sum())
        # tessellated size, known before any array is converted
        grown = nverts if kind == "linear" else nverts * CUBIC_STEPS
        points_total += grown
        if points_total > limits.max_hair_points:
            raise LimitExceeded(file, f"{where}.points", f"{points_total} points after "
                                "tessellation", limit=f"max_hair_points={limits.max_hair_points}")
        raw = curves.GetPointsAttr().Get()
        pts = np.asarray(raw if raw is not None else [], dtype=np.float64).reshape(-1, 3)
        if len(pts) != nverts:
            raise AssetError(file, f"{where}.points", f"{len(pts)} points, curveVertexCounts "
                             f"sum to {nverts}")
        refuse_bad(file, f"{where}.points", pts)
        segs = (counts - 1) if kind == "linear" else np.array(
            [_cubic_segments(int(c), basis) for c in counts])
        if (segs < 1).any():
            i = int(np.argmax(segs < 1))
            raise AssetError(file, f"{where}.curveVertexCounts[{i}]",
                             f"{counts[i]} vertices do not make whole {basis} segments")
        widths = _per_vertex(file, f"{where}.widths", curves.GetWidthsAttr().Get(),
                             curves.GetWidthsInterpolation(), counts, segs, 1, default_width)
        bad = ~(np.isfinite(widths) & (widths > 0)).ravel()
        if bad.any():
            raise AssetError(file, f"{where}.widths[{int(np.argmax(bad))}]",
                             "is not a positive finite width")
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
        col_raw = pv.Get() if pv and pv.HasValue() else None
        interp = pv.GetInterpolation() if pv and pv.HasValue() else "constant"
        colors = _per_vertex(file, f"{where}.primvars:displayColor", col_raw, interp, counts,
                             segs, 3, default_color)
        bad = ~(np.isfinite(colors) & (colors >= 0)).all(axis=1)
        if bad.any():
            raise AssetError(file, f"{where}.primvars:displayColor[{int(np.argmax(bad))}]",
                             "is not a non-negative finite colour")
        world = np.asarray(cache.GetLocalToWorldTransform(prim), dtype=np.float64)
        # USD matrices act on row vectors: p_world = [p, 1] · M
        pts = (pts @ world[:3, :3] + world[3, :3]) @ to_y_up.T * meters
        width_scale = meters * float(np.cbrt(abs(np.linalg.det(world[:3, :3]))))
        strands, ths, cols = [], [], []
        start = 0
        for c in counts:
            cv = pts[start:start + c]
            w = widths[start:start + c] * width_scale
            col = colors[start:start + c]
            if kind == "cubic":
                attrs = np.concatenate([cv, w, col], axis=1)
                poly, _ = _tessellate(attrs, basis)
                cv, w, col = poly[:, :3], poly[:, 3:4], poly[:, 4:]
            strands.append(cv)
            ths.append(w[:, 0])
            cols.append(col)
            start += c
        parts.append((strands, ths, cols))
    if not parts or strands_total == 0:
        raise AssetError(file, "", "no BasisCurves prim with curves in the stage")
    strands = [s for p in parts for s in p[0]]
    counts = np.array([len(s) for s in strands], dtype=np.int64)
    return Hair(offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
                points=np.concatenate(strands), thickness=np.concatenate(
                    [t for p in parts for t in p[1]]),
                color=np.clip(np.concatenate([c for p in parts for c in p[2]]), 0.0, None),
                name=Path(file).name)


def _opened(file: str, open_fn, what: str):
    """``open_fn(file)``; a failure or None becomes an AssetError naming the file."""
    try:
        out = open_fn(file)
    except Exception as e:  # pxr raises Tf.ErrorException for unreadable layers
        raise AssetError(file, "", f"not a readable USD {what} ({str(e).splitlines()[0]})"
                         ) from None
    if out is None:
        raise AssetError(file, "", f"not a readable USD {what}")
    return out


def _refuse_external_layers(file: str) -> None:
    """A hair file must be self-contained: sublayers, references and payloads to other
    files (which USD would open from anywhere on disk) are refused before the stage is
    composed."""
    from pxr import Sdf

    layer = _opened(file, Sdf.Layer.OpenAsAnonymous, "layer")
    deps = [str(d) for d in layer.GetCompositionAssetDependencies()]
    if deps:
        raise UnsupportedAsset(file, "", f"the layer composes other files ({', '.join(deps[:3])}"
                               f"{', …' if len(deps) > 3 else ''}); hair files must be "
                               "self-contained")


def _per_vertex(file: str, where: str, raw, interpolation: str, counts: np.ndarray,
                segs: np.ndarray, channels: int, default) -> np.ndarray:
    """A primvar expanded to one value per control vertex, (n, channels) float64.

    ``varying`` values (one per segment end) are spread over the control vertices by
    linear interpolation in the vertex index (exact for linear curves)."""
    nverts = int(counts.sum())
    if raw is None or len(raw) == 0:
        return np.tile(np.asarray(default, dtype=np.float64).reshape(1, channels), (nverts, 1))
    vals = np.asarray(raw, dtype=np.float64).reshape(-1, channels)
    expect = {"constant": 1, "uniform": len(counts), "vertex": nverts,
              "varying": int((segs + 1).sum())}
    if interpolation not in expect:
        raise UnsupportedAsset(file, where, f"interpolation {interpolation!r}")
    if len(vals) != expect[interpolation]:
        raise AssetError(file, where, f"{len(vals)} values for {interpolation} interpolation, "
                         f"expected {expect[interpolation]}")
    if interpolation == "constant":
        return np.tile(vals, (nverts, 1))
    if interpolation == "uniform":
        return np.repeat(vals, counts, axis=0)
    if interpolation == "vertex":
        return vals
    out = []
    start = 0
    for c, s in zip(counts, segs, strict=True):
        v = vals[start:start + s + 1]
        x = np.linspace(0.0, s, int(c))
        out.append(np.stack([np.interp(x, np.arange(s + 1), v[:, j]) for j in
                             range(channels)], axis=1))
        start += s + 1
    return np.concatenate(out)


def write_usd_hair(path: str | Path, hair: Hair, prim: str = "/Hair") -> Path:
    """Write ``hair`` as one linear ``BasisCurves`` prim (metres, +Y up; widths and
    ``displayColor`` per vertex) to a ``.usda`` / ``.usdc`` / ``.usd`` file."""
    Usd, UsdGeom = _pxr()
    from pxr import Gf, Sdf, Vt

    path = Path(path)
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    curves = UsdGeom.BasisCurves.Define(stage, Sdf.Path(prim))
    curves.CreateTypeAttr(UsdGeom.Tokens.linear)
    curves.CreateCurveVertexCountsAttr(Vt.IntArray([int(c) for c in np.diff(hair.offsets)]))
    curves.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in hair.points]))
    curves.CreateWidthsAttr(Vt.FloatArray([float(w) for w in hair.thickness]))
    curves.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
    color = curves.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex)
    color.Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, c)) for c in hair.color]))
    stage.GetRootLayer().Save()
    return path
