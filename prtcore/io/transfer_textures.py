"""Transfer textures on disk (issue 17, docs/sh_prt.md): SH transfer vectors per lightmap
texel as RGBA EXRs, ``sh_transfer_{R,G,B}_{k:02d}.exr`` holding coefficients 4k .. 4k+3 of
that colour channel (the last file of a channel zero-padded), dilated by the writer's
caller (the atlas image it is given)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from prtcore.io.imageio import read_image, write_exr


def transfer_texture_names(bands: int) -> list[str]:
    """The file names of ``bands`` bands, R files first."""
    return [f"sh_transfer_{c}_{k:02d}.exr" for c in "RGB"
            for k in range(math.ceil(bands * bands / 4))]


def write_transfer_textures(directory: Path, image: np.ndarray, dtype: str = "half"
                            ) -> list[str]:
    """Write the atlas ``image`` (H, W, 3, L²) float; returns the file names."""
    h, w, _, n = image.shape
    names = transfer_texture_names(math.isqrt(n))
    files = len(names) // 3
    for i, name in enumerate(names):
        c, k = divmod(i, files)
        block = np.zeros((h, w, 4), np.float32)
        part = image[:, :, c, 4 * k:4 * k + 4]
        block[:, :, :part.shape[2]] = part
        write_exr(directory / name, block, dtype=dtype)  # R, G, B, A = 4k .. 4k+3
    return names


def read_transfer_textures(directory: Path, bands: int) -> np.ndarray:
    """The (H, W, 3, L²) float32 image written by :func:`write_transfer_textures`."""
    names = transfer_texture_names(bands)
    files = len(names) // 3
    imgs = [read_image(Path(directory) / name) for name in names]
    return np.stack([np.concatenate(imgs[c * files:(c + 1) * files], axis=2)[:, :, :bands ** 2]
                     for c in range(3)], axis=2)
