"""The viewer page and its static files: what both the local server and the service serve.

The page is ``static/index.html`` with two prefixes filled in: where the static files are
served (``static``) and where the bundle's files are (``bundle``). Both may be relative to
the page's URL; each ends with ``/``.
"""

from __future__ import annotations

import html
from functools import cache
from pathlib import Path

from prtcore.core.errors import PrtError

STATIC = Path(__file__).resolve().parent / "static"
#: Files of the GL runtime the page also loads, under these static paths: one source for
#: a shader both renderers run (``shaders/chiang.glsl``: the Chiang fibre's BCSDF).
SHARED = {"shaders/chiang.glsl":
          Path(__file__).resolve().parents[1] / "runtime" / "shaders" / "chiang.glsl"}

#: Content types of the static files (module scripts need a JavaScript type).
CONTENT_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
                 ".css": "text/css; charset=utf-8", ".json": "application/json",
                 ".exr": "image/x-exr", ".glb": "model/gltf-binary", ".png": "image/png",
                 ".glsl": "text/plain; charset=utf-8"}


def viewer_content_type(name: str) -> str:
    """The Content-Type of a served file by its name (``application/octet-stream`` when the
    suffix is unknown; ``text/plain`` for the licence and checksum files)."""
    suffix = Path(name).suffix.lower()
    if suffix in CONTENT_TYPES:
        return CONTENT_TYPES[suffix]
    return "text/plain; charset=utf-8" if not suffix else "application/octet-stream"


def viewer_page(static: str, bundle: str, reference: str = "") -> str:
    """The viewer page (HTML) with its static files at ``static``, the bundle at ``bundle``
    and, optionally, a path-traced reference at ``reference`` (``reference.exr``, the
    indirect lightmap of ``prtcore reference``, and ``light.json``, its light): URL prefixes
    ending with ``/``; ``reference`` empty for none."""
    for what, prefix in (("static", static), ("bundle", bundle), ("reference", reference)):
        if not prefix.endswith("/") and (prefix or what != "reference"):
            raise PrtError(f"viewer page: the {what} prefix {prefix!r} must end with '/'")
    text = (STATIC / "index.html").read_text(encoding="utf-8")
    for key, value in (("STATIC", static), ("BUNDLE", bundle), ("REFERENCE", reference)):
        text = text.replace("{{" + key + "}}", html.escape(value))
    return text


@cache
def static_files() -> frozenset[str]:
    """Relative paths (``/``-separated) of every file the viewer may serve from static/;
    nothing else under that name is served."""
    return frozenset(p.relative_to(STATIC).as_posix() for p in STATIC.rglob("*")
                     if p.is_file() and p.name != "index.html") | frozenset(SHARED)


def viewer_static_path(relative: str) -> Path | None:
    """The file of a static path, or None when it is not one of :func:`static_files`."""
    if relative in SHARED:
        return SHARED[relative]
    return STATIC / relative if relative in static_files() else None
