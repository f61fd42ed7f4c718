"""Materials (the Lambertian base colour and, for translucent materials, the medium
inside: docs/subsurface.md), textures, samplers and images."""

from __future__ import annotations

import io
import warnings

import numpy as np

from prtcore.core.errors import PrtError
from prtcore.core.materials import srgb_to_linear, subsurface_medium
from prtcore.core.scene import (
    Material,
    Subsurface,
    Texture,
)
from prtcore.io.gltf.accessors import buffer_data, buffer_view
from prtcore.io.gltf.schema import (
    Ctx,
    get_bool,
    get_dict,
    get_extension,
    get_index,
    get_int,
    get_items,
    get_num,
    get_nums,
    get_str,
)
from prtcore.io.gltf.uris import uri_bytes

DEFAULT_GREY = 0.8
WRAP_MODES = (10497, 33071, 33648)
_IMAGE_FORMATS = ("PNG", "JPEG", "WEBP")


def texture_transform_matrix(offset=(0.0, 0.0), rotation: float = 0.0, scale=(1.0, 1.0)
                             ) -> np.ndarray:
    """KHR_texture_transform as a (3, 3) float64 matrix on homogeneous UVs: T · R · S.

    R = [[cos r, sin r, 0], [−sin r, cos r, 0], [0, 0, 1]] in row-major form, the rotation
    the extension's worked examples (and three.js, Babylon.js) use: a positive ``rotation``
    turns UVs counter-clockwise as seen on the image (v points down). With offset (0, 1),
    rotation π/2 and scale 0.5 the unit square maps onto the lower-left image quadrant.
    """
    c, s = np.cos(rotation), np.sin(rotation)
    t = np.array([[1.0, 0.0, offset[0]], [0.0, 1.0, offset[1]], [0.0, 0.0, 1.0]])
    r = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    sc = np.diag([float(scale[0]), float(scale[1]), 1.0])
    return t @ r @ sc


def image_bytes(ctx: Ctx, doc: dict, index: int, buffers: list) -> bytes:
    """Encoded bytes of ``images[index]`` from its URI (confined, size-checked) or bufferView."""
    where = f"images[{index}]"
    img = get_items(ctx, doc, "images")[index]
    uri = get_str(ctx, img, "uri", where, default=None)
    if uri is not None:
        return uri_bytes(ctx, uri, f"{where}.uri", "max_buffer_bytes")
    bv = get_index(ctx, img, "bufferView", where, "bufferViews", default=-1)
    if bv < 0:
        raise ctx.fail(where, "has neither uri nor bufferView")
    b, off, length, _ = buffer_view(ctx, doc, bv)
    return bytes(buffer_data(ctx, buffers, b, where)[off: off + length])


def decode_image(ctx: Ctx, data: bytes, where: str, srgb: bool = True) -> np.ndarray:
    """PNG/JPEG/WebP bytes → (h, w, 4) float32 linear RGBA, row 0 = image top.

    Dimensions come from the header (Pillow opens lazily) and are checked against
    ``max_texture_pixels`` before any pixel is decoded. Colour is sRGB-decoded (unless
    ``srgb`` is False: data such as a normal map, kept as stored in [0, 1]), alpha kept.
    """
    from PIL import Image

    ctx.where = where
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            im = Image.open(io.BytesIO(data), formats=_IMAGE_FORMATS)
            w, h = im.size
            if w * h > ctx.limits.max_texture_pixels:
                raise ctx.over(where, f"image of {w}x{h} = {w * h} pixels",
                               "max_texture_pixels")
            im.load()
            if im.mode.startswith("I"):  # 16/32-bit grey
                arr = np.asarray(im, dtype=np.float64)
                top = 65535.0 if im.mode.startswith("I;16") or arr.max() <= 65535 else arr.max()
                grey = (arr / top).astype(np.float32)
                rgba = np.stack([grey, grey, grey, np.ones_like(grey)], axis=-1)
            else:
                rgba = np.asarray(im.convert("RGBA"), dtype=np.float32) / 255.0
    except PrtError:
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning):
        raise ctx.over(where, "image is a decompression bomb", "max_texture_pixels") from None
    except MemoryError:
        raise
    except Exception as e:
        raise ctx.fail(where, f"cannot decode image ({type(e).__name__}: {str(e)[:80]})"
                       ) from None
    if not srgb:
        return np.ascontiguousarray(rgba, dtype=np.float32)
    out = np.empty(rgba.shape, dtype=np.float32)
    out[..., :3] = srgb_to_linear(rgba[..., :3])
    out[..., 3] = rgba[..., 3]
    return out


