"""The receiver interface: where indirect light is stored and what the runtime samples.

A receiver is a set of *receiver elements* — lightmap texels today; hair strand texels
(strand index × arc length, paper 6.3) next — each with a world position, a unit shading
normal, an albedo and a world-space footprint. Transport operators gather light at these
elements (:mod:`prtcore.transport.base`), the fit stores one value per element per basis
vector, and the receiver says how those values become the images an engine samples.

Members: :class:`prtcore.receivers.texels.TexelSpace` (``kind = "texels"``). A strand
receiver is a new module here, ``prtcore/receivers/strands.py``, satisfying the same
protocol (with no triangle or UV: the runtime samples it by strand and arc length).
"""

from __future__ import annotations

from typing import ClassVar, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Receiver(Protocol):
    """What transport and the fit need of a receiver (arrays float64 unless stated).

    kind : the member's name, written to the manifest with its layout
    count : number of elements t
    position : (t, 3) world positions; normal : (t, 3) unit shading normals
    albedo : (t, 3) raw linear albedo (clamped for transport by core.materials)
    footprint : (t, 2, 3) world extent of one element step along its two axes
    width, height : the size of the image the elements are stored in
    """

    kind: ClassVar[str]

    @property
    def count(self) -> int: ...

    position: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    footprint: np.ndarray
    width: int
    height: int

    def to_image(self, values: np.ndarray, dilate: bool = True) -> np.ndarray:
        """Per-element values (t, c) → the stored image (height, width, c + 1), the last
        channel 1 where an element is stored (coverage)."""
        ...
