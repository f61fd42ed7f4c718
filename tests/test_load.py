"""Tests for prtcore.io.gltf.loader: real assets against trimesh, constructed scenes against
hand-computed transforms and spec formulas, and one test per hostile input."""

from __future__ import annotations

import builtins
import io
import json
import os
import socket
import struct

import numpy as np
import pytest
import trimesh
from hostile_assets import (
    TRIANGLE,
    GltfBuilder,
    accessor_overrun_asset,
    data_uri_asset,
    glb_bytes,
    indices_asset,
    instanced_asset,
    json_chunk_asset,
    patched_asset,
    path_traversal_asset,
    points_only_asset,
    positions_asset,
    required_extension_asset,
    symlink_escape_asset,
    textured_asset,
    triangle_builder,
    truncated_glb_asset,
    uri_buffer_asset,
    wrong_magic_asset,
)

import prtcore.io.gltf.animation
import prtcore.io.gltf.meshes
from prtcore.core.errors import AssetError, LimitExceeded, UnsupportedAsset
from prtcore.core.limits import IntakeLimits
from prtcore.core.materials import albedo_at, srgb_to_linear
from prtcore.io.gltf.loader import load_asset, texture_transform_matrix

REAL_ASSETS = ["Duck", "BoxTextured", "CesiumMilkTruck", "CesiumMan", "monkey"]


def quat(axis, angle):
    """xyzw quaternion of a rotation by ``angle`` about unit ``axis``."""
    axis = np.asarray(axis, dtype=float)
    return np.append(axis * np.sin(angle / 2), np.cos(angle / 2))


def forbid_decoding(monkeypatch, replacement):
    """Replace ``read_accessor`` in every loader module that decodes accessors."""
    for mod in (prtcore.io.gltf.meshes, prtcore.io.gltf.animation):
        monkeypatch.setattr(mod, "read_accessor", replacement)


@pytest.fixture
def no_decode(monkeypatch):
    """Fail the test if any accessor is decoded (limits must trip before allocation)."""

    def boom(*args, **kwargs):  # pytest.fail is a BaseException: the loader cannot wrap it
        pytest.fail("an accessor was decoded before the refusal")

    forbid_decoding(monkeypatch, boom)


@pytest.fixture
def opened(monkeypatch):
    """Record the real path of every file opened through open/io.open/os.open.

    Tests build their files first, then ``opened.clear()`` before loading.
    """
    seen: list[str] = []
    real_open, real_io_open, real_os_open = builtins.open, io.open, os.open

    def record(p):
        if isinstance(p, (str, bytes, os.PathLike)):
            seen.append(os.path.realpath(os.fsdecode(p)))

    def b_open(file, *a, **k):
        record(file)
        return real_open(file, *a, **k)

    def i_open(file, *a, **k):
        record(file)
        return real_io_open(file, *a, **k)

    def o_open(path, *a, **k):
        record(path)
        return real_os_open(path, *a, **k)

    monkeypatch.setattr(builtins, "open", b_open)
    monkeypatch.setattr(io, "open", i_open)
    monkeypatch.setattr(os, "open", o_open)
    return seen


@pytest.fixture
def no_network(monkeypatch):
    def refuse(*args, **kwargs):
        pytest.fail("the loader tried to open a network connection")

    monkeypatch.setattr(socket, "socket", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)


def refused(path, kind=AssetError, limits=None) -> str:
    """Load ``path`` expecting exactly error type ``kind``; return its message."""
    with pytest.raises(AssetError) as info:
        load_asset(path, limits)
    assert type(info.value) is kind, f"{type(info.value).__name__}: {info.value}"
    msg = str(info.value)
    assert str(path) in msg and "\n" not in msg
    return msg


# ------------------------------------------------------------------------------------------
# Real assets
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", REAL_ASSETS)
def test_real_asset_matches_trimesh(shared_assets, name):
    path = shared_assets / f"{name}.glb"
    scene = load_asset(path)
    ref = trimesh.load(path, force="mesh")  # an independent glTF reader, flattened
    assert scene.triangle_count == len(ref.faces)
    tol = 1e-6 * float(np.linalg.norm(ref.extents))
    np.testing.assert_allclose(scene.bounds, ref.bounds, atol=tol)
    assert np.isclose(scene.face_areas().sum(), ref.area, rtol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(scene.normals, axis=1), 1.0, atol=1e-9)
    assert scene.faces.min() >= 0 and scene.faces.max() < len(scene.positions)
    assert scene.face_material.max() < len(scene.materials)
    assert scene.face_instance.max() < len(scene.instances)
    # vertex normals agree with the geometric orientation of their faces almost everywhere
    agree = np.einsum("ij,ij->i", scene.face_normals(), scene.normals[scene.faces[:, 0]]) > 0
    assert agree.mean() > 0.9


def test_duck_texture_is_the_linearised_image(shared_assets):
    scene = load_asset(shared_assets / "Duck.glb")
    mat = scene.materials[int(scene.face_material[0])]
    assert mat.texture >= 0 and scene.has_uv0.all()
    tex = scene.textures[mat.texture]
    ref_scene = trimesh.load(shared_assets / "Duck.glb")
    (geom,) = ref_scene.geometry.values()
    image = geom.visual.material.baseColorTexture
    expected = np.asarray(image.convert("RGBA"), dtype=np.float32) / 255.0
    assert tex.pixels.shape == (image.size[1], image.size[0], 4)
    assert tex.pixels.dtype == np.float32
    np.testing.assert_allclose(tex.pixels[..., :3], srgb_to_linear(expected[..., :3]), atol=1e-6)
    np.testing.assert_allclose(tex.pixels[..., 3], expected[..., 3], atol=1e-6)


