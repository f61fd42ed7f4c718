"""Scene scale from 1e-3 to 1e4 units, thin walls, coplanar overlapping faces, degenerate
and sliver triangles, huge triangle-count disparity (issue 8)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from stab_helpers import (
    ROOM_BOX,
    TINY,
    Transport,
    assert_bundle_finite,
    bake,
    heldout_rmse,
    scaled_cornell,
    spec_with,
    write_scene,
)
from trimesh.visual.material import PBRMaterial

from prtcore.io.bundle import load_runtime, read_manifest
from prtcore.scenes.cornell import cornell_box
from prtcore.transport.direct import direct_radiance
from prtcore.validate import validate_bundle

#: Bakes of the same room in other units (light boxes scaled, intensities × scale²).
SCALE_RTOL = 1e-5

#: Fixed accuracy bounds (issue 21), measured, not relative to the bake itself. ``pt``:
#: noise-corrected relative RMSE of the bundle against the path tracer
#: (prtcore.validate: every held-out light's error with the reference's own standard error
#: removed, sqrt(max(rmse² − noise², 0))), at the worst n of the table; ``heldout``: the
#: report's held-out error against the fast transport, worst n. For scale: the plain Cornell
#: box with TINY measures pt 0.185 (64 spp, 6 lights), held-out 0.153.
#: coplanar (TINY, 64 spp, 6 lights, seed 0): pt 0.258 (seed 1: 0.289, noise 0.122), held-out
#: 0.169. sphere (128² atlas): 16 spp, 3 lights, seed 0: pt 0.235 (noise 0.243); 64 spp,
#: 6 lights: 0.265 (seed 1: 0.264, noise 0.126); held-out 0.194. Bounds: measured + ~20 %.
COPLANAR_PT, COPLANAR_HELDOUT = 0.31, 0.20
SPHERE_PT_FAST, SPHERE_PT, SPHERE_HELDOUT = 0.29, 0.32, 0.23


def worst_against_path_tracer(bundle, spp: int, count: int) -> float:
    """Worst (over n) mean noise-corrected relative RMSE against the path tracer."""
    v = validate_bundle(bundle, spp=spp, count=count, seed=0)
    return max(r["rmse_noise_corrected_mean"] for r in v["rows"])


def _room_spec(scale: float) -> dict:
    fam = {"type": "point", "position": {"box": (np.array(ROOM_BOX) * scale).tolist()},
           "intensity": {"uniform": [0.5 * scale**2, 3.0 * scale**2]}}
    return spec_with(lights={"families": [fam]})


@pytest.fixture(scope="module")
def unit_room(tmp_path_factory):
    root = tmp_path_factory.mktemp("scale")
    return bake(scaled_cornell(root / "room.glb", 1.0), _room_spec(1.0), root / "b")


@pytest.mark.parametrize("scale", [1e-3, 1e4])
def test_scene_scale_does_not_change_the_bake(unit_room, tmp_path, scale):
    """Millimetres to ten kilometres: the same atlas, dataset and basis. Before the fixes
    the atlas had 203 instead of 229 covered texels at 1e-3 (xatlas saw world units) and
    5 texels' direct light differed (a tie in the choice of their visible origin)."""
    b = bake(scaled_cornell(tmp_path / "room.glb", scale), _room_spec(scale), tmp_path / "b")
    ma, mb = read_manifest(unit_room), assert_bundle_finite(b)
    assert ma["atlas"]["covered_texels"] == mb["atlas"]["covered_texels"]
    a, c = load_runtime(unit_room), load_runtime(b)
    np.testing.assert_array_equal(a.coverage, c.coverage)
    for name in ("planes", "transfer", "offset"):
        x, y = getattr(a, name), getattr(c, name)
        assert np.linalg.norm(x - y) <= SCALE_RTOL * np.linalg.norm(x), name
    ra, rb = heldout_rmse(unit_room), heldout_rmse(b)
    assert ra == pytest.approx(rb, rel=SCALE_RTOL)


def _white(mesh: trimesh.Trimesh, name: str, color=(0.8, 0.8, 0.8)) -> trimesh.Trimesh:
    mesh.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(
        name=name, baseColorFactor=[*color, 1.0], metallicFactor=0.0, roughnessFactor=1.0))
    return mesh


def _floor(half: float = 2.0, y: float = 0.0) -> trimesh.Trimesh:
    from prtcore.scenes.parts import quad as _quad

    c = np.array([[-half, y, half], [half, y, half], [half, y, -half], [-half, y, -half]])
    return _quad(c, subdiv=4)


THIN = 1e-4  # wall thickness, times the scene radius (10× the ray offset)


