"""Asset intake: glTF 2.0 (``.glb``/``.gltf``) and OBJ/PLY → a flattened :class:`Scene`.

Untrusted input is the normal case. The glTF JSON is parsed here with :mod:`json` and typed
getters rather than with pygltflib, so that no library ever follows a URI or allocates a
buffer before the checks below have passed. Order of work for glTF:

1. file size (``os.stat``) → GLB container (header, chunks) → JSON → ``asset.version`` and
   ``extensionsRequired`` (Draco/meshopt refused);
2. element counts (nodes, meshes, materials, images, animations) against the limits;
3. node hierarchy (single parent, no cycles) and world transforms at rest;
4. every primitive of every mesh instance in the scene is *planned* from the JSON alone:
   accessor byte ranges must fit their bufferView and buffer (Python ints), vertex and
   triangle totals over all instances are compared with the limits;
5. only then buffers are read (URIs confined to the asset's folder, sizes checked first),
   accessors decoded, images decoded (header dimensions checked before pixels), and the
   geometry flattened to world space.

Every refusal is a :class:`~prtcore.core.errors.AssetError` (or its subclasses
:class:`~prtcore.core.errors.LimitExceeded`, :class:`~prtcore.core.errors.UnsupportedAsset`) whose
one-line message names the file, the glTF path and, where one applies, the limit. Any other
exception raised while parsing malformed data is turned into an ``AssetError`` naming the
best glTF path known at that point; ``MemoryError`` passes through unchanged.
"""

from __future__ import annotations

import base64
import binascii
import io
import json
import os
import re
import stat
import struct
import urllib.parse
import warnings
from dataclasses import dataclass, field

import numpy as np

from prtcore.core.errors import AssetError, LimitExceeded, PrtError, UnsupportedAsset
from prtcore.core.limits import IntakeLimits
from prtcore.core.materials import srgb_to_linear
from prtcore.core.scene import (
    Animation,
    AnimationChannel,
    Light,
    Material,
    Node,
    PrimitiveInstance,
    Scene,
    Skin,
    Texture,
)
from prtcore.core.tolerances import NORMAL_EPS

__all__ = ["load_asset", "texture_transform_matrix"]

GLB_MAGIC = b"glTF"
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942

#: componentType → (little-endian numpy dtype, bytes per component)
COMPONENTS = {
    5120: ("<i1", 1),
    5121: ("<u1", 1),
    5122: ("<i2", 2),
    5123: ("<u2", 2),
    5125: ("<u4", 4),
    5126: ("<f4", 4),
}
TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
MODE_NAMES = {
    0: "POINTS",
    1: "LINES",
    2: "LINE_LOOP",
    3: "LINE_STRIP",
    4: "TRIANGLES",
    5: "TRIANGLE_STRIP",
    6: "TRIANGLE_FAN",
}
WRAP_MODES = (10497, 33071, 33648)

#: Required extensions we refuse outright, with what they would need.
REFUSED_EXTENSIONS = {
    "KHR_draco_mesh_compression": "Draco-compressed geometry",
    "EXT_meshopt_compression": "meshopt-compressed buffers",
}
#: Required extensions we honour (plus every ``KHR_materials_*``, whose extra terms the
#: Lambertian transport ignores).
SUPPORTED_EXTENSIONS = frozenset(
    {"KHR_lights_punctual", "KHR_texture_transform", "KHR_mesh_quantization", "EXT_texture_webp"}
)

# Allowed component types per use (KHR_mesh_quantization widens POSITION/NORMAL/TEXCOORD).
_FLOAT = (5126,)
_POSITION_CT = (5126, 5120, 5121, 5122, 5123)
_NORMAL_CT = (5126, 5120, 5122)
_TEXCOORD_CT = (5126, 5120, 5121, 5122, 5123)
_JOINTS_CT = (5121, 5123)
_WEIGHTS_CT = (5126, 5121, 5123)
_INDEX_CT = (5121, 5123, 5125)
_ANIM_OUT_CT = (5126, 5120, 5121, 5122, 5123)

DEFAULT_GREY = 0.8
_IMAGE_FORMATS = ("PNG", "JPEG", "WEBP")
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*:")
_DATA_URI = re.compile(r"^data:([^,]*),(.*)$", re.DOTALL)
_REQUIRED = object()


# --------------------------------------------------------------------------------------
# Context and typed JSON access
# --------------------------------------------------------------------------------------


@dataclass
class _Ctx:
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


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def _show(value) -> str:
    text = json.dumps(value) if isinstance(value, (str, int, float, bool, type(None))) else (
        type(value).__name__
    )
    return text if len(text) <= 40 else text[:37] + "..."


def _value(ctx: _Ctx, obj: dict, key: str, where: str, default):
    if key in obj:
        return obj[key], True
    if default is _REQUIRED:
        raise ctx.fail(_join(where, key), "is missing")
    return default, False


def _int(ctx: _Ctx, obj: dict, key: str, where: str, default=_REQUIRED, lo: int | None = 0,
         hi: int | None = None) -> int:
    """obj[key] as a JSON integer in [lo, hi] (``bool`` and ``3.0`` are not integers)."""
    v, present = _value(ctx, obj, key, where, default)
    if not present:
        return v
    path = _join(where, key)
    if isinstance(v, bool) or not isinstance(v, int):
        raise ctx.fail(path, f"must be an integer, got {_show(v)}")
    if lo is not None and v < lo:
        raise ctx.fail(path, f"must be >= {lo}, got {v}")
    if hi is not None and v > hi:
        raise ctx.fail(path, f"must be <= {hi}, got {v}")
    return v


def _num(ctx: _Ctx, obj: dict, key: str, where: str, default=_REQUIRED) -> float:
    """obj[key] as a finite JSON number."""
    v, present = _value(ctx, obj, key, where, default)
    if not present:
        return v
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(float(v)):
        raise ctx.fail(_join(where, key), f"must be a finite number, got {_show(v)}")
    return float(v)


def _str(ctx: _Ctx, obj: dict, key: str, where: str, default=_REQUIRED) -> str:
    v, present = _value(ctx, obj, key, where, default)
    if present and not isinstance(v, str):
        raise ctx.fail(_join(where, key), f"must be a string, got {_show(v)}")
    return v


def _bool(ctx: _Ctx, obj: dict, key: str, where: str, default=_REQUIRED) -> bool:
    v, present = _value(ctx, obj, key, where, default)
    if present and not isinstance(v, bool):
        raise ctx.fail(_join(where, key), f"must be true or false, got {_show(v)}")
    return v


def _list(ctx: _Ctx, obj: dict, key: str, where: str, default=_REQUIRED) -> list:
    v, present = _value(ctx, obj, key, where, default)
    if present and not isinstance(v, list):
        raise ctx.fail(_join(where, key), f"must be an array, got {_show(v)}")
    return v


def _dict(ctx: _Ctx, obj: dict, key: str, where: str, default=_REQUIRED) -> dict:
    v, present = _value(ctx, obj, key, where, default)
    if present and not isinstance(v, dict):
        raise ctx.fail(_join(where, key), f"must be an object, got {_show(v)}")
    return v


def _nums(ctx: _Ctx, obj: dict, key: str, where: str, n: int, default) -> np.ndarray:
    """obj[key] as exactly ``n`` finite numbers → (n,) float64 (``default`` when absent)."""
    if key not in obj:
        return np.array(default, dtype=np.float64)
    v = obj[key]
    ok = isinstance(v, list) and len(v) == n and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) for x in v
    )
    out = np.array(v, dtype=np.float64) if ok else None
    if out is None or not np.isfinite(out).all():
        raise ctx.fail(_join(where, key), f"must be an array of {n} finite numbers")
    return out


def _index(ctx: _Ctx, obj: dict, key: str, where: str, target: str, default=_REQUIRED) -> int:
    """obj[key] as a valid index into the top-level array ``target``."""
    if key not in obj and default is not _REQUIRED:
        return default
    v = _int(ctx, obj, key, where)
    n = len(_items(ctx, ctx.doc, target))
    if v >= n:
        raise ctx.fail(_join(where, key), f"refers to {target}[{v}] but there are {n} {target}")
    return v


def _items(ctx: _Ctx, doc: dict, name: str) -> list[dict]:
    """Top-level array ``name`` (empty when absent), every element checked to be an object."""
    if name not in ctx.items:
        arr = _list(ctx, doc, name, "", default=[])
        for i, el in enumerate(arr):
            if not isinstance(el, dict):
                raise ctx.fail(f"{name}[{i}]", f"must be an object, got {_show(el)}")
        ctx.items[name] = arr
    return ctx.items[name]


def _extension(ctx: _Ctx, obj: dict, name: str, where: str) -> dict | None:
    exts = _dict(ctx, obj, "extensions", where, default={})
    return _dict(ctx, exts, name, _join(where, "extensions"), default=None)


# --------------------------------------------------------------------------------------
# Container: GLB chunks and JSON
# --------------------------------------------------------------------------------------