def test_box_textured_albedo_varies_through_texcoord0(shared_assets):
    scene = load_asset(shared_assets / "BoxTextured.glb")
    assert scene.textures and scene.uv1 is None
    rng = np.random.default_rng(3)
    tri = rng.integers(0, scene.triangle_count, 500)
    bary = rng.dirichlet([1.0, 1.0, 1.0], 500)
    albedo = albedo_at(scene, tri, bary)
    assert np.ptp(albedo, axis=0).max() > 0.2  # the checker/logo texture is far from flat


def test_milk_truck_animation_targets_wheels(shared_assets):
    scene = load_asset(shared_assets / "CesiumMilkTruck.glb")
    used = {scene.materials[m].name for m in np.unique(scene.face_material)}
    assert len(used) > 1 and "wheels" in used
    wheel_nodes = {
        inst.node for k, inst in enumerate(scene.instances)
        if scene.materials[int(scene.face_material[inst.face_start])].name == "wheels"
    }
    assert len(wheel_nodes) == 2
    (anim,) = scene.animations
    assert {c.node for c in anim.channels} == wheel_nodes
    for c in anim.channels:
        assert c.path == "rotation" and c.values.shape == (len(c.times), 4)
        assert np.all(np.diff(c.times) > 0)
        np.testing.assert_allclose(np.linalg.norm(c.values, axis=1), 1.0, atol=1e-4)
    assert anim.duration > 0


def test_monkey_gets_default_grey(shared_assets):
    scene = load_asset(shared_assets / "monkey.glb")
    (mat,) = scene.materials
    np.testing.assert_allclose(mat.base_color_factor, [0.8, 0.8, 0.8, 1.0])
    assert mat.texture == -1


# ------------------------------------------------------------------------------------------
# Constructed valid assets
# ------------------------------------------------------------------------------------------


def test_gltf_with_external_bin_and_png(tmp_path):
    rng = np.random.default_rng(1)
    rgba = rng.integers(0, 256, (8, 16, 4), dtype=np.uint8)
    b = GltfBuilder()
    mat = b.material(base_color=(0.5, 1.0, 1.0, 1.0),
                     texture=b.texture(b.image(rgba), wrap_s=33071, wrap_t=33648))
    uv = np.array([[0.1, 0.2], [0.9, 0.2], [0.1, 0.8]])
    b.node(b.mesh(TRIANGLE, [0, 1, 2], uv0=uv, material=mat))
    path = b.write_gltf(tmp_path / "model.gltf", external_images=True)
    doc = json.loads(path.read_text())
    assert doc["buffers"][0]["uri"] == "data.bin" and doc["images"][0]["uri"] == "image_0.png"
    scene = load_asset(path)
    np.testing.assert_allclose(scene.positions, TRIANGLE)
    np.testing.assert_allclose(scene.uv0, uv, atol=1e-7)
    (tex,) = scene.textures
    assert (tex.wrap_s, tex.wrap_t) == (33071, 33648)
    np.testing.assert_allclose(tex.pixels[..., :3], srgb_to_linear(rgba[..., :3] / 255.0),
                               atol=1e-6)
    np.testing.assert_allclose(tex.pixels[..., 3], rgba[..., 3] / 255.0, atol=1e-6)
    np.testing.assert_allclose(scene.materials[0].base_color_factor, [0.5, 1, 1, 1])
    # albedo at a vertex = factor x texel there (CLAMP in x, nearest texel centre)
    x, y = int(0.1 * 16), int(0.2 * 8)
    centre_uv = np.array([[(x + 0.5) / 16, (y + 0.5) / 8]])
    scene2 = scene.replace(uv0=np.repeat(centre_uv, 3, axis=0))
    got = albedo_at(scene2, np.array([0]), np.array([[1.0, 0.0, 0.0]]))[0]
    np.testing.assert_allclose(got, [0.5, 1, 1] * srgb_to_linear(rgba[y, x, :3] / 255.0),
                               atol=1e-6)


