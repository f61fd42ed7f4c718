"""URIs of buffers and images: ``data:`` URIs (size checked before decoding) and relative
paths confined to the asset's folder (size checked before reading)."""

from __future__ import annotations

import base64
import binascii
import os
import re
import stat
import urllib.parse

from prtcore.io.gltf.schema import Ctx, show

_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*:")
_BASE64 = re.compile(r"[A-Za-z0-9+/]*={0,2}")
_DATA_URI = re.compile(r"^data:([^,]*),(.*)$", re.DOTALL)


def resolve_uri(ctx: Ctx, uri: str, where: str) -> str:
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
        raise ctx.fail(where, f"absolute path {show(uri)} is not allowed")
    parts = re.split(r"[/\\]", decoded)
    if ".." in parts:
        raise ctx.fail(where, f"'..' in {show(uri)}: URIs may not leave the asset's folder")
    parts = [p for p in parts if p not in ("", ".")]
    if not parts:
        raise ctx.fail(where, "URI names no file")
    real = os.path.realpath(os.path.join(ctx.folder, *parts))
    if os.path.commonpath([real, ctx.folder]) != ctx.folder:
        raise ctx.fail(where, f"{show(uri)} resolves outside the asset's folder (symlink)")
    return real


def read_local_file(ctx: Ctx, real: str, where: str, limit: str, want: int | None = None
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


def data_uri_size(ctx: Ctx, uri: str, where: str) -> tuple[int, str]:
    """Decoded size of a base64 ``data:`` URI computed from its length, and its payload."""
    m = _DATA_URI.match(uri)
    if m is None:
        raise ctx.fail(where, "malformed data: URI (no comma)")
    params = [p.strip().lower() for p in m.group(1).split(";")[1:]]
    if "base64" not in params:
        raise ctx.unsupported(where, "only base64 data: URIs are supported")
    payload = m.group(2)
    if _BASE64.fullmatch(payload) is None:
        raise ctx.fail(where, "malformed base64 in data: URI")
    if len(payload) % 4:
        raise ctx.fail(where, "malformed base64 in data: URI (length not a multiple of 4)")
    pad = len(payload) - len(payload.rstrip("="))
    if pad > 2:
        raise ctx.fail(where, "malformed base64 in data: URI (too much padding)")
    return len(payload) // 4 * 3 - pad, payload


def decode_data_uri(ctx: Ctx, uri: str, where: str, limit: str, want: int | None = None
                    ) -> bytes:
    """Decode a base64 ``data:`` URI after checking its decoded size against
    ``max_data_uri_bytes`` and ``limit`` (and the total budget), and, for a buffer, against
    its ``byteLength`` ``want`` (they must be equal, as the Khronos validator requires)."""
    size, payload = data_uri_size(ctx, uri, where)
    if want is not None and size != want:
        raise ctx.fail(where, f"data: URI decodes to {size} bytes but the buffer's byteLength "
                              f"is {want} (they must be equal)")
    if size > ctx.limits.max_data_uri_bytes:
        raise ctx.over(where, f"data: URI decodes to {size} bytes", "max_data_uri_bytes")
    if size > getattr(ctx.limits, limit):
        raise ctx.over(where, f"data: URI decodes to {size} bytes", limit)
    ctx.charge(size, where)
    try:
        return base64.b64decode(payload, validate=True)
    except (binascii.Error, ValueError):
        raise ctx.fail(where, "malformed base64 in data: URI") from None


def uri_bytes(ctx: Ctx, uri: str, where: str, limit: str, want: int | None = None) -> bytes:
    if uri.startswith("data:"):
        return decode_data_uri(ctx, uri, where, limit, want)
    return read_local_file(ctx, resolve_uri(ctx, uri, where), where, limit, want)
