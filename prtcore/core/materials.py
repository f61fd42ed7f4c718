"""Surface albedo for transport: baseColorFactor × baseColorTexture (docs/bundle.md),
and the translucent materials' media (docs/subsurface.md).

The one place where albedo is evaluated; texels, measurement points, the fast transport
and the reference tracer all call :func:`albedo_at`. The one place where a translucent
material's medium is derived from its colour and mean free path:
:func:`subsurface_medium` (the multiple- to single-scattering albedo inversion,
:func:`single_scattering_albedo`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from prtcore.core.errors import SpecError
from prtcore.core.scene import Scene, Subsurface, Texture
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


def texcoords(scene: Scene, texcoord: int) -> np.ndarray:
    """(v, 2) float64 vertex UVs of set TEXCOORD_``texcoord`` (TEXCOORD_0 when the scene
    has no TEXCOORD_1)."""
    return scene.uv0 if texcoord == 0 or scene.uv1 is None else scene.uv1


def texture_uv(scene: Scene, texcoord: int, uv_transform: np.ndarray, triangle: np.ndarray,
               barycentric: np.ndarray) -> np.ndarray:
    """Texture coordinates (n, 2) float64 at surface points (triangle (n,), barycentric
    (n, 3)): set ``texcoord`` interpolated, then ``uv_transform`` (3, 3) applied."""
    f = scene.faces[triangle]
    uv = np.einsum("nk,nkj->nj", barycentric, texcoords(scene, texcoord)[f])
    uvh = np.concatenate([uv, np.ones((len(triangle), 1))], axis=1) @ uv_transform.T
    return uvh[:, :2]


def tangent_space_normals(scene: Scene, material: int, triangle: np.ndarray,
                          barycentric: np.ndarray) -> np.ndarray:
    """The normal map of material ``material`` at surface points: unit tangent-space
    normals (n, 3) float64, ``(2·rgb − 1)`` with X and Y times ``normal_scale``
    (glTF normalTexture: +X right, +Y up on the image, +Z out of the surface)."""
    mat = scene.materials[material]
    uv = texture_uv(scene, mat.normal_texcoord, mat.normal_uv_transform, triangle,
                    barycentric)
    v = 2.0 * sample_texture(scene.textures[mat.normal_texture], uv)[:, :3] - 1.0
    v[:, :2] *= float(mat.normal_scale)
    ln = np.linalg.norm(v, axis=1, keepdims=True)
    return np.divide(v, ln, out=np.tile([0.0, 0.0, 1.0], (len(v), 1)), where=ln > 0)


def albedo_at(scene: Scene, triangle: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
    """Raw (unclamped) linear RGB albedo at surface points.

    triangle : (n,) int face indices; barycentric : (n, 3) float weights of the face's
    three vertices. Returns (n, 3) float64.

    On a translucent material (``Material.subsurface``) this is the albedo of its
    symmetric Lambertian boundary, the same on both sides and for reflection and
    transmission alike: ``ρ_b = ½ ((1 − t) · base + t · transmission colour)``, at most
    ALBEDO_MAX / 2 so that reflection and transmission together stay below ALBEDO_MAX
    (docs/subsurface.md).
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
            uv = texture_uv(scene, mat.texcoord, mat.uv_transform, triangle[sel],
                            barycentric[sel])
            col = col * sample_texture(scene.textures[mat.texture], uv)[:, :3]
        if mat.subsurface is not None:
            col = boundary_albedo(mat.subsurface, col)
        out[sel] = col
    return out


def boundary_albedo(medium: Subsurface, base: np.ndarray) -> np.ndarray:
    """The symmetric boundary albedo ``½ ((1 − t) · base + t · c_t)`` (n, 3) float64 of a
    translucent material whose base colour is ``base`` (n, 3), clipped to ALBEDO_MAX / 2."""
    t = float(medium.transmission)
    ct = np.asarray(medium.transmission_color, np.float64)
    return np.clip(0.5 * ((1.0 - t) * base + t * ct), 0.0, 0.5 * ALBEDO_MAX)