def test_node_hierarchy_trs_matrix_and_mirror(tmp_path):
    tilted = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1.0]])
    n_obj = np.array([0.0, -1.0, 1.0]) / np.sqrt(2.0)  # its geometric normal
    b = GltfBuilder()
    m_tilted = b.mesh(tilted, [0, 1, 2], normals=np.repeat(n_obj[None], 3, axis=0))
    m_flat = b.mesh(TRIANGLE, [0, 1, 2], normals=np.repeat([[0.0, 0.0, 1.0]], 3, axis=0))
    child = b.node(m_tilted, root=False, translation=[0.0, 1.0, 0.0], scale=[1.0, 3.0, 1.0])
    b.node(children=[child], translation=[1.0, 2.0, 3.0], rotation=quat([0, 1, 0], np.pi / 2),
           scale=[2.0, 2.0, 2.0])
    # the same combined transform, written as a column-major matrix:
    # x' = 2z + 1, y' = 6y + 4, z' = 3 - 2x
    world = np.array([[0, 0, 2, 1], [0, 6, 0, 4], [-2, 0, 0, 3], [0, 0, 0, 1]], dtype=float)
    b.node(m_tilted, matrix=world.T.ravel().tolist())
    b.node(m_flat, translation=[0.0, 0.0, 5.0])
    b.node(m_flat, translation=[0.0, 0.0, 5.0], scale=[-1.0, 1.0, 1.0])
    scene = load_asset(b.write_glb(tmp_path / "tree.glb"))
    assert len(scene.instances) == 4 and scene.triangle_count == 4

    expected = np.array([[1.0, 4.0, 3.0], [1.0, 4.0, 1.0], [3.0, 10.0, 3.0]])
    for k in (0, 1):  # TRS hierarchy, then the matrix node
        inst = scene.instances[k]
        sl = slice(inst.vertex_start, inst.vertex_start + inst.vertex_count)
        np.testing.assert_allclose(scene.positions[sl], expected, atol=1e-12)
        # inverse-transpose: world normals equal the world triangle's geometric normal
        geo = scene.face_normals()[inst.face_start]
        np.testing.assert_allclose(scene.normals[sl], np.repeat(geo[None], 3, axis=0),
                                   atol=1e-12)
        np.testing.assert_allclose(inst.object_positions, tilted)
    np.testing.assert_allclose(scene.nodes[child].world_from_node, world, atol=1e-12)

    plain, mirror = scene.instances[2], scene.instances[3]
    p_sl = slice(mirror.vertex_start, mirror.vertex_start + 3)
    np.testing.assert_allclose(scene.positions[p_sl], TRIANGLE * [-1, 1, 1] + [0, 0, 5])
    np.testing.assert_allclose(scene.normals[p_sl], [[0, 0, 1]] * 3, atol=1e-12)
    f_plain = scene.faces[plain.face_start] - plain.vertex_start
    f_mirror = scene.faces[mirror.face_start] - mirror.vertex_start
    assert list(f_plain) == [0, 1, 2] and list(f_mirror) == [0, 2, 1]
    # both instances' faces face the way their normals point (+Z)
    np.testing.assert_allclose(scene.face_normals()[[plain.face_start, mirror.face_start]],
                               [[0, 0, 1], [0, 0, 1]], atol=1e-12)


def test_lights_punctual_world_placement(tmp_path):
    b = GltfBuilder()
    b.node(b.mesh(TRIANGLE, [0, 1, 2]))
    b.doc["extensions"] = {"KHR_lights_punctual": {"lights": [
        {"type": "point", "color": [1.0, 0.5, 0.25], "intensity": 5.0, "range": 10.0},
        {"type": "spot", "intensity": 2.0, "spot": {"outerConeAngle": 0.5}},
        {"type": "directional", "intensity": 3.0},
        {"type": "spot", "spot": {}},
        {"type": "point"},  # not placed by any scene node
    ]}}
    b.use_extension("KHR_lights_punctual")
    ext = lambda k: {"KHR_lights_punctual": {"light": k}}  # noqa: E731
    child = b.node(root=False, translation=[0.0, 2.0, 0.0], extensions=ext(0))
    b.node(children=[child], translation=[1.0, 0.0, 0.0])
    b.node(translation=[0.0, 3.0, 0.0], rotation=quat([1, 0, 0], -np.pi / 2), extensions=ext(1))
    b.node(rotation=quat([0, 1, 0], np.pi / 2), extensions=ext(2))
    b.node(extensions=ext(3))
    scene = load_asset(b.write_glb(tmp_path / "lights.glb"))
    point, spot, sun, spot_default = scene.lights
    assert point.type == "point" and point.intensity == 5.0 and point.range == 10.0
    np.testing.assert_allclose(point.position, [1.0, 2.0, 0.0])
    np.testing.assert_allclose(point.color, [1.0, 0.5, 0.25])
    # R_x(-90°) maps -Z to (0, sin(-90°), -cos(-90°)) = (0, -1, 0)
    assert spot.type == "spot" and spot.range is None
    np.testing.assert_allclose(spot.position, [0.0, 3.0, 0.0])
    np.testing.assert_allclose(spot.direction, [0.0, -1.0, 0.0], atol=1e-12)
    assert spot.inner_cone_angle == 0.0 and spot.outer_cone_angle == 0.5
    # R_y(90°) maps (x, y, z) to (z, y, -x): -Z becomes -X
    assert sun.type == "directional" and sun.intensity == 3.0
    np.testing.assert_allclose(sun.direction, [-1.0, 0.0, 0.0], atol=1e-12)
    assert spot_default.inner_cone_angle == 0.0
    assert spot_default.outer_cone_angle == pytest.approx(np.pi / 4)
    np.testing.assert_allclose(spot_default.color, [1, 1, 1])
    assert spot_default.intensity == 1.0