def read_glb(ctx: _Ctx, data: bytes) -> tuple[dict, memoryview | None]:
    """Split a GLB file into its JSON document and BIN chunk (``None`` when absent).

    Strict container checks: magic ``glTF``, version 2, declared length not beyond the
    file, every chunk inside the declared length, JSON chunk first, BIN (if any) second.
    """
    if len(data) < 12:
        raise ctx.fail("", f"truncated GLB: {len(data)} bytes, the header alone needs 12")
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != GLB_MAGIC:
        raise ctx.fail("", f"not a GLB file (magic {magic!r}, expected b'glTF')")
    if version != 2:
        raise ctx.unsupported("", f"GLB container version {version}; only version 2 is read")
    if length > len(data):
        raise ctx.fail("", f"truncated GLB: header declares {length} bytes, file has {len(data)}")
    if length < len(data):
        ctx.warn("", f"{len(data) - length} bytes after the GLB's declared length ignored")
    view = memoryview(data)
    pos, k = 12, 0
    json_chunk = bin_chunk = None
    while pos < length:
        where = f"GLB chunk {k}"
        if pos + 8 > length:
            raise ctx.fail(where, f"truncated GLB: chunk header at byte {pos} is cut off")
        clen, ctype = struct.unpack_from("<II", data, pos)
        start, end = pos + 8, pos + 8 + clen
        if end > length:
            raise ctx.fail(
                where, f"truncated GLB: chunk of {clen} bytes at byte {start} runs past the "
                f"end ({length} bytes)",
            )
        if k == 0:
            if ctype != CHUNK_JSON:
                raise ctx.fail(where, f"first chunk must be JSON, got type 0x{ctype:08x}")
            json_chunk = view[start:end]
        elif ctype == CHUNK_BIN:
            if k != 1:
                raise ctx.fail(where, "the BIN chunk must be the second chunk")
            bin_chunk = view[start:end]
        elif ctype == CHUNK_JSON:
            raise ctx.fail(where, "a second JSON chunk")
        pos, k = end, k + 1  # unknown chunk types are skipped, as the spec says
    if json_chunk is None:
        raise ctx.fail("", "GLB has no JSON chunk")
    return parse_json(ctx, bytes(json_chunk)), bin_chunk


def _reject_constant(name: str):
    raise ValueError(f"{name} is not valid JSON")


def parse_json(ctx: _Ctx, raw: bytes) -> dict:
    """UTF-8 JSON text → the glTF document (a dict); NaN/Infinity literals rejected."""
    try:
        text = raw.rstrip(b"\x00 \t\r\n").decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise ctx.fail("", f"invalid JSON: not UTF-8 ({e.reason} at byte {e.start})") from None
    try:
        doc = json.loads(text, parse_constant=_reject_constant)
    except (ValueError, RecursionError) as e:
        raise ctx.fail("", f"invalid JSON: {str(e)[:120]}") from None
    if not isinstance(doc, dict):
        raise ctx.fail("", f"the glTF JSON must be an object, got {type(doc).__name__}")
    return doc


def check_header(ctx: _Ctx, doc: dict) -> None:
    """``asset.version`` 2.x and every ``extensionsRequired`` entry supported."""
    asset = _dict(ctx, doc, "asset", "")
    version = _str(ctx, asset, "version", "asset")
    m = re.fullmatch(r"(\d+)\.(\d+)", version)
    if m is None:
        raise ctx.fail("asset.version", f"malformed version {_show(version)}")
    if m.group(1) != "2":
        raise ctx.unsupported("asset.version", f"glTF {version}; only glTF 2.x is supported")
    min_version = _str(ctx, asset, "minVersion", "asset", default="2.0")
    if min_version not in ("2.0",):
        raise ctx.unsupported("asset.minVersion", f"asset requires glTF {_show(min_version)}")
    for i, name in enumerate(_list(ctx, doc, "extensionsRequired", "", default=[])):
        where = f"extensionsRequired[{i}]"
        if not isinstance(name, str):
            raise ctx.fail(where, f"must be a string, got {_show(name)}")
        if name in REFUSED_EXTENSIONS:
            raise ctx.unsupported(
                where, f"{name} is required but {REFUSED_EXTENSIONS[name]} is refused (not "
                "decoded); export the asset without mesh compression",
            )
        if name not in SUPPORTED_EXTENSIONS and not name.startswith("KHR_materials_"):
            raise ctx.unsupported(where, f"required extension {name} is not supported")


def check_counts(ctx: _Ctx, doc: dict) -> None:
    """Top-level element counts against the intake limits."""
    for name, limit in (
        ("nodes", "max_nodes"),
        ("meshes", "max_meshes"),
        ("materials", "max_materials"),
        ("images", "max_textures"),
        ("animations", "max_animations"),
    ):
        n = len(_items(ctx, doc, name))
        if n > getattr(ctx.limits, limit):
            raise ctx.over(name, f"{n} {name}", limit)


# --------------------------------------------------------------------------------------
# URIs and external files
# --------------------------------------------------------------------------------------


def resolve_uri(ctx: _Ctx, uri: str, where: str) -> str:
    """Real path of a relative, non-data URI, guaranteed to lie inside the asset's folder.

    Refused: any scheme (``http:``, ``file:``, ``C:`` …), absolute paths, ``..``
    components (checked after percent-decoding, as glTF URIs are percent-encoded), NUL
    bytes, and paths whose real location (symlinks resolved) leaves the folder.
    """
    if _SCHEME.match(uri):
        scheme = uri.split(":", 1)[0]
        raise ctx.fail(where, f"URI scheme {scheme!r} is not allowed (only relative paths "
                              "inside the asset's folder and data: URIs)")
    try:
        decoded = urllib.parse.unquote(uri, errors="strict")
    except UnicodeDecodeError:
        raise ctx.fail(where, "URI percent-encoding is not valid UTF-8") from None
    if "\x00" in decoded:
        raise ctx.fail(where, "URI contains a NUL byte")
    if _SCHEME.match(decoded):
        raise ctx.fail(where, "URI has a scheme or drive letter after percent-decoding")
    if decoded.startswith(("/", "\\")) or os.path.isabs(decoded):
        raise ctx.fail(where, f"absolute path {_show(uri)} is not allowed")
    parts = re.split(r"[/\\]", decoded)
    if ".." in parts:
        raise ctx.fail(where, f"'..' in {_show(uri)}: URIs may not leave the asset's folder")
    parts = [p for p in parts if p not in ("", ".")]
    if not parts:
        raise ctx.fail(where, "URI names no file")
    real = os.path.realpath(os.path.join(ctx.folder, *parts))
    if os.path.commonpath([real, ctx.folder]) != ctx.folder:
        raise ctx.fail(where, f"{_show(uri)} resolves outside the asset's folder (symlink)")
    return real