def single_scattering_albedo(multiple: np.ndarray) -> np.ndarray:
    """The single-scattering albedo α of a medium whose multiple-scattering albedo (the
    colour a thick slab of it shows under diffuse light) is ``multiple``, by the fit of
    Chiang, Kutz & Burley 2016 ("Practical and controllable subsurface scattering for
    production path tracing", SIGGRAPH Talks; the one Cycles' random walk used):
    ``α = 1 − exp(−5.09406 A + 2.61188 A² − 4.31805 A³)``. Fitted for isotropic
    scattering. multiple : any shape, in [0, 1]; returns float64 of the same shape."""
    a = np.clip(np.asarray(multiple, dtype=np.float64), 0.0, 1.0)
    return 1.0 - np.exp(a * (-5.09406 + a * (2.61188 - a * 4.31805)))


def multiple_scattering_albedo(single: np.ndarray) -> np.ndarray:
    """The inverse of :func:`single_scattering_albedo` (bisection to float64 round-off; the
    fit is increasing on [0, 1]). single : any shape in [0, 1]; returns float64."""
    a = np.clip(np.asarray(single, dtype=np.float64), 0.0, 1.0)
    lo, hi = np.zeros_like(a), np.ones_like(a)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        below = single_scattering_albedo(mid) < a
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def subsurface_medium(multiple_albedo, mean_free_path, anisotropy: float = 0.0,
                      transmission: float = 0.5, transmission_color=(1.0, 1.0, 1.0)
                      ) -> Subsurface:
    """A translucent material's medium from its colour and mean free path: σ_t = 1/ℓ per
    channel (ℓ the mean free path, world units; ∞ → σ_t = 0), α =
    :func:`single_scattering_albedo` of the multiple-scattering albedo, σ_s = α σ_t,
    σ_a = (1 − α) σ_t. multiple_albedo, mean_free_path, transmission_color : 3 numbers
    each (or one for all channels)."""
    a = np.broadcast_to(np.asarray(multiple_albedo, np.float64), (3,)).copy()
    mfp = np.broadcast_to(np.asarray(mean_free_path, np.float64), (3,)).copy()
    tc = np.broadcast_to(np.asarray(transmission_color, np.float64), (3,)).copy()
    return Subsurface(sigma_t=1.0 / mfp, albedo=single_scattering_albedo(a),
                      anisotropy=float(anisotropy), transmission=float(transmission),
                      transmission_color=tc)


def translucent_faces(scene: Scene) -> np.ndarray:
    """(f,) bool: the faces whose material has a medium inside."""
    medium = np.array([m.subsurface is not None for m in scene.materials], dtype=bool)
    if not len(medium):
        return np.zeros(len(scene.faces), dtype=bool)
    return medium[scene.face_material]


def has_translucency(scene: Scene) -> bool:
    """True when some face's material is translucent (``Material.subsurface``)."""
    return bool(translucent_faces(scene).any())


def apply_material_spec(scene: Scene, materials: dict) -> Scene:
    """The scene with the spec's ``materials`` section applied (material name →
    :class:`~prtcore.core.spec.MaterialOverride`): ``subsurface`` makes the material
    translucent with that medium (:func:`subsurface_medium`, transmission colour = the base
    colour factor); without it, ``transmission`` changes an already translucent material's
    boundary. A name no material has, or a boundary change on an opaque material, is a
    :class:`~prtcore.core.errors.SpecError` naming ``materials.<name>``."""
    if not materials:
        return scene
    names = {m.name for m in scene.materials}
    for name in materials:
        if name not in names:
            known = ", ".join(sorted(repr(n) for n in names if n)) or "none named"
            raise SpecError(f"materials.{name}", f"the asset has no material of that name "
                            f"(its materials: {known})")
    mats = []
    for m in scene.materials:
        o = materials.get(m.name)
        if o is None:
            mats.append(m)
        elif o.subsurface is not None:
            ss = o.subsurface
            mats.append(replace(m, subsurface=subsurface_medium(
                ss.albedo, ss.mean_free_path, ss.anisotropy, o.transmission,
                np.asarray(m.base_color_factor[:3], np.float64))))
        elif m.subsurface is None:
            raise SpecError(f"materials.{m.name}", "the material is opaque: give "
                            "`subsurface` to make it translucent")
        else:
            mats.append(replace(m, subsurface=replace(m.subsurface,
                                                      transmission=o.transmission)))
    return scene.replace(materials=tuple(mats))


def clamp_albedo(albedo: np.ndarray) -> tuple[np.ndarray, int]:
    """Clamp to [0, ALBEDO_MAX] per channel for transport.

    Returns the clamped (n, 3) array and how many values were clamped above (to report).
    """
    over = int(np.count_nonzero(albedo > ALBEDO_MAX))
    return np.clip(albedo, 0.0, ALBEDO_MAX), over
