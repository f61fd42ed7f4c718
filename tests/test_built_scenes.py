"""The test scenes the project builds for issue 13: the open L-shaped room and the house
on a ground plane. They load through the hardened loader (factor-only Lambertian
materials, normals, no TEXCOORD_0), face the right way, and bake at a small size with
their own light families."""

from __future__ import annotations

import copy
import json

import numpy as np
import pygltflib
import pytest
from scenes import TINY_SPEC

from prtcore import pipeline
from prtcore.core.raytrace import RayTracer
from prtcore.core.spec import parse_spec
from prtcore.emitters.families import sample_configurations
from prtcore.emitters.punctual import irradiance
from prtcore.io.gltf.loader import load_asset
from prtcore.scenes import exterior, open_room

BUILT = {
    "open_room": (open_room.write_open_room, open_room.SPEC, open_room.ALBEDO),
    "exterior": (exterior.write_exterior, exterior.SPEC, exterior.ALBEDO),
}


@pytest.mark.parametrize("name", list(BUILT))
def test_glb_has_normals_factor_materials_and_no_texcoords(tmp_path, name):
    write, _, albedo = BUILT[name]
    path = write(tmp_path / f"{name}.glb")
    g = pygltflib.GLTF2().load(str(path))
    for mesh in g.meshes:
        for prim in mesh.primitives:
            attrs = prim.attributes
            assert attrs.NORMAL is not None
            assert attrs.TEXCOORD_0 is None and attrs.TEXCOORD_1 is None
    by_name = {m.name: m for m in g.materials}
    assert set(by_name) == set(albedo)
    for mname, rgb in albedo.items():
        pbr = by_name[mname].pbrMetallicRoughness
        assert pbr.baseColorTexture is None
        assert pbr.metallicFactor == 0.0 and pbr.roughnessFactor == 1.0
        np.testing.assert_allclose(pbr.baseColorFactor[:3], rgb, atol=1 / 255)
    # varied albedos: no two parts alike, some coloured
    rgbs = np.array(list(albedo.values()))
    assert len({tuple(np.round(c, 3)) for c in rgbs}) == len(rgbs)
    assert np.ptp(rgbs, axis=1).max() > 0.3
    scene = load_asset(path)
    assert scene.triangle_count > 0 and np.isfinite(scene.positions).all()


def test_open_room_faces_inward():
    scene = open_room.open_room()

    def inside_l(p):
        x, y, z = p.T
        leg_a = (x > 0) & (x < 4) & (z > 0) & (z < 2)
        leg_b = (x > 0) & (x < 2) & (z >= 2) & (z < 4)
        return (leg_a | leg_b) & (y > 0) & (y < open_room.HEIGHT)

    shell = [n for n in scene.geometry if n == "floor" or n.startswith("wall_")]
    assert len(shell) == 6
    for name in shell:
        m = scene.geometry[name]
        # every face of the floor and the walls sees the room's air
        assert inside_l(m.triangles_center + 0.05 * m.face_normals).all(), name
    # the occluders are closed solids with outward faces
    for name in ("pillar", "low_wall"):
        m = scene.geometry[name].copy()
        m.merge_vertices()
        assert m.is_watertight and m.volume > 0, name
    # open: no ceiling, and the end of leg B (z = 4) has no wall
    everything = [scene.geometry[n] for n in scene.geometry]
    centres = np.concatenate([m.triangles_center for m in everything])
    normals = np.concatenate([m.face_normals for m in everything])
    assert not np.any((normals[:, 1] < -0.5) & (centres[:, 1] > 0.01))  # only block bottoms
    assert not np.any(np.isclose(centres[:, 2], 4.0) & (np.abs(normals[:, 2]) > 0.5))


def test_exterior_ground_faces_up_and_solids_are_closed():
    scene = exterior.house()
    ground = scene.geometry["ground"]
    assert np.all(ground.face_normals[:, 1] > 0.99)
    for name in ("body", "roof", "chimney", "garden_wall"):
        m = scene.geometry[name].copy()
        m.merge_vertices()
        assert m.is_watertight and m.volume > 0, name  # closed, outward


@pytest.mark.parametrize("name", list(BUILT))
def test_light_family_lights_the_scene(tmp_path, name):
    write, spec_d, _ = BUILT[name]
    scene = load_asset(write(tmp_path / f"{name}.glb"))
    spec = parse_spec(spec_d)
    train, hold = sample_configurations(spec.lights, scene.center, scene.radius)
    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    # the floor / ground's centre area receives direct light from most configurations
    probe = np.array([[1.0, 1e-3, 0.5], [3.5, 1e-3, 1.5], [1.0, 1e-3, 3.5]]
                     if name == "open_room" else [[2.0, 1e-3, -2.0], [-3.0, 1e-3, 3.0]])
    up = np.tile([0.0, 1.0, 0.0], (len(probe), 1))
    lit = [float(irradiance(light, probe, up, tracer).max()) > 0 for light in train]
    assert np.mean(lit) > 0.6
    kinds = {light.type for light in (*train, *hold)}
    assert kinds == ({"point"} if name == "open_room" else {"point", "directional"})


@pytest.mark.parametrize("name", list(BUILT))
def test_bakes_at_small_size(tmp_path, name):
    write, spec_d, _ = BUILT[name]
    asset = write(tmp_path / f"{name}.glb")
    spec = copy.deepcopy(TINY_SPEC)
    spec["lights"] = {**copy.deepcopy(spec_d["lights"]), "count": 24, "holdout": 4}
    out = pipeline.bake(asset, parse_spec(spec), tmp_path / "bundle", quiet=True)
    report = json.loads((out / "report.json").read_text())
    rows = report["table"]["rows"]
    assert rows and all(np.isfinite(r["heldout_rmse_mean"]) for r in rows)
    assert report["fit"]["used"] >= 20
    # a basis that explains the held-out lights: the error at the largest n is moderate
    assert rows[-1]["projection_bound_mean"] < 0.6
