"""Shared test data (issue 21): the tiny bake spec, point lights, quads and the inside of a
sphere. One copy here; test modules (and the service and stability suites) import it from
here rather than from each other. ``tests/conftest.py`` puts ``tests/`` on ``sys.path``.
"""

from __future__ import annotations

import copy

import numpy as np
import trimesh

from prtcore.core.scene import Light

#: A bake of about a second on the Cornell box (point lights across the room).
TINY_SPEC = {
    "atlas": {"resolution": 32, "padding": 2},
    "measurement_points": {"count": 32, "supersample": 2},
    "lights": {"count": 24, "holdout": 4, "families": [
        {"type": "point", "position": {"box": [[-0.8, 0.3, -0.8], [0.8, 1.9, 0.9]]},
         "intensity": {"uniform": [0.5, 3.0]}}]},
    "transport": {"gather_rays": 16, "max_bounces": 8},
    "fit": {"basis": 8},
    "output": {"dtype": "float"},
}


def tiny_spec(**sections) -> dict:
    """A deep copy of TINY_SPEC with top-level sections replaced."""
    spec = copy.deepcopy(TINY_SPEC)
    spec.update(copy.deepcopy(sections))
    return spec


def point_light(pos, intensity: float = 1.0, color=(1.0, 1.0, 1.0)) -> Light:
    return Light(type="point", color=np.asarray(color, float), intensity=float(intensity),
                 position=np.asarray(pos, float))


def quad(corners, subdiv: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """A planar quad from corners a, b, c, d (counter-clockwise seen from the front), split
    into subdiv × subdiv cells of two triangles: (vertices (v, 3), faces (f, 3))."""
    a, b, c, d = np.asarray(corners, float)
    k = subdiv + 1
    s, t = (g.ravel()[:, None] for g in np.meshgrid(np.linspace(0, 1, k),
                                                    np.linspace(0, 1, k), indexing="ij"))
    v = (1 - s) * (1 - t) * a + s * (1 - t) * b + s * t * c + (1 - s) * t * d
    i, j = (g.ravel() for g in np.meshgrid(np.arange(subdiv), np.arange(subdiv),
                                           indexing="ij"))
    v00, v10, v11, v01 = i * k + j, (i + 1) * k + j, (i + 1) * k + j + 1, i * k + j + 1
    return v, np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])


def quad_normal(corners) -> np.ndarray:
    """The unit front normal of the quad ``corners``."""
    a, b, _c, d = np.asarray(corners, float)
    n = np.cross(b - a, d - a)
    return n / np.linalg.norm(n)


