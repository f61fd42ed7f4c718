"""Build small glTF/GLB files, valid or deliberately hostile, for the loader tests.

:class:`GltfBuilder` writes a valid asset from numpy arrays (one buffer, one bufferView per
accessor); the ``*_asset`` functions below take a valid triangle and corrupt exactly one
thing, writing the file into a given folder and returning its path.
"""

from __future__ import annotations

import base64
import io
import json
import struct
from pathlib import Path

import numpy as np

COMPONENT_TYPES = {
    np.dtype(np.int8): 5120,
    np.dtype(np.uint8): 5121,
    np.dtype(np.int16): 5122,
    np.dtype(np.uint16): 5123,
    np.dtype(np.uint32): 5125,
    np.dtype(np.float32): 5126,
}
TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4", 16: "MAT4"}

#: One counter-clockwise (seen from +Z) triangle in the z = 0 plane.
TRIANGLE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype=np.float32)


def glb_bytes(doc: dict, bin_data: bytes | None) -> bytes:
    """A GLB container: 12-byte header, JSON chunk (space-padded), optional BIN chunk."""
    js = json.dumps(doc).encode("utf-8")
    js += b" " * (-len(js) % 4)
    chunks = struct.pack("<II", len(js), 0x4E4F534A) + js
    if bin_data is not None:
        b = bytes(bin_data) + b"\x00" * (-len(bin_data) % 4)
        chunks += struct.pack("<II", len(b), 0x004E4942) + b
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def png_bytes(rgba: np.ndarray) -> bytes:
    """(h, w, 4) or (h, w, 3) uint8 → PNG bytes."""
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgba)).save(out, format="PNG")
    return out.getvalue()


