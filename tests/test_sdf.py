"""Analytic SDF scenes (prtcore.core.sdf, prtcore.io.sdf) and their learnt transfer
(prtcore.methods.learnt_sh on an ``*.sdf.json`` asset): distances against closed forms,
level-set projection, marching cubes, the file's errors, and the sphere-tracing GL pass
against its CPU twin."""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest

from prtcore.core.errors import AssetError
from prtcore.core.sdf import Primitive, SdfScene, marching_cubes, smooth_min, sphere_trace
from prtcore.io.gltf.loader import load_asset
from prtcore.io.sdf import load_sdf, parse_sdf
from prtcore.scenes.sdf_scenes import BUNNY, OLD_CAR

SPHERE = SdfScene((Primitive("sphere", centre=(0.1, 0.2, -0.3), radius=0.7),),
                  resolution=48)


def test_primitive_distances_match_closed_forms():
    rng = np.random.default_rng(0)
    p = rng.uniform(-2, 2, (500, 3))
    c = np.array([0.1, 0.2, -0.3])
    np.testing.assert_allclose(SPHERE.distance(p), np.linalg.norm(p - c, axis=1) - 0.7)
    box = Primitive("box", half_size=(1.0, 0.5, 0.25), rounding=0.1)
    # along an axis outside the box, and at a corner direction (rounded by 0.1)
    np.testing.assert_allclose(box.distance(np.array([[2.0, 0, 0], [0, -1.5, 0]])),
                               [1.0, 1.0])
    corner = np.array([[1.0, 0.5, 0.25]]) + 0.3 / math.sqrt(3)
    inner = np.array([0.9, 0.4, 0.15])  # the rounded corner's centre
    np.testing.assert_allclose(box.distance(corner),
                               np.linalg.norm(corner - inner) - 0.1)
    torus = Primitive("torus", major=1.0, minor=0.2, axis="z")
    np.testing.assert_allclose(torus.distance(np.array([[0, 1.0, 0.5], [0, 0, 0]])),
                               [0.3, math.hypot(1.0, 0.0) - 0.2])
    cap = Primitive("capsule", a=(0, 0, 0), b=(0, 1, 0), radius=0.1)
    np.testing.assert_allclose(cap.distance(np.array([[0.5, 0.5, 0], [0, 2, 0]])),
                               [0.4, 0.9])
    a, b = rng.normal(size=100), rng.normal(size=100)
    assert np.array_equal(smooth_min(a, b, 0.0), np.minimum(a, b))
    s = smooth_min(a, b, 0.5)
    assert (s <= np.minimum(a, b)).all() and (s >= np.minimum(a, b) - 0.125 - 1e-12).all()


def test_projection_normals_and_marching_cubes_of_a_sphere():
    """Newton projection lands on the zero level set; normals are radial; the marching
    cubes mesh of a sphere has the sphere's area within 1 % and its vertices on it."""
    rng = np.random.default_rng(1)
    c = np.array([0.1, 0.2, -0.3])
    p = c + rng.normal(size=(200, 3))
    q = SPHERE.project(p)
    assert np.abs(SPHERE.distance(q)).max() < 1e-9
    radial = (q - c) / np.linalg.norm(q - c, axis=1, keepdims=True)
    assert np.abs(SPHERE.normal(q) - radial).max() < 1e-6
    pos, faces, nrm = marching_cubes(SPHERE)
    v = pos[faces]
    cross = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1).sum()
    assert abs(area / (4 * math.pi * 0.49) - 1) < 0.01
    assert np.abs(SPHERE.distance(pos)).max() < 0.01 * 0.7
    outward = np.einsum("ij,ij->i", cross, (v.mean(axis=1) - c))
    solid = np.linalg.norm(cross, axis=1) > 1e-12  # marching cubes leaves slivers
    assert solid.mean() > 0.9 and (outward[solid] > 0).all()  # counter-clockwise outside
    assert np.abs(np.linalg.norm(nrm, axis=1) - 1).max() < 1e-12


def test_sphere_trace_hits_a_sphere_where_the_closed_form_does():
    o = np.array([[0.1, 0.2, 3.0], [0.1, 5.0, 3.0]])
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    hit, t = sphere_trace(SPHERE, o, d, 10.0)
    assert hit.tolist() == [True, False]
    assert abs(t[0] - (3.3 - 0.7)) < 1e-4