def inside_sphere(subdivisions: int = 2, radius: float = 1.0
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An icosphere wound so that its inside is the front: (vertices, faces, radial inward
    unit normals)."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    v = np.asarray(m.vertices, float)
    return v, np.asarray(m.faces)[:, ::-1].copy(), -v / np.linalg.norm(v, axis=1,
                                                                        keepdims=True)


def bake_sh_prt_bundle(tmp_path, storage: str, *, bounce: bool = True,
                       specular: float = 0.0):
    """An sh_prt bundle (``storage`` "texture" or "vertex", 3 bands, 16 rays per sample;
    ``specular`` > 0: a glossy layer, exponent 8) of the project's floor-and-object scene at
    a 32² atlas, baked through the CLI."""
    import json

    from prtcore.cli import main
    from prtcore.scenes import floor_object

    asset = floor_object.write_floor_object(tmp_path / "fo.glb")
    spec = dict(floor_object.SPEC, atlas={"resolution": 32, "padding": 2},
                method={"name": "sh_prt"},
                sh_prt={"storage": storage, "bands": 3, "strata": 4, "bounce": bounce,
                        "specular": specular, "exponent": 8.0},
                output={"dtype": "float"})
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    out = tmp_path / f"b_{storage}"
    assert main(["bake", str(asset), "--spec", str(tmp_path / "spec.json"), "--out",
                 str(out), "-q"]) == 0
    return out


def write_render_inputs(tmp_path, width: int = 64, height: int = 48):
    """A camera file looking at the floor-and-object scene (``width`` × ``height``) and a
    directional light file: (camera path, light path) for ``prtcore render``."""
    import json

    (tmp_path / "cam.json").write_text(json.dumps(
        {"position": [2.3, 2.0, 3.1], "target": [0, 0.2, 0.8], "fov_y_deg": 45,
         "width": width, "height": height}))
    (tmp_path / "sun.json").write_text(json.dumps(
        {"type": "directional", "direction": [0.3, -1, 0.4], "intensity": 2}))
    return tmp_path / "cam.json", tmp_path / "sun.json"


def bake_learnt_sh_bundle(tmp_path, *, specular: float = 0.5, views: int = 2,
                          name: str = "b_learnt"):
    """A learnt_sh bundle of the floor-and-object scene at a 32² atlas, baked through the
    CLI with a tiny network (k 16, l 2, 3 bands, 600 samples × 16 rays, 60 steps, seed 0;
    ``specular`` > 0: the glossy visibility outputs, exponent 8) and ``views`` metrics
    views of 32 × 24 against 16-ray transfer textures."""
    import json

    from prtcore.cli import main
    from prtcore.scenes import floor_object

    asset = floor_object.write_floor_object(tmp_path / "fo.glb")
    spec = dict(floor_object.SPEC, atlas={"resolution": 32, "padding": 2},
                method={"name": "learnt_sh"},
                learnt_sh={"bands": 3, "width": 16, "layers": 2, "samples": 600, "strata": 4,
                           "steps": 60, "batch": 128, "views": views, "view_width": 32,
                           "view_height": 24, "baseline_strata": 4, "specular": specular,
                           "exponent": 8.0},
                output={"dtype": "float"})
    (tmp_path / "spec_learnt.json").write_text(json.dumps(spec))
    out = tmp_path / name
    assert main(["bake", str(asset), "--spec", str(tmp_path / "spec_learnt.json"), "--out",
                 str(out), "-q"]) == 0
    return out


def write_normal_mapped_quad(path, normal_map: np.ndarray, scale: float = 1.0,
                             albedo=(0.6, 0.6, 0.6)):
    """A 2 m × 2 m quad at y = 0 facing +y, TEXCOORD_0 = ((x + 1)/2, (z + 1)/2) — so
    ∂P/∂u = +2x̂, ∂P/∂v = +2ẑ and the image's up is −ẑ — with a glTF
    ``normalTexture`` (``scale``) whose image is ``normal_map`` (h, w, 3) tangent-space unit
    normals, stored as 8-bit PNG ``round((n + 1)/2 · 255)``; TEXCOORD_1 (the lightmap) =
    0.05 + 0.9 · TEXCOORD_0, leaving the atlas a padding border. Written with pygltflib.
    Returns the path and the stored 8-bit pixels (h, w, 3) uint8."""
    import io
    from pathlib import Path

    import pygltflib as gl
    from PIL import Image

    pix = np.round((np.asarray(normal_map, float) + 1.0) / 2.0 * 255.0).astype(np.uint8)
    png = io.BytesIO()
    Image.fromarray(pix, "RGB").save(png, format="PNG")
    pos = np.array([[-1, 0, -1], [-1, 0, 1], [1, 0, 1], [1, 0, -1]], np.float32)
    nrm = np.tile(np.array([0, 1, 0], np.float32), (4, 1))
    uv = np.stack([(pos[:, 0] + 1) / 2, (pos[:, 2] + 1) / 2], 1).astype(np.float32)
    uv1 = (0.05 + 0.9 * uv).astype(np.float32)
    idx = np.array([0, 1, 2, 0, 2, 3], np.uint32)
    chunks = [pos.tobytes(), nrm.tobytes(), uv.tobytes(), idx.tobytes(), png.getvalue(),
              uv1.tobytes()]
    data, views, off = b"", [], 0
    for c in chunks:
        views.append(gl.BufferView(buffer=0, byteOffset=off, byteLength=len(c)))
        c = c + b"\0" * (-len(c) % 4)
        data += c
        off += len(c)
    acc = [gl.Accessor(bufferView=0, componentType=5126, count=4, type="VEC3",
                       min=pos.min(0).tolist(), max=pos.max(0).tolist()),
           gl.Accessor(bufferView=1, componentType=5126, count=4, type="VEC3"),
           gl.Accessor(bufferView=2, componentType=5126, count=4, type="VEC2"),
           gl.Accessor(bufferView=3, componentType=5125, count=6, type="SCALAR"),
           gl.Accessor(bufferView=5, componentType=5126, count=4, type="VEC2")]
    doc = gl.GLTF2(
        asset=gl.Asset(version="2.0"), scene=0, scenes=[gl.Scene(nodes=[0])],
        nodes=[gl.Node(mesh=0)], buffers=[gl.Buffer(byteLength=len(data))],
        bufferViews=views, accessors=acc,
        images=[gl.Image(bufferView=4, mimeType="image/png")],
        samplers=[gl.Sampler(magFilter=9729, minFilter=9729, wrapS=33071, wrapT=33071)],
        textures=[gl.Texture(source=0, sampler=0)],
        materials=[gl.Material(
            name="bumpy", normalTexture=gl.NormalMaterialTexture(index=0, scale=scale),
            pbrMetallicRoughness=gl.PbrMetallicRoughness(
                baseColorFactor=[*albedo, 1.0], metallicFactor=0.0, roughnessFactor=1.0))],
        meshes=[gl.Mesh(primitives=[gl.Primitive(
            attributes=gl.Attributes(POSITION=0, NORMAL=1, TEXCOORD_0=2, TEXCOORD_1=4),
            indices=3, material=0)])])
    doc.set_binary_blob(data)
    path = Path(path)
    doc.save_binary(str(path))
    return path, pix