def test_thin_wall_does_not_leak(tmp_path):
    """A floor split by a closed wall 1e-4 of the scene radius thick, lights on one side:
    nothing on the other side receives direct or indirect light."""
    scene = trimesh.Scene()
    scene.add_geometry(_white(_floor(), "floor"), geom_name="floor")
    radius = float(np.linalg.norm([2.0, 1.0, 2.0]))  # about the bounding sphere's
    t = THIN * radius
    wall = trimesh.creation.box(extents=[t, 2.0, 4.0])
    wall.apply_translation([0.0, 1.0, 0.0])
    wall.unmerge_vertices()
    scene.add_geometry(_white(wall, "wall"), geom_name="wall")
    asset = write_scene(scene, tmp_path / "thin.glb")
    fam = {"type": "point", "position": {"box": [[-1.5, 0.5, -1.0], [-0.5, 1.5, 1.0]]},
           "intensity": {"uniform": [0.5, 3.0]}}
    spec = spec_with(lights={"families": [fam]}, atlas={"resolution": 48})
    tr = Transport(asset, spec)
    train, _ = tr.configurations()
    _, I = tr.dataset(train)
    pts, tx = tr.intake.points, tr.intake.texels
    # direct light per supersample (a measurement point's cluster is a 3-D Voronoi cell and
    # may hold samples from both faces of the wall; the runtime averages the same samples)
    E = direct_radiance(tr.intake.scene, tr.tracer, train, pts.cluster_position,
                        pts.cluster_normal, pts.cluster_albedo)
    right = pts.cluster_position[:, 0] > 0.0
    assert right.sum() >= 10 and (~right).sum() >= 10
    assert np.abs(E[~right]).max() > 0
    assert np.abs(E[right]).max() == 0.0
    right_tex = (tx.position[:, 0] > 0.5) | (tx.normal[:, 0] > 0.99)
    assert right_tex.sum() >= 20
    assert np.abs(I[~right_tex]).max() > 0
    assert np.abs(I[right_tex]).max() == 0.0
    assert_bundle_finite(bake(asset, spec, tmp_path / "b"))


def _cornell_plus(extra: dict[str, trimesh.Trimesh]) -> trimesh.Scene:
    scene = cornell_box()
    for name, mesh in extra.items():
        scene.add_geometry(_white(mesh, name), geom_name=name, node_name=name)
    return scene


def test_coplanar_overlapping_faces(tmp_path):
    """A second floor exactly on the first, and a third 1e-7 of the radius above it."""
    f2 = _floor(1.0)
    f3 = _floor(1.0, y=1e-7 * np.sqrt(3.0))
    asset = write_scene(_cornell_plus({"floor_copy": f2, "floor_lifted": f3}),
                        tmp_path / "coplanar.glb")
    b = bake(asset, TINY, tmp_path / "b")
    m = assert_bundle_finite(b)
    assert m["fit"]["used"] == m["fit"]["configurations"]
    assert max(heldout_rmse(b).values()) <= COPLANAR_HELDOUT, heldout_rmse(b)
    assert worst_against_path_tracer(b, spp=64, count=6) <= COPLANAR_PT


def test_degenerate_and_sliver_triangles(tmp_path):
    """Zero-area (collinear, repeated-vertex) triangles and a sliver (1 m × 1e-6 m, kept:
    above DEGENERATE_AREA_REL) floating in the room: the bake is finite and the two
    degenerate ones are removed by repair and counted."""
    v = np.array([[0.0, 1.0, 0.0], [0.5, 1.0, 0.0], [1.0, 1.0, 0.0],      # collinear
                  [0.2, 1.2, 0.2], [0.2, 1.2, 0.2], [0.4, 1.3, 0.2],      # repeated vertex
                  [-0.5, 0.8, 0.0], [0.5, 0.8, 0.0], [0.0, 0.8 + 1e-6, 0.0],  # sliver
                  [-0.3, 1.5, -0.3], [0.3, 1.5, -0.3], [0.0, 1.5, 0.3]])  # a normal one
    f = np.arange(12).reshape(4, 3)
    junk = trimesh.Trimesh(v, f, process=False, validate=False)
    asset = write_scene(_cornell_plus({"junk": junk}), tmp_path / "junk.glb")
    b = bake(asset, TINY, tmp_path / "b")
    m = assert_bundle_finite(b)
    assert m["fit"]["used"] == m["fit"]["configurations"]
    assert m["prepare"]["repair_counts"]["degenerate_faces"] == 2, m["prepare"]
    assert m["asset"]["triangles"] == m["prepare"]["repair_counts"]["faces_before"] - 2


@pytest.fixture(scope="module")
def sphere_room(tmp_path_factory):
    """A 20 480-triangle sphere in a room of 34 triangles, baked at 128²."""
    root = tmp_path_factory.mktemp("sphere")
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.2)
    sphere.apply_translation([0.3, 1.0, 0.2])
    asset = write_scene(_cornell_plus({"sphere": sphere}), root / "sphere.glb")
    return bake(asset, spec_with(atlas={"resolution": 128}), root / "b")


def test_huge_triangle_count_disparity(sphere_room):
    b = sphere_room
    m = assert_bundle_finite(b)
    assert m["asset"]["triangles"] >= 20480
    assert m["fit"]["used"] == m["fit"]["configurations"]
    assert max(heldout_rmse(b).values()) <= SPHERE_HELDOUT, heldout_rmse(b)
    assert worst_against_path_tracer(b, spp=16, count=3) <= SPHERE_PT_FAST


@pytest.mark.slow
def test_huge_triangle_count_disparity_accurate_reference(sphere_room):
    """The same bound at 64 spp over all 6 held-out lights (~40 s of path tracing)."""
    assert worst_against_path_tracer(sphere_room, spp=64, count=6) <= SPHERE_PT