def read_local_file(ctx: _Ctx, real: str, where: str, limit: str, want: int | None = None
                    ) -> bytes:
    """Bytes of a file already confined by :func:`resolve_uri`.

    Size from ``os.stat`` is checked against ``limit`` (an IntakeLimits field name) and the
    total budget before anything is read; ``want`` bytes (default: all) are read.
    """
    try:
        st = os.stat(real)
    except OSError as e:
        raise ctx.fail(where, f"cannot access {os.path.basename(real)!r}: {e.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        raise ctx.fail(where, f"{os.path.basename(real)!r} is not a regular file")
    n = st.st_size if want is None else want
    if want is not None and st.st_size < want:
        raise ctx.fail(where, f"file has {st.st_size} bytes but byteLength declares {want}")
    if n > getattr(ctx.limits, limit):
        raise ctx.over(where, f"file of {n} bytes", limit)
    ctx.charge(n, where)
    fd = os.open(real, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_BINARY", 0))
    with os.fdopen(fd, "rb") as f:
        data = f.read(n)
    if len(data) != n:
        raise ctx.fail(where, f"file shrank while reading ({len(data)} of {n} bytes)")
    return data


def data_uri_size(ctx: _Ctx, uri: str, where: str) -> tuple[int, str]:
    """Decoded size of a base64 ``data:`` URI computed from its length, and its payload."""
    m = _DATA_URI.match(uri)
    if m is None:
        raise ctx.fail(where, "malformed data: URI (no comma)")
    params = [p.strip().lower() for p in m.group(1).split(";")[1:]]
    if "base64" not in params:
        raise ctx.unsupported(where, "only base64 data: URIs are supported")
    payload = m.group(2)
    if len(payload) % 4:
        raise ctx.fail(where, "malformed base64 in data: URI (length not a multiple of 4)")
    pad = len(payload) - len(payload.rstrip("="))
    if pad > 2:
        raise ctx.fail(where, "malformed base64 in data: URI (too much padding)")
    return len(payload) // 4 * 3 - pad, payload


def decode_data_uri(ctx: _Ctx, uri: str, where: str, limit: str) -> bytes:
    """Decode a base64 ``data:`` URI after checking its decoded size against
    ``max_data_uri_bytes`` and ``limit`` (and the total budget)."""
    size, payload = data_uri_size(ctx, uri, where)
    if size > ctx.limits.max_data_uri_bytes:
        raise ctx.over(where, f"data: URI decodes to {size} bytes", "max_data_uri_bytes")
    if size > getattr(ctx.limits, limit):
        raise ctx.over(where, f"data: URI decodes to {size} bytes", limit)
    ctx.charge(size, where)
    try:
        return base64.b64decode(payload, validate=True)
    except (binascii.Error, ValueError):
        raise ctx.fail(where, "malformed base64 in data: URI") from None


def _uri_bytes(ctx: _Ctx, uri: str, where: str, limit: str, want: int | None = None) -> bytes:
    if uri.startswith("data:"):
        return decode_data_uri(ctx, uri, where, limit)
    return read_local_file(ctx, resolve_uri(ctx, uri, where), where, limit, want)


# --------------------------------------------------------------------------------------
# Buffers and accessors
# --------------------------------------------------------------------------------------


def buffer_lengths(ctx: _Ctx, doc: dict) -> list[int]:
    """Declared ``byteLength`` of every buffer, checked against the limits (no reading)."""
    lengths = []
    for i, b in enumerate(_items(ctx, doc, "buffers")):
        n = _int(ctx, b, "byteLength", f"buffers[{i}]", lo=1)
        if n > ctx.limits.max_buffer_bytes:
            raise ctx.over(f"buffers[{i}].byteLength", f"{n} bytes", "max_buffer_bytes")
        lengths.append(n)
    if sum(lengths) > ctx.limits.max_total_bytes:
        raise ctx.over("buffers", f"{sum(lengths)} bytes declared", "max_total_bytes")
    return lengths


def load_buffers(ctx: _Ctx, doc: dict, bin_chunk: memoryview | None) -> list:
    """Every buffer's bytes, exactly ``byteLength`` long (bytes or memoryview)."""
    out = []
    for i, (b, n) in enumerate(zip(_items(ctx, doc, "buffers"), buffer_lengths(ctx, doc),
                                   strict=True)):
        where = f"buffers[{i}]"
        ctx.where = where
        uri = _str(ctx, b, "uri", where, default=None)
        if uri is None:
            if bin_chunk is None:
                if _extension(ctx, b, "EXT_meshopt_compression", where) is not None:
                    raise ctx.unsupported(where, "meshopt fallback buffer without data: "
                                                 "meshopt-compressed buffers are refused")
                raise ctx.fail(where, "has no uri and the file has no GLB BIN chunk")
            if i != 0:
                raise ctx.fail(where, "only buffers[0] may refer to the GLB BIN chunk")
            if len(bin_chunk) < n:
                raise ctx.fail(f"{where}.byteLength",
                               f"declares {n} bytes but the GLB BIN chunk has {len(bin_chunk)}")
            ctx.charge(n, where)
            out.append(bin_chunk[:n])
            continue
        data = _uri_bytes(ctx, uri, f"{where}.uri", "max_buffer_bytes", want=n)
        if len(data) < n:
            raise ctx.fail(f"{where}.byteLength", f"declares {n} bytes but the data has "
                                                  f"{len(data)}")
        out.append(memoryview(data)[:n])
    return out


@dataclass(frozen=True)
class SparseLayout:
    """Validated byte placement of an accessor's sparse substitution."""

    count: int
    index_component: int
    index_buffer: int
    index_offset: int
    value_buffer: int
    value_offset: int


@dataclass(frozen=True)
class AccessorLayout:
    """Validated byte placement of one accessor (offsets absolute within ``buffer``).

    ``buffer`` is -1 for an accessor without bufferView (all zeros, maybe sparse).
    """

    index: int
    where: str
    component_type: int
    type: str
    count: int
    normalized: bool
    buffer: int
    byte_offset: int
    byte_stride: int
    sparse: SparseLayout | None = None

    @property
    def ncomp(self) -> int:
        return TYPE_SIZES[self.type]


def buffer_view(ctx: _Ctx, doc: dict, index: int) -> tuple[int, int, int, int]:
    """(buffer, byteOffset, byteLength, byteStride or 0) of a bufferView, range-checked
    against the buffer's declared byteLength."""
    where = f"bufferViews[{index}]"
    bv = _items(ctx, doc, "bufferViews")[index]
    b = _index(ctx, bv, "buffer", where, "buffers")
    off = _int(ctx, bv, "byteOffset", where, default=0)
    length = _int(ctx, bv, "byteLength", where, lo=1)
    stride = _int(ctx, bv, "byteStride", where, default=0)
    if stride and not (4 <= stride <= 252 and stride % 4 == 0):
        raise ctx.fail(f"{where}.byteStride", f"must be a multiple of 4 in [4, 252], got {stride}")
    blen = _int(ctx, _items(ctx, doc, "buffers")[b], "byteLength", f"buffers[{b}]", lo=1)
    if off + length > blen:
        raise ctx.fail(where, f"byteOffset {off} + byteLength {length} runs past buffers[{b}] "
                              f"({blen} bytes)")
    return b, off, length, stride


def _sparse_layout(ctx: _Ctx, doc: dict, acc: dict, here: str, where: str, count: int,
                   elem: int) -> SparseLayout | None:
    s = _dict(ctx, acc, "sparse", here, default=None)
    if s is None:
        return None
    sw = f"{here}.sparse"
    n = _int(ctx, s, "count", sw, lo=1)
    if n > count:
        raise ctx.fail(f"{sw}.count", f"{n} substitutions for an accessor of {count} elements")
    ind = _dict(ctx, s, "indices", sw)
    iw = f"{sw}.indices"
    ict = _int(ctx, ind, "componentType", iw)
    if ict not in _INDEX_CT:
        raise ctx.fail(f"{iw}.componentType", f"must be 5121, 5123 or 5125, got {ict}")
    ib, ioff, ilen, _ = buffer_view(ctx, doc, _index(ctx, ind, "bufferView", iw, "bufferViews"))
    io_ = _int(ctx, ind, "byteOffset", iw, default=0)
    if io_ + n * COMPONENTS[ict][1] > ilen:
        raise ctx.fail(f"{where} {iw}", f"{n} sparse indices do not fit their bufferView")
    val = _dict(ctx, s, "values", sw)
    vw = f"{sw}.values"
    vb, voff, vlen, _ = buffer_view(ctx, doc, _index(ctx, val, "bufferView", vw, "bufferViews"))
    vo = _int(ctx, val, "byteOffset", vw, default=0)
    if vo + n * elem > vlen:
        raise ctx.fail(f"{where} {vw}", f"{n} sparse values do not fit their bufferView")
    return SparseLayout(n, ict, ib, ioff + io_, vb, voff + vo)


def accessor_layout(ctx: _Ctx, doc: dict, index: int, use: str, types: tuple[str, ...],
                    components: tuple[int, ...]) -> AccessorLayout:
    """Validate accessor ``index`` for ``use`` (a glTF path) without touching any buffer.

    Checks type/componentType for the use, ``count`` against ``max_accessor_elements`` and
    that ``byteOffset + stride·(count−1) + elementSize`` fits inside its bufferView, which
    itself must fit inside its buffer — all with Python ints, before numpy sees a byte.
    """
    here = f"accessors[{index}]"
    where = f"{use} ({here})" if use else here
    ctx.where = where
    acc = _items(ctx, doc, "accessors")[index]
    ctype = _int(ctx, acc, "componentType", here)
    if ctype not in COMPONENTS:
        raise ctx.fail(f"{here}.componentType", f"unknown componentType {ctype}")
    atype = _str(ctx, acc, "type", here)
    if atype not in TYPE_SIZES:
        raise ctx.fail(f"{here}.type", f"unknown type {_show(atype)}")
    if atype not in types:
        raise ctx.fail(where, f"type {atype} where {' or '.join(types)} is expected")
    if ctype not in components:
        raise ctx.fail(where, f"componentType {ctype} is not allowed here")
    count = _int(ctx, acc, "count", here, lo=1)
    if count > ctx.limits.max_accessor_elements:
        raise ctx.over(where, f"count {count}", "max_accessor_elements")
    normalized = _bool(ctx, acc, "normalized", here, default=False)
    csize = COMPONENTS[ctype][1]
    if atype.startswith("MAT") and csize < 4:
        raise ctx.unsupported(where, f"{atype} with {csize}-byte components is not supported")
    elem = TYPE_SIZES[atype] * csize
    acc_off = _int(ctx, acc, "byteOffset", here, default=0)
    bv = _index(ctx, acc, "bufferView", here, "bufferViews", default=-1)
    if bv < 0:
        buffer, offset, stride = -1, 0, elem
    else:
        buffer, bv_off, bv_len, bv_stride = buffer_view(ctx, doc, bv)
        stride = bv_stride or elem
        if stride < elem:
            raise ctx.fail(where, f"bufferViews[{bv}].byteStride {stride} is smaller than one "
                                  f"element ({elem} bytes)")
        need = acc_off + stride * (count - 1) + elem
        if need > bv_len:
            raise ctx.fail(where, f"count {count} x stride {stride} from byteOffset {acc_off} "
                                  f"needs {need} bytes but bufferViews[{bv}] has {bv_len}")
        offset = bv_off + acc_off
    sparse = _sparse_layout(ctx, doc, acc, here, where, count, elem)
    return AccessorLayout(index, where, ctype, atype, count, normalized, buffer, offset, stride,
                          sparse)


def read_accessor(ctx: _Ctx, lay: AccessorLayout, buffers: list) -> np.ndarray:
    """Decode a validated accessor → (count, ncomp) array in its own (native-order) dtype."""
    ctx.where = lay.where
    dt = np.dtype(COMPONENTS[lay.component_type][0])
    native = dt.newbyteorder("=")
    shape = (lay.count, lay.ncomp)
    if lay.buffer < 0:
        out = np.zeros(shape, dtype=native)
    else:
        view = np.ndarray(shape, dtype=dt, buffer=buffers[lay.buffer], offset=lay.byte_offset,
                          strides=(lay.byte_stride, dt.itemsize))
        out = view.astype(native)  # copy, detached from the file bytes
    s = lay.sparse
    if s is not None:
        idt = np.dtype(COMPONENTS[s.index_component][0])
        idx = np.ndarray((s.count,), dtype=idt, buffer=buffers[s.index_buffer],
                         offset=s.index_offset).astype(np.int64)
        if idx.max() >= lay.count:
            raise ctx.fail(f"{lay.where} sparse.indices",
                           f"index {int(idx.max())} out of range for {lay.count} elements")
        vals = np.ndarray((s.count, lay.ncomp), dtype=dt, buffer=buffers[s.value_buffer],
                          offset=s.value_offset)
        out[idx] = vals
    return out


def to_float(raw: np.ndarray, lay: AccessorLayout) -> np.ndarray:
    """Accessor values → float64, applying glTF's normalized-integer decoding.

    unsigned: c / (2^b − 1); signed: max(c / (2^(b−1) − 1), −1).
    """
    out = raw.astype(np.float64)
    if lay.normalized and lay.component_type != 5126:
        info = np.iinfo(raw.dtype)
        out /= float(info.max)
        if info.min < 0:
            np.maximum(out, -1.0, out=out)
    return out


# --------------------------------------------------------------------------------------
# Nodes: hierarchy and world transforms
# --------------------------------------------------------------------------------------


def trs_matrix(translation: np.ndarray, rotation: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Local matrix T·R·S. rotation : (4,) unit quaternion xyzw. Returns (4, 4) float64."""
    from scipy.spatial.transform import Rotation

    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(rotation).as_matrix() * scale[None, :]
    m[:3, 3] = translation
    return m


def decompose_matrix(m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(4, 4) affine → translation (3,), rotation xyzw (4,), scale (3,) float64.

    Exact for T·R·S matrices; with shear the rotation is the nearest one (for the record
    only: ``Node.matrix`` stays authoritative).
    """
    from scipy.spatial.transform import Rotation

    lin = m[:3, :3]
    scale = np.linalg.norm(lin, axis=0)
    if np.linalg.det(lin) < 0:
        scale[0] = -scale[0]
    if np.all(np.abs(scale) > 0):
        rot = Rotation.from_matrix(lin / scale[None, :]).as_quat()
    else:
        rot = np.array([0.0, 0.0, 0.0, 1.0])
    return m[:3, 3].copy(), rot, scale


def _local_transform(ctx: _Ctx, nd: dict, where: str):
    if "matrix" in nd:
        matrix = _nums(ctx, nd, "matrix", where, 16, None).reshape(4, 4).T  # column-major
        if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0]):
            raise ctx.fail(f"{where}.matrix", "is not an affine transform (last row != 0 0 0 1)")
        t, r, s = decompose_matrix(matrix)
        return t, r, s, matrix
    t = _nums(ctx, nd, "translation", where, 3, [0.0, 0.0, 0.0])
    r = _nums(ctx, nd, "rotation", where, 4, [0.0, 0.0, 0.0, 1.0])
    s = _nums(ctx, nd, "scale", where, 3, [1.0, 1.0, 1.0])
    norm = float(np.linalg.norm(r))
    if norm < 1e-6:
        raise ctx.fail(f"{where}.rotation", "quaternion has zero length")
    r = r / norm
    return t, r, s, trs_matrix(t, r, s)


def parse_nodes(ctx: _Ctx, doc: dict) -> tuple[list[Node], list[int]]:
    """All nodes with parents and rest ``world_from_node``; plus each node's light index.

    Enforces a forest: a node has at most one parent and no cycles. Returns the nodes and,
    per node, its ``KHR_lights_punctual.light`` index (−1 when none).
    """
    nodes_json = _items(ctx, doc, "nodes")
    n = len(nodes_json)
    parent = [-1] * n
    kids: list[tuple[int, ...]] = []
    local, trs, meshes, skins, lights = [], [], [], [], []
    n_lights = len(_light_definitions_raw(ctx, doc))
    for i, nd in enumerate(nodes_json):
        where = f"nodes[{i}]"
        ctx.where = where
        children = _list(ctx, nd, "children", where, default=[])
        for k, c in enumerate(children):
            cw = f"{where}.children[{k}]"
            if isinstance(c, bool) or not isinstance(c, int) or not 0 <= c < n:
                raise ctx.fail(cw, f"must be a node index below {n}, got {_show(c)}")
            if c == i or parent[c] != -1:
                raise ctx.fail(cw, f"nodes[{c}] already has a parent (the hierarchy must be "
                                   "a tree)")
            parent[c] = i
        kids.append(tuple(children))
        meshes.append(_index(ctx, nd, "mesh", where, "meshes", default=-1))
        skins.append(_index(ctx, nd, "skin", where, "skins", default=-1))
        t, r, s, m = _local_transform(ctx, nd, where)
        trs.append((t, r, s))
        local.append(m)
        ext = _extension(ctx, nd, "KHR_lights_punctual", where)
        light = -1
        if ext is not None:
            lw = f"{where}.extensions.KHR_lights_punctual"
            light = _int(ctx, ext, "light", lw)
            if light >= n_lights:
                raise ctx.fail(f"{lw}.light", f"refers to light {light} but there are "
                                              f"{n_lights}")
        lights.append(light)
    world = [None] * n
    order = [i for i in range(n) if parent[i] == -1]
    for i in order:
        world[i] = local[i]
    k = 0
    while k < len(order):
        i = order[k]
        for c in kids[i]:
            world[c] = world[i] @ local[c]
            order.append(c)
        k += 1
    if len(order) != n:
        bad = next(i for i in range(n) if world[i] is None)
        raise ctx.fail(f"nodes[{bad}]", "is part of a cycle in the node hierarchy")
    nodes = [
        Node(
            name=_str(ctx, nd, "name", f"nodes[{i}]", default=""),
            parent=parent[i], children=kids[i],
            translation=trs[i][0], rotation=trs[i][1], scale=trs[i][2],
            matrix=local[i], world_from_node=world[i], mesh=meshes[i], skin=skins[i],
        )
        for i, nd in enumerate(nodes_json)
    ]
    return nodes, lights


def scene_roots(ctx: _Ctx, doc: dict, nodes: list[Node]) -> tuple[list[int], str]:
    """Root nodes of the scene to flatten (``scene`` or 0; all roots when no scenes), and
    the glTF path naming that scene (for messages)."""
    scenes = _items(ctx, doc, "scenes")
    if not scenes:
        if "scene" in doc:
            raise ctx.fail("scene", "refers to a scene but there are no scenes")
        return [i for i, nd in enumerate(nodes) if nd.parent == -1], "nodes"
    s = _index(ctx, doc, "scene", "", "scenes", default=0)
    where = f"scenes[{s}]"
    roots = []
    for k, r in enumerate(_list(ctx, scenes[s], "nodes", where, default=[])):
        rw = f"{where}.nodes[{k}]"
        if isinstance(r, bool) or not isinstance(r, int) or not 0 <= r < len(nodes):
            raise ctx.fail(rw, f"must be a node index below {len(nodes)}, got {_show(r)}")
        if nodes[r].parent != -1:
            raise ctx.fail(rw, f"nodes[{r}] is not a root node")
        if r in roots:
            raise ctx.fail(rw, f"nodes[{r}] is listed twice")
        roots.append(r)
    return roots, where


def traverse(nodes: list[Node], roots: list[int]) -> list[int]:
    """Node indices of the scene in depth-first pre-order (children in listed order)."""
    out, stack = [], list(reversed(roots))
    while stack:
        i = stack.pop()
        out.append(i)
        stack.extend(reversed(nodes[i].children))
    return out


# --------------------------------------------------------------------------------------
# Geometry: planning (JSON only), decoding, flattening
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PrimitivePlan:
    """One mesh primitive, validated from the JSON alone (no buffer read yet)."""

    mesh: int
    primitive: int
    where: str
    mode: int
    material: int
    position: AccessorLayout
    indices: AccessorLayout | None
    attributes: dict  # semantic → AccessorLayout for NORMAL, TEXCOORD_0/1, JOINTS_0, WEIGHTS_0
    vertex_count: int
    triangle_count: int  # upper bound (degenerate strip/fan triangles are dropped later)


def triangle_count(mode: int, n: int) -> int:
    """Triangles produced by ``n`` vertices/indices in a glTF primitive ``mode``."""
    if mode == 4:
        return n // 3
    if mode in (5, 6):
        return max(n - 2, 0)
    return 0


_ATTRIBUTES = {
    "NORMAL": (("VEC3",), _NORMAL_CT),
    "TEXCOORD_0": (("VEC2",), _TEXCOORD_CT),
    "TEXCOORD_1": (("VEC2",), _TEXCOORD_CT),
    "JOINTS_0": (("VEC4",), _JOINTS_CT),
    "WEIGHTS_0": (("VEC4",), _WEIGHTS_CT),
}


def plan_primitive(ctx: _Ctx, doc: dict, m: int, p: int, prim: dict) -> PrimitivePlan:
    """Validate one primitive's mode, accessors and material from the JSON."""
    where = f"meshes[{m}].primitives[{p}]"
    ctx.where = where
    mode = _int(ctx, prim, "mode", where, default=4)
    if mode not in MODE_NAMES:
        raise ctx.fail(f"{where}.mode", f"unknown primitive mode {mode}")
    attrs = _dict(ctx, prim, "attributes", where)
    aw = f"{where}.attributes"
    if "POSITION" not in attrs:
        raise ctx.fail(f"{aw}.POSITION", "is missing")
    draco = _extension(ctx, prim, "KHR_draco_mesh_compression", where) is not None
    pos = accessor_layout(ctx, doc, _index(ctx, attrs, "POSITION", aw, "accessors"),
                          f"{aw}.POSITION", ("VEC3",), _POSITION_CT)
    layouts = {}
    for sem, (types, comps) in _ATTRIBUTES.items():
        if sem in attrs:
            lay = accessor_layout(ctx, doc, _index(ctx, attrs, sem, aw, "accessors"),
                                  f"{aw}.{sem}", types, comps)
            if lay.count != pos.count:
                raise ctx.fail(lay.where, f"count {lay.count} differs from POSITION count "
                                          f"{pos.count}")
            layouts[sem] = lay
    indices = None
    if "indices" in prim:
        indices = accessor_layout(ctx, doc, _index(ctx, prim, "indices", where, "accessors"),
                                  f"{where}.indices", ("SCALAR",), _INDEX_CT)
        if indices.normalized:
            raise ctx.fail(indices.where, "indices must not be normalized")
    if draco and any(lay.buffer < 0 and lay.sparse is None
                     for lay in (pos, indices, *layouts.values()) if lay is not None):
        raise ctx.unsupported(where, "geometry only available Draco-compressed "
                                     "(KHR_draco_mesh_compression is refused, not decoded)")
    n = indices.count if indices is not None else pos.count
    if mode < 4:
        ctx.warn(where, f"{MODE_NAMES[mode]} primitive skipped (only triangles are baked)")
    elif mode == 4 and n % 3:
        ctx.warn(where, f"{n} indices is not a multiple of 3; the last {n % 3} ignored")
    if "targets" in prim:
        ctx.warn(where, "morph targets ignored (rest shape used)")
    material = _index(ctx, prim, "material", where, "materials", default=-1)
    return PrimitivePlan(m, p, where, mode, material, pos, indices, layouts, pos.count,
                         triangle_count(mode, n))


def plan_mesh(ctx: _Ctx, doc: dict, m: int) -> list[PrimitivePlan]:
    """Plans of every primitive of mesh ``m``."""
    where = f"meshes[{m}]"
    ctx.where = where
    prims = _list(ctx, _items(ctx, doc, "meshes")[m], "primitives", where)
    if not prims:
        raise ctx.fail(f"{where}.primitives", "is empty")
    out = []
    for p, prim in enumerate(prims):
        if not isinstance(prim, dict):
            raise ctx.fail(f"{where}.primitives[{p}]", f"must be an object, got {_show(prim)}")
        out.append(plan_primitive(ctx, doc, m, p, prim))
    return out


def check_totals(ctx: _Ctx, scene_where: str, nodes: list[Node], order: list[int],
                 plans: dict[int, list[PrimitivePlan]]) -> None:
    """Vertex and triangle totals summed over every instance, against the limits."""
    tris = verts = instances = 0
    for i in order:
        m = nodes[i].mesh
        if m < 0:
            continue
        instances += 1
        for plan in plans[m]:
            if plan.triangle_count:
                tris += plan.triangle_count
                verts += plan.vertex_count
    if verts > ctx.limits.max_vertices:
        raise ctx.over(scene_where, f"{verts} vertices over {instances} mesh instances",
                       "max_vertices")
    if tris > ctx.limits.max_triangles:
        raise ctx.over(scene_where, f"{tris} triangles over {instances} mesh instances",
                       "max_triangles")
    if tris == 0:
        raise ctx.fail(scene_where, "no triangles: the scene has no triangle primitives")


def triangulate(mode: int, idx: np.ndarray) -> np.ndarray:
    """Vertex indices (n,) int64 of a TRIANGLES/STRIP/FAN primitive → faces (f, 3) int64.

    Strip triangle i is (v_i, v_{i+1+i%2}, v_{i+2−i%2}) and fan triangle i is
    (v_{i+1}, v_{i+2}, v_0), as in the glTF spec; strip/fan triangles that repeat a vertex
    (used as restarts) are dropped.
    """
    n = len(idx)
    if mode == 4:
        return idx[: n - n % 3].reshape(-1, 3)
    i = np.arange(max(n - 2, 0))
    if mode == 5:
        odd = i % 2
        f = np.stack([idx[i], idx[i + 1 + odd], idx[i + 2 - odd]], axis=1)
    else:
        f = np.stack([idx[i + 1], idx[i + 2], np.full_like(i, idx[0] if n else 0)], axis=1)
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    return f[keep]


def area_weighted_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Vertex normals as the area-weighted sum of adjacent face normals.

    positions : (v, 3) float64; faces : (f, 3) int64. Returns (v, 3) float64 unit vectors;
    vertices with no non-degenerate face get +Z.
    """
    v = positions[faces]
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])  # length = 2 × area
    corner = faces.ravel()
    acc = np.stack([np.bincount(corner, weights=np.repeat(fn[:, c], 3),
                                minlength=len(positions)) for c in range(3)], axis=1)
    return _normalize_rows(acc)


def _normalize_rows(n: np.ndarray, fallback=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(k, 3) rows scaled to unit length; rows shorter than NORMAL_EPS become ``fallback``."""
    length = np.sqrt(np.einsum("ij,ij->i", n, n))
    ok = length > NORMAL_EPS
    out = n / np.where(ok, length, 1.0)[:, None]
    if not ok.all():
        out[~ok] = fallback
    return out


def _apply_linear(rows: np.ndarray, lin: np.ndarray) -> np.ndarray:
    """rows (k, 3) float64 mapped by lin (3, 3): ``rows @ lin.T`` without a BLAS call
    (a (k, 3)·(3, 3) product is memory-bound; BLAS threading only slows it down)."""
    return rows[:, 0:1] * lin[:, 0] + rows[:, 1:2] * lin[:, 1] + rows[:, 2:3] * lin[:, 2]


def normal_matrix(lin: np.ndarray) -> np.ndarray:
    """Normal transform for linear part(s) ``lin`` (..., 3, 3): the inverse-transpose up to a
    positive factor, as sign(det)·cofactor (defined even for singular matrices)."""
    a, b, c = lin[..., :, 0], lin[..., :, 1], lin[..., :, 2]
    cof = np.stack([np.cross(b, c), np.cross(c, a), np.cross(a, b)], axis=-1)
    det = np.einsum("...i,...i->...", a, np.cross(b, c))
    return cof * np.where(det < 0, -1.0, 1.0)[..., None, None]


@dataclass(frozen=True)
class DecodedPrimitive:
    """Object-space data of one primitive.

    positions, normals (v, 3) float64; uv0, uv1 (v, 2) float64 or None; joints (v, 4) int32
    and weights (v, 4) float64 or None; faces (f, 3) int64 in the file's winding.
    """

    positions: np.ndarray
    normals: np.ndarray
    uv0: np.ndarray | None
    uv1: np.ndarray | None
    joints: np.ndarray | None
    weights: np.ndarray | None
    faces: np.ndarray


def _finite_floats(ctx: _Ctx, raw: np.ndarray, lay: AccessorLayout) -> np.ndarray:
    out = to_float(raw, lay)
    if np.isnan(out).any():
        raise ctx.fail(lay.where, "contains NaN")
    if np.isinf(out).any():
        raise ctx.fail(lay.where, "contains Inf")
    return out


def decode_primitive(ctx: _Ctx, plan: PrimitivePlan, buffers: list) -> DecodedPrimitive:
    """Decode a planned triangle primitive (positions checked finite, indices in range,
    normals filled area-weighted where absent or unusable)."""
    ctx.where = plan.where
    positions = _finite_floats(ctx, read_accessor(ctx, plan.position, buffers), plan.position)
    nv = plan.vertex_count
    if plan.indices is not None:
        idx = read_accessor(ctx, plan.indices, buffers)[:, 0].astype(np.int64)
        if len(idx) and idx.max() >= nv:
            raise ctx.fail(plan.indices.where, f"index {int(idx.max())} out of range for "
                                               f"{nv} vertices")
    else:
        idx = np.arange(nv, dtype=np.int64)
    faces = triangulate(plan.mode, idx)
    lay = plan.attributes.get("NORMAL")
    if lay is None:
        normals = area_weighted_normals(positions, faces)
    else:
        normals = to_float(read_accessor(ctx, lay, buffers), lay)
        length = np.linalg.norm(normals, axis=1)
        bad = ~np.isfinite(length) | (length <= NORMAL_EPS)
        if bad.any():
            ctx.warn(lay.where, f"{int(bad.sum())} unusable normals replaced by area-weighted "
                                "ones")
            normals[bad] = area_weighted_normals(positions, faces)[bad]
        normals = _normalize_rows(normals)

    def floats(sem: str) -> np.ndarray | None:
        lay = plan.attributes.get(sem)
        return None if lay is None else _finite_floats(ctx, read_accessor(ctx, lay, buffers),
                                                       lay)

    joints = weights = None
    if "JOINTS_0" in plan.attributes and "WEIGHTS_0" in plan.attributes:
        joints = read_accessor(ctx, plan.attributes["JOINTS_0"], buffers).astype(np.int32)
        weights = floats("WEIGHTS_0")
    return DecodedPrimitive(positions, normals, floats("TEXCOORD_0"), floats("TEXCOORD_1"),
                            joints, weights, faces)


def place_primitive(world_from_node: np.ndarray, prim: DecodedPrimitive
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Object → world: positions by the matrix, normals by its inverse-transpose
    (renormalised); winding flipped when det < 0. Returns positions (v, 3), normals (v, 3),
    faces (f, 3)."""
    lin = world_from_node[:3, :3]
    pos = _apply_linear(prim.positions, lin) + world_from_node[:3, 3]
    nrm = _normalize_rows(_apply_linear(prim.normals, normal_matrix(lin)))
    faces = prim.faces[:, [0, 2, 1]] if np.linalg.det(lin) < 0 else prim.faces
    return pos, nrm, faces


def place_skinned(ctx: _Ctx, where: str, world_from_node: np.ndarray, skin: Skin,
                  nodes: list[Node], prim: DecodedPrimitive
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rest pose of a skinned primitive by linear blend skinning: each vertex moved by
    Σ_k w_k · world_from_joint_k · inverse_bind_k (the mesh node's own transform is ignored,
    as glTF specifies). Vertices with zero total weight use ``world_from_node``."""
    if prim.joints.size and prim.joints.max() >= len(skin.joints):
        raise ctx.fail(f"{where}.attributes.JOINTS_0",
                       f"joint {int(prim.joints.max())} out of range for a skin of "
                       f"{len(skin.joints)} joints")
    joint_mats = np.stack([nodes[j].world_from_node for j in skin.joints]) @ skin.inverse_bind
    w = prim.weights
    total = w.sum(axis=1, keepdims=True)
    unweighted = total[:, 0] <= 0
    w = np.divide(w, total, out=np.zeros_like(w), where=total > 0)
    per_vertex = np.einsum("vk,vkij->vij", w, joint_mats[prim.joints])
    per_vertex[unweighted] = world_from_node
    lin = per_vertex[:, :3, :3]
    pos = np.einsum("vij,vj->vi", lin, prim.positions) + per_vertex[:, :3, 3]
    nrm = _normalize_rows(np.einsum("vij,vj->vi", normal_matrix(lin), prim.normals))
    det = np.linalg.det(lin)
    flip = det[prim.faces].mean(axis=1) < 0
    faces = prim.faces.copy()
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return pos, nrm, faces


@dataclass(frozen=True)
class FlatGeometry:
    """Concatenated world-space geometry of all instances (see :class:`Scene`)."""

    positions: np.ndarray
    normals: np.ndarray
    uv0: np.ndarray
    has_uv0: np.ndarray
    uv1: np.ndarray | None
    faces: np.ndarray
    face_material: np.ndarray
    face_instance: np.ndarray
    instances: tuple[PrimitiveInstance, ...]
    uses_default_material: bool


def flatten(ctx: _Ctx, nodes: list[Node], order: list[int], plans: dict, buffers: list,
            skins: list[Skin], default_material: int) -> FlatGeometry:
    """Place every triangle primitive of every mesh instance in world space."""
    cache: dict[tuple[int, int], DecodedPrimitive] = {}
    chunks = []
    v0 = f0 = 0
    for i in order:
        node = nodes[i]
        if node.mesh < 0:
            continue
        for plan in plans[node.mesh]:
            if plan.mode < 4:
                continue
            key = (plan.mesh, plan.primitive)
            if key not in cache:
                cache[key] = decode_primitive(ctx, plan, buffers)
            prim = cache[key]
            ctx.where = f"nodes[{i}] {plan.where}"
            if node.skin >= 0 and prim.joints is not None:
                pos, nrm, faces = place_skinned(ctx, plan.where, node.world_from_node,
                                                skins[node.skin], nodes, prim)
            else:
                pos, nrm, faces = place_primitive(node.world_from_node, prim)
            nv, nf = len(pos), len(faces)
            empty4 = np.zeros((0, 4))
            inst = PrimitiveInstance(
                node=i, mesh=plan.mesh, primitive=plan.primitive,
                vertex_start=v0, vertex_count=nv, face_start=f0, face_count=nf,
                object_positions=prim.positions, object_normals=prim.normals,
                joints=prim.joints if prim.joints is not None else empty4.astype(np.int32),
                weights=prim.weights if prim.weights is not None else empty4,
            )
            mat = plan.material if plan.material >= 0 else default_material
            chunks.append((inst, pos, nrm, faces + v0, prim.uv0, prim.uv1, mat))
            v0, f0 = v0 + nv, f0 + nf
    insts = tuple(c[0] for c in chunks)
    n_uv1 = sum(c[5] is not None for c in chunks)
    uv1 = None
    if n_uv1:
        if n_uv1 < len(chunks):
            ctx.warn("", f"TEXCOORD_1 present on {n_uv1} of {len(chunks)} primitive instances;"
                         " zeros filled in elsewhere")
        uv1 = np.concatenate([c[5] if c[5] is not None else np.zeros((c[0].vertex_count, 2))
                              for c in chunks])
    faces = np.concatenate([c[3] for c in chunks]).astype(np.int64)
    if len(faces) == 0:
        raise ctx.fail("", "no triangles: every triangle primitive is degenerate")
    return FlatGeometry(
        positions=np.concatenate([c[1] for c in chunks]),
        normals=np.concatenate([c[2] for c in chunks]),
        uv0=np.concatenate([c[4] if c[4] is not None else np.zeros((c[0].vertex_count, 2))
                            for c in chunks]),
        has_uv0=np.concatenate([np.full(c[0].vertex_count, c[4] is not None) for c in chunks]),
        uv1=uv1,
        faces=faces,
        face_material=np.concatenate([np.full(len(c[3]), c[6], dtype=np.int32)
                                      for c in chunks]),
        face_instance=np.concatenate([np.full(len(c[3]), k, dtype=np.int32)
                                      for k, c in enumerate(chunks)]),
        instances=insts,
        uses_default_material=any(c[6] == default_material for c in chunks),
    )


# --------------------------------------------------------------------------------------
# Materials and textures
# --------------------------------------------------------------------------------------


def texture_transform_matrix(offset=(0.0, 0.0), rotation: float = 0.0, scale=(1.0, 1.0)
                             ) -> np.ndarray:
    """KHR_texture_transform as a (3, 3) float64 matrix on homogeneous UVs: T · R · S.

    R = [[cos r, sin r, 0], [−sin r, cos r, 0], [0, 0, 1]] in row-major form, the rotation
    the extension's worked examples (and three.js, Babylon.js) use: a positive ``rotation``
    turns UVs counter-clockwise as seen on the image (v points down). With offset (0, 1),
    rotation π/2 and scale 0.5 the unit square maps onto the lower-left image quadrant.
    """
    c, s = np.cos(rotation), np.sin(rotation)
    t = np.array([[1.0, 0.0, offset[0]], [0.0, 1.0, offset[1]], [0.0, 0.0, 1.0]])
    r = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    sc = np.diag([float(scale[0]), float(scale[1]), 1.0])
    return t @ r @ sc


def image_bytes(ctx: _Ctx, doc: dict, index: int, buffers: list) -> bytes:
    """Encoded bytes of ``images[index]`` from its URI (confined, size-checked) or bufferView."""
    where = f"images[{index}]"
    img = _items(ctx, doc, "images")[index]
    uri = _str(ctx, img, "uri", where, default=None)
    if uri is not None:
        return _uri_bytes(ctx, uri, f"{where}.uri", "max_buffer_bytes")
    bv = _index(ctx, img, "bufferView", where, "bufferViews", default=-1)
    if bv < 0:
        raise ctx.fail(where, "has neither uri nor bufferView")
    b, off, length, _ = buffer_view(ctx, doc, bv)
    return bytes(buffers[b][off: off + length])


def decode_image(ctx: _Ctx, data: bytes, where: str) -> np.ndarray:
    """PNG/JPEG/WebP bytes → (h, w, 4) float32 linear RGBA, row 0 = image top.

    Dimensions come from the header (Pillow opens lazily) and are checked against
    ``max_texture_pixels`` before any pixel is decoded. Colour is sRGB-decoded, alpha kept.
    """
    from PIL import Image

    ctx.where = where
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            im = Image.open(io.BytesIO(data), formats=_IMAGE_FORMATS)
            w, h = im.size
            if w * h > ctx.limits.max_texture_pixels:
                raise ctx.over(where, f"image of {w}x{h} = {w * h} pixels",
                               "max_texture_pixels")
            im.load()
            if im.mode.startswith("I"):  # 16/32-bit grey
                arr = np.asarray(im, dtype=np.float64)
                top = 65535.0 if im.mode.startswith("I;16") or arr.max() <= 65535 else arr.max()
                grey = (arr / top).astype(np.float32)
                rgba = np.stack([grey, grey, grey, np.ones_like(grey)], axis=-1)
            else:
                rgba = np.asarray(im.convert("RGBA"), dtype=np.float32) / 255.0
    except PrtError:
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning):
        raise ctx.over(where, "image is a decompression bomb", "max_texture_pixels") from None
    except MemoryError:
        raise
    except Exception as e:
        raise ctx.fail(where, f"cannot decode image ({type(e).__name__}: {str(e)[:80]})"
                       ) from None
    out = np.empty(rgba.shape, dtype=np.float32)
    out[..., :3] = srgb_to_linear(rgba[..., :3])
    out[..., 3] = rgba[..., 3]
    return out


def parse_materials(ctx: _Ctx, doc: dict, buffers: list
                    ) -> tuple[list[Material], list[Texture]]:
    """glTF materials → Lambertian :class:`Material` records and their decoded base-colour
    textures (one :class:`Texture` per distinct image + wrap modes)."""
    materials, textures = [], []
    tex_index: dict[tuple[int, int, int], int] = {}
    pixels: dict[int, np.ndarray] = {}
    for i, mj in enumerate(_items(ctx, doc, "materials")):
        where = f"materials[{i}]"
        ctx.where = where
        pbr = _dict(ctx, mj, "pbrMetallicRoughness", where, default={})
        pw = f"{where}.pbrMetallicRoughness"
        factor = _nums(ctx, pbr, "baseColorFactor", pw, 4, [1.0, 1.0, 1.0, 1.0])
        emissive = _nums(ctx, mj, "emissiveFactor", where, 3, [0.0, 0.0, 0.0])
        strength = _extension(ctx, mj, "KHR_materials_emissive_strength", where)
        if strength is not None:
            emissive = emissive * _num(ctx, strength, "emissiveStrength",
                                       f"{where}.extensions.KHR_materials_emissive_strength",
                                       default=1.0)
        info = _dict(ctx, pbr, "baseColorTexture", pw, default=None)
        tw = f"{pw}.baseColorTexture"
        sg = _extension(ctx, mj, "KHR_materials_pbrSpecularGlossiness", where)
        if sg is not None and "pbrMetallicRoughness" not in mj:  # legacy diffuse workflow
            sw = f"{where}.extensions.KHR_materials_pbrSpecularGlossiness"
            factor = _nums(ctx, sg, "diffuseFactor", sw, 4, [1.0, 1.0, 1.0, 1.0])
            info, tw = _dict(ctx, sg, "diffuseTexture", sw, default=None), f"{sw}.diffuseTexture"
        texture, texcoord, uv_transform = -1, 0, np.eye(3)
        if info is not None:
            texture, texcoord, uv_transform = _texture_info(ctx, doc, info, tw, buffers,
                                                            textures, tex_index, pixels)
        materials.append(Material(
            name=_str(ctx, mj, "name", where, default=""),
            base_color_factor=factor, texture=texture, uv_transform=uv_transform,
            texcoord=texcoord, emissive_factor=emissive,
            double_sided=_bool(ctx, mj, "doubleSided", where, default=False),
        ))
    return materials, textures


def _texture_info(ctx: _Ctx, doc: dict, info: dict, where: str, buffers: list,
                  textures: list, tex_index: dict, pixels: dict):
    """(Scene texture index, texcoord, uv_transform) of one textureInfo."""
    t = _index(ctx, info, "index", where, "textures")
    texcoord = _int(ctx, info, "texCoord", where, default=0)
    uv_transform = np.eye(3)
    kt = _extension(ctx, info, "KHR_texture_transform", where)
    if kt is not None:
        kw = f"{where}.extensions.KHR_texture_transform"
        uv_transform = texture_transform_matrix(
            _nums(ctx, kt, "offset", kw, 2, [0.0, 0.0]),
            _num(ctx, kt, "rotation", kw, default=0.0),
            _nums(ctx, kt, "scale", kw, 2, [1.0, 1.0]),
        )
        texcoord = _int(ctx, kt, "texCoord", kw, default=texcoord)
    if texcoord > 1:
        ctx.warn(where, f"TEXCOORD_{texcoord} is not kept; TEXCOORD_0 used instead")
        texcoord = 0
    tex = _items(ctx, doc, "textures")[t]
    tjw = f"textures[{t}]"
    source = _index(ctx, tex, "source", tjw, "images", default=-1)
    webp = _extension(ctx, tex, "EXT_texture_webp", tjw)
    if webp is not None:
        source = _index(ctx, webp, "source", f"{tjw}.extensions.EXT_texture_webp", "images")
    if source < 0:
        ctx.warn(tjw, "texture has no image this loader can decode; base colour factor only")
        return -1, texcoord, uv_transform
    sampler = _index(ctx, tex, "sampler", tjw, "samplers", default=-1)
    wrap_s = wrap_t = 10497
    if sampler >= 0:
        sj, sw = _items(ctx, doc, "samplers")[sampler], f"samplers[{sampler}]"
        wrap_s = _int(ctx, sj, "wrapS", sw, default=10497)
        wrap_t = _int(ctx, sj, "wrapT", sw, default=10497)
        for name, mode in (("wrapS", wrap_s), ("wrapT", wrap_t)):
            if mode not in WRAP_MODES:
                raise ctx.fail(f"{sw}.{name}", f"unknown wrap mode {mode}")
    key = (source, wrap_s, wrap_t)
    if key not in tex_index:
        if source not in pixels:
            iw = f"images[{source}]"
            ctx.where = iw
            pixels[source] = decode_image(ctx, image_bytes(ctx, doc, source, buffers), iw)
        name = _str(ctx, _items(ctx, doc, "images")[source], "name", f"images[{source}]",
                    default="")
        tex_index[key] = len(textures)
        textures.append(Texture(pixels=pixels[source], wrap_s=wrap_s, wrap_t=wrap_t, name=name))
    return tex_index[key], texcoord, uv_transform


# --------------------------------------------------------------------------------------
# Lights, skins, animations
# --------------------------------------------------------------------------------------


def _light_definitions_raw(ctx: _Ctx, doc: dict) -> list:
    ext = _extension(ctx, doc, "KHR_lights_punctual", "")
    if ext is None:
        return []
    return _list(ctx, ext, "lights", "extensions.KHR_lights_punctual", default=[])


def parse_lights(ctx: _Ctx, doc: dict, nodes: list[Node], node_light: list[int],
                 order: list[int]) -> tuple[Light, ...]:
    """KHR_lights_punctual lights placed by the scene's nodes, in world space.

    position = world_from_node · (0, 0, 0, 1); direction = the node's −Z axis transformed
    and normalised. Spot cone angles default to 0 and π/4; ``range`` stays None when absent.
    """
    defs = _light_definitions_raw(ctx, doc)
    out = []
    for i in order:
        k = node_light[i]
        if k < 0:
            continue
        where = f"extensions.KHR_lights_punctual.lights[{k}]"
        ctx.where = where
        lj = defs[k]
        if not isinstance(lj, dict):
            raise ctx.fail(where, f"must be an object, got {_show(lj)}")
        kind = _str(ctx, lj, "type", where)
        if kind not in ("point", "spot", "directional"):
            raise ctx.fail(f"{where}.type", f"unknown light type {_show(kind)}")
        color = _nums(ctx, lj, "color", where, 3, [1.0, 1.0, 1.0])
        intensity = _num(ctx, lj, "intensity", where, default=1.0)
        rng = _num(ctx, lj, "range", where, default=None)
        if rng is not None and rng <= 0:
            raise ctx.fail(f"{where}.range", f"must be > 0, got {rng}")
        inner, outer = 0.0, np.pi / 4
        if kind == "spot":
            spot = _dict(ctx, lj, "spot", where, default={})
            inner = _num(ctx, spot, "innerConeAngle", f"{where}.spot", default=0.0)
            outer = _num(ctx, spot, "outerConeAngle", f"{where}.spot", default=np.pi / 4)
            if not 0.0 <= inner < outer <= np.pi / 2:
                raise ctx.fail(f"{where}.spot", "cone angles must satisfy 0 <= inner < outer "
                                                "<= pi/2")
        m = nodes[i].world_from_node
        direction = m[:3, :3] @ np.array([0.0, 0.0, -1.0])
        norm = float(np.linalg.norm(direction))
        if norm <= NORMAL_EPS and kind != "point":
            raise ctx.fail(f"nodes[{i}]", "light node transform collapses its direction")
        out.append(Light(
            type=kind, color=color, intensity=intensity, position=m[:3, 3].copy(),
            direction=direction / norm if norm > NORMAL_EPS else np.array([0.0, 0.0, -1.0]),
            inner_cone_angle=inner, outer_cone_angle=outer, range=rng,
            name=_str(ctx, lj, "name", where, default=""),
        ))
    return tuple(out)


def parse_skins(ctx: _Ctx, doc: dict, buffers: list) -> list[Skin]:
    """glTF skins: joint node indices, inverse bind matrices (identity when absent)."""
    out = []
    n_nodes = len(_items(ctx, doc, "nodes"))
    for i, sj in enumerate(_items(ctx, doc, "skins")):
        where = f"skins[{i}]"
        ctx.where = where
        joints = _list(ctx, sj, "joints", where)
        for k, j in enumerate(joints):
            if isinstance(j, bool) or not isinstance(j, int) or not 0 <= j < n_nodes:
                raise ctx.fail(f"{where}.joints[{k}]", f"must be a node index below {n_nodes}")
        if not joints:
            raise ctx.fail(f"{where}.joints", "is empty")
        ibm = np.broadcast_to(np.eye(4), (len(joints), 4, 4)).copy()
        if "inverseBindMatrices" in sj:
            lay = accessor_layout(ctx, doc, _index(ctx, sj, "inverseBindMatrices", where,
                                                   "accessors"),
                                  f"{where}.inverseBindMatrices", ("MAT4",), _FLOAT)
            if lay.count < len(joints):
                raise ctx.fail(lay.where, f"{lay.count} matrices for {len(joints)} joints")
            mats = _finite_floats(ctx, read_accessor(ctx, lay, buffers), lay)
            ibm = mats[: len(joints)].reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
        out.append(Skin(
            name=_str(ctx, sj, "name", where, default=""),
            joints=np.array(joints, dtype=np.int64), inverse_bind=ibm,
            skeleton=_int(ctx, sj, "skeleton", where, default=-1, lo=-1, hi=n_nodes - 1),
        ))
    return out


_PATH_WIDTH = {"translation": 3, "rotation": 4, "scale": 3}


def parse_animations(ctx: _Ctx, doc: dict, buffers: list) -> tuple[Animation, ...]:
    """glTF animations → channels with (k,) times and (k, c) values (3k rows for
    CUBICSPLINE); channels without a node target or with other paths are skipped."""
    out = []
    n_nodes = len(_items(ctx, doc, "nodes"))
    for a, aj in enumerate(_items(ctx, doc, "animations")):
        where = f"animations[{a}]"
        ctx.where = where
        samplers = _list(ctx, aj, "samplers", where)
        channels = []
        for c, ch in enumerate(_list(ctx, aj, "channels", where)):
            cw = f"{where}.channels[{c}]"
            ctx.where = cw
            if not isinstance(ch, dict):
                raise ctx.fail(cw, f"must be an object, got {_show(ch)}")
            target = _dict(ctx, ch, "target", cw)
            path = _str(ctx, target, "path", f"{cw}.target")
            node = _int(ctx, target, "node", f"{cw}.target", default=-1,
                        hi=n_nodes - 1)
            if node < 0 or path not in (*_PATH_WIDTH, "weights"):
                ctx.warn(cw, f"channel targeting {_show(path)} without a node is skipped")
                continue
            s = _int(ctx, ch, "sampler", cw, hi=len(samplers) - 1)
            sw = f"{where}.samplers[{s}]"
            sj = samplers[s]
            if not isinstance(sj, dict):
                raise ctx.fail(sw, f"must be an object, got {_show(sj)}")
            interp = _str(ctx, sj, "interpolation", sw, default="LINEAR")
            if interp not in ("LINEAR", "STEP", "CUBICSPLINE"):
                raise ctx.fail(f"{sw}.interpolation", f"unknown interpolation {_show(interp)}")
            tin = accessor_layout(ctx, doc, _index(ctx, sj, "input", sw, "accessors"),
                                  f"{sw}.input", ("SCALAR",), _FLOAT)
            width = _PATH_WIDTH.get(path, 1)
            types = ("SCALAR",) if path == "weights" else (("VEC3",) if width == 3 else
                                                           ("VEC4",))
            tout = accessor_layout(ctx, doc, _index(ctx, sj, "output", sw, "accessors"),
                                   f"{sw}.output", types, _ANIM_OUT_CT)
            rows = tin.count * (3 if interp == "CUBICSPLINE" else 1)
            if tout.count % rows:
                raise ctx.fail(tout.where, f"count {tout.count} does not match {tin.count} "
                                           f"keyframes ({interp})")
            times = _finite_floats(ctx, read_accessor(ctx, tin, buffers), tin)[:, 0]
            if np.any(np.diff(times) < 0):
                raise ctx.fail(tin.where, "keyframe times decrease")
            values = _finite_floats(ctx, read_accessor(ctx, tout, buffers), tout)
            values = values.reshape(rows, -1)
            channels.append(AnimationChannel(node=node, path=path, times=times,
                                             values=values, interpolation=interp))
        out.append(Animation(name=_str(ctx, aj, "name", where, default=""),
                             channels=tuple(channels)))
    return tuple(out)


# --------------------------------------------------------------------------------------
# glTF and trimesh front ends
# --------------------------------------------------------------------------------------


def load_gltf(ctx: _Ctx, data: bytes) -> Scene:
    """A GLB or glTF JSON file's bytes → the flattened :class:`Scene` (see module doc)."""
    if data[:4] == GLB_MAGIC or ctx.file.lower().endswith(".glb"):
        doc, bin_chunk = read_glb(ctx, data)
    else:
        doc, bin_chunk = parse_json(ctx, data), None
    ctx.doc = doc
    check_header(ctx, doc)
    check_counts(ctx, doc)
    buffer_lengths(ctx, doc)
    nodes, node_light = parse_nodes(ctx, doc)
    roots, scene_where = scene_roots(ctx, doc, nodes)
    order = traverse(nodes, roots)
    plans = {}
    for i in order:
        m = nodes[i].mesh
        if m >= 0 and m not in plans:
            plans[m] = plan_mesh(ctx, doc, m)
    check_totals(ctx, scene_where, nodes, order, plans)

    buffers = load_buffers(ctx, doc, bin_chunk)
    materials, textures = parse_materials(ctx, doc, buffers)
    skins = parse_skins(ctx, doc, buffers)
    geo = flatten(ctx, nodes, order, plans, buffers, skins, default_material=len(materials))
    if geo.uses_default_material:
        materials.append(Material(name="default", base_color_factor=np.array(
            [DEFAULT_GREY, DEFAULT_GREY, DEFAULT_GREY, 1.0])))
    lights = parse_lights(ctx, doc, nodes, node_light, order)
    animations = parse_animations(ctx, doc, buffers)
    return Scene(
        source=ctx.file, positions=geo.positions, normals=geo.normals, uv0=geo.uv0,
        uv1=geo.uv1, faces=geo.faces, face_material=geo.face_material,
        face_instance=geo.face_instance, materials=tuple(materials), textures=tuple(textures),
        lights=lights, nodes=tuple(nodes), instances=geo.instances, animations=animations,
        skins=tuple(skins), has_uv0=geo.has_uv0, warnings=tuple(ctx.warnings),
    )


def _precount_obj(data: bytes) -> tuple[int, int]:
    """(vertices, triangles) an OBJ declares, counted from its ``v`` and ``f`` lines."""
    verts = tris = 0
    for line in data.splitlines():
        if line.startswith(b"v "):
            verts += 1
        elif line.startswith(b"f "):
            tris += max(len(line.split()) - 3, 0)
    return verts, tris


def _precount_ply(ctx: _Ctx, data: bytes) -> tuple[int, int]:
    """(vertices, faces) declared by a PLY header."""
    end = data.find(b"end_header", 0, 1 << 16)
    if not data.startswith(b"ply") or end < 0:
        raise ctx.fail("header", "not a PLY file (no 'ply' ... 'end_header' header)")
    counts = {}
    for line in data[:end].splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0] == b"element":
            if not parts[2].isdigit():
                raise ctx.fail("header", f"bad element count {parts[2][:20]!r}")
            counts[parts[1]] = int(parts[2])
    return counts.get(b"vertex", 0), counts.get(b"face", 0)