class GltfBuilder:
    """Accumulates a glTF document and its single binary buffer.

    >>> b = GltfBuilder()
    >>> node = b.node(b.mesh(TRIANGLE, [0, 1, 2]))
    >>> data = b.to_glb()
    """

    def __init__(self) -> None:
        self.doc: dict = {
            "asset": {"version": "2.0", "generator": "prtcore tests"},
            "scene": 0,
            "scenes": [{"nodes": []}],
            "nodes": [],
            "meshes": [],
            "accessors": [],
            "bufferViews": [],
        }
        self.bin = bytearray()

    # -- binary data ------------------------------------------------------------------
    def buffer_view(self, data: bytes, **extra) -> int:
        while len(self.bin) % 4:
            self.bin.append(0)
        self.doc["bufferViews"].append(
            {"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data), **extra})
        self.bin += data
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, array, dtype=None, *, normalized: bool = False, **extra) -> int:
        """Append ``array`` ((n,), (n, k) or (n, 4, 4) matrices) as one accessor."""
        a = np.asarray(array, dtype=dtype)
        if a.dtype == np.float64:
            a = a.astype(np.float32)
        if a.ndim == 3:  # matrices are stored column-major
            a = a.transpose(0, 2, 1).reshape(len(a), -1)
        ncomp = 1 if a.ndim == 1 else a.shape[1]
        acc = {
            "bufferView": self.buffer_view(np.ascontiguousarray(a).tobytes()),
            "componentType": COMPONENT_TYPES[a.dtype],
            "count": len(a),
            "type": TYPES[ncomp],
            **extra,
        }
        if normalized:
            acc["normalized"] = True
        if ncomp == 3 and a.dtype == np.float32 and len(a) and np.isfinite(a).all():
            acc["min"] = a.min(axis=0).tolist()
            acc["max"] = a.max(axis=0).tolist()
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    # -- scene content ----------------------------------------------------------------
    def primitive(self, positions, indices=None, *, normals=None, uv0=None, uv1=None,
                  material=None, mode=None, joints=None, weights=None) -> dict:
        attrs = {"POSITION": self.accessor(positions, np.float32)}
        for name, arr, dt in (("NORMAL", normals, np.float32), ("TEXCOORD_0", uv0, np.float32),
                              ("TEXCOORD_1", uv1, np.float32), ("JOINTS_0", joints, np.uint16),
                              ("WEIGHTS_0", weights, np.float32)):
            if arr is not None:
                attrs[name] = self.accessor(arr, dt)
        prim: dict = {"attributes": attrs}
        if indices is not None:
            prim["indices"] = self.accessor(np.asarray(indices).ravel(), np.uint16)
        if material is not None:
            prim["material"] = material
        if mode is not None:
            prim["mode"] = mode
        return prim

    def mesh(self, positions, indices=None, **kw) -> int:
        """A one-primitive mesh (see :meth:`primitive` for the keywords)."""
        self.doc["meshes"].append({"primitives": [self.primitive(positions, indices, **kw)]})
        return len(self.doc["meshes"]) - 1

    def node(self, mesh: int | None = None, *, children=(), root: bool = True, **fields) -> int:
        """A node (``translation``/``rotation``/``scale``/``matrix``/``extensions``...)."""
        nd = {k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v)
              for k, v in fields.items()}
        if mesh is not None:
            nd["mesh"] = mesh
        if children:
            nd["children"] = list(children)
        self.doc["nodes"].append(nd)
        i = len(self.doc["nodes"]) - 1
        if root:
            self.doc["scenes"][0]["nodes"].append(i)
        return i

    def material(self, base_color=(1.0, 1.0, 1.0, 1.0), texture: int | None = None,
                 texture_extensions: dict | None = None, **fields) -> int:
        pbr: dict = {"baseColorFactor": list(base_color)}
        if texture is not None:
            pbr["baseColorTexture"] = {"index": texture}
            if texture_extensions:
                pbr["baseColorTexture"]["extensions"] = texture_extensions
        self.doc.setdefault("materials", []).append({"pbrMetallicRoughness": pbr, **fields})
        return len(self.doc["materials"]) - 1

    def image(self, rgba: np.ndarray) -> int:
        """An embedded PNG image (bufferView + mimeType)."""
        bv = self.buffer_view(png_bytes(rgba))
        self.doc.setdefault("images", []).append({"bufferView": bv, "mimeType": "image/png"})
        return len(self.doc["images"]) - 1

    def texture(self, image: int, wrap_s: int | None = None, wrap_t: int | None = None) -> int:
        tex: dict = {"source": image}
        if wrap_s is not None or wrap_t is not None:
            sampler = {k: v for k, v in (("wrapS", wrap_s), ("wrapT", wrap_t)) if v is not None}
            self.doc.setdefault("samplers", []).append(sampler)
            tex["sampler"] = len(self.doc["samplers"]) - 1
        self.doc.setdefault("textures", []).append(tex)
        return len(self.doc["textures"]) - 1

    def use_extension(self, name: str, required: bool = False) -> None:
        self.doc.setdefault("extensionsUsed", []).append(name)
        if required:
            self.doc.setdefault("extensionsRequired", []).append(name)

    # -- output -----------------------------------------------------------------------
    def finish(self) -> dict:
        """The document with ``buffers`` filled in for the GLB BIN chunk."""
        while len(self.bin) % 4:
            self.bin.append(0)
        doc = json.loads(json.dumps(self.doc))
        doc["buffers"] = [{"byteLength": len(self.bin)}]
        return doc

    def to_glb(self) -> bytes:
        return glb_bytes(self.finish(), bytes(self.bin))

    def write_glb(self, path: Path) -> Path:
        path = Path(path)
        path.write_bytes(self.to_glb())
        return path

    def write_gltf(self, path: Path, bin_uri: str = "data.bin", bin_path: Path | None = None,
                   external_images: bool = False) -> Path:
        """A ``.gltf`` with its buffer in ``bin_uri`` (written to ``bin_path``, by default
        next to the ``.gltf``); embedded images moved to ``image_<i>.png`` files when
        ``external_images``."""
        path = Path(path)
        doc = self.finish()
        doc["buffers"][0]["uri"] = bin_uri
        if external_images:
            for i, img in enumerate(doc.get("images", [])):
                bv = doc["bufferViews"][img.pop("bufferView")]
                data = bytes(self.bin[bv["byteOffset"]: bv["byteOffset"] + bv["byteLength"]])
                (path.parent / f"image_{i}.png").write_bytes(data)
                img.pop("mimeType", None)
                img["uri"] = f"image_{i}.png"
        (bin_path or path.parent / bin_uri).write_bytes(bytes(self.bin))
        path.write_text(json.dumps(doc))
        return path


def triangle_builder(positions=TRIANGLE) -> GltfBuilder:
    """A valid asset: one indexed triangle placed by one root node."""
    b = GltfBuilder()
    b.node(b.mesh(positions, [0, 1, 2]))
    return b


