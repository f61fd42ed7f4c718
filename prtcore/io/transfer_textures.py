"""Transfer textures on disk (issue 17, docs/sh_prt.md): SH vectors per lightmap texel as
RGBA EXRs, ``{prefix}_{channel}_{k:02d}.exr`` holding coefficients 4k .. 4k+3 of that
channel (the last file of a channel zero-padded), dilated by the writer's caller (the atlas
image it is given). The diffuse transfer has channels R, G, B (prefix ``sh_transfer``); the
glossy layer's visibility (TP) one channel V (prefix ``sh_visibility``)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from prtcore.io.imageio import read_image, write_exr

#: (prefix, channel names) of the two kinds of transfer texture
TRANSFER = ("sh_transfer", "RGB")
VISIBILITY = ("sh_visibility", "V")


def transfer_texture_names(bands: int, kind: tuple[str, str] = TRANSFER) -> list[str]:
    """The file names of ``bands`` bands, the first channel's files first."""
    prefix, channels = kind
    return [f"{prefix}_{c}_{k:02d}.exr" for c in channels
            for k in range(math.ceil(bands * bands / 4))]


def write_transfer_textures(directory: Path, image: np.ndarray, dtype: str = "half",
                            kind: tuple[str, str] = TRANSFER) -> list[str]:
    """Write the atlas ``image`` (H, W, C, L²) float (C = the kind's channels); returns the
    file names."""
    h, w, _, n = image.shape
    names = transfer_texture_names(math.isqrt(n), kind)
    files = len(names) // len(kind[1])
    for i, name in enumerate(names):
        c, k = divmod(i, files)
        block = np.zeros((h, w, 4), np.float32)
        part = image[:, :, c, 4 * k:4 * k + 4]
        block[:, :, :part.shape[2]] = part
        write_exr(directory / name, block, dtype=dtype)  # R, G, B, A = 4k .. 4k+3
    return names


def read_transfer_textures(directory: Path, bands: int, kind: tuple[str, str] = TRANSFER
                           ) -> np.ndarray:
    """The (H, W, C, L²) float32 image written by :func:`write_transfer_textures`."""
    names = transfer_texture_names(bands, kind)
    files = len(names) // len(kind[1])
    imgs = [read_image(Path(directory) / name) for name in names]
    return np.stack([np.concatenate(imgs[c * files:(c + 1) * files], axis=2)[:, :, :bands ** 2]
                     for c in range(len(kind[1]))], axis=2)