def load_trimesh_asset(ctx: _Ctx, data: bytes, kind: str) -> Scene:
    """OBJ/PLY through trimesh: one flattened mesh, one default grey material, trimesh's
    vertex normals, uv0 (flipped to glTF's top-left origin) when the file has UVs.

    Loaded from memory without a resolver, so ``mtllib``/texture references are never
    followed. Declared vertex/face counts are checked against the limits first.
    """
    import trimesh

    verts, tris = _precount_obj(data) if kind == "obj" else _precount_ply(ctx, data)
    if verts > ctx.limits.max_vertices:
        raise ctx.over("vertices", f"{verts} vertices", "max_vertices")
    if tris > ctx.limits.max_triangles:
        raise ctx.over("faces", f"at least {tris} triangles", "max_triangles")
    ctx.where = "mesh"
    mesh = trimesh.load(io.BytesIO(data), file_type=kind, force="mesh", process=False)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ctx.fail("faces", "no triangles")
    if len(mesh.faces) > ctx.limits.max_triangles:
        raise ctx.over("faces", f"{len(mesh.faces)} triangles", "max_triangles")
    positions = np.asarray(mesh.vertices, dtype=np.float64)
    if not np.isfinite(positions).all():
        bad = "NaN" if np.isnan(positions).any() else "Inf"
        raise ctx.fail("vertices", f"contains {bad}")
    faces = np.asarray(mesh.faces, dtype=np.int64)
    normals = _normalize_rows(np.asarray(mesh.vertex_normals, dtype=np.float64))
    uv = getattr(mesh.visual, "uv", None)
    nv = len(positions)
    if uv is not None and np.shape(uv) == (nv, 2) and np.isfinite(uv).all():
        uv0 = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]).astype(np.float64)
        has_uv0 = np.ones(nv, dtype=bool)
    else:
        uv0, has_uv0 = np.zeros((nv, 2)), np.zeros(nv, dtype=bool)
    empty4 = np.zeros((0, 4))
    inst = PrimitiveInstance(node=-1, mesh=0, primitive=0, vertex_start=0, vertex_count=nv,
                             face_start=0, face_count=len(faces), object_positions=positions,
                             object_normals=normals, joints=empty4.astype(np.int32),
                             weights=empty4)
    grey = Material(name="default",
                    base_color_factor=np.array([DEFAULT_GREY, DEFAULT_GREY, DEFAULT_GREY, 1.0]))
    return Scene(
        source=ctx.file, positions=positions, normals=normals, uv0=uv0, uv1=None, faces=faces,
        face_material=np.zeros(len(faces), dtype=np.int32),
        face_instance=np.zeros(len(faces), dtype=np.int32), materials=(grey,),
        instances=(inst,), has_uv0=has_uv0, warnings=tuple(ctx.warnings),
    )


