"""Surface albedo for transport: baseColorFactor × baseColorTexture (docs/bundle.md).

The one place where albedo is evaluated; texels, measurement points, the fast transport
and the reference tracer all call :func:`albedo_at`.
"""

from __future__ import annotations

import numpy as np

from prtcore.core.scene import Scene, Texture
from prtcore.core.tolerances import ALBEDO_MAX

REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT = 10497, 33071, 33648


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] → linear, same shape, float32."""
    c = np.asarray(c, dtype=np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    c = np.clip(np.asarray(c, dtype=np.float32), 0.0, None)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055).astype(np.float32)


def _wrap(coord: np.ndarray, n: int, mode: int) -> np.ndarray:
    """Integer texel coordinates wrapped by a glTF sampler mode."""
    if mode == CLAMP_TO_EDGE:
        return np.clip(coord, 0, n - 1)
    if mode == MIRRORED_REPEAT:
        period = 2 * n
        c = np.mod(coord, period)
        return np.where(c >= n, period - 1 - c, c)
    return np.mod(coord, n)


def sample_texture(tex: Texture, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup. uv : (n, 2) float64 glTF UVs (origin top-left). Returns (n, 4) float64."""
    h, w = tex.pixels.shape[:2]
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    xs0, xs1 = _wrap(x0, w, tex.wrap_s), _wrap(x0 + 1, w, tex.wrap_s)
    ys0, ys1 = _wrap(y0, h, tex.wrap_t), _wrap(y0 + 1, h, tex.wrap_t)
    p = tex.pixels
    top = p[ys0, xs0] * (1 - fx) + p[ys0, xs1] * fx
    bot = p[ys1, xs0] * (1 - fx) + p[ys1, xs1] * fx
    return (top * (1 - fy) + bot * fy).astype(np.float64)


def albedo_at(scene: Scene, triangle: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
    """Raw (unclamped) linear RGB albedo at surface points.

    triangle : (n,) int face indices; barycentric : (n, 3) float weights of the face's
    three vertices. Returns (n, 3) float64.
    """
    triangle = np.asarray(triangle, dtype=np.int64)
    out = np.empty((len(triangle), 3), dtype=np.float64)
    if len(triangle) == 0:
        return out
    mat_of = scene.face_material[triangle]
    for m in np.unique(mat_of):
        sel = np.nonzero(mat_of == m)[0]
        mat = scene.materials[int(m)]
        col = np.broadcast_to(mat.base_color_factor[:3], (len(sel), 3)).astype(np.float64)
        if mat.texture >= 0:
            uvsrc = scene.uv0 if mat.texcoord == 0 or scene.uv1 is None else scene.uv1
            f = scene.faces[triangle[sel]]
            uv = np.einsum("nk,nkj->nj", barycentric[sel], uvsrc[f])
            uvh = np.concatenate([uv, np.ones((len(sel), 1))], axis=1) @ mat.uv_transform.T
            col = col * sample_texture(scene.textures[mat.texture], uvh[:, :2])[:, :3]
        out[sel] = col
    return out


def clamp_albedo(albedo: np.ndarray) -> tuple[np.ndarray, int]:
    """Clamp to [0, ALBEDO_MAX] per channel for transport.

    Returns the clamped (n, 3) array and how many values were clamped above (to report).
    """
    over = int(np.count_nonzero(albedo > ALBEDO_MAX))
    return np.clip(albedo, 0.0, ALBEDO_MAX), over
