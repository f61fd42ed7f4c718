"""Receive ``POST /v1/bakes`` bodies as a stream, enforcing limits while bytes arrive.

The multipart body is parsed incrementally (python-multipart's push parser): the asset part
is written to a staging file and hashed as it comes, and the request is refused with 413 the
moment the asset passes ``max_upload_bytes`` (or the spec ``max_spec_bytes``) — before the
rest is read, never after storing it. A declared ``Content-Length`` that is already too
large is refused before reading anything. The staging folder is removed on any refusal.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from fastapi import Request
from python_multipart import MultipartParser
from python_multipart.multipart import parse_options_header

from jobs.config import Settings

from .errors import ApiError

#: glTF, and hair (docs/hair.md): cyHair .hair and self-contained USD BasisCurves
ASSET_SUFFIXES = (".glb", ".gltf", ".hair", ".usd", ".usda", ".usdc")
FIELDS = ("asset", "spec", "mesh")
#: the optional ``mesh`` part of a hair bake (docs/hair.md): a glTF baked with the hair
MESH_SUFFIXES = (".glb", ".gltf")
_MULTIPART_OVERHEAD = 64 * 1024


@dataclass
class Upload:
    """What a bake submission carried, staged on disk."""

    folder: Path
    asset_path: Path | None = None
    asset_name: str = ""  # the name it is stored under: ``asset`` + suffix
    original_name: str = ""  # the name it was uploaded under, sanitised (safe_filename)
    asset_bytes: int = 0
    asset_sha256: str = ""
    spec_bytes: bytes = b""
    spec_seen: bool = False
    #: the optional mesh baked with a hair asset: stored as ``mesh`` + suffix
    mesh_path: Path | None = None
    mesh_name: str = ""
    mesh_bytes: int = 0
    mesh_sha256: str = ""
    _hash: object = field(default=None, repr=False)
    _mesh_hash: object = field(default=None, repr=False)

    def discard(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


def _safe_suffix(filename: str, part: str = "asset",
                 allowed: tuple[str, ...] = ASSET_SUFFIXES) -> str:
    """The checked, lowercase file type of an uploaded ``part``, one of ``allowed``."""
    suffix = os.path.splitext(filename)[1].lower()
    if suffix not in allowed:
        raise ApiError(422, "invalid_asset",
                       f"{part} {_clean(filename)!r}: unsupported file type "
                       f"{suffix or '(none)'!r} (expected {', '.join(allowed)})")
    return suffix


def _clean(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._ -]", "_", name)[:120]


def safe_filename(filename: str, suffix: str, limit: int = 120) -> str:
    """The uploaded file's name, safe to keep, show and use as a file name: the last path
    segment only, every run of characters outside ``A-Za-z0-9._-`` made one ``_``, no
    leading dot, at most ``limit`` characters, ending in ``suffix`` (the checked, lowercase
    type). ``asset`` + suffix when nothing is left."""
    base = re.split(r"[\\/]", filename)[-1]
    stem = base[:len(base) - len(os.path.splitext(base)[1])]
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", stem).lstrip(".").rstrip(".")
    stem = stem[:max(1, limit - len(suffix))].rstrip(".")
    return (stem or "asset") + suffix


async def receive(request: Request, settings: Settings) -> Upload:
    """Stream the request body into an :class:`Upload`; raise :class:`ApiError` on any
    refusal (the staging folder is gone by then)."""
    ctype, params = parse_options_header(request.headers.get("content-type", ""))
    if ctype != b"multipart/form-data" or not params.get(b"boundary"):
        raise ApiError(415, "unsupported_media_type",
                       "expected multipart/form-data with parts 'asset' (file) and 'spec' "
                       "(JSON), and for hair optionally 'mesh' (a glTF file)")
    limit = settings.max_upload_bytes
    declared = request.headers.get("content-length")
    if declared is not None:
        try:
            n = int(declared)
        except ValueError:
            raise ApiError(400, "bad_request", "invalid Content-Length") from None
        if n > limit + settings.max_spec_bytes + _MULTIPART_OVERHEAD:
            raise ApiError(413, "too_large", f"request of {n} bytes exceeds the upload limit "
                                             f"max_upload_bytes={limit}")
    settings.uploads.mkdir(parents=True, exist_ok=True)
    up = Upload(folder=settings.uploads / uuid.uuid4().hex)
    up.folder.mkdir()
    state: dict = {"headers": {}, "field": None, "name": b"", "value": b"", "file": None,
                   "error": None}

    def on_header_field(data: bytes, start: int, end: int) -> None:
        state["name"] += data[start:end]

    def on_header_value(data: bytes, start: int, end: int) -> None:
        state["value"] += data[start:end]

    def on_header_end() -> None:
        state["headers"][state["name"].lower()] = state["value"]
        state["name"], state["value"] = b"", b""

    def on_headers_finished() -> None:
        disp, opts = parse_options_header(state["headers"].get(b"content-disposition", b""))
        name = opts.get(b"name", b"").decode("utf-8", "replace")
        if disp != b"form-data" or name not in FIELDS:
            raise ApiError(422, "unknown_field", f"unexpected form field {_clean(name)!r} "
                                                 f"(expected: {', '.join(FIELDS)})")
        state["field"] = name
        if name == "asset":
            if up.asset_path is not None:
                raise ApiError(422, "duplicate_field", "more than one 'asset' part")
            filename = opts.get(b"filename", b"").decode("utf-8", "replace")
            suffix = _safe_suffix(filename)
            up.asset_name = "asset" + suffix
            up.original_name = safe_filename(filename, suffix)
            up.asset_path = up.folder / up.asset_name
            state["file"] = open(up.asset_path, "wb")
            up._hash = hashlib.sha256()
        elif name == "mesh":
            if up.mesh_path is not None:
                raise ApiError(422, "duplicate_field", "more than one 'mesh' part")
            filename = opts.get(b"filename", b"").decode("utf-8", "replace")
            up.mesh_name = "mesh" + _safe_suffix(filename, "mesh", MESH_SUFFIXES)
            up.mesh_path = up.folder / up.mesh_name
            state["file"] = open(up.mesh_path, "wb")
            up._mesh_hash = hashlib.sha256()
        else:
            if up.spec_seen:
                raise ApiError(422, "duplicate_field", "more than one 'spec' part")
            up.spec_seen = True

    def on_part_data(data: bytes, start: int, end: int) -> None:
        chunk = data[start:end]
        if state["field"] in ("asset", "mesh"):  # one limit for the files together
            if state["field"] == "asset":
                up.asset_bytes += len(chunk)
                up._hash.update(chunk)  # type: ignore[attr-defined]
            else:
                up.mesh_bytes += len(chunk)
                up._mesh_hash.update(chunk)  # type: ignore[attr-defined]
            if up.asset_bytes + up.mesh_bytes > limit:
                raise ApiError(413, "too_large", f"{state['field']} exceeds the upload "
                                                 f"limit max_upload_bytes={limit}")
            state["file"].write(chunk)
        else:
            up.spec_bytes += chunk
            if len(up.spec_bytes) > settings.max_spec_bytes:
                raise ApiError(413, "too_large", f"spec exceeds the limit "
                                                 f"max_spec_bytes={settings.max_spec_bytes}")

    def on_part_end() -> None:
        if state["file"] is not None:
            state["file"].close()
            state["file"] = None
        state["headers"], state["field"] = {}, None

    parser = MultipartParser(params[b"boundary"], callbacks={
        "on_header_field": on_header_field, "on_header_value": on_header_value,
        "on_header_end": on_header_end, "on_headers_finished": on_headers_finished,
        "on_part_data": on_part_data, "on_part_end": on_part_end,
    })
    try:
        async for chunk in request.stream():
            parser.write(chunk)
        parser.finalize()
    except ApiError:
        _close(state)
        up.discard()
        raise
    except Exception as e:  # malformed multipart, client went away
        _close(state)
        up.discard()
        raise ApiError(400, "bad_request", f"malformed multipart body: {e}"[:300]) from None
    _close(state)
    if up.asset_path is None or not up.asset_path.is_file():
        up.discard()
        raise ApiError(422, "missing_asset", "the 'asset' file part is required")
    up.asset_sha256 = up._hash.hexdigest()  # type: ignore[attr-defined]
    if up.mesh_path is not None:
        up.mesh_sha256 = up._mesh_hash.hexdigest()  # type: ignore[attr-defined]
    return up


def _close(state: dict) -> None:
    if state["file"] is not None:
        state["file"].close()
        state["file"] = None
