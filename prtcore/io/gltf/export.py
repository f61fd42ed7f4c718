"""Write a flattened :class:`~prtcore.core.scene.Scene` as a glTF binary (the bundle's asset.glb).

One node, one mesh, one primitive per material; attributes POSITION, NORMAL, TEXCOORD_0
(with any KHR_texture_transform already applied) and TEXCOORD_1 (the lightmap UVs);
base-colour textures re-encoded as sRGB PNG. Written with pygltflib.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pygltflib as gl
from PIL import Image

from prtcore.core.materials import linear_to_srgb, multiple_scattering_albedo
from prtcore.core.scene import Scene, Subsurface

_FLOAT, _UINT = 5126, 5125
_ARRAY, _ELEMENT_ARRAY = 34962, 34963


class _Blob:
    """Accumulates 4-byte aligned buffer views in one binary buffer."""

    def __init__(self, doc: gl.GLTF2):
        self.doc = doc
        self.data = bytearray()

    def view(self, payload: bytes, target: int | None) -> int:
        while len(self.data) % 4:
            self.data.append(0)
        self.doc.bufferViews.append(gl.BufferView(buffer=0, byteOffset=len(self.data),
                                                  byteLength=len(payload), target=target))
        self.data.extend(payload)
        return len(self.doc.bufferViews) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int | None,
                 minmax: bool = False) -> int:
        comp = _UINT if array.dtype == np.uint32 else _FLOAT
        array = np.ascontiguousarray(array, dtype="<u4" if comp == _UINT else "<f4")
        acc = gl.Accessor(bufferView=self.view(array.tobytes(), target), componentType=comp,
                          count=len(array), type=kind)
        if minmax:
            flat = array.reshape(len(array), -1)
            acc.min = [float(v) for v in flat.min(axis=0)]
            acc.max = [float(v) for v in flat.max(axis=0)]
        self.doc.accessors.append(acc)
        return len(self.doc.accessors) - 1


def _png(pixels_linear: np.ndarray) -> bytes:
    rgb = linear_to_srgb(pixels_linear[:, :, :3])
    rgba = np.concatenate([rgb, np.clip(pixels_linear[:, :, 3:4], 0, 1)], axis=2)
    img = Image.fromarray(np.round(np.clip(rgba, 0, 1) * 255).astype(np.uint8), "RGBA")
    buf = io.BytesIO()
    img.save(buf, format="PNG", optimize=False)
    return buf.getvalue()


def scene_to_glb(scene: Scene) -> bytes:
    """The scene as GLB bytes (deterministic for a given scene)."""
    if scene.uv1 is None:
        raise ValueError("scene has no TEXCOORD_1; generate lightmap UVs before export")
    doc = gl.GLTF2(asset=gl.Asset(version="2.0", generator="prtcore"))
    blob = _Blob(doc)
    tex_index: dict[int, int] = {}
    for ti, tex in enumerate(scene.textures):
        bv = blob.view(_png(tex.pixels), None)
        doc.images.append(gl.Image(bufferView=bv, mimeType="image/png", name=tex.name or None))
        doc.samplers.append(gl.Sampler(wrapS=tex.wrap_s, wrapT=tex.wrap_t))
        doc.textures.append(gl.Texture(source=len(doc.images) - 1,
                                       sampler=len(doc.samplers) - 1))
        tex_index[ti] = len(doc.textures) - 1
    uv0 = scene.uv0.copy()
    prims = []
    for m, mat in enumerate(scene.materials):
        fsel = np.nonzero(scene.face_material == m)[0]
        if len(fsel) == 0:
            continue
        verts, inverse = np.unique(scene.faces[fsel].ravel(), return_inverse=True)
        faces = inverse.reshape(-1, 3).astype(np.uint32)
        uv = uv0[verts]
        if mat.texture >= 0 and not np.allclose(mat.uv_transform, np.eye(3)):
            uv = (np.c_[uv, np.ones(len(uv))] @ mat.uv_transform.T)[:, :2]
        attrs = gl.Attributes(
            POSITION=blob.accessor(scene.positions[verts], "VEC3", _ARRAY, minmax=True),
            NORMAL=blob.accessor(scene.normals[verts], "VEC3", _ARRAY),
            TEXCOORD_0=blob.accessor(uv, "VEC2", _ARRAY),
            TEXCOORD_1=blob.accessor(scene.uv1[verts], "VEC2", _ARRAY),
        )
        pbr = gl.PbrMetallicRoughness(
            baseColorFactor=[float(c) for c in mat.base_color_factor],
            metallicFactor=0.0, roughnessFactor=1.0)
        if mat.texture >= 0:
            pbr.baseColorTexture = gl.TextureInfo(index=tex_index[mat.texture])
        doc.materials.append(gl.Material(
            name=mat.name or f"material_{m}", pbrMetallicRoughness=pbr,
            emissiveFactor=[float(c) for c in mat.emissive_factor],
            doubleSided=bool(mat.double_sided),
            extensions=_subsurface_extensions(mat.subsurface)))
        prims.append(gl.Primitive(attributes=attrs, material=len(doc.materials) - 1,
                                  indices=blob.accessor(faces.ravel(), "SCALAR",
                                                        _ELEMENT_ARRAY), mode=4))
    used = sorted({k for mat in doc.materials for k in (mat.extensions or {})})
    if used:
        doc.extensionsUsed = used
    doc.meshes.append(gl.Mesh(primitives=prims, name="baked"))
    doc.nodes.append(gl.Node(mesh=0, name="baked"))
    doc.scenes.append(gl.Scene(nodes=[0]))
    doc.scene = 0
    doc.buffers.append(gl.Buffer(byteLength=len(blob.data)))
    doc.set_binary_blob(bytes(blob.data))
    return b"".join(doc.save_to_bytes())


def _subsurface_extensions(medium: Subsurface | None) -> dict:
    """A translucent material's medium as the glTF extensions the loader reads back
    (:func:`prtcore.io.gltf.materials.parse_subsurface`): attenuation over d = the
    shortest mean free path, so every colour lies in [1/e, 1]."""
    if medium is None:
        return {}
    sigma = np.asarray(medium.sigma_t, np.float64)
    top = float(sigma.max())
    d = 1.0 / top if top > 0 else 1.0
    return {
        "KHR_materials_volume": {"thicknessFactor": 1.0, "attenuationDistance": d,
                                 "attenuationColor": [float(c) for c in np.exp(-sigma * d)]},
        "KHR_materials_volume_scatter": {
            "multiscatterColorFactor": [float(a) for a in
                                        multiple_scattering_albedo(medium.albedo)],
            "scatterAnisotropy": float(medium.anisotropy)},
        "KHR_materials_diffuse_transmission": {
            "diffuseTransmissionFactor": float(medium.transmission),
            "diffuseTransmissionColorFactor": [float(c) for c in medium.transmission_color]},
    }


def write_glb(scene: Scene, path: str | Path) -> None:
    Path(path).write_bytes(scene_to_glb(scene))
