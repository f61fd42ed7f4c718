"""SDF scene files (``*.sdf.json``, docs/learnt_sh.md "SDF scenes"): analytic primitives
joined by a smooth union (:mod:`prtcore.core.sdf`), read into an :class:`SdfScene`, and
turned into the mesh every other stage works on (marching cubes, the field's gradient as
vertex normals, one Lambertian material of the file's albedo).

File: ``{"primitives": [{"type": "sphere", "centre": [x, y, z], "radius": r}, ...],
"smooth": k, "albedo": [r, g, b], "resolution": n}``; parameters per type as
:mod:`prtcore.core.sdf` lists them; unknown keys and wrong shapes are refused naming the
file and the key.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

from prtcore.core.errors import AssetError
from prtcore.core.jsonfile import read_json
from prtcore.core.scene import Material, Scene, single_mesh_scene
from prtcore.core.sdf import AXES, KINDS, Primitive, SdfScene, marching_cubes

#: the suffix that makes an asset an SDF scene file
SUFFIX = ".sdf.json"
#: parameters each primitive type takes: name → "vec3" | "num" | "axis"
PARAMETERS = {
    "sphere": {"centre": "vec3", "radius": "num"},
    "ellipsoid": {"centre": "vec3", "radii": "vec3"},
    "box": {"centre": "vec3", "half_size": "vec3", "rounding": "num"},
    "capsule": {"a": "vec3", "b": "vec3", "radius": "num"},
    "torus": {"centre": "vec3", "major": "num", "minor": "num", "axis": "axis"},
}
#: optional parameters (default)
OPTIONAL = {"rounding": 0.0, "axis": "y"}
#: marching-cubes resolution limits
MAX_RESOLUTION = 512


def is_sdf_file(path: str | os.PathLike) -> bool:
    return os.fspath(path).lower().endswith(SUFFIX)


def _num(file: str, key: str, v: Any, lo: float = -math.inf, positive: bool = False) -> float:
    if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
        raise AssetError(file, key, f"expected a number, got {v!r}")
    if v < lo or (positive and v <= 0):
        raise AssetError(file, key, f"{v} is out of range ({'> 0' if positive else f'≥ {lo}'})")
    return float(v)


def _vec3(file: str, key: str, v: Any, positive: bool = False) -> tuple[float, float, float]:
    if not isinstance(v, list) or len(v) != 3:
        raise AssetError(file, key, f"expected [x, y, z], got {v!r}")
    return tuple(_num(file, f"{key}[{i}]", x, positive=positive)
                 for i, x in enumerate(v))  # type: ignore[return-value]


def parse_sdf(data: Any, file: str) -> SdfScene:
    """An :class:`SdfScene` from decoded JSON; errors name ``file`` and the key."""
    if not isinstance(data, dict):
        raise AssetError(file, "", "expected a JSON object with \"primitives\"")
    unknown = sorted(set(data) - {"primitives", "smooth", "albedo", "resolution"})
    if unknown:
        raise AssetError(file, unknown[0], "unknown key")
    prims = data.get("primitives")
    if not isinstance(prims, list) or not prims:
        raise AssetError(file, "primitives", "expected a non-empty list")
    out = []
    for i, p in enumerate(prims):
        where = f"primitives[{i}]"
        if not isinstance(p, dict) or p.get("type") not in KINDS:
            raise AssetError(file, f"{where}.type", f"expected one of {sorted(KINDS)}")
        params = PARAMETERS[p["type"]]
        bad = sorted(set(p) - set(params) - {"type"})
        if bad:
            raise AssetError(file, f"{where}.{bad[0]}", f"unknown key for a {p['type']}")
        kw: dict[str, Any] = {}
        for name, kind in params.items():
            key = f"{where}.{name}"
            if name not in p:
                if name not in OPTIONAL:
                    raise AssetError(file, key, "missing")
                kw[name] = OPTIONAL[name]
            elif kind == "vec3":
                kw[name] = _vec3(file, key, p[name], positive=name in ("radii", "half_size"))
            elif kind == "axis":
                if p[name] not in AXES:
                    raise AssetError(file, key, f"expected one of {sorted(AXES)}")
                kw[name] = p[name]
            else:
                kw[name] = _num(file, key, p[name], lo=0.0,
                                positive=name in ("radius", "major", "minor"))
        out.append(Primitive(kind=p["type"], **kw))
    albedo = _vec3(file, "albedo", data.get("albedo", [0.8, 0.8, 0.8]))
    if not all(0.0 <= a <= 1.0 for a in albedo):
        raise AssetError(file, "albedo", "each channel must lie in [0, 1]")
    res = data.get("resolution", 128)
    if not isinstance(res, int) or isinstance(res, bool) or not 8 <= res <= MAX_RESOLUTION:
        raise AssetError(file, "resolution", f"expected an integer 8–{MAX_RESOLUTION}")
    return SdfScene(tuple(out), _num(file, "smooth", data.get("smooth", 0.0), lo=0.0),
                    albedo, res)


def load_sdf(path: str | os.PathLike) -> SdfScene:
    """Read and check an SDF scene file."""
    file = os.fspath(path)
    return parse_sdf(read_json(path, lambda what: AssetError(file, "", what)), file)


def asset_sdf(path: str | os.PathLike) -> SdfScene | None:
    """The field of an asset that is an SDF scene file (``*.sdf.json``), else None: what a
    learnt_sh bake of the asset takes its training samples on (the zero level set)."""
    return load_sdf(path) if is_sdf_file(path) else None


def sdf_mesh_scene(sdf: SdfScene, file: str) -> Scene:
    """The mesh of an SDF scene as a :class:`Scene`: marching cubes, vertex normals the
    field's gradient, one material of the scene's albedo, no UVs (the bake generates the
    lightmap UVs, as for any asset without them)."""
    positions, faces, normals = marching_cubes(sdf)
    if not len(faces):
        raise AssetError(file, "primitives", "the field has no zero level set inside its "
                                             "bounds")
    material = Material(name="sdf", base_color_factor=np.array([*sdf.albedo, 1.0]))
    return single_mesh_scene(file, positions, normals, faces, material)
