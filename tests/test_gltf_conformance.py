"""glTF conformance (issue 14): flat normals, compressed and quantized geometry written by
the project itself, and one constructed file per validity rule the loader enforces, with
valid counterparts. Every file loads, or ``prtcore plan`` refuses it with exit status 2, one
line and no traceback; no valid file whose scene holds triangles is refused."""

from __future__ import annotations

import base64
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hostile_assets import TRIANGLE, GltfBuilder, glb_bytes

from prtcore.core.errors import AssetError
from prtcore.core.scene import Light
from prtcore.emitters.punctual import unshadowed_irradiance
from prtcore.io.gltf.loader import load_asset

# A box of 8 shared corners, as trimesh and many exporters write it (outward winding).
BOX_CORNERS = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
BOX_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


def box_glb(path: Path, size=(1.0, 1.0, 1.0), normals: bool = False, **node) -> Path:
    pos = BOX_CORNERS * size
    b = GltfBuilder()
    if normals:  # one vertex per corner of each face, with the face normal
        p = pos[BOX_FACES].reshape(-1, 3)
        v = p.reshape(-1, 3, 3)
        fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        fn /= np.linalg.norm(fn, axis=1, keepdims=True)
        b.node(b.mesh(p, np.arange(len(p)), normals=np.repeat(fn, 3, axis=0)), **node)
    else:
        b.node(b.mesh(pos, BOX_FACES.ravel()), **node)
    return b.write_glb(path)


# --------------------------------------------------------------------------------------
# Flat normals when NORMAL is absent
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("rotated", [False, True])
def test_box_without_normals_shades_with_face_normals(tmp_path, rotated):
    node = {"rotation": [0.2, 0.3, 0.1, 0.927]} if rotated else {}
    s = load_asset(box_glb(tmp_path / "box.glb", **node))
    assert s.triangle_count == 12 and len(s.positions) == 36
    fn = s.face_normals()
    for c in range(3):  # every corner's shading normal is its face's normal
        np.testing.assert_allclose(s.normals[s.faces[:, c]], fn, atol=1e-9)
    np.testing.assert_allclose(np.abs(fn).max(axis=1), 1.0, atol=1e-9) if not rotated else None


@pytest.mark.parametrize("normals", [False, True])
def test_slab_under_grazing_point_light_matches_closed_form(tmp_path, normals):
    # a 4 x 4 x 0.2 slab; its top face at z = 0.2; a point light 0.5 above, 3 to the side
    s = load_asset(box_glb(tmp_path / "slab.glb", size=(4.0, 4.0, 0.2), normals=normals))
    top = np.flatnonzero(np.isclose(s.face_normals()[:, 2], 1.0))
    verts = np.unique(s.faces[top])
    light = Light(type="point", color=np.ones(3), intensity=10.0,
                  position=np.array([-3.0, 2.0, 0.7]), direction=np.array([0.0, 0.0, -1.0]))
    e, _, _ = unshadowed_irradiance(light, s.positions[verts], s.normals[verts])
    d = light.position - s.positions[verts]
    r = np.linalg.norm(d, axis=1)
    expected = 10.0 * (d[:, 2] / r) / r**2  # E = I cos(theta) / r^2, n = +Z
    assert (d[:, 2] / r).max() < 0.2  # grazing: 80 degrees or more from the normal
    np.testing.assert_allclose(e[:, 0], expected, rtol=1e-9)


# --------------------------------------------------------------------------------------
# Compressed and quantized geometry, written from the shared assets
# --------------------------------------------------------------------------------------

SHARED_ASSET = "Duck.glb"


@pytest.fixture
def duck(shared_assets):
    s = load_asset(shared_assets / SHARED_ASSET)
    return s.positions, s.normals, s.faces


def _finish(b: GltfBuilder, path: Path, extra_buffers=(), bin_data=None) -> Path:
    doc = b.finish()
    doc["buffers"] += list(extra_buffers)
    path.write_bytes(glb_bytes(doc, bytes(b.bin) if bin_data is None else bin_data))
    return path