def test_texture_transform_matches_spec(tmp_path):
    ox, oy, rot, sx, sy = 0.1, 0.2, 0.3, 2.0, 0.5
    b = GltfBuilder()
    tex = b.texture(b.image(np.full((4, 4, 4), 200, dtype=np.uint8)))
    mat = b.material(texture=tex, texture_extensions={"KHR_texture_transform": {
        "offset": [ox, oy], "rotation": rot, "scale": [sx, sy], "texCoord": 1}})
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    b.node(b.mesh(TRIANGLE, [0, 1, 2], uv0=uv, uv1=uv, material=mat))
    b.use_extension("KHR_texture_transform", required=True)
    scene = load_asset(b.write_glb(tmp_path / "kt.glb"))
    m = scene.materials[0].uv_transform
    assert scene.materials[0].texcoord == 1
    # the spec's transform written out: scale, rotate, offset
    c, s = np.cos(rot), np.sin(rot)
    for u, v in [(0.3, 0.7), (1.0, 0.0), (-0.5, 2.0)]:
        su, sv = sx * u, sy * v
        expected = [c * su + s * sv + ox, -s * su + c * sv + oy]
        np.testing.assert_allclose((m @ [u, v, 1.0])[:2], expected, atol=1e-12)
    # the spec's worked examples: lower-left quadrant rotated 90°, and a T-axis flip
    ex = texture_transform_matrix((0.0, 1.0), np.pi / 2, (0.5, 0.5))
    corners = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1]], dtype=float) @ ex.T
    np.testing.assert_allclose(corners[:, :2].min(axis=0), [0.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(corners[:, :2].max(axis=0), [0.5, 1.0], atol=1e-12)
    flip = texture_transform_matrix((0.0, 1.0), 0.0, (1.0, -1.0))
    np.testing.assert_allclose(flip @ [0.25, 0.1, 1.0], [0.25, 0.9, 1.0])


def test_partial_texcoord1_and_flat_normals(tmp_path):
    b = GltfBuilder()
    # shared vertex 0; triangle A in z=0 (+Z), triangle B in y=0 (+Y); no NORMAL: the spec's
    # flat normals, so vertex 0 is split, one copy per triangle, each with its face normal
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 2], [2, 0, 0]], dtype=float)
    uv1 = np.arange(10, dtype=float).reshape(5, 2) / 10
    b.node(b.mesh(pos, [0, 1, 2, 0, 3, 4], uv1=uv1))
    b.node(b.mesh(TRIANGLE, [0, 1, 2]), translation=[5.0, 0.0, 0.0])
    scene = load_asset(b.write_glb(tmp_path / "uv1.glb"))
    assert len(scene.positions) == 9 and scene.triangle_count == 3
    corners = [0, 1, 2, 0, 3, 4]
    np.testing.assert_allclose(scene.positions[:6], pos[corners], atol=1e-7)
    np.testing.assert_allclose(scene.normals[:3], [[0, 0, 1]] * 3, atol=1e-12)
    np.testing.assert_allclose(scene.normals[3:6], [[0, 1, 0]] * 3, atol=1e-12)
    np.testing.assert_allclose(scene.uv1[:6], uv1[corners], atol=1e-7)
    np.testing.assert_array_equal(scene.uv1[6:], 0.0)
    assert any("TEXCOORD_1" in w for w in scene.warnings)
    assert not scene.has_uv0.any()
    assert load_asset(triangle_builder().write_glb(tmp_path / "t.glb")).uv1 is None


def test_strip_fan_and_skipped_lines(tmp_path):
    b = GltfBuilder()
    strip = np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0], [1, 1, 0], [2, 0, 0]], dtype=float)
    fan = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [-1, 1, 0]], dtype=float)
    b.node(b.mesh(strip, mode=5))
    b.node(b.mesh(fan, mode=6))
    b.node(b.mesh(strip, mode=1))
    scene = load_asset(b.write_glb(tmp_path / "modes.glb"))
    # strip: (0,1,2) then (1,3,2), (2,3,4); fan: (1,2,0), (2,3,0), (3,4,0)
    assert scene.triangle_count == 6
    fn = scene.face_normals()
    # (0,1,2) with v1 = (0,1,0), v2 = (1,0,0) winds clockwise seen from +Z: all three -Z
    np.testing.assert_allclose(fn[:3], [[0, 0, -1]] * 3, atol=1e-12)
    np.testing.assert_allclose(fn[3:], [[0, 0, 1]] * 3, atol=1e-12)
    # no NORMAL: flat normals, one vertex per corner, in the spec's triangle order
    np.testing.assert_allclose(scene.positions[scene.faces[3:]],
                               fan[[[1, 2, 0], [2, 3, 0], [3, 4, 0]]], atol=1e-7)
    assert any("LINES" in w for w in scene.warnings)


def test_sparse_normalized_and_strided_accessors(tmp_path):
    b = GltfBuilder()
    prim = b.primitive(np.zeros((3, 3)), [0, 1, 2])
    b.doc["meshes"].append({"primitives": [prim]})
    b.node(0)
    pos_acc = b.doc["accessors"][prim["attributes"]["POSITION"]]
    # sparse: replace vertices 1 and 2 of the all-zero positions
    pos_acc["sparse"] = {
        "count": 2,
        "indices": {"bufferView": b.buffer_view(np.array([1, 2], np.uint8).tobytes()),
                    "componentType": 5121},
        "values": {"bufferView": b.buffer_view(TRIANGLE[1:].tobytes())},
    }
    del pos_acc["min"], pos_acc["max"]
    # normalized uint8 TEXCOORD_0 and an interleaved (stride 12) uint16 normalized TEXCOORD_1
    prim["attributes"]["TEXCOORD_0"] = b.accessor(
        np.array([[0, 255], [128, 64], [255, 0]], np.uint8), normalized=True)
    inter = np.zeros((3, 6), np.uint16)
    inter[:, :2] = [[0, 65535], [32768, 0], [65535, 65535]]
    inter[:, 2:] = 999  # garbage between elements, must be skipped by byteStride
    bv = b.buffer_view(inter.tobytes(), byteStride=12)
    b.doc["accessors"].append({"bufferView": bv, "componentType": 5123, "count": 3,
                               "type": "VEC2", "normalized": True})
    prim["attributes"]["TEXCOORD_1"] = len(b.doc["accessors"]) - 1
    scene = load_asset(b.write_glb(tmp_path / "acc.glb"))
    np.testing.assert_allclose(scene.positions, TRIANGLE)
    np.testing.assert_allclose(scene.uv0, [[0, 1], [128 / 255, 64 / 255], [1, 0]])
    np.testing.assert_allclose(scene.uv1, [[0, 1], [32768 / 65535, 0], [1, 1]])


