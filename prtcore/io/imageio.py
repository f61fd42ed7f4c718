"""Image files through OpenImageIO: EXR (linear, row 0 at the top) and PNG."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from prtcore.core.errors import PrtError

#: The EXR DateTime attribute written on every file (see write_exr).
REPRODUCIBLE_DATETIME = "1980:01:01 00:00:00"
#: Row order of every EXR written here: row 0 is the top row of the image (the manifest's
#: ``atlas.exr_row_order``). three.js's EXRLoader stores scanlines bottom-up, so the web
#: viewer samples a top-down file at (u, 1 - v).
EXR_ROW_ORDER = "top_down"
#: EXR compressions the writer accepts: lossless ones that three.js r187's EXRLoader decodes
#: (the web viewer reads the bundle's EXRs). Refused: the lossy B44/B44A, DWAA/DWAB and
#: PXR24 (a basis plane must round-trip exactly) and HTJ2K (EXRLoader cannot decode it).
EXR_COMPRESSIONS = ("none", "rle", "zips", "zip", "piz")


def write_exr(path: str | Path, image: np.ndarray, dtype: str = "float",
              channel_names: tuple[str, ...] | None = None, compression: str = "zip") -> None:
    """Write (h, w, c) float data as a scanline EXR. dtype "half" or "float"; compression one
    of :data:`EXR_COMPRESSIONS` (zip by default: what browsers' EXRLoader reads).

    Row 0 of ``image`` is the top row of the file (:data:`EXR_ROW_ORDER`). Non-finite values
    are refused.
    """
    if compression not in EXR_COMPRESSIONS:
        raise PrtError(f"{path}: EXR compression {compression!r} is not written (lossy or not "
                       f"decodable by the web viewer); use one of {', '.join(EXR_COMPRESSIONS)}")
    if dtype not in ("half", "float"):
        raise PrtError(f"{path}: EXR dtype {dtype!r}; expected half or float")
    image = np.asarray(image, dtype=np.float32)
    if image.ndim == 2:
        image = image[:, :, None]
    if not np.isfinite(image).all():
        raise PrtError(f"{path}: refusing to write non-finite values to an EXR")
    h, w, c = image.shape
    fmt = oiio.HALF if dtype == "half" else oiio.FLOAT
    spec = oiio.ImageSpec(w, h, c, fmt)
    spec.attribute("compression", compression)
    # OpenImageIO stamps the write time otherwise; a fixed stamp keeps bundles bit-identical
    # for the same asset + spec + seed.
    spec.attribute("DateTime", REPRODUCIBLE_DATETIME)
    if channel_names is None:
        channel_names = ("R", "G", "B", "A")[:c] if c <= 4 else tuple(f"c{i}" for i in range(c))
    spec.channelnames = tuple(channel_names)
    if c == 4:
        spec.alpha_channel = 3
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise PrtError(f"{path}: cannot create image writer: {oiio.geterror()}")
    try:
        if not out.open(str(path), spec):
            raise PrtError(f"{path}: cannot open for writing: {out.geterror()}")
        if not out.write_image(image):
            raise PrtError(f"{path}: write failed: {out.geterror()}")
    finally:
        out.close()


def _open(path: str | Path):
    """An OpenImageIO input for ``path`` (the caller closes it); errors name the file."""
    if not os.path.exists(path):
        raise PrtError(f"{path}: no such file")
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise PrtError(f"{path}: cannot read image: {oiio.geterror()}")
    return inp


def image_size(path: str | Path) -> tuple[int, int, int]:
    """(height, width, channels) of an image file, from its header (no pixels read)."""
    inp = _open(path)
    try:
        spec = inp.spec()
        return spec.height, spec.width, spec.nchannels
    finally:
        inp.close()


def read_image(path: str | Path) -> np.ndarray:
    """Read any image OpenImageIO knows as (h, w, c) float32 (row 0 = top)."""
    inp = _open(path)
    try:
        data = inp.read_image(format=oiio.FLOAT)
    finally:
        inp.close()
    if data is None:
        raise PrtError(f"{path}: cannot decode image")
    return np.asarray(data, dtype=np.float32).reshape(
        inp.spec().height, inp.spec().width, inp.spec().nchannels)


def write_png(path: str | Path, rgb8: np.ndarray) -> None:
    """Write (h, w, 3|4) uint8 as PNG."""
    rgb8 = np.ascontiguousarray(rgb8, dtype=np.uint8)
    h, w, c = rgb8.shape
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise PrtError(f"{path}: cannot create image writer: {oiio.geterror()}")
    try:
        if not out.open(str(path), oiio.ImageSpec(w, h, c, oiio.UINT8)):
            raise PrtError(f"{path}: cannot open for writing: {out.geterror()}")
        out.write_image(rgb8)
    finally:
        out.close()
