"""Buffers, bufferViews and accessors (sparse included): byte ranges validated with Python
ints from the JSON before numpy reads a byte, then decoded."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prtcore.io.gltf.schema import (
    Ctx,
    get_bool,
    get_dict,
    get_index,
    get_int,
    get_items,
    get_str,
    show,
)
from prtcore.io.gltf.uris import uri_bytes

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
# Allowed component types per use (KHR_mesh_quantization widens POSITION/NORMAL/TEXCOORD).
FLOAT_CT = (5126,)
POSITION_CT = (5126, 5120, 5121, 5122, 5123)
NORMAL_CT = (5126, 5120, 5122)
TEXCOORD_CT = (5126, 5120, 5121, 5122, 5123)
JOINTS_CT = (5121, 5123)
WEIGHTS_CT = (5126, 5121, 5123)
INDEX_CT = (5121, 5123, 5125)
ANIM_OUT_CT = (5126, 5120, 5121, 5122, 5123)


def buffer_lengths(ctx: Ctx, doc: dict) -> list[int]:
    """Declared ``byteLength`` of every buffer, checked against the limits (no reading)."""
    lengths = []
    for i, b in enumerate(get_items(ctx, doc, "buffers")):
        n = get_int(ctx, b, "byteLength", f"buffers[{i}]", lo=1)
        if n > ctx.limits.max_buffer_bytes:
            raise ctx.over(f"buffers[{i}].byteLength", f"{n} bytes", "max_buffer_bytes")
        lengths.append(n)
    if sum(lengths) > ctx.limits.max_total_bytes:
        raise ctx.over("buffers", f"{sum(lengths)} bytes declared", "max_total_bytes")
    return lengths


@dataclass(frozen=True)
class NoData:
    """A buffer without bytes of its own (no ``uri``, not the GLB BIN chunk): valid JSON, an
    error only where an accessor or image reads it (or meshopt decodes into it)."""

    why: str


def buffer_data(ctx: Ctx, buffers: list, b: int, where: str):
    """The bytes of ``buffers[b]``, or the refusal naming ``where`` (the reader)."""
    data = buffers[b]
    if isinstance(data, NoData):
        raise ctx.fail(where, f"reads buffers[{b}], which {data.why}")
    return data


def load_buffers(ctx: Ctx, doc: dict, bin_chunk: memoryview | None) -> list:
    """Every buffer's bytes, exactly ``byteLength`` long (bytes or memoryview), or
    :class:`NoData` for a buffer with neither uri nor GLB BIN chunk."""
    out = []
    for i, (b, n) in enumerate(zip(get_items(ctx, doc, "buffers"), buffer_lengths(ctx, doc),
                                   strict=True)):
        where = f"buffers[{i}]"
        ctx.where = where
        uri = get_str(ctx, b, "uri", where, default=None)
        if uri is None:
            if bin_chunk is None:
                out.append(NoData("has no uri and the file has no GLB BIN chunk"))
                continue
            if i != 0:
                out.append(NoData("has no uri (only buffers[0] may be the GLB BIN chunk)"))
                continue
            if len(bin_chunk) < n:
                raise ctx.fail(f"{where}.byteLength",
                               f"declares {n} bytes but the GLB BIN chunk has {len(bin_chunk)}")
            ctx.charge(n, where)
            out.append(bin_chunk[:n])
            continue
        data = uri_bytes(ctx, uri, f"{where}.uri", "max_buffer_bytes", want=n)
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


def buffer_view(ctx: Ctx, doc: dict, index: int) -> tuple[int, int, int, int]:
    """(buffer, byteOffset, byteLength, byteStride or 0) of a bufferView, range-checked
    against the buffer's declared byteLength."""
    where = f"bufferViews[{index}]"
    bv = get_items(ctx, doc, "bufferViews")[index]
    b = get_index(ctx, bv, "buffer", where, "buffers")
    off = get_int(ctx, bv, "byteOffset", where, default=0)
    length = get_int(ctx, bv, "byteLength", where, lo=1)
    stride = get_int(ctx, bv, "byteStride", where, default=0)
    if stride and not (4 <= stride <= 252 and stride % 4 == 0):
        raise ctx.fail(f"{where}.byteStride", f"must be a multiple of 4 in [4, 252], got {stride}")
    blen = get_int(ctx, get_items(ctx, doc, "buffers")[b], "byteLength", f"buffers[{b}]", lo=1)
    if off + length > blen:
        raise ctx.fail(where, f"byteOffset {off} + byteLength {length} runs past buffers[{b}] "
                              f"({blen} bytes)")
    return b, off, length, stride