# ------------------------------------------------------------------------------------
# Hostile files. Each writes into ``folder`` and returns the asset's path.
# ------------------------------------------------------------------------------------


def uri_buffer_asset(folder: Path, uri: str) -> Path:
    """A ``.gltf`` whose ``buffers[0].uri`` is ``uri`` (nothing written there)."""
    b = triangle_builder()
    doc = b.finish()
    doc["buffers"][0]["uri"] = uri
    path = Path(folder) / "model.gltf"
    path.write_text(json.dumps(doc))
    return path


def path_traversal_asset(root: Path) -> tuple[Path, Path]:
    """``root/asset/model.gltf`` with ``buffers[0].uri = "../secret.bin"``, and a real,
    valid ``root/secret.bin`` it would read if the check failed. Returns both paths."""
    asset_dir = Path(root) / "asset"
    asset_dir.mkdir()
    b = triangle_builder()
    secret = Path(root) / "secret.bin"
    b.write_gltf(asset_dir / "model.gltf", bin_uri="../secret.bin", bin_path=secret)
    return asset_dir / "model.gltf", secret


def symlink_escape_asset(root: Path) -> tuple[Path, Path]:
    """``root/asset/model.gltf`` reading ``data.bin``, a symlink to ``root/secret.bin``."""
    asset_dir = Path(root) / "asset"
    asset_dir.mkdir()
    secret = Path(root) / "secret.bin"
    path = triangle_builder().write_gltf(asset_dir / "model.gltf", bin_uri="data.bin",
                                         bin_path=secret)
    (asset_dir / "data.bin").symlink_to(secret)
    return path, secret


def accessor_overrun_asset(folder: Path, count: int = 1_000_000) -> Path:
    """POSITION accessor claiming ``count`` vertices in a 36-byte bufferView."""
    b = GltfBuilder()
    b.node(b.mesh(TRIANGLE))
    doc = b.finish()
    doc["accessors"][0]["count"] = count
    path = Path(folder) / "overrun.glb"
    path.write_bytes(glb_bytes(doc, bytes(b.bin)))
    return path


def data_uri_asset(folder: Path, payload_bytes: int) -> Path:
    """A ``.gltf`` whose only buffer is a base64 data: URI decoding to ``payload_bytes``
    (the triangle's data followed by zeros)."""
    b = triangle_builder()
    doc = b.finish()
    data = bytes(b.bin) + b"\x00" * max(payload_bytes - len(b.bin), 0)
    doc["buffers"][0] = {
        "byteLength": len(data),
        "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode(),
    }
    path = Path(folder) / "datauri.gltf"
    path.write_text(json.dumps(doc))
    return path