def parse_materials(ctx: Ctx, doc: dict, buffers: list
                    ) -> tuple[list[Material], list[Texture]]:
    """glTF materials → Lambertian :class:`Material` records and their decoded base-colour
    and normal textures (one :class:`Texture` per distinct image + wrap modes + colour
    decoding; normal maps are not sRGB-decoded)."""
    materials, textures = [], []
    tex_index: dict[tuple[int, int, int, bool], int] = {}
    pixels: dict[tuple[int, bool], np.ndarray] = {}
    for i, mj in enumerate(get_items(ctx, doc, "materials")):
        where = f"materials[{i}]"
        ctx.where = where
        pbr = get_dict(ctx, mj, "pbrMetallicRoughness", where, default={})
        pw = f"{where}.pbrMetallicRoughness"
        factor = get_nums(ctx, pbr, "baseColorFactor", pw, 4, [1.0, 1.0, 1.0, 1.0])
        emissive = get_nums(ctx, mj, "emissiveFactor", where, 3, [0.0, 0.0, 0.0])
        strength = get_extension(ctx, mj, "KHR_materials_emissive_strength", where)
        if strength is not None:
            emissive = emissive * get_num(ctx, strength, "emissiveStrength",
                                          f"{where}.extensions.KHR_materials_emissive_strength",
                                          default=1.0)
        info = get_dict(ctx, pbr, "baseColorTexture", pw, default=None)
        tw = f"{pw}.baseColorTexture"
        sg = get_extension(ctx, mj, "KHR_materials_pbrSpecularGlossiness", where)
        if sg is not None and "pbrMetallicRoughness" not in mj:  # legacy diffuse workflow
            sw = f"{where}.extensions.KHR_materials_pbrSpecularGlossiness"
            factor = get_nums(ctx, sg, "diffuseFactor", sw, 4, [1.0, 1.0, 1.0, 1.0])
            info, tw = get_dict(ctx, sg, "diffuseTexture", sw, default=None), f"{sw}.diffuseTexture"
        texture, texcoord, uv_transform = -1, 0, np.eye(3)
        if info is not None:
            texture, texcoord, uv_transform = _texture_info(ctx, doc, info, tw, buffers,
                                                            textures, tex_index, pixels)
        normal = get_dict(ctx, mj, "normalTexture", where, default=None)
        n_tex, n_coord, n_transform, n_scale = -1, 0, np.eye(3), 1.0
        if normal is not None:
            nw = f"{where}.normalTexture"
            n_tex, n_coord, n_transform = _texture_info(ctx, doc, normal, nw, buffers,
                                                        textures, tex_index, pixels,
                                                        srgb=False)
            n_scale = get_num(ctx, normal, "scale", nw, default=1.0)
        materials.append(Material(
            name=get_str(ctx, mj, "name", where, default=""),
            base_color_factor=factor, texture=texture, uv_transform=uv_transform,
            texcoord=texcoord, emissive_factor=emissive,
            double_sided=get_bool(ctx, mj, "doubleSided", where, default=False),
            subsurface=parse_subsurface(ctx, mj, where),
            normal_texture=n_tex, normal_scale=float(n_scale), normal_texcoord=n_coord,
            normal_uv_transform=n_transform,
        ))
    return materials, textures


VOLUME = "KHR_materials_volume"
DIFFUSE_TRANSMISSION = "KHR_materials_diffuse_transmission"
VOLUME_SCATTER = "KHR_materials_volume_scatter"


def parse_subsurface(ctx: Ctx, mj: dict, where: str) -> Subsurface | None:
    """The medium of a translucent material (docs/subsurface.md), or None.

    Translucent = ``KHR_materials_volume`` with ``thicknessFactor`` > 0 (a closed mesh
    filled with a medium). Its ``attenuationColor`` c over ``attenuationDistance`` d gives
    ``−ln(c)/d``: with ``KHR_materials_volume_scatter`` (draft) the extinction σ_t, whose
    ``multiscatterColorFactor`` is the multiple-scattering albedo (inverted,
    :func:`~prtcore.core.materials.single_scattering_albedo`) and ``scatterAnisotropy`` the
    Henyey–Greenstein g; without it the absorption σ_a of a medium that does not scatter.
    ``KHR_materials_diffuse_transmission`` gives the boundary's t and transmission colour
    (factors; its textures are not read: a warning). Scatter or transmission without a
    volume (thin-walled) is not modelled: the material stays opaque, with a warning.
    """
    vol = get_extension(ctx, mj, VOLUME, where)
    dt = get_extension(ctx, mj, DIFFUSE_TRANSMISSION, where)
    vs = get_extension(ctx, mj, VOLUME_SCATTER, where)
    thick = 0.0 if vol is None else get_num(ctx, vol, "thicknessFactor",
                                            f"{where}.extensions.{VOLUME}", default=0.0)
    if thick <= 0.0:
        if dt is not None or vs is not None:
            ctx.warn(where, "diffuse transmission or scattering without a volume "
                     f"({VOLUME} thicknessFactor > 0) is thin-walled, which is not "
                     "modelled: the material is opaque")
        return None
    vw = f"{where}.extensions.{VOLUME}"
    dist = get_num(ctx, vol, "attenuationDistance", vw, default=float("inf"))
    if dist <= 0.0:
        raise ctx.fail(f"{vw}.attenuationDistance", f"must be > 0, got {dist}")
    color = get_nums(ctx, vol, "attenuationColor", vw, 3, [1.0, 1.0, 1.0])
    if (color <= 0.0).any() or (color > 1.0).any():
        raise ctx.fail(f"{vw}.attenuationColor", "components must be in (0, 1]")
    coeff = -np.log(color) / dist  # per world unit (0 where c = 1 or d = ∞)
    with np.errstate(divide="ignore"):
        mfp = np.where(coeff > 0, 1.0 / np.where(coeff > 0, coeff, 1.0), np.inf)
    multiple, g = np.zeros(3), 0.0
    if vs is not None:
        sw = f"{where}.extensions.{VOLUME_SCATTER}"
        multiple = get_nums(ctx, vs, "multiscatterColorFactor", sw, 3, [0.0, 0.0, 0.0])
        if (multiple < 0).any() or (multiple > 1).any():
            raise ctx.fail(f"{sw}.multiscatterColorFactor", "components must be in [0, 1]")
        g = get_num(ctx, vs, "scatterAnisotropy", sw, default=0.0)
        if not -1.0 < g < 1.0:
            raise ctx.fail(f"{sw}.scatterAnisotropy", f"must be in (−1, 1), got {g}")
    t, tc = 0.0, np.ones(3)
    if dt is not None:
        dw = f"{where}.extensions.{DIFFUSE_TRANSMISSION}"
        t = get_num(ctx, dt, "diffuseTransmissionFactor", dw, default=0.0)
        if not 0.0 <= t <= 1.0:
            raise ctx.fail(f"{dw}.diffuseTransmissionFactor", f"must be in [0, 1], got {t}")
        tc = get_nums(ctx, dt, "diffuseTransmissionColorFactor", dw, 3, [1.0, 1.0, 1.0])
        for k in ("diffuseTransmissionTexture", "diffuseTransmissionColorTexture"):
            if k in dt:
                ctx.warn(dw, f"{k} is not read; its factor is used")
    return subsurface_medium(multiple, mfp, g, t, tc)


