"""Compressed geometry: ``KHR_draco_mesh_compression`` (decoded with DracoPy) and
``EXT_meshopt_compression`` (decoded with meshopt, a binding of meshoptimizer's decoder).

Both run under the intake limits, checked before the decoder allocates:

* Draco: the accessors of the primitive declare its counts (checked against the limits with
  every other primitive when the scene is planned); the Draco header's face count (and, for
  sequential connectivity, its point count) is read from the bitstream and must not exceed
  them before DracoPy decodes; the decoded counts must then equal the accessors' counts.
* meshopt: a compressed bufferView decodes to exactly ``count × byteStride`` bytes, which
  must equal its ``byteLength``; the fallback buffer it fills is allocated at its declared
  ``byteLength`` (checked against ``max_buffer_bytes`` and ``max_total_bytes`` with every
  other buffer before anything is read), so the decoder never writes more than was checked.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from prtcore.io.gltf.accessors import (
    COMPONENTS,
    AccessorLayout,
    NoData,
    buffer_data,
    buffer_view,
)
from prtcore.io.gltf.schema import (
    Ctx,
    get_dict,
    get_extension,
    get_index,
    get_int,
    get_items,
    get_str,
    join,
    show,
)

DRACO = "KHR_draco_mesh_compression"
MESHOPT = "EXT_meshopt_compression"
_DRACO_MAX_NESTING = 32


# --------------------------------------------------------------------------------------
# KHR_draco_mesh_compression
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DracoPlan:
    """Where a primitive's Draco bitstream lies and which Draco attribute is which."""

    where: str
    buffer: int
    offset: int
    length: int
    attributes: dict  # glTF semantic → Draco attribute unique id


def plan_draco(ctx: Ctx, doc: dict, ext: dict, where: str) -> DracoPlan:
    """Validate a primitive's ``KHR_draco_mesh_compression`` object from the JSON."""
    ew = f"{where}.extensions.{DRACO}"
    bv = get_index(ctx, ext, "bufferView", ew, "bufferViews")
    b, off, length, _ = buffer_view(ctx, doc, bv)
    attrs = get_dict(ctx, ext, "attributes", ew)
    ids = {sem: get_int(ctx, attrs, sem, f"{ew}.attributes") for sem in attrs}
    return DracoPlan(ew, b, off, length, ids)