def test_skin_rest_pose_and_animation(tmp_path):
    b = GltfBuilder()
    joints = np.array([[0, 0, 0, 0], [1, 0, 0, 0], [0, 1, 0, 0]])
    weights = np.array([[1, 0, 0, 0], [1, 0, 0, 0], [0.5, 0.5, 0, 0]], dtype=float)
    mesh = b.mesh(TRIANGLE, [0, 1, 2], joints=joints, weights=weights)
    j1 = b.node(root=False, translation=[0.0, 1.0, 0.0])
    j0 = b.node(children=[j1], name="root-joint")
    ibm = b.accessor(np.stack([np.eye(4), np.eye(4)]))
    b.doc["skins"] = [{"joints": [j0, j1], "inverseBindMatrices": ibm, "skeleton": j0}]
    skinned = b.node(mesh, translation=[5.0, 0.0, 0.0])  # ignored for skinned meshes
    b.doc["nodes"][skinned]["skin"] = 0
    times = b.accessor(np.array([0.0, 1.0, 2.0]))
    values = b.accessor(np.array([[0, 1, 0], [0, 2, 0], [0, 1, 0]], dtype=float))
    cubic = b.accessor(np.arange(27, dtype=float).reshape(9, 3))
    b.doc["animations"] = [{"name": "lift", "channels": [
        {"sampler": 0, "target": {"node": j1, "path": "translation"}},
        {"sampler": 1, "target": {"node": j1, "path": "scale"}},
        {"sampler": 0, "target": {"path": "pointer"}},
    ], "samplers": [
        {"input": times, "output": values},
        {"input": times, "output": cubic, "interpolation": "CUBICSPLINE"},
    ]}]
    scene = load_asset(b.write_glb(tmp_path / "skin.glb"))
    (skin,) = scene.skins
    assert list(skin.joints) == [j0, j1] and skin.skeleton == j0
    np.testing.assert_allclose(skin.inverse_bind, [np.eye(4)] * 2)
    # vertex 1 follows joint 1 (+1 in y), vertex 2 half of it; the node's +5 x is ignored
    lift = np.array([[0, 0, 0], [0, 1, 0], [0, 0.5, 0]])
    np.testing.assert_allclose(scene.positions, TRIANGLE + lift)
    (inst,) = scene.instances
    np.testing.assert_array_equal(inst.joints, joints)
    np.testing.assert_allclose(inst.weights, weights)
    (anim,) = scene.animations
    assert anim.name == "lift" and len(anim.channels) == 2 and anim.duration == 2.0
    lin, cub = anim.channels
    assert (lin.node, lin.path, lin.interpolation) == (j1, "translation", "LINEAR")
    np.testing.assert_allclose(lin.values, [[0, 1, 0], [0, 2, 0], [0, 1, 0]])
    assert cub.interpolation == "CUBICSPLINE" and cub.values.shape == (9, 3)
    assert any("pointer" in w for w in scene.warnings)


def test_obj_and_ply_through_trimesh(tmp_path):
    obj = tmp_path / "quad.obj"
    obj.write_text("mtllib ../../etc/evil.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
                   "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n")
    scene = load_asset(obj)
    assert scene.triangle_count == 2 and len(scene.materials) == 1
    # OBJ's v points up; glTF's (and Scene's) v points down
    order = np.lexsort(scene.positions.T[::-1])
    np.testing.assert_allclose(scene.uv0[order], [[0, 1], [0, 0], [1, 1], [1, 0]])
    np.testing.assert_allclose(scene.face_normals(), [[0, 0, 1], [0, 0, 1]], atol=1e-12)
    ply = tmp_path / "box.ply"
    trimesh.creation.box().export(ply)
    scene = load_asset(ply)
    assert scene.triangle_count == 12 and scene.uv1 is None
    assert np.isclose(scene.face_areas().sum(), 6.0)
    msg = refused(obj, LimitExceeded, IntakeLimits(max_triangles=1))
    assert "max_triangles=1" in msg