def _read_asset_file(ctx: _Ctx, path: str) -> bytes:
    try:
        st = os.stat(path)
    except OSError as e:
        raise ctx.fail("", f"cannot read asset: {e.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        raise ctx.fail("", "is not a regular file")
    if st.st_size > ctx.limits.max_file_bytes:
        raise ctx.over("", f"file of {st.st_size} bytes", "max_file_bytes")
    with open(path, "rb") as f:
        return f.read(ctx.limits.max_file_bytes + 1)


def load_asset(path: str | os.PathLike, limits: IntakeLimits | None = None) -> Scene:
    """Load a ``.glb``/``.gltf`` (external buffers/images next to it) or ``.obj``/``.ply``
    into a flattened world-space :class:`Scene`.

    limits : intake limits, checked before allocation (default
        :meth:`IntakeLimits.from_env`).

    Raises :class:`AssetError` (:class:`LimitExceeded`, :class:`UnsupportedAsset`) with a
    one-line message naming the file, the glTF path and the limit.
    """
    limits = IntakeLimits.from_env() if limits is None else limits
    file = os.fspath(path)
    ctx = _Ctx(file=file, folder=os.path.realpath(os.path.dirname(os.path.abspath(file))),
               limits=limits)
    suffix = os.path.splitext(file)[1].lower()
    if suffix not in (".glb", ".gltf", ".obj", ".ply"):
        raise UnsupportedAsset(file, "", f"unsupported file type {suffix or '(none)'!r} "
                                         "(expected .glb, .gltf, .obj or .ply)")
    try:
        data = _read_asset_file(ctx, file)
        if suffix in (".glb", ".gltf"):
            return load_gltf(ctx, data)
        return load_trimesh_asset(ctx, data, suffix[1:])
    except PrtError:
        raise
    except MemoryError:
        raise
    except Exception as e:
        detail = f"{type(e).__name__}: {e}"
        raise AssetError(file, ctx.where, f"malformed asset ({detail[:160]})") from e