def _varint(data: bytes, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if pos >= len(data) or shift > 63:
            raise ValueError("truncated varint")
        byte = data[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, pos


def _skip_metadata(data: bytes, pos: int, depth: int = 0) -> int:
    """Past one Draco metadata block (entries, then named sub-metadata, recursively)."""
    if depth > _DRACO_MAX_NESTING:
        raise ValueError("metadata nested too deep")
    n, pos = _varint(data, pos)
    for _ in range(n):
        pos += 1 + data[pos]  # name: uint8 length + bytes
        size, pos = _varint(data, pos)
        pos += size
    n, pos = _varint(data, pos)
    for _ in range(n):
        pos += 1 + data[pos]
        pos = _skip_metadata(data, pos, depth + 1)
    return pos


def draco_counts(data: bytes) -> tuple[int, int | None]:
    """(faces, points or None) a Draco mesh bitstream (version ≥ 2.2) declares in its header,
    read without decoding anything (points are known up front only for sequential
    connectivity; edgebreaker meshes have at most 3 points per face)."""
    if data[:5] != b"DRACO" or len(data) < 11:
        raise ValueError("not a Draco bitstream (no DRACO header)")
    major, minor, kind, method = data[5], data[6], data[7], data[8]
    (flags,) = struct.unpack_from("<H", data, 9)
    if kind != 1:
        raise ValueError("a Draco point cloud, not a triangle mesh")
    if (major, minor) < (2, 2):
        raise ValueError(f"Draco bitstream version {major}.{minor} (2.2 or later is read)")
    pos = 11
    if flags & 0x8000:  # metadata precede the connectivity
        n, pos = _varint(data, pos)
        for _ in range(n):
            _, pos = _varint(data, pos)
            pos = _skip_metadata(data, pos)
        pos = _skip_metadata(data, pos)
    if method == 0:  # sequential
        faces, pos = _varint(data, pos)
        points, pos = _varint(data, pos)
        return faces, points
    if method == 1:  # edgebreaker: traversal decoder type, encoded vertices, faces
        _, pos = _varint(data, pos + 1)
        faces, pos = _varint(data, pos)
        return faces, None
    raise ValueError(f"unknown Draco encoder method {method}")


def decode_draco(ctx: Ctx, plan: DracoPlan, buffers: list, position: AccessorLayout,
                 attributes: dict, max_faces: int) -> tuple[dict, np.ndarray]:
    """Decode a primitive's Draco bitstream → ({semantic: (count, ncomp) array in the
    accessor's component type}, indices (3f,) int64).

    ``attributes`` maps the semantics the loader keeps to their accessor layouts;
    ``max_faces`` is what the primitive's accessors declare (already within the limits).
    """
    import DracoPy

    where = plan.where
    ctx.where = where
    data = bytes(buffer_data(ctx, buffers, plan.buffer, where)[plan.offset:
                                                               plan.offset + plan.length])
    try:
        faces, points = draco_counts(data)
    except (ValueError, IndexError) as e:
        raise ctx.fail(where, f"cannot read the Draco header ({e})") from None
    if faces > max_faces:
        raise ctx.fail(where, f"Draco data holds {faces} triangles but the primitive's "
                              f"accessors declare at most {max_faces}")
    if points is not None and points > position.count:
        raise ctx.fail(where, f"Draco data holds {points} points but POSITION declares "
                              f"{position.count}")
    try:
        mesh = DracoPy.decode(data)
    except Exception as e:  # DracoPy raises its own types, or ValueError/RuntimeError
        raise ctx.fail(where, f"cannot decode the Draco data ({type(e).__name__}: "
                              f"{str(e)[:80]})") from None
    if not hasattr(mesh, "faces"):
        raise ctx.fail(where, "the Draco data is a point cloud, not a triangle mesh")
    idx = np.asarray(mesh.faces, dtype=np.int64).reshape(-1)
    out = {}
    for sem, lay in {"POSITION": position, **attributes}.items():
        if sem not in plan.attributes:
            if sem == "POSITION":
                raise ctx.fail(join(where, "attributes"), "has no POSITION")
            continue
        att = mesh.get_attribute_by_unique_id(plan.attributes[sem])
        aw = f"{where}.attributes.{sem}"
        if att is None:
            raise ctx.fail(aw, f"no Draco attribute with id {plan.attributes[sem]}")
        values = np.asarray(att["data"]).reshape(len(att["data"]), -1)
        if values.shape != (lay.count, lay.ncomp):
            raise ctx.fail(aw, f"Draco attribute of {values.shape[0]}x{values.shape[1]} values "
                               f"where {lay.where} declares {lay.count}x{lay.ncomp}")
        out[sem] = values.astype(np.dtype(COMPONENTS[lay.component_type][0]).newbyteorder("="))
    if len(idx) and idx.max() >= position.count:
        raise ctx.fail(where, f"Draco index {int(idx.max())} out of range for "
                              f"{position.count} points")
    return out, idx


# --------------------------------------------------------------------------------------
# EXT_meshopt_compression
# --------------------------------------------------------------------------------------

_MESHOPT_MODES = ("ATTRIBUTES", "TRIANGLES", "INDICES")
_MESHOPT_FILTERS = ("NONE", "OCTAHEDRAL", "QUATERNION", "EXPONENTIAL")


def decode_meshopt_views(ctx: Ctx, doc: dict, buffers: list) -> None:
    """Decode every ``EXT_meshopt_compression`` bufferView whose own buffer has no data into
    that buffer (allocated at its declared, already checked ``byteLength``). Views whose
    buffer has data (an uncompressed fallback) are read as they are."""
    filled: set[int] = set()  # fallback buffers allocated here
    for v, bv in enumerate(get_items(ctx, doc, "bufferViews")):
        where = f"bufferViews[{v}]"
        ext = get_extension(ctx, bv, MESHOPT, where)
        if ext is None:
            continue
        ctx.where = ew = f"{where}.extensions.{MESHOPT}"
        target, off, length, _ = buffer_view(ctx, doc, v)
        if target not in filled and not isinstance(buffers[target], NoData):
            continue  # the fallback holds the plain data
        src = get_index(ctx, ext, "buffer", ew, "buffers")
        src_off = get_int(ctx, ext, "byteOffset", ew, default=0)
        src_len = get_int(ctx, ext, "byteLength", ew, lo=1)
        stride = get_int(ctx, ext, "byteStride", ew, lo=1, hi=256)
        count = get_int(ctx, ext, "count", ew, lo=1)
        mode = get_str(ctx, ext, "mode", ew)
        filt = get_str(ctx, ext, "filter", ew, default="NONE")
        if mode not in _MESHOPT_MODES:
            raise ctx.fail(f"{ew}.mode", f"unknown mode {show(mode)}")
        if filt not in _MESHOPT_FILTERS:
            raise ctx.fail(f"{ew}.filter", f"unknown filter {show(filt)}")
        if count * stride != length:
            raise ctx.fail(ew, f"count {count} x byteStride {stride} = {count * stride} bytes "
                               f"but the bufferView's byteLength is {length}")
        if mode == "ATTRIBUTES" and stride % 4:
            raise ctx.fail(f"{ew}.byteStride", f"must be a multiple of 4 for ATTRIBUTES, "
                                               f"got {stride}")
        if mode != "ATTRIBUTES" and (stride not in (2, 4) or filt != "NONE"):
            raise ctx.fail(ew, f"{mode} needs byteStride 2 or 4 and no filter")
        if mode == "TRIANGLES" and count % 3:
            raise ctx.fail(f"{ew}.count", f"{count} is not a multiple of 3 for TRIANGLES")
        source = buffer_data(ctx, buffers, src, ew)
        if src_off + src_len > len(source):
            raise ctx.fail(ew, f"byteOffset {src_off} + byteLength {src_len} runs past "
                               f"buffers[{src}] ({len(source)} bytes)")
        decoded = _meshopt_decode(ctx, ew, bytes(source[src_off: src_off + src_len]), count,
                                  stride, mode, filt)
        if target not in filled:
            filled.add(target)
            n = get_int(ctx, get_items(ctx, doc, "buffers")[target], "byteLength",
                        f"buffers[{target}]", lo=1)
            ctx.charge(n, f"buffers[{target}]")
            buffers[target] = memoryview(bytearray(n))
        buffers[target][off: off + length] = decoded


def _meshopt_decode(ctx: Ctx, where: str, data: bytes, count: int, stride: int, mode: str,
                    filt: str) -> bytes:
    import meshopt

    try:
        rows = meshopt.decode_gltf_buffer(data, count, stride, mode,
                                          None if filt == "NONE" else filt)
    except MemoryError:
        raise
    except Exception as e:
        raise ctx.fail(where, f"cannot decode the meshopt data ({type(e).__name__}: "
                              f"{str(e)[:80]})") from None
    out = np.ascontiguousarray(rows).view(np.uint8).reshape(-1)
    if len(out) != count * stride:
        raise ctx.fail(where, f"meshopt data decoded to {len(out)} bytes, expected "
                              f"{count * stride}")
    return out.tobytes()