def test_random_corruption_is_refused_or_loads_a_valid_scene(tmp_path):
    """A small textured GLB, corrupted. Per case, decided by where the bytes landed:

    * every byte of the 12-byte GLB header and of both chunk headers (magic, version,
      lengths, chunk types), inverted one at a time: must be refused, with an AssetError
      of one line naming the file;
    * 300 copies with 1–3 random bytes overwritten anywhere: either refused the same way
      (and never when the bytes kept their values), or loaded into a valid scene — finite
      geometry, indices in range, consistent shapes, materials that exist — never a raw
      exception, never a header corruption accepted.

    Measured on this seed: 287 refused (most bytes of this small file are JSON, where a
    random byte rarely stays valid JSON), 13 loaded validly; both outcomes must occur, and
    a loader that stopped refusing would lower the first count."""
    import struct as _struct

    def valid(s, case) -> None:
        nv, nf = len(s.positions), len(s.faces)
        assert s.positions.shape == (nv, 3) and np.isfinite(s.positions).all(), case
        assert s.normals.shape == (nv, 3) and np.isfinite(s.normals).all(), case
        assert s.uv0.shape == (nv, 2) and np.isfinite(s.uv0).all(), case
        assert s.uv1 is None or (s.uv1.shape == (nv, 2) and np.isfinite(s.uv1).all()), case
        assert s.faces.shape == (nf, 3), case
        assert s.face_material.shape == (nf,) and s.face_instance.shape == (nf,), case
        if nf:
            assert 0 <= s.faces.min() and s.faces.max() < nv, case
            assert 0 <= s.face_material.min() and s.face_material.max() < len(s.materials)
        for m in s.materials:
            assert np.isfinite(m.base_color_factor).all(), case

    def outcome(data: bytes):
        path.write_bytes(data)
        try:
            return load_asset(path)
        except AssetError as e:
            assert "\n" not in str(e) and "fuzz.glb" in str(e), str(e)
            return None

    b = GltfBuilder()
    mat = b.material(texture=b.texture(b.image(np.zeros((2, 2, 4), np.uint8))))
    b.node(b.mesh(TRIANGLE, [0, 1, 2], uv0=TRIANGLE[:, :2], material=mat))
    good = b.to_glb()
    path = tmp_path / "fuzz.glb"
    json_len = _struct.unpack_from("<I", good, 12)[0]
    headers = [*range(0, 20), *range(20 + json_len, 28 + json_len)]
    assert good[20 + json_len + 4:20 + json_len + 8] == b"BIN\0"
    original = outcome(good)
    assert original is not None
    for pos in headers:
        data = bytearray(good)
        data[pos] ^= 0xFF
        assert outcome(bytes(data)) is None, f"header byte {pos} inverted: loaded"

    rng = np.random.default_rng(7)
    refused_n = loaded_n = 0
    for case in range(300):
        data = bytearray(good)
        spots = rng.integers(0, len(data), rng.integers(1, 4))
        for pos in spots:
            data[pos] = rng.integers(0, 256)
        changed = sorted({int(p) for p in spots if data[p] != good[p]})
        scene = outcome(bytes(data))
        if scene is None:
            assert changed, (case, "an unchanged file was refused")
            refused_n += 1
            continue
        loaded_n += 1
        assert not set(headers).intersection(changed), (case, changed, "header loaded")
        valid(scene, case)
        if not changed:
            np.testing.assert_array_equal(scene.positions, original.positions)
            np.testing.assert_array_equal(scene.faces, original.faces)
    assert refused_n >= 270 and loaded_n >= 5, (refused_n, loaded_n)


# ------------------------------------------------------------------------------------------
# Hostile inputs: one test per case
# ------------------------------------------------------------------------------------------


def test_path_traversal_uri_never_opens_the_secret(tmp_path, opened):
    path, secret = path_traversal_asset(tmp_path)
    opened.clear()
    msg = refused(path)
    assert "buffers[0].uri" in msg and ".." in msg
    assert os.path.realpath(secret) not in opened
    assert os.path.realpath(path) in opened  # the recorder works


def test_percent_encoded_traversal(tmp_path, opened):
    asset_dir = tmp_path / "asset"
    asset_dir.mkdir()
    (tmp_path / "secret.bin").write_bytes(b"\0" * 64)
    path = uri_buffer_asset(asset_dir, "%2e%2e/secret.bin")
    opened.clear()
    msg = refused(path)
    assert "buffers[0].uri" in msg
    assert os.path.realpath(tmp_path / "secret.bin") not in opened


@pytest.mark.parametrize("uri", ["http://example.com/model.bin", "https://example.com/m.bin",
                                 "file:///etc/passwd", "ftp://example.com/m.bin"])
def test_uri_schemes_refused(tmp_path, no_network, uri):
    msg = refused(uri_buffer_asset(tmp_path, uri))
    assert "buffers[0].uri" in msg and uri.split(":")[0] in msg


def test_absolute_path_uri(tmp_path, opened):
    secret = tmp_path / "secret.bin"
    triangle_builder().write_gltf(tmp_path / "unused.gltf", bin_path=secret)
    asset_dir = tmp_path / "asset"
    asset_dir.mkdir()
    path = uri_buffer_asset(asset_dir, str(secret))
    opened.clear()
    msg = refused(path)
    assert "buffers[0].uri" in msg and "absolute" in msg
    assert os.path.realpath(secret) not in opened


def test_symlink_escaping_the_folder(tmp_path, opened):
    path, secret = symlink_escape_asset(tmp_path)
    opened.clear()
    msg = refused(path)
    assert "buffers[0].uri" in msg and "outside" in msg
    assert os.path.realpath(secret) not in opened


def test_symlink_inside_the_folder_is_fine(tmp_path):
    path = triangle_builder().write_gltf(tmp_path / "model.gltf", bin_uri="link.bin",
                                         bin_path=tmp_path / "real.bin")
    (tmp_path / "link.bin").symlink_to(tmp_path / "real.bin")
    np.testing.assert_allclose(load_asset(path).positions, TRIANGLE)


def test_image_uri_traversal(tmp_path, opened):
    asset_dir = tmp_path / "asset"
    asset_dir.mkdir()
    (tmp_path / "secret.png").write_bytes(b"\x89PNG")
    b = GltfBuilder()
    mat = b.material(texture=b.texture(b.image(np.zeros((2, 2, 4), np.uint8))))
    b.node(b.mesh(TRIANGLE, [0, 1, 2], uv0=TRIANGLE[:, :2], material=mat))
    path = b.write_gltf(asset_dir / "model.gltf", external_images=True)
    doc = json.loads(path.read_text())
    doc["images"][0]["uri"] = "sub/../../secret.png"
    path.write_text(json.dumps(doc))
    opened.clear()
    msg = refused(path)
    assert "images[0].uri" in msg
    assert os.path.realpath(tmp_path / "secret.png") not in opened


