"""Measurement points (paper 4.1, 5.1): blue noise by weighted sample elimination, hull
placement and supersampling clusters. Scenes are built from arrays / trimesh primitives."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh
from scipy import stats
from scipy.spatial import ConvexHull, cKDTree

from prtcore.core.errors import AssetError, PrtError
from prtcore.core.materials import albedo_at
from prtcore.core.progress import StageTimer
from prtcore.core.scene import Material, PrimitiveInstance, Scene
from prtcore.core.spec import PointsSpec
from prtcore.intake.points import (
    MeasurementPoints,
    closest_points,
    eliminate_samples,
    max_poisson_radius,
    place_measurement_points,
    sample_surface,
)

GREY = Material("default", np.array([0.8, 0.8, 0.8, 1.0]))


def make_scene(positions, faces, normals=None, face_material=None, materials=(GREY,)) -> Scene:
    """A flattened Scene: one primitive instance covering everything, default material."""
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if normals is None:
        normals = trimesh.Trimesh(positions, faces, process=False).vertex_normals
    normals = np.array(normals, dtype=np.float64)
    v, f = len(positions), len(faces)
    inst = PrimitiveInstance(node=0, mesh=0, primitive=0, vertex_start=0, vertex_count=v,
                             face_start=0, face_count=f, object_positions=positions,
                             object_normals=normals, joints=np.zeros((0, 4), np.int32),
                             weights=np.zeros((0, 4)))
    fm = np.zeros(f, np.int32) if face_material is None else np.asarray(face_material, np.int32)
    return Scene(source="test.glb", positions=positions, normals=normals,
                 uv0=np.zeros((v, 2)), uv1=None, faces=faces, face_material=fm,
                 face_instance=np.zeros(f, np.int32), materials=tuple(materials),
                 instances=(inst,))


def unit_square() -> Scene:
    return make_scene([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]])


def sphere() -> Scene:
    m = trimesh.creation.icosphere(subdivisions=4)
    return make_scene(m.vertices, m.faces)


def min_spacing(x: np.ndarray) -> float:
    d, _ = cKDTree(x).query(x, k=2)
    return float(d[:, 1].min())


def hex_spacing(area: float, n: int) -> float:
    """Neighbour distance of n points in a hexagonal packing of ``area``."""
    return float(np.sqrt(2.0 * area / (np.sqrt(3.0) * n)))


def surface_point(scene: Scene, tri: np.ndarray, bary: np.ndarray) -> np.ndarray:
    return np.einsum("nk,nkj->nj", bary, scene.positions[scene.faces[tri]])


# ---------------------------------------------------------------------------------------
# eliminate_samples


def test_max_poisson_radius_closed_forms():
    # Hexagonal packing: each sample owns a hexagon of inradius r, area 2·sqrt(3)·r².
    r = max_poisson_radius(3.0, 7, dims=2)
    assert 7 * 2 * np.sqrt(3) * r**2 == pytest.approx(3.0, rel=1e-12)
    # Value printed by the reference implementation's own tests (area 1, 16 samples).
    assert max_poisson_radius(1.0, 16, dims=2) == pytest.approx(0.1343212, abs=1e-7)
    # FCC packing: each sphere of radius r owns 4·sqrt(2)·r³.
    r3 = max_poisson_radius(2.0, 5, dims=3)
    assert 5 * 4 * np.sqrt(2) * r3**3 == pytest.approx(2.0, rel=1e-12)


def _naive_elimination(x: np.ndarray, target: int, area: float) -> np.ndarray:
    """Yuksel 2015 from scratch: recompute all weights after every removal (O(n³))."""
    n = len(x)
    d_max = 2.0 * np.sqrt(area / (2.0 * np.sqrt(3.0) * target))
    d_min = d_max * (1.0 - (target / n) ** 1.5) * 0.65
    d = np.linalg.norm(x[:, None] - x[None], axis=2)
    w = np.where(d < d_max, (1.0 - np.maximum(d, d_min) / d_max) ** 8, 0.0)
    np.fill_diagonal(w, 0.0)
    alive = np.ones(n, bool)
    for _ in range(n - target):
        weight = np.where(alive, (w * alive[None]).sum(axis=1), -np.inf)
        alive[int(np.argmax(weight))] = False  # argmax: lowest index among ties
    return np.nonzero(alive)[0]


def test_elimination_matches_naive_definition():
    x = np.random.default_rng(7).random((240, 2))
    got = eliminate_samples(x, 48, area=1.0)
    assert got.dtype == np.int64
    np.testing.assert_array_equal(got, _naive_elimination(x, 48, 1.0))


def test_elimination_ties_are_deterministic_and_counts_exact():
    # A regular grid: many exactly equal weights; the result must not depend on anything
    # but the input, and must keep exactly `target` distinct samples.
    g = np.stack(np.meshgrid(np.arange(20.0), np.arange(20.0)), -1).reshape(-1, 2) / 19
    a = eliminate_samples(g, 80, area=1.0)
    b = eliminate_samples(g.copy(), 80, area=1.0)
    np.testing.assert_array_equal(a, b)
    assert len(np.unique(a)) == 80 and np.all(np.diff(a) > 0)
    np.testing.assert_array_equal(eliminate_samples(g, 400, 1.0), np.arange(400))
    with pytest.raises(ValueError):
        eliminate_samples(g, 401, 1.0)


# ---------------------------------------------------------------------------------------
# (1) blue-noise quality


@pytest.mark.parametrize("make", [unit_square, sphere], ids=["square", "sphere"])
def test_blue_noise_spacing(make):
    scene = make()
    p = 256
    area = float(scene.face_areas().sum())
    d_hex = hex_spacing(area, p)
    elim, uniform = [], []
    for seed in range(3):
        mp = place_measurement_points(scene, PointsSpec(count=p, supersample=1, seed=seed))
        assert mp.count == p
        elim.append(min_spacing(mp.position))
        tri, bary = sample_surface(scene, p, np.random.default_rng(1000 + seed))
        uniform.append(min_spacing(surface_point(scene, tri, bary)))
    # Measured (seeds 0–2): d_min / d_hex = 0.76 (square) and 0.73–0.74 (sphere) with the
    # 10× dense set (5× gives 0.71; clamping at r_min instead of 2·r_min gives 0.66);
    # uniform samples have 0.02–0.07, so the ratio of the mean spacings is 16–18. The
    # bound 0.65 leaves ~0.08 of margin over seeds and fails for a broken weight or heap;
    # 8× is far above the brief's 1.5× and about half the smallest measured ratio.
    norm = np.array(elim) / d_hex
    assert norm.min() > 0.65, norm
    assert np.mean(elim) > 8.0 * np.mean(uniform), (np.mean(elim), np.mean(uniform))


# ---------------------------------------------------------------------------------------
# (2) area uniformity


def two_regions() -> tuple[Scene, np.ndarray]:
    """One big right triangle and a copy (shifted by 3) split into 256 small triangles.

    Returns the scene and a (f,) bool mask of the subdivided region's faces.
    """
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    v, f = tri.copy(), np.array([[0, 1, 2]])
    for _ in range(4):
        v, f = trimesh.remesh.subdivide(v, f)
    positions = np.concatenate([tri, v + np.array([3.0, 0.0, 0.0])])
    faces = np.concatenate([[[0, 1, 2]], f + 3])
    fine = np.zeros(len(faces), bool)
    fine[1:] = True
    return make_scene(positions, faces), fine


def test_dense_sampler_is_area_uniform():
    scene, fine = two_regions()
    assert scene.face_areas()[fine].sum() == pytest.approx(scene.face_areas()[0], rel=1e-12)
    n = 40_000
    tri, bary = sample_surface(scene, n, np.random.default_rng(3))
    assert tri.dtype == np.int64 and bary.shape == (n, 3)
    k = int(np.count_nonzero(fine[tri]))
    assert abs(k - n / 2) < 4.0 * np.sqrt(n / 4), k  # binomial(n, 1/2), 4 sigma
    # Chi-square over all 257 faces against n·a_i/A.
    counts = np.bincount(tri, minlength=len(scene.faces))
    expected = n * scene.face_areas() / scene.face_areas().sum()
    assert stats.chisquare(counts, expected).pvalue > 1e-3
    # Within a triangle: uniform in the barycentric simplex (b1 + b2 ≤ 1 area-uniform):
    # the marginal of b0 has CDF 1 − (1 − t)², tested with Kolmogorov-Smirnov.
    assert stats.kstest(bary[:, 0], lambda t: 1 - (1 - t) ** 2).pvalue > 1e-3


def test_eliminated_points_split_by_area():
    scene, fine = two_regions()
    p = 256
    counts = []
    for seed in range(3):
        mp = place_measurement_points(scene, PointsSpec(count=p, supersample=1, seed=seed))
        counts.append(int(np.count_nonzero(fine[mp.triangle])))
    # Both regions are the same triangle, so elimination must treat them alike: p/2 each
    # within 3·sqrt(p)/2 (three binomial sigmas). Measured: 125–128.
    for k in counts:
        assert abs(k - p / 2) <= 3 * np.sqrt(p) / 2, counts


def test_zero_area_faces_never_sampled_and_zero_area_scene_refused():
    base = unit_square()
    # A degenerate (collinear) triangle and a repeated-vertex one, each first in the list.
    pos = np.concatenate([base.positions, [[0.5, 0.5, 0.0], [2.0, 2.0, 0.0]]])
    faces = np.concatenate([[[0, 4, 2], [1, 1, 5]], base.faces])
    scene = make_scene(pos, faces)
    tri, _ = sample_surface(scene, 20_000, np.random.default_rng(0))
    assert set(np.unique(tri)) == {2, 3}
    flat = make_scene(pos, [[0, 4, 2], [1, 1, 5]])
    with pytest.raises(AssetError, match="surface area is zero") as err:
        place_measurement_points(flat, PointsSpec(count=16))
    assert isinstance(err.value, PrtError) and err.value.file == "test.glb"


# ---------------------------------------------------------------------------------------
# (3) points on the surface, normals


def _check_on_surface(scene: Scene, pos, tri, bary):
    assert tri.dtype == np.int64 and np.all((tri >= 0) & (tri < len(scene.faces)))
    np.testing.assert_allclose(bary.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    assert np.all(bary >= 0) and np.all(bary <= 1)
    tol = 1e-12 * scene.radius
    np.testing.assert_allclose(pos, surface_point(scene, tri, bary), rtol=0, atol=tol)
    # Distance to the triangle's plane, computed independently with trimesh.
    fn = scene.face_normals()[tri]
    corner = scene.positions[scene.faces[tri, 0]]
    assert np.abs(np.einsum("ij,ij->i", pos - corner, fn)).max() < tol


def test_points_lie_on_surface_with_face_normals_on_flat_mesh():
    # A tilted, non-axis-aligned plane with vertex normals given as the face normal.
    scene0 = unit_square()
    rot = trimesh.transformations.rotation_matrix(0.7, [1.0, 2.0, 0.5])[:3, :3]
    pos = scene0.positions @ rot.T * 3.0 + [1.0, -2.0, 0.5]
    scene = make_scene(pos, scene0.faces)
    mp = place_measurement_points(scene, PointsSpec(count=64, supersample=4, seed=5))
    _check_on_surface(scene, mp.position, mp.triangle, mp.barycentric)
    _check_on_surface(scene, mp.cluster_position, mp.cluster_triangle, mp.cluster_barycentric)
    face_n = rot @ [0.0, 0.0, 1.0]
    np.testing.assert_allclose(mp.normal, np.broadcast_to(face_n, mp.normal.shape), atol=1e-12)
    np.testing.assert_allclose(mp.albedo, np.full((64, 3), 0.8))
    assert mp.placement == "surface"


def test_normals_interpolated_on_sphere_and_geometric_when_missing():
    scene = sphere()
    mp = place_measurement_points(scene, PointsSpec(count=128, supersample=1, seed=2))
    _check_on_surface(scene, mp.position, mp.triangle, mp.barycentric)
    np.testing.assert_allclose(np.linalg.norm(mp.normal, axis=1), 1.0, atol=1e-12)
    radial = mp.position / np.linalg.norm(mp.position, axis=1, keepdims=True)
    # Interpolated vertex normals are closer to the true radial normal than the facets'.
    err_interp = 1 - np.einsum("ij,ij->i", mp.normal, radial)
    err_face = 1 - np.einsum("ij,ij->i", scene.face_normals()[mp.triangle], radial)
    assert err_interp.mean() < 0.5 * err_face.mean()
    # Zero vertex normals: fall back to the geometric face normal.
    bare = make_scene(scene.positions, scene.faces, normals=np.zeros_like(scene.positions))
    mb = place_measurement_points(bare, PointsSpec(count=128, supersample=1, seed=2))
    np.testing.assert_allclose(mb.normal, scene.face_normals()[mb.triangle], atol=1e-12)


def test_albedo_is_raw_and_per_material():
    scene0 = unit_square()
    red = Material("red", np.array([1.5, 0.1, 0.1, 1.0]))  # > 1: raw, not clamped
    blue = Material("blue", np.array([0.1, 0.2, 0.9, 1.0]))
    scene = make_scene(scene0.positions, scene0.faces, face_material=[0, 1],
                       materials=(red, blue))
    mp = place_measurement_points(scene, PointsSpec(count=32, supersample=2, seed=0))
    want = np.where((mp.triangle == 0)[:, None], red.base_color_factor[:3],
                    blue.base_color_factor[:3])
    np.testing.assert_array_equal(mp.albedo, want)
    assert np.any(mp.triangle == 0) and np.any(mp.triangle == 1)


# ---------------------------------------------------------------------------------------
# (4) supersampling


def test_supersample_clusters():
    scene = sphere()
    p, s = 256, 8
    mp = place_measurement_points(scene, PointsSpec(count=p, supersample=s, seed=4))
    owner = mp.cluster_owner
    assert owner.dtype == np.int32 and np.all(np.diff(owner) >= 0)
    counts = np.bincount(owner, minlength=p)
    assert counts.min() >= 1 and counts.max() <= s
    # Most cells are full (measured 99 % of p·s samples, smallest cluster 5).
    assert counts.sum() >= 0.9 * p * s
    # Each point's own sample is in its cluster (the first row of its block).
    first = np.searchsorted(owner, np.arange(p))
    np.testing.assert_array_equal(mp.cluster_position[first], mp.position)
    np.testing.assert_array_equal(mp.cluster_triangle[first], mp.triangle)
    # Voronoi: every cluster sample's nearest measurement point is its owner.
    d_own = np.linalg.norm(mp.cluster_position - mp.position[owner], axis=1)
    d_near, _ = cKDTree(mp.position).query(mp.cluster_position, k=1)
    np.testing.assert_allclose(d_own, d_near, rtol=0, atol=1e-12)
    # Clusters are local: measured max 0.79 and mean 0.28 of the point spacing.
    d_hex = hex_spacing(float(scene.face_areas().sum()), p)
    assert d_own.max() < 1.0 * d_hex and d_own.mean() < 0.4 * d_hex
    _check_on_surface(scene, mp.cluster_position, mp.cluster_triangle, mp.cluster_barycentric)
    np.testing.assert_allclose(np.linalg.norm(mp.cluster_normal, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(mp.cluster_albedo, albedo_at(scene, mp.cluster_triangle,
                                                            mp.cluster_barycentric))


def test_supersample_one_is_the_points_themselves():
    mp = place_measurement_points(unit_square(), PointsSpec(count=40, supersample=1, seed=9))
    np.testing.assert_array_equal(mp.cluster_owner, np.arange(40))
    for a, b in [("position", "cluster_position"), ("normal", "cluster_normal"),
                 ("albedo", "cluster_albedo"), ("triangle", "cluster_triangle"),
                 ("barycentric", "cluster_barycentric")]:
        np.testing.assert_array_equal(getattr(mp, a), getattr(mp, b))


# ---------------------------------------------------------------------------------------
# (5) hull placement


def torus_scene() -> Scene:
    m = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3, major_sections=48,
                               minor_sections=16)
    cx = m.triangles_center[:, 0]
    red = Material("red", np.array([0.9, 0.1, 0.1, 1.0]))
    return make_scene(m.vertices, m.faces, face_material=(cx > 0).astype(np.int32),
                      materials=(GREY, red))


def test_hull_placement_on_concave_mesh():
    scene = torus_scene()
    p = 128
    mp = place_measurement_points(scene, PointsSpec(count=p, placement="hull", supersample=4,
                                                    seed=1))
    assert mp.placement == "hull" and mp.count == p
    hull = ConvexHull(scene.positions)
    unit = hull.equations[:, :3] / np.linalg.norm(hull.equations[:, :3], axis=1)[:, None]
    offs = hull.equations[:, 3] / np.linalg.norm(hull.equations[:, :3], axis=1)
    tol = 1e-9 * scene.radius
    for pos, nrm in [(mp.position, mp.normal), (mp.cluster_position, mp.cluster_normal)]:
        signed = pos @ unit.T + offs  # ≤ 0 inside every half-space
        assert signed.max() < tol  # inside (or on) the hull …
        assert np.abs(signed.max(axis=1)).max() < tol  # … and on its boundary
        # The normal is the outward normal of a hull facet the point lies on.
        match = (np.abs(signed) < tol) & (nrm @ unit.T > 1 - 1e-12)
        assert match.any(axis=1).all()
    # The hull of a torus covers its hole: some points float far off the surface.
    asset = surface_point(scene, mp.triangle, mp.barycentric)
    gap = np.linalg.norm(mp.position - asset, axis=1)
    assert gap.max() > 0.2
    # triangle/barycentric name a valid asset point at least as close as any of a dense
    # set of surface samples (an independent brute-force closest point).
    np.testing.assert_allclose(mp.barycentric.sum(axis=1), 1.0, atol=1e-12)
    assert np.all(mp.barycentric >= 0)
    tri, bary = sample_surface(scene, 50_000, np.random.default_rng(0))
    brute, _ = cKDTree(surface_point(scene, tri, bary)).query(mp.position, k=1)
    assert np.all(gap <= brute + 1e-9)
    np.testing.assert_array_equal(mp.albedo, albedo_at(scene, mp.triangle, mp.barycentric))
    assert np.any(mp.albedo[:, 1] < 0.5) and np.any(mp.albedo[:, 1] > 0.5)  # both materials


def test_closest_points_match_trimesh():
    # Mixed face sizes (a fine torus plus one huge triangle) exercise the size buckets.
    m = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3, major_sections=32,
                               minor_sections=12)
    big = np.array([[-5.0, -2.0, -5.0], [5.0, -2.0, -5.0], [0.0, -2.0, 5.0]])
    pos = np.concatenate([m.vertices, big])
    faces = np.concatenate([m.faces, [[len(m.vertices), len(m.vertices) + 1,
                                       len(m.vertices) + 2]]])
    q = np.random.default_rng(5).uniform(-3, 3, size=(500, 3))
    got, face = closest_points(pos, faces, q)
    ref, ref_d, _ = trimesh.proximity.closest_point(trimesh.Trimesh(pos, faces, process=False), q)
    np.testing.assert_allclose(np.linalg.norm(got - q, axis=1), ref_d, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got, ref, atol=1e-9)
    # The returned face holds the returned point.
    on = trimesh.triangles.closest_point(pos[faces[face]], got)
    np.testing.assert_allclose(on, got, atol=1e-12)
    assert np.any(face == len(faces) - 1) and np.any(face < len(faces) - 1)


def test_hull_refuses_flat_asset():
    with pytest.raises(AssetError, match="coplanar"):
        place_measurement_points(unit_square(), PointsSpec(count=16, placement="hull"))


# ---------------------------------------------------------------------------------------
# (6) determinism and seeds


@pytest.mark.parametrize("placement", ["surface", "hull"])
def test_deterministic_and_seed_sensitive(placement):
    scene = torus_scene()
    spec = PointsSpec(count=64, placement=placement, supersample=3, seed=11)
    timer = StageTimer(quiet=True)
    a = place_measurement_points(scene, spec, timer)
    b = place_measurement_points(scene, spec)
    assert "points" in timer.seconds
    for f in dataclasses.fields(MeasurementPoints):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), f.name
    c = place_measurement_points(scene, dataclasses.replace(spec, seed=12))
    assert not np.array_equal(a.position, c.position)
    # Different seeds must not merely permute: most points move.
    d, _ = cKDTree(c.position).query(a.position, k=1)
    assert np.count_nonzero(d > 1e-6) > 0.9 * len(d)


# ---------------------------------------------------------------------------------------
# (7) average_clusters


def test_average_clusters_is_per_owner_mean():
    mp = place_measurement_points(sphere(), PointsSpec(count=50, supersample=6, seed=3))
    values = np.random.default_rng(1).normal(size=(len(mp.cluster_owner), 3))
    got = mp.average_clusters(values)
    assert got.shape == (50, 3)
    for i in range(50):
        np.testing.assert_allclose(got[i], values[mp.cluster_owner == i].mean(axis=0),
                                   rtol=1e-12, atol=1e-12)