def _sparse_layout(ctx: Ctx, doc: dict, acc: dict, here: str, where: str, count: int,
                   elem: int) -> SparseLayout | None:
    s = get_dict(ctx, acc, "sparse", here, default=None)
    if s is None:
        return None
    sw = f"{here}.sparse"
    n = get_int(ctx, s, "count", sw, lo=1)
    if n > count:
        raise ctx.fail(f"{sw}.count", f"{n} substitutions for an accessor of {count} elements")
    ind = get_dict(ctx, s, "indices", sw)
    iw = f"{sw}.indices"
    ict = get_int(ctx, ind, "componentType", iw)
    if ict not in INDEX_CT:
        raise ctx.fail(f"{iw}.componentType", f"must be 5121, 5123 or 5125, got {ict}")
    ib, ioff, ilen, _ = buffer_view(ctx, doc, get_index(ctx, ind, "bufferView", iw, "bufferViews"))
    io_ = get_int(ctx, ind, "byteOffset", iw, default=0)
    if io_ + n * COMPONENTS[ict][1] > ilen:
        raise ctx.fail(f"{where} {iw}", f"{n} sparse indices do not fit their bufferView")
    val = get_dict(ctx, s, "values", sw)
    vw = f"{sw}.values"
    vb, voff, vlen, _ = buffer_view(ctx, doc, get_index(ctx, val, "bufferView", vw, "bufferViews"))
    vo = get_int(ctx, val, "byteOffset", vw, default=0)
    if vo + n * elem > vlen:
        raise ctx.fail(f"{where} {vw}", f"{n} sparse values do not fit their bufferView")
    return SparseLayout(n, ict, ib, ioff + io_, vb, voff + vo)


def accessor_layout(ctx: Ctx, doc: dict, index: int, use: str, types: tuple[str, ...],
                    components: tuple[int, ...]) -> AccessorLayout:
    """Validate accessor ``index`` for ``use`` (a glTF path) without touching any buffer.

    Checks type/componentType for the use, ``count`` against ``max_accessor_elements`` and
    that ``byteOffset + stride·(count−1) + elementSize`` fits inside its bufferView, which
    itself must fit inside its buffer — all with Python ints, before numpy sees a byte.
    """
    here = f"accessors[{index}]"
    where = f"{use} ({here})" if use else here
    ctx.where = where
    acc = get_items(ctx, doc, "accessors")[index]
    ctype = get_int(ctx, acc, "componentType", here)
    if ctype not in COMPONENTS:
        raise ctx.fail(f"{here}.componentType", f"unknown componentType {ctype}")
    atype = get_str(ctx, acc, "type", here)
    if atype not in TYPE_SIZES:
        raise ctx.fail(f"{here}.type", f"unknown type {show(atype)}")
    if atype not in types:
        raise ctx.fail(where, f"type {atype} where {' or '.join(types)} is expected")
    if ctype not in components:
        raise ctx.fail(where, f"componentType {ctype} is not allowed here")
    count = get_int(ctx, acc, "count", here, lo=1)
    if count > ctx.limits.max_accessor_elements:
        raise ctx.over(where, f"count {count}", "max_accessor_elements")
    normalized = get_bool(ctx, acc, "normalized", here, default=False)
    csize = COMPONENTS[ctype][1]
    if atype.startswith("MAT") and csize < 4:
        raise ctx.unsupported(where, f"{atype} with {csize}-byte components is not supported")
    elem = TYPE_SIZES[atype] * csize
    acc_off = get_int(ctx, acc, "byteOffset", here, default=0)
    bv = get_index(ctx, acc, "bufferView", here, "bufferViews", default=-1)
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


def read_accessor(ctx: Ctx, lay: AccessorLayout, buffers: list) -> np.ndarray:
    """Decode a validated accessor → (count, ncomp) array in its own (native-order) dtype."""
    ctx.where = lay.where
    dt = np.dtype(COMPONENTS[lay.component_type][0])
    native = dt.newbyteorder("=")
    shape = (lay.count, lay.ncomp)
    if lay.buffer < 0:
        out = np.zeros(shape, dtype=native)
    else:
        data = buffer_data(ctx, buffers, lay.buffer, lay.where)
        view = np.ndarray(shape, dtype=dt, buffer=data, offset=lay.byte_offset,
                          strides=(lay.byte_stride, dt.itemsize))
        out = view.astype(native)  # copy, detached from the file bytes
    s = lay.sparse
    if s is not None:
        idt = np.dtype(COMPONENTS[s.index_component][0])
        idx = np.ndarray((s.count,), dtype=idt, offset=s.index_offset,
                         buffer=buffer_data(ctx, buffers, s.index_buffer, lay.where)
                         ).astype(np.int64)
        if idx.max() >= lay.count:
            raise ctx.fail(f"{lay.where} sparse.indices",
                           f"index {int(idx.max())} out of range for {lay.count} elements")
        vals = np.ndarray((s.count, lay.ncomp), dtype=dt, offset=s.value_offset,
                          buffer=buffer_data(ctx, buffers, s.value_buffer, lay.where))
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


def finite_floats(ctx: Ctx, raw: np.ndarray, lay: AccessorLayout) -> np.ndarray:
    out = to_float(raw, lay)
    if np.isnan(out).any():
        raise ctx.fail(lay.where, "contains NaN")
    if np.isinf(out).any():
        raise ctx.fail(lay.where, "contains Inf")
    return out