def test_accessor_count_far_beyond_its_buffer(tmp_path, no_decode):
    msg = refused(accessor_overrun_asset(tmp_path, count=1_000_000))
    assert "meshes[0].primitives[0].attributes.POSITION" in msg
    assert "accessors[0]" in msg and "bufferViews[0]" in msg and "1000000" in msg


def test_accessor_count_over_limit(tmp_path, no_decode):
    path = accessor_overrun_asset(tmp_path, count=100)
    msg = refused(path, LimitExceeded, IntakeLimits(max_accessor_elements=10))
    assert "accessors[0]" in msg and "max_accessor_elements=10" in msg


def test_giant_data_uri_refused_without_decoding(tmp_path, monkeypatch):
    import base64

    def boom(*args, **kwargs):
        pytest.fail("base64 was decoded before the size check")

    path = data_uri_asset(tmp_path, 4096)
    monkeypatch.setattr(base64, "b64decode", boom)
    msg = refused(path, LimitExceeded, IntakeLimits(max_data_uri_bytes=1024))
    assert "buffers[0].uri" in msg and "max_data_uri_bytes=1024" in msg and "4096" in msg


def test_data_uri_within_limit_and_malformed_base64(tmp_path):
    path = data_uri_asset(tmp_path, 100)
    np.testing.assert_allclose(load_asset(path).positions, TRIANGLE)
    doc = json.loads(path.read_text())
    doc["buffers"][0]["uri"] = doc["buffers"][0]["uri"][:-8] + "!!!!****"
    path.write_text(json.dumps(doc))
    msg = refused(path)
    assert "buffers[0].uri" in msg and "base64" in msg


def test_external_buffer_over_limit(tmp_path, opened):
    path = triangle_builder().write_gltf(tmp_path / "model.gltf")
    bin_size = (tmp_path / "data.bin").stat().st_size
    opened.clear()
    msg = refused(path, LimitExceeded, IntakeLimits(max_buffer_bytes=bin_size - 1))
    assert "buffers[0]" in msg and f"max_buffer_bytes={bin_size - 1}" in msg
    assert os.path.realpath(tmp_path / "data.bin") not in opened


def test_file_over_limit(tmp_path, opened):
    path = triangle_builder().write_glb(tmp_path / "t.glb")
    opened.clear()
    msg = refused(path, LimitExceeded, IntakeLimits(max_file_bytes=100))
    assert "max_file_bytes=100" in msg
    assert os.path.realpath(path) not in opened


def test_truncated_glb(tmp_path):
    path = truncated_glb_asset(tmp_path)
    assert "truncated" in refused(path)
    path.write_bytes(path.read_bytes()[:7])
    assert "truncated" in refused(path)


def test_glb_chunk_running_past_the_end(tmp_path):
    data = bytearray(triangle_builder().to_glb())
    (json_len,) = struct.unpack_from("<I", data, 12)
    struct.pack_into("<I", data, 20 + json_len, 1 << 30)  # BIN chunk length
    path = tmp_path / "chunk.glb"
    path.write_bytes(bytes(data))
    msg = refused(path)
    assert "GLB chunk 1" in msg and "truncated" in msg


def test_wrong_magic(tmp_path):
    assert "magic" in refused(wrong_magic_asset(tmp_path))


@pytest.mark.parametrize("text", [b"{not json", b'{"asset": NaN}', b"\xff\xfe{}", b"[" * 100000])
def test_invalid_json(tmp_path, text):
    assert "invalid JSON" in refused(json_chunk_asset(tmp_path, text))


def test_json_not_an_object(tmp_path):
    assert "must be an object" in refused(json_chunk_asset(tmp_path, b"[1, 2, 3]"))
    path = tmp_path / "list.gltf"
    path.write_text('"a string"')
    assert "must be an object" in refused(path)


@pytest.mark.parametrize("value, word", [(np.nan, "NaN"), (np.inf, "Inf"), (-np.inf, "Inf")])
def test_non_finite_positions(tmp_path, value, word):
    msg = refused(positions_asset(tmp_path, value))
    assert "meshes[0].primitives[0].attributes.POSITION" in msg and "accessors[0]" in msg
    assert word in msg


def test_zero_triangles(tmp_path):
    msg = refused(points_only_asset(tmp_path))
    assert "no triangles" in msg and "scenes[0]" in msg


def test_triangles_over_limit_counts_instances(tmp_path, monkeypatch):
    path = instanced_asset(tmp_path, copies=3)
    assert load_asset(path, IntakeLimits(max_triangles=3)).triangle_count == 3
    forbid_decoding(monkeypatch, lambda *a, **k: pytest.fail("decoded"))
    msg = refused(path, LimitExceeded, IntakeLimits(max_triangles=2))
    assert "scenes[0]" in msg and "max_triangles=2" in msg and "3 triangles" in msg
    msg = refused(path, LimitExceeded, IntakeLimits(max_vertices=8))
    assert "max_vertices=8" in msg and "9 vertices" in msg


def test_texture_pixels_over_limit(tmp_path, monkeypatch):
    from PIL import ImageFile

    path = textured_asset(tmp_path, 64, 32)
    monkeypatch.setattr(ImageFile.ImageFile, "load",
                        lambda self: pytest.fail("pixels decoded before the size check"))
    msg = refused(path, LimitExceeded, IntakeLimits(max_texture_pixels=1000))
    assert "images[0]" in msg and "max_texture_pixels=1000" in msg and "64x32" in msg


