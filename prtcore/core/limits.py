"""Configurable intake limits, checked *before* memory is allocated for the asset.

Defaults suit a desktop bake; the service narrows them through its settings. Every field
can be overridden from the environment as ``PRT_LIMIT_<FIELD>`` (e.g.
``PRT_LIMIT_MAX_TRIANGLES=500000``).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

from prtcore.core.errors import SpecError

MiB = 1 << 20


@dataclass(frozen=True)
class IntakeLimits:
    max_file_bytes: int = 512 * MiB  # the .glb/.gltf/.obj/.ply itself
    max_buffer_bytes: int = 512 * MiB  # one buffer (external file or data URI, decoded)
    max_total_bytes: int = 1024 * MiB  # all buffers + images together
    max_data_uri_bytes: int = 64 * MiB  # one data: URI, decoded size
    max_triangles: int = 4_000_000
    max_vertices: int = 8_000_000
    max_nodes: int = 100_000
    max_meshes: int = 10_000
    max_materials: int = 10_000
    max_textures: int = 128
    max_texture_pixels: int = 8192 * 8192  # per image, width * height
    max_animations: int = 1_000
    max_accessor_elements: int = 32_000_000
    max_atlas_resolution: int = 4096
    max_strands: int = 2_000_000  # hair strands in one .hair / USD file
    max_hair_points: int = 32_000_000  # hair polyline points (after tessellating cubics)
    #: estimated peak memory of the bake (prtcore.transport.dataset.estimate_bake_bytes), checked
    #: once the texel space is built, before transport allocates
    max_bake_bytes: int = 16 * 1024 * MiB

    def check_spec(self, spec) -> None:
        """Refuse, before anything is loaded, a spec these limits do not allow
        (:class:`~prtcore.core.errors.SpecError` naming the key and the limit)."""
        if spec.atlas.resolution > self.max_atlas_resolution:
            raise SpecError("atlas.resolution", f"{spec.atlas.resolution} exceeds the "
                            f"configured limit max_atlas_resolution="
                            f"{self.max_atlas_resolution}")

    @classmethod
    def from_env(cls, environ: dict[str, str] | None = None) -> IntakeLimits:
        """Defaults overridden by ``PRT_LIMIT_*`` variables."""
        env = os.environ if environ is None else environ
        kwargs = {}
        for f in dataclasses.fields(cls):
            key = "PRT_LIMIT_" + f.name.upper()
            if key in env:
                kwargs[f.name] = int(env[key])
        return cls(**kwargs)
