"""Typed access to the glTF JSON: the load context and the field readers.

Every reader takes the :class:`Ctx`, the object, the key and the glTF path of the object,
and raises an :class:`~prtcore.core.errors.AssetError` naming ``path.key`` when the value has
the wrong JSON type or range. Shared by every other module of :mod:`prtcore.io.gltf`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from prtcore.core.errors import AssetError, LimitExceeded, UnsupportedAsset
from prtcore.core.limits import IntakeLimits

REQUIRED = object()


@dataclass
class Ctx:
    """Mutable state of one load: where we are (for error messages), budgets, warnings."""

    file: str
    folder: str  # real path of the asset's folder: the only place URIs may point into
    limits: IntakeLimits
    warnings: list[str] = field(default_factory=list)
    where: str = ""  # best glTF path known, for wrapped unexpected errors
    loaded_bytes: int = 0
    doc: dict = field(default_factory=dict)  # the glTF JSON document
    items: dict[str, list[dict]] = field(default_factory=dict)  # checked top-level arrays

    def fail(self, where: str, what: str) -> AssetError:
        return AssetError(self.file, where, what)

    def unsupported(self, where: str, what: str) -> UnsupportedAsset:
        return UnsupportedAsset(self.file, where, what)

    def over(self, where: str, what: str, name: str) -> LimitExceeded:
        return LimitExceeded(self.file, where, what, f"{name}={getattr(self.limits, name)}")

    def warn(self, where: str, what: str) -> None:
        self.warnings.append(f"{where}: {what}" if where else what)

    def charge(self, nbytes: int, where: str) -> None:
        """Count ``nbytes`` against ``max_total_bytes`` *before* they are read or decoded."""
        self.loaded_bytes += nbytes
        if self.loaded_bytes > self.limits.max_total_bytes:
            raise self.over(
                where, f"buffers and images need {self.loaded_bytes} bytes in all",
                "max_total_bytes",
            )


def join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def show(value) -> str:
    text = json.dumps(value) if isinstance(value, (str, int, float, bool, type(None))) else (
        type(value).__name__
    )
    return text if len(text) <= 40 else text[:37] + "..."


def _value(ctx: Ctx, obj: dict, key: str, where: str, default):
    if key in obj:
        return obj[key], True
    if default is REQUIRED:
        raise ctx.fail(join(where, key), "is missing")
    return default, False


def as_int(v) -> int | None:
    """A JSON Schema integer as a Python int, else None: ``3`` and ``3.0`` are integers (JSON
    Schema: "a number with a zero fractional part"), ``true`` and ``3.5`` are not."""
    if isinstance(v, bool):
        return None
    if isinstance(v, int):
        return v
    if isinstance(v, float) and np.isfinite(v) and v == int(v):
        return int(v)
    return None


def index_list(ctx: Ctx, obj: dict, key: str, where: str, n: int, what: str) -> list[int]:
    """obj[key] (default []) as a list of indices below ``n`` (``what``: "a node index")."""
    out = []
    for k, v in enumerate(get_list(ctx, obj, key, where, default=[])):
        i = as_int(v)
        if i is None or not 0 <= i < n:
            raise ctx.fail(f"{join(where, key)}[{k}]", f"must be {what} below {n}, got {show(v)}")
        out.append(i)
    return out


def get_int(ctx: Ctx, obj: dict, key: str, where: str, default=REQUIRED, lo: int | None = 0,
            hi: int | None = None) -> int:
    """obj[key] as a JSON integer in [lo, hi] (``3.0`` is one, ``true`` and ``3.5`` are not)."""
    v, present = _value(ctx, obj, key, where, default)
    if not present:
        return v
    path = join(where, key)
    if as_int(v) is None:
        raise ctx.fail(path, f"must be an integer, got {show(v)}")
    v = as_int(v)
    if lo is not None and v < lo:
        raise ctx.fail(path, f"must be >= {lo}, got {v}")
    if hi is not None and v > hi:
        raise ctx.fail(path, f"must be <= {hi}, got {v}")
    return v


def get_num(ctx: Ctx, obj: dict, key: str, where: str, default=REQUIRED) -> float:
    """obj[key] as a finite JSON number."""
    v, present = _value(ctx, obj, key, where, default)
    if not present:
        return v
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(float(v)):
        raise ctx.fail(join(where, key), f"must be a finite number, got {show(v)}")
    return float(v)


def _typed(ctx: Ctx, obj: dict, key: str, where: str, default, kind: type, word: str):
    v, present = _value(ctx, obj, key, where, default)
    if present and not isinstance(v, kind):
        raise ctx.fail(join(where, key), f"must be {word}, got {show(v)}")
    return v


def get_str(ctx: Ctx, obj: dict, key: str, where: str, default=REQUIRED) -> str:
    return _typed(ctx, obj, key, where, default, str, "a string")


def get_bool(ctx: Ctx, obj: dict, key: str, where: str, default=REQUIRED) -> bool:
    return _typed(ctx, obj, key, where, default, bool, "true or false")


def get_list(ctx: Ctx, obj: dict, key: str, where: str, default=REQUIRED) -> list:
    return _typed(ctx, obj, key, where, default, list, "an array")


def get_dict(ctx: Ctx, obj: dict, key: str, where: str, default=REQUIRED) -> dict:
    return _typed(ctx, obj, key, where, default, dict, "an object")


def get_nums(ctx: Ctx, obj: dict, key: str, where: str, n: int, default) -> np.ndarray:
    """obj[key] as exactly ``n`` finite numbers → (n,) float64 (``default`` when absent)."""
    if key not in obj:
        return np.array(default, dtype=np.float64)
    v = obj[key]
    ok = isinstance(v, list) and len(v) == n and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) for x in v
    )
    out = np.array(v, dtype=np.float64) if ok else None
    if out is None or not np.isfinite(out).all():
        raise ctx.fail(join(where, key), f"must be an array of {n} finite numbers")
    return out


def get_index(ctx: Ctx, obj: dict, key: str, where: str, target: str, default=REQUIRED) -> int:
    """obj[key] as a valid index into the top-level array ``target``."""
    if key not in obj and default is not REQUIRED:
        return default
    v = get_int(ctx, obj, key, where)
    n = len(get_items(ctx, ctx.doc, target))
    if v >= n:
        raise ctx.fail(join(where, key), f"refers to {target}[{v}] but there are {n} {target}")
    return v


def get_items(ctx: Ctx, doc: dict, name: str) -> list[dict]:
    """Top-level array ``name`` (empty when absent), every element checked to be an object."""
    if name not in ctx.items:
        arr = get_list(ctx, doc, name, "", default=[])
        for i, el in enumerate(arr):
            if not isinstance(el, dict):
                raise ctx.fail(f"{name}[{i}]", f"must be an object, got {show(el)}")
        ctx.items[name] = arr
    return ctx.items[name]


def get_extension(ctx: Ctx, obj: dict, name: str, where: str) -> dict | None:
    exts = get_dict(ctx, obj, "extensions", where, default={})
    return get_dict(ctx, exts, name, join(where, "extensions"), default=None)
