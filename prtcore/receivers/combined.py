"""Two receivers baked together: a mesh's lightmap texels and a hair's strand texels (a
hair + mesh bake, docs/hair.md).

Elements are numbered mesh first: i < T_m is atlas texel i of ``mesh``
(:class:`~prtcore.receivers.texels.TexelSpace`), i ≥ T_m is strand texel i − T_m of
``strands`` (:class:`~prtcore.receivers.strands.StrandSpace`). One fit drives both (one
transfer matrix, one set of measurement points); the basis is stored as two images, the
lightmap atlas (:meth:`CombinedSpace.to_image`, the receiver's image as the method writes
it) and the strand texture (:meth:`CombinedSpace.strand_image`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from prtcore.receivers.strands import StrandSpace
from prtcore.receivers.texels import TexelSpace


@dataclass(frozen=True, eq=False)
class CombinedSpace:
    """The atlas texels of ``mesh`` then the strand texels of ``strands``. ``position``,
    ``normal``, ``albedo`` (t, 3) and ``footprint`` (t, 2, 3) float64 stack both's;
    ``width``, ``height`` are the atlas's (the image :meth:`to_image` makes)."""

    mesh: TexelSpace
    strands: StrandSpace
    position: np.ndarray = field(init=False)
    normal: np.ndarray = field(init=False)
    albedo: np.ndarray = field(init=False)
    footprint: np.ndarray = field(init=False)

    kind: ClassVar[str] = "texels+strands"

    def __post_init__(self):
        for name in ("position", "normal", "albedo", "footprint"):
            object.__setattr__(self, name, np.concatenate([
                np.asarray(getattr(self.mesh, name), np.float64),
                np.asarray(getattr(self.strands, name), np.float64)]))

    @property
    def count(self) -> int:
        return self.mesh.count + self.strands.count

    @property
    def width(self) -> int:
        return self.mesh.width

    @property
    def height(self) -> int:
        return self.mesh.height

    def _split(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        values = np.asarray(values)
        if values.shape[0] != self.count:
            raise ValueError(f"CombinedSpace: values must have {self.count} rows "
                             f"({self.mesh.count} atlas + {self.strands.count} strand "
                             f"texels), got {values.shape}")
        return values[:self.mesh.count], values[self.mesh.count:]

    def to_image(self, values: np.ndarray, dilate: bool = True) -> np.ndarray:
        """The atlas image of the mesh's rows (the lightmap: (H, W, c + 1) float32,
        :meth:`TexelSpace.to_image`)."""
        return self.mesh.to_image(self._split(values)[0], dilate=dilate)

    def strand_image(self, values: np.ndarray) -> np.ndarray:
        """The strand texture of the hair's rows (:meth:`StrandSpace.to_image`)."""
        return self.strands.to_image(self._split(values)[1])