def truncated_glb_asset(folder: Path) -> Path:
    data = triangle_builder().to_glb()
    path = Path(folder) / "truncated.glb"
    path.write_bytes(data[: len(data) // 2])
    return path


def wrong_magic_asset(folder: Path) -> Path:
    data = bytearray(triangle_builder().to_glb())
    data[:4] = b"glTX"
    path = Path(folder) / "magic.glb"
    path.write_bytes(bytes(data))
    return path


def json_chunk_asset(folder: Path, text: bytes, name: str = "json.glb") -> Path:
    """A GLB whose JSON chunk holds ``text`` verbatim (invalid JSON, a non-object...)."""
    text = text + b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text
    path = Path(folder) / name
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)
    return path


def positions_asset(folder: Path, value: float) -> Path:
    """The triangle with one coordinate replaced by ``value`` (NaN, inf...)."""
    pos = TRIANGLE.copy()
    pos[1, 1] = value
    path = Path(folder) / "positions.glb"
    return triangle_builder(pos).write_glb(path)


def points_only_asset(folder: Path) -> Path:
    """A mesh whose single primitive is POINTS: zero triangles in the scene."""
    b = GltfBuilder()
    b.node(b.mesh(TRIANGLE, mode=0))
    return b.write_glb(Path(folder) / "points.glb")


def instanced_asset(folder: Path, copies: int) -> Path:
    """One 1-triangle mesh placed by ``copies`` nodes."""
    b = GltfBuilder()
    m = b.mesh(TRIANGLE, [0, 1, 2])
    for k in range(copies):
        b.node(m, translation=[2.0 * k, 0.0, 0.0])
    return b.write_glb(Path(folder) / "instanced.glb")


def textured_asset(folder: Path, width: int, height: int) -> Path:
    """The triangle with UVs and a ``width`` × ``height`` base-colour PNG."""
    b = GltfBuilder()
    rgba = np.zeros((height, width, 4), dtype=np.uint8)
    rgba[..., 3] = 255
    mat = b.material(texture=b.texture(b.image(rgba)))
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    b.node(b.mesh(TRIANGLE, [0, 1, 2], uv0=uv, material=mat))
    return b.write_glb(Path(folder) / "textured.glb")


def required_extension_asset(folder: Path, name: str) -> Path:
    b = triangle_builder()
    b.use_extension(name, required=True)
    return b.write_glb(Path(folder) / "required.glb")


def indices_asset(folder: Path, indices) -> Path:
    b = GltfBuilder()
    b.node(b.mesh(TRIANGLE, indices))
    return b.write_glb(Path(folder) / "indices.glb")


def patched_asset(folder: Path, patch) -> Path:
    """The valid triangle GLB after ``patch(doc)`` edited its JSON in place."""
    b = triangle_builder()
    doc = b.finish()
    patch(doc)
    path = Path(folder) / "patched.glb"
    path.write_bytes(glb_bytes(doc, bytes(b.bin)))
    return path


def _draco_box(corrupt: bool) -> tuple[GltfBuilder, bytes]:
    """A Draco-compressed box (12 triangles); with ``corrupt`` its payload's body is
    replaced by bytes that are not a Draco stream (the header kept)."""
    import DracoPy
    import numpy as np

    pos = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float32)
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],
                     np.uint32)
    data = bytes(DracoPy.encode(pos, faces, preserve_order=True))
    if corrupt:
        data = data[:16] + bytes((b * 37 + 11) & 0xFF for b in data[16:])
    b = GltfBuilder()
    bv = b.buffer_view(data)
    b.doc["accessors"] += [{"componentType": 5126, "count": 8, "type": "VEC3",
                            "min": [0, 0, 0], "max": [1, 1, 1]},
                           {"componentType": 5125, "count": 36, "type": "SCALAR"}]
    b.doc["meshes"].append({"primitives": [{
        "attributes": {"POSITION": 0}, "indices": 1,
        "extensions": {"KHR_draco_mesh_compression": {"bufferView": bv,
                                                      "attributes": {"POSITION": 0}}}}]})
    b.node(0)
    b.use_extension("KHR_draco_mesh_compression", required=True)
    return b, data


def corrupt_draco_asset(folder: Path) -> Path:
    """A required-Draco GLB whose compressed payload is garbage: refused, never decoded
    into something else."""
    b, _ = _draco_box(corrupt=True)
    return b.write_glb(Path(folder) / "draco_corrupt.glb")


def corrupt_meshopt_asset(folder: Path) -> Path:
    """A required-meshopt GLB whose compressed vertex stream is garbage."""
    import numpy as np

    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    payload = bytes(range(7, 7 + 40))  # not a meshopt vertex stream
    b = GltfBuilder()
    src = b.buffer_view(payload)
    off = b.doc["bufferViews"][src]["byteOffset"]
    b.doc["bufferViews"] = [{"buffer": 1, "byteOffset": 0, "byteLength": pos.nbytes,
                             "byteStride": 12, "extensions": {"EXT_meshopt_compression": {
                                 "buffer": 0, "byteOffset": off, "byteLength": len(payload),
                                 "byteStride": 12, "count": 3, "mode": "ATTRIBUTES"}}}]
    b.doc["accessors"] = [{"bufferView": 0, "componentType": 5126, "count": 3,
                           "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}]
    b.doc["meshes"].append({"primitives": [{"attributes": {"POSITION": 0}}]})
    b.node(0)
    b.use_extension("EXT_meshopt_compression", required=True)
    doc = b.finish()
    doc["buffers"].append({"byteLength": pos.nbytes,
                           "extensions": {"EXT_meshopt_compression": {"fallback": True}}})
    path = Path(folder) / "meshopt_corrupt.glb"
    path.write_bytes(glb_bytes(doc, bytes(b.bin)))
    return path