def test_scene_files_parse_and_errors_name_the_key(tmp_path):
    for data in (BUNNY, OLD_CAR):
        assert len(parse_sdf(data, "x").primitives) == len(data["primitives"])
    bad = copy.deepcopy(BUNNY)
    bad["primitives"][2]["radius"] = -1
    with pytest.raises(AssetError, match=r"primitives\[2\]\.radius"):
        parse_sdf(bad, "b.sdf.json")
    bad = copy.deepcopy(OLD_CAR)
    bad["primitives"][0]["colour"] = 1
    with pytest.raises(AssetError, match=r"primitives\[0\]\.colour"):
        parse_sdf(bad, "c.sdf.json")
    with pytest.raises(AssetError, match="primitives"):
        parse_sdf({"primitives": []}, "e.sdf.json")
    path = tmp_path / "s.sdf.json"
    path.write_text(json.dumps({"primitives": [{"type": "sphere", "centre": [0, 0, 0],
                                                "radius": 1}], "resolution": 16}))
    scene = load_asset(path)  # the marching-cubes mesh, one material of the albedo
    assert scene.triangle_count > 100 and scene.uv1 is None
    assert np.abs(load_sdf(path).distance(scene.positions)).max() < 0.02


@pytest.fixture(scope="module")
def sdf_bundle(tmp_path_factory):
    """A learnt_sh bundle of a coarse bunny (marching cubes at 20 cells) with a tiny
    glossy network, baked through the CLI: (folder of the asset, bundle)."""
    tmp_path = tmp_path_factory.mktemp("sdf")
    from prtcore.cli import main
    from prtcore.scenes.sdf_scenes import write_sdf

    asset = write_sdf(tmp_path / "bunny.sdf.json", dict(BUNNY, resolution=20))
    spec = {"atlas": {"resolution": 96, "padding": 1}, "method": {"name": "learnt_sh"},
            "learnt_sh": {"bands": 3, "width": 16, "layers": 2, "samples": 600,
                          "strata": 4, "steps": 60, "batch": 128, "views": 2,
                          "view_width": 32, "view_height": 24, "baseline_strata": 4,
                          "specular": 0.5}}
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    out = tmp_path / "b"
    assert main(["bake", str(asset), "--spec", str(tmp_path / "spec.json"), "--out",
                 str(out), "-q"]) == 0
    return tmp_path, out


def test_sdf_bake_samples_on_the_level_set_and_gl_sphere_tracing(sdf_bundle, gl_ctx):
    """The bake keeps the field (scene.sdf.json, manifest learnt_sh.sdf); training
    samples lie on the zero level set; the GL full-screen pass (sphere tracing, network at
    the hit) covers the same pixels as the CPU sphere tracer and matches its colour."""
    from prtcore.fit.learnt_sh import level_set_samples
    from prtcore.io.bundle import read_manifest
    from prtcore.methods import learnt_sh
    from prtcore.reference.camera import orbit_cameras
    from prtcore.runtime.learnt_sh import LearntShRenderer

    tmp_path, out = sdf_bundle
    m = read_manifest(out)
    assert m["learnt_sh"]["sdf"]["primitives"] == len(BUNNY["primitives"])
    sdf = load_sdf(out / m["learnt_sh"]["sdf"]["file"])
    mesh = load_asset(tmp_path / "bunny.sdf.json")
    traced, on_level_set = level_set_samples(mesh, 300, 0, sdf)
    assert np.abs(sdf.distance(on_level_set)).max() < 1e-6 * sdf.radius
    # rays start on the mesh, a marching-cubes cell at most from the level set
    gap = np.linalg.norm(traced.position - on_level_set, axis=1)
    assert 0 < gap.max() < 2 * (sdf.bounds()[1] - sdf.bounds()[0]).max() / 20
    model, _ = learnt_sh.load_model(out, m)
    light, _ = learnt_sh.metrics_lighting(3, 0)
    lo, hi = sdf.bounds()
    cam = orbit_cameras((lo + hi) / 2, sdf.radius, 3, 48, 32)[1]
    cpu = learnt_sh.shade_sdf_view(model, sdf, cam, light, specular=0.5, exponent=8.0)
    with LearntShRenderer(out, ctx=gl_ctx) as r:
        gl = r.render(light, cam).image
    assert 0.05 < (cpu[..., 3] > 0).mean() < 0.9
    assert np.mean((gl[..., 3] > 0) != (cpu[..., 3] > 0)) < 0.002
    both = (gl[..., 3] > 0) & (cpu[..., 3] > 0)
    err = np.abs(gl[both][:, :3] - cpu[both][:, :3])
    print(f"SDF pass GL vs CPU: max {err.max():.3g}, median {np.median(err):.3g} of "
          f"{np.abs(cpu).max():.3g}")
    # float32 marching and central differences on the GPU (measured ≈ 4e-5 relative)
    assert err.max() < 1e-3 * np.abs(cpu[..., :3]).max()


def test_report_times_the_sphere_tracing_pass(sdf_bundle, capsys):
    from prtcore.cli import main

    _, out = sdf_bundle
    capsys.readouterr()
    assert main(["report", str(out), "--gpu"]) == 0
    assert "(learnt_sh_sdf pass)" in capsys.readouterr().out
    assert json.loads((out / "report.json").read_text())["gpu_frame"]["median_ms"] > 0