def _texture_info(ctx: Ctx, doc: dict, info: dict, where: str, buffers: list,
                  textures: list, tex_index: dict, pixels: dict, srgb: bool = True):
    """(Scene texture index, texcoord, uv_transform) of one textureInfo (its image
    sRGB-decoded unless ``srgb`` is False)."""
    t = get_index(ctx, info, "index", where, "textures")
    texcoord = get_int(ctx, info, "texCoord", where, default=0)
    uv_transform = np.eye(3)
    kt = get_extension(ctx, info, "KHR_texture_transform", where)
    if kt is not None:
        kw = f"{where}.extensions.KHR_texture_transform"
        uv_transform = texture_transform_matrix(
            get_nums(ctx, kt, "offset", kw, 2, [0.0, 0.0]),
            get_num(ctx, kt, "rotation", kw, default=0.0),
            get_nums(ctx, kt, "scale", kw, 2, [1.0, 1.0]),
        )
        texcoord = get_int(ctx, kt, "texCoord", kw, default=texcoord)
    if texcoord > 1:
        ctx.warn(where, f"TEXCOORD_{texcoord} is not kept; TEXCOORD_0 used instead")
        texcoord = 0
    tex = get_items(ctx, doc, "textures")[t]
    tjw = f"textures[{t}]"
    source = get_index(ctx, tex, "source", tjw, "images", default=-1)
    webp = get_extension(ctx, tex, "EXT_texture_webp", tjw)
    if webp is not None:
        source = get_index(ctx, webp, "source", f"{tjw}.extensions.EXT_texture_webp", "images")
    if source < 0:
        ctx.warn(tjw, "texture has no image this loader can decode; base colour factor only")
        return -1, texcoord, uv_transform
    sampler = get_index(ctx, tex, "sampler", tjw, "samplers", default=-1)
    wrap_s = wrap_t = 10497
    if sampler >= 0:
        sj, sw = get_items(ctx, doc, "samplers")[sampler], f"samplers[{sampler}]"
        wrap_s = get_int(ctx, sj, "wrapS", sw, default=10497)
        wrap_t = get_int(ctx, sj, "wrapT", sw, default=10497)
        for name, mode in (("wrapS", wrap_s), ("wrapT", wrap_t)):
            if mode not in WRAP_MODES:
                raise ctx.fail(f"{sw}.{name}", f"unknown wrap mode {mode}")
    key = (source, wrap_s, wrap_t, srgb)
    if key not in tex_index:
        if (source, srgb) not in pixels:
            iw = f"images[{source}]"
            ctx.where = iw
            pixels[source, srgb] = decode_image(ctx, image_bytes(ctx, doc, source, buffers),
                                                iw, srgb)
        name = get_str(ctx, get_items(ctx, doc, "images")[source], "name", f"images[{source}]",
                       default="")
        tex_index[key] = len(textures)
        textures.append(Texture(pixels=pixels[source, srgb], wrap_s=wrap_s, wrap_t=wrap_t,
                                name=name))
    return tex_index[key], texcoord, uv_transform