def test_draco_round_trip(tmp_path, duck):
    import DracoPy

    pos, nrm, faces = duck
    data = DracoPy.encode(pos, faces.astype(np.uint32), quantization_bits=14, normals=nrm,
                          preserve_order=True)
    mesh = DracoPy.decode(data)
    ids = {a["attribute_type"]: a["unique_id"] for a in mesh.attributes}
    b = GltfBuilder()
    bv = b.buffer_view(data)
    n, f = len(mesh.points), len(mesh.faces)
    acc = b.doc["accessors"]
    acc += [{"componentType": 5126, "count": n, "type": "VEC3"},
            {"componentType": 5126, "count": n, "type": "VEC3"},
            {"componentType": 5125, "count": 3 * f, "type": "SCALAR"}]
    b.doc["meshes"].append({"primitives": [{
        "attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2,
        "extensions": {"KHR_draco_mesh_compression": {
            "bufferView": bv, "attributes": {"POSITION": ids[0], "NORMAL": ids[1]}}}}]})
    b.node(0)
    b.use_extension("KHR_draco_mesh_compression", required=True)
    s = load_asset(_finish(b, tmp_path / "draco.glb"))
    assert s.triangle_count == len(faces)
    step = np.ptp(pos, axis=0).max() / (2**14 - 1)
    np.testing.assert_allclose(s.positions[s.faces], pos[faces], atol=step)
    # the header's counts are checked before decoding
    b.doc["accessors"][2]["count"] = 3 * (f - 1)
    with pytest.raises(AssetError, match="Draco data holds"):
        load_asset(_finish(b, tmp_path / "draco_short.glb"))


@pytest.mark.parametrize(("build", "where"), [
    ("corrupt_draco_asset", "extensions.KHR_draco_mesh_compression: cannot decode"),
    ("corrupt_meshopt_asset", "extensions.EXT_meshopt_compression: cannot decode")])
def test_corrupt_compressed_payloads_are_refused(tmp_path, build, where):
    import hostile_assets as H

    with pytest.raises(AssetError, match=where):
        load_asset(getattr(H, build)(tmp_path))