def test_too_many_images(tmp_path):
    path = textured_asset(tmp_path, 2, 2)
    msg = refused(path, LimitExceeded, IntakeLimits(max_textures=0))
    assert "images" in msg and "max_textures=0" in msg


def test_undecodable_image(tmp_path):
    b = GltfBuilder()
    bv = b.buffer_view(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)
    b.doc["images"] = [{"bufferView": bv, "mimeType": "image/png"}]
    mat = b.material(texture=b.texture(0))
    b.node(b.mesh(TRIANGLE, [0, 1, 2], uv0=TRIANGLE[:, :2], material=mat))
    msg = refused(b.write_glb(tmp_path / "bad_png.glb"))
    assert "images[0]" in msg and "decode" in msg


@pytest.mark.parametrize("name", ["KHR_draco_mesh_compression", "EXT_meshopt_compression"])
def test_compression_extensions_are_supported(tmp_path, name):
    assert load_asset(required_extension_asset(tmp_path, name)).triangle_count == 1


def test_unknown_required_extension(tmp_path):
    msg = refused(required_extension_asset(tmp_path, "EXT_made_up"), UnsupportedAsset)
    assert "extensionsRequired[0]" in msg and "EXT_made_up" in msg
    ok = required_extension_asset(tmp_path, "KHR_materials_variants")
    assert load_asset(ok).triangle_count == 1


def test_out_of_range_indices(tmp_path):
    msg = refused(indices_asset(tmp_path, [0, 1, 7]))
    assert "meshes[0].primitives[0].indices" in msg and "7" in msg and "3 vertices" in msg


def _set(path_keys, value):
    def patch(doc):
        obj = doc
        for k in path_keys[:-1]:
            obj = obj[k]
        obj[path_keys[-1]] = value
    return patch


@pytest.mark.parametrize("keys, value, where", [
    (("accessors", 0, "count"), "x", "accessors[0].count"),
    (("accessors", 0, "count"), 3.5, "accessors[0].count"),
    (("accessors", 0, "componentType"), True, "accessors[0].componentType"),
    (("accessors", 0, "type"), 3, "accessors[0].type"),
    (("meshes", 0, "primitives", 0, "attributes", "POSITION"), "a",
     "meshes[0].primitives[0].attributes.POSITION"),
    (("meshes", 0, "primitives", 0, "attributes", "POSITION"), 99,
     "meshes[0].primitives[0].attributes.POSITION"),
    (("meshes", 0, "primitives"), {}, "meshes[0].primitives"),
    (("nodes", 0, "translation"), [1, 2], "nodes[0].translation"),
    (("nodes", 0, "children"), [0], "nodes[0].children[0]"),
    (("nodes",), {"0": {}}, "nodes"),
    (("scene",), 1.5, "scene"),
    (("buffers", 0, "byteLength"), -1, "buffers[0].byteLength"),
    (("bufferViews", 0, "byteStride"), 3, "bufferViews[0].byteStride"),
    (("asset",), "2.0", "asset"),
])
def test_wrong_json_types(tmp_path, keys, value, where):
    msg = refused(patched_asset(tmp_path, _set(keys, value)))
    assert where in msg


def test_node_cycle(tmp_path):
    def patch(doc):
        doc["nodes"].append({"children": [2]})
        doc["nodes"].append({"children": [1]})
    assert "cycle" in refused(patched_asset(tmp_path, patch))


def test_glb_buffer_longer_than_bin_chunk(tmp_path):
    b = triangle_builder()
    doc = b.finish()
    doc["buffers"][0]["byteLength"] += 64
    path = tmp_path / "short.glb"
    path.write_bytes(glb_bytes(doc, bytes(b.bin)))
    assert "buffers[0].byteLength" in refused(path)


def test_unsupported_file_type(tmp_path):
    path = tmp_path / "model.fbx"
    path.write_bytes(b"x")
    assert "unsupported file type" in refused(path, UnsupportedAsset)


def test_total_bytes_budget(tmp_path):
    path = textured_asset(tmp_path, 4, 4)
    size = json.loads(path.read_bytes()[20:20 + struct.unpack_from("<I", path.read_bytes(),
                                                                   12)[0]])
    total = size["buffers"][0]["byteLength"]
    msg = refused(path, LimitExceeded, IntakeLimits(max_total_bytes=total - 1))
    assert "buffers" in msg and f"max_total_bytes={total - 1}" in msg
    assert load_asset(path, IntakeLimits(max_total_bytes=total)).triangle_count == 1


def test_spec_gloss_diffuse_is_the_albedo(tmp_path):
    b = triangle_builder()
    b.doc["materials"] = [{"extensions": {"KHR_materials_pbrSpecularGlossiness": {
        "diffuseFactor": [0.2, 0.4, 0.6, 1.0]}}}]
    b.doc["meshes"][0]["primitives"][0]["material"] = 0
    scene = load_asset(b.write_glb(tmp_path / "sg.glb"))
    np.testing.assert_allclose(albedo_at(scene, np.array([0]), np.array([[1 / 3] * 3])),
                               [[0.2, 0.4, 0.6]])


def test_non_base64_data_uri_is_unsupported(tmp_path):
    path = uri_buffer_asset(tmp_path, "data:application/octet-stream,%00%01")
    assert "buffers[0].uri" in refused(path, UnsupportedAsset)
