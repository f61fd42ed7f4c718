"""The glTF container: GLB chunks, the JSON text, ``asset``/``extensionsRequired`` and the
top-level element counts."""

from __future__ import annotations

import json
import re
import struct

from prtcore.io.gltf.schema import Ctx, get_dict, get_items, get_list, get_str, show

GLB_MAGIC = b"glTF"
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942
#: Required extensions we honour (plus every ``KHR_materials_*``, whose extra terms the
#: Lambertian transport ignores).
SUPPORTED_EXTENSIONS = frozenset({
    "KHR_lights_punctual", "KHR_texture_transform", "KHR_mesh_quantization", "EXT_texture_webp",
    "KHR_draco_mesh_compression", "EXT_meshopt_compression",
})


def read_glb(ctx: Ctx, data: bytes) -> tuple[dict, memoryview | None]:
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


def parse_json(ctx: Ctx, raw: bytes) -> dict:
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


def check_header(ctx: Ctx, doc: dict) -> None:
    """``asset.version`` 2.x and every ``extensionsRequired`` entry supported."""
    asset = get_dict(ctx, doc, "asset", "")
    version = get_str(ctx, asset, "version", "asset")
    m = re.fullmatch(r"(\d+)\.(\d+)", version)
    if m is None:
        raise ctx.fail("asset.version", f"malformed version {show(version)}")
    if m.group(1) != "2":
        raise ctx.unsupported("asset.version", f"glTF {version}; only glTF 2.x is supported")
    min_version = get_str(ctx, asset, "minVersion", "asset", default="2.0")
    if min_version not in ("2.0",):
        raise ctx.unsupported("asset.minVersion", f"asset requires glTF {show(min_version)}")
    for i, name in enumerate(get_list(ctx, doc, "extensionsRequired", "", default=[])):
        where = f"extensionsRequired[{i}]"
        if not isinstance(name, str):
            raise ctx.fail(where, f"must be a string, got {show(name)}")
        if name not in SUPPORTED_EXTENSIONS and not name.startswith("KHR_materials_"):
            raise ctx.unsupported(where, f"required extension {name} is not supported")


def check_counts(ctx: Ctx, doc: dict) -> None:
    """Top-level element counts against the intake limits."""
    for name, limit in (
        ("nodes", "max_nodes"),
        ("meshes", "max_meshes"),
        ("materials", "max_materials"),
        ("images", "max_textures"),
        ("animations", "max_animations"),
    ):
        n = len(get_items(ctx, doc, name))
        if n > getattr(ctx.limits, limit):
            raise ctx.over(name, f"{n} {name}", limit)