def test_meshopt_round_trip(tmp_path, duck):
    import meshopt

    pos, _, faces = duck
    p32 = np.ascontiguousarray(pos, np.float32)
    idx = np.ascontiguousarray(faces.ravel(), np.uint32)
    vdata = meshopt.encode_gltf_buffer(p32, "ATTRIBUTES")
    idata = meshopt.encode_gltf_buffer(idx, "TRIANGLES")
    b = GltfBuilder()
    src_v = b.buffer_view(vdata)
    src_i = b.buffer_view(vdata[:0] + idata)
    offs = [b.doc["bufferViews"][k]["byteOffset"] for k in (src_v, src_i)]
    b.doc["bufferViews"] = [
        {"buffer": 1, "byteOffset": 0, "byteLength": p32.nbytes, "byteStride": 12,
         "extensions": {"EXT_meshopt_compression": {
             "buffer": 0, "byteOffset": offs[0], "byteLength": len(vdata), "byteStride": 12,
             "count": len(p32), "mode": "ATTRIBUTES"}}},
        {"buffer": 1, "byteOffset": p32.nbytes, "byteLength": idx.nbytes,
         "extensions": {"EXT_meshopt_compression": {
             "buffer": 0, "byteOffset": offs[1], "byteLength": len(idata), "byteStride": 4,
             "count": len(idx), "mode": "TRIANGLES"}}}]
    b.doc["accessors"] = [{"bufferView": 0, "componentType": 5126, "count": len(p32),
                           "type": "VEC3"},
                          {"bufferView": 1, "componentType": 5125, "count": len(idx),
                           "type": "SCALAR"}]
    b.doc["meshes"].append({"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]})
    b.node(0)
    b.use_extension("EXT_meshopt_compression", required=True)
    fallback = {"byteLength": p32.nbytes + idx.nbytes,
                "extensions": {"EXT_meshopt_compression": {"fallback": True}}}
    s = load_asset(_finish(b, tmp_path / "meshopt.glb", [fallback]))

    def canonical(tris):  # the index codec may rotate a triangle's corners: compare sets
        return np.sort(tris.view([("", tris.dtype)] * 3).reshape(len(tris), 3), axis=1)

    got, want = s.positions[s.faces], p32[faces].astype(np.float64)  # lossless codec
    np.testing.assert_array_equal(canonical(np.ascontiguousarray(got)),
                                  canonical(np.ascontiguousarray(want)))
    wn = np.cross(want[:, 1] - want[:, 0], want[:, 2] - want[:, 0])
    wn /= np.linalg.norm(wn, axis=1, keepdims=True)
    np.testing.assert_allclose(s.face_normals(), wn, atol=1e-9)  # same winding


def test_quantized_positions_and_normals(tmp_path, duck):
    pos, nrm, faces = duck
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    ext = (hi - lo).max()
    q = np.round((pos - lo) / ext * 65535).astype(np.uint16)
    qn = np.round(nrm * 127).astype(np.int8)
    b = GltfBuilder()
    b.doc["meshes"].append({"primitives": [{
        "attributes": {"POSITION": b.accessor(np.pad(q, ((0, 0), (0, 1))), np.uint16,
                                              normalized=True),
                       "NORMAL": b.accessor(np.pad(qn, ((0, 0), (0, 1))), np.int8,
                                            normalized=True)},
        "indices": b.accessor(faces.ravel(), np.uint32)}]})
    for a in b.doc["accessors"][:2]:  # VEC3 in 4-component rows (4-byte aligned stride)
        a["type"] = "VEC3"
        b.doc["bufferViews"][a["bufferView"]]["byteStride"] = 8 if a is b.doc["accessors"][0] \
            else 4
    b.node(0, translation=lo.tolist(), scale=[ext] * 3)
    b.use_extension("KHR_mesh_quantization", required=True)
    s = load_asset(b.write_glb(tmp_path / "quantized.glb"))
    np.testing.assert_allclose(s.positions[s.faces], pos[faces], atol=ext / 65535)
    cos = np.einsum("ij,ij->i", s.normals, nrm)
    assert cos.min() > 1 - 2e-4


# --------------------------------------------------------------------------------------
# One file per validity rule (and the valid counterparts)
# --------------------------------------------------------------------------------------


def _tri() -> GltfBuilder:
    b = GltfBuilder()
    b.node(b.mesh(TRIANGLE, [0, 1, 2]))
    return b


def _doc(edit):
    def make(folder: Path) -> Path:
        b = _tri()
        doc = b.finish()
        edit(doc)
        path = folder / "case.glb"
        path.write_bytes(glb_bytes(doc, bytes(b.bin)))
        return path
    return make


def _gltf(edit):
    def make(folder: Path) -> Path:
        b = _tri()
        doc = b.finish()
        doc["buffers"][0]["uri"] = ("data:application/octet-stream;base64,"
                                    + base64.b64encode(bytes(b.bin)).decode())
        edit(doc)
        path = folder / "case.gltf"
        path.write_text(json.dumps(doc))
        return path
    return make


def _set(*keys, value):
    def edit(doc):
        obj = doc
        for k in keys[:-1]:
            obj = obj[k]
        obj[keys[-1]] = value
    return edit


def _pop(*keys):
    def edit(doc):
        obj = doc
        for k in keys[:-1]:
            obj = obj[k]
        del obj[keys[-1]]
    return edit


def _both(*edits):
    def edit(doc):
        for e in edits:
            e(doc)
    return edit


def _unused_buffer(doc):
    doc["buffers"].append({"byteLength": 16})


# name → (file maker, valid?)
CASES = {
    # valid files the loader once refused
    "index_as_float": (_doc(_both(_set("scene", value=0.0),
                                  _set("scenes", 0, "nodes", value=[0.0]),
                                  _set("nodes", 0, "mesh", value=0.0),
                                  _set("accessors", 0, "count", value=3.0))), True),
    "unused_buffer_without_uri": (_gltf(_unused_buffer), True),
    "primitive_without_position": (_doc(lambda d: d["meshes"][0]["primitives"].append(
        {"attributes": {}})), True),
    "draco_and_meshopt_declared": (_doc(_set("extensionsUsed", value=[
        "KHR_draco_mesh_compression", "EXT_meshopt_compression"])), True),
    "node_without_scene": (_doc(_both(_pop("scene"), _pop("scenes"))), True),
    # invalid: one rule each
    "asset_missing": (_doc(_pop("asset")), False),
    "version_malformed": (_doc(_set("asset", "version", value="2")), False),
    "version_3": (_doc(_set("asset", "version", value="3.0")), False),
    "index_fractional": (_doc(_set("nodes", 0, "mesh", value=0.5)), False),
    "index_out_of_range": (_doc(_set("nodes", 0, "mesh", value=7)), False),
    "count_zero": (_doc(_set("accessors", 0, "count", value=0)), False),
    "stride_not_multiple_of_4": (_doc(_set("bufferViews", 0, "byteStride", value=6)), False),
    "view_past_buffer": (_doc(_set("bufferViews", 0, "byteLength", value=10_000)), False),
    "unknown_component_type": (_doc(_set("accessors", 0, "componentType", value=5130)),
                               False),
    "unknown_mode": (_doc(_set("meshes", 0, "primitives", 0, "mode", value=9)), False),
    "empty_primitives": (_doc(_set("meshes", 0, "primitives", value=[])), False),
    "node_cycle": (_doc(_set("nodes", 0, "children", value=[0])), False),
    "scene_without_scenes": (_doc(_pop("scenes")), False),
    "non_root_in_scene": (_doc(lambda d: (d["nodes"].append({"children": [0]}),
                                          d["scenes"][0]["nodes"].append(1))), False),
    "zero_quaternion": (_doc(_set("nodes", 0, "rotation", value=[0, 0, 0, 0])), False),
    "non_affine_matrix": (_doc(_set("nodes", 0, "matrix", value=[1] * 16)), False),
    "unknown_required_extension": (_doc(_set("extensionsRequired", value=["EXT_unknown"])),
                                   False),
    "used_buffer_without_data": (_gltf(_pop("buffers", 0, "uri")), False),
    "data_uri_length_mismatch": (_gltf(_set("buffers", 0, "byteLength", value=8)), False),
    "bad_wrap_mode": (_doc(lambda d: (d.update(samplers=[{"wrapS": 1}], images=[
        {"uri": "x.png"}], textures=[{"source": 0, "sampler": 0}], materials=[
        {"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]),
        d["meshes"][0]["primitives"][0].update(material=0))), False),
    "light_range_zero": (_doc(lambda d: (d.update(extensions={"KHR_lights_punctual": {
        "lights": [{"type": "point", "range": 0}]}}), d["nodes"][0].update(
        extensions={"KHR_lights_punctual": {"light": 0}}))), False),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_conformance_case_loads_or_is_refused(tmp_path, name):
    make, valid = CASES[name]
    path = make(tmp_path)
    if valid:
        assert load_asset(path).triangle_count >= 1
    else:
        with pytest.raises(AssetError):
            load_asset(path)


@pytest.mark.slow
def test_conformance_corpus_through_the_cli(tmp_path):
    """``prtcore plan`` on every case in one process pool: 0 for valid files; 2, one line
    and no traceback for the others."""
    paths = {}
    for name, (make, valid) in CASES.items():
        folder = tmp_path / name
        folder.mkdir()
        paths[name] = (make(folder), valid)
    script = (
        "import sys, subprocess, json\n"
        "out = {}\n"
        "for name, path in json.loads(sys.argv[1]).items():\n"
        "    p = subprocess.run([sys.executable, '-m', 'prtcore', 'plan', path],\n"
        "                       capture_output=True, text=True)\n"
        "    out[name] = [p.returncode, p.stderr]\n"
        "print(json.dumps(out))\n"
    )
    arg = json.dumps({n: str(p) for n, (p, _) in paths.items()})
    res = subprocess.run([sys.executable, "-c", script, arg], capture_output=True, text=True,
                         check=True)
    out = json.loads(res.stdout)
    for name, (_, valid) in paths.items():
        code, err = out[name]
        if valid:
            assert code == 0, (name, err)
        else:
            assert code == 2, (name, code, err)
            assert "Traceback" not in err and len(err.strip().splitlines()) == 1, (name, err)
