"""The GLSL of the GL runtime (:mod:`prtcore.runtime.gl`): package data in
``prtcore/runtime/shaders/*.glsl``, read with :mod:`importlib.resources`.

Two directives are resolved here, before the driver's compiler sees the source:
``#include "name.glsl"`` (a whole line) is replaced by that file — ``lights.glsl`` (the
light table, KHR_lights_punctual irradiance and shadow-map visibility) and ``blend.glsl``
(the basis blend, :func:`prtcore.runtime.cpu.blend` on the GPU) are shared this way — and
the ``defines`` of :func:`shader_source` become ``#define NAME value`` lines right after
``#version``.
"""

from __future__ import annotations

import functools
import re
from importlib.resources import files

_INCLUDE = re.compile(r'^#include "([A-Za-z0-9_]+\.glsl)"[ \t]*$', re.MULTILINE)


@functools.cache
def shader_file(name: str) -> str:
    """The text of ``prtcore/runtime/shaders/<name>`` as stored."""
    return files("prtcore.runtime").joinpath("shaders", name).read_text(encoding="utf-8")


def shader_source(name: str, **defines: int | float) -> str:
    """The shader ``name`` ready to compile: includes resolved (recursively; a file is
    included at most once per shader) and ``defines`` as ``#define`` lines after
    ``#version``."""
    seen: set[str] = set()

    def expand(text: str) -> str:
        def one(m: re.Match) -> str:
            inc = m.group(1)
            if inc in seen:
                return ""
            seen.add(inc)
            return expand(shader_file(inc)).rstrip("\n")

        return _INCLUDE.sub(one, text)

    text = expand(shader_file(name))
    if defines:
        head, sep, rest = text.partition("\n")
        if not head.startswith("#version"):
            raise ValueError(f"{name}: defines need a #version line first")
        text = head + sep + "".join(f"#define {k} {v}\n" for k, v in defines.items()) + rest
    return text
