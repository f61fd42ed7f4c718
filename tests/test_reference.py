"""The reference path tracer against closed forms and independent quadrature.

Scenes and texel spaces are built by hand here (analytic geometry, texels at chosen
surface points), so these tests depend only on the tracer, the lights and the albedo.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import trimesh
from scenes import inside_sphere, point_light, quad, quad_normal
from scipy import integrate

from prtcore.core.materials import albedo_at
from prtcore.core.progress import StageTimer
from prtcore.core.scene import Light, Material, Scene
from prtcore.emitters.punctual import unshadowed_irradiance
from prtcore.receivers.texels import TexelSpace, sample_texel_regions, texel_centres, texel_regions
from prtcore.reference.pathtracer import (
    cosine_directions,
    default_tracer,
    reference_direct,
    reference_lightmap,
    reference_lightmap_with_error,
    reference_lightmaps,
)
from prtcore.scenes import cornell

# ---------------------------------------------------------------------------------------
# Hand-built scenes and texel spaces


def make_scene(parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, tuple]]) -> Scene:
    """parts: (vertices (v, 3), faces (f, 3) CCW front, vertex normals (v, 3), rgb)."""
    pos, nor, fac, fmat, mats = [], [], [], [], []
    base = 0
    for i, (v, f, n, rgb) in enumerate(parts):
        pos.append(np.asarray(v, float))
        nor.append(np.asarray(n, float))
        fac.append(np.asarray(f, np.int64) + base)
        fmat.append(np.full(len(f), i, np.int32))
        mats.append(Material(f"m{i}", np.array([*rgb, 1.0])))
        base += len(v)
    positions = np.concatenate(pos)
    faces = np.concatenate(fac)
    return Scene(source="test", positions=positions, normals=np.concatenate(nor),
                 uv0=np.zeros((len(positions), 2)), uv1=None, faces=faces,
                 face_material=np.concatenate(fmat),
                 face_instance=np.zeros(len(faces), np.int32), materials=tuple(mats))


def quad_part(corners, rgb, subdiv: int = 2):
    """A part for make_scene: the shared quad (tests/scenes.py) with its flat normal."""
    v, f = quad(corners, subdiv)
    return v, f, np.broadcast_to(quad_normal(corners), v.shape).copy(), rgb


def make_texels(scene: Scene, triangle: np.ndarray, barycentric: np.ndarray,
                size: float) -> TexelSpace:
    """Texels at (triangle, barycentric) with a square footprint of side ``size`` in the
    triangle's plane."""
    triangle = np.asarray(triangle, np.int64)
    v = scene.positions[scene.faces[triangle]]
    p = np.einsum("nk,nkj->nj", barycentric, v)
    n = np.einsum("nk,nkj->nj", barycentric, scene.normals[scene.faces[triangle]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    g = scene.face_normals()[triangle]
    e1 = v[:, 1] - v[:, 0]
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(g, e1)
    t = len(triangle)
    return TexelSpace(width=64, height=64, xy=np.zeros((t, 2), np.int32), position=p,
                      normal=n, geometric_normal=g,
                      albedo=albedo_at(scene, triangle, barycentric), triangle=triangle,
                      barycentric=np.asarray(barycentric, float),
                      coverage=np.ones(t, np.float32),
                      footprint=np.stack([e1 * size, e2 * size], axis=1),
                      dilate_xy=np.zeros((0, 2), np.int32),
                      dilate_src=np.zeros(0, np.int64))


def texels_at_points(scene: Scene, points: np.ndarray, size: float,
                     faces: np.ndarray | None = None) -> TexelSpace:
    """Texels at given surface points (located with trimesh's closest-point query, among
    ``faces`` (indices) when given)."""
    faces = np.arange(len(scene.faces)) if faces is None else np.asarray(faces)
    mesh = trimesh.Trimesh(scene.positions, scene.faces[faces], process=False)
    _, _, tri = trimesh.proximity.closest_point(mesh, points)
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[tri], points)
    return make_texels(scene, faces[tri], bary, size)


def random_texels(scene: Scene, count: int, size: float, seed: int) -> TexelSpace:
    """Area-uniform random texels over the whole scene."""
    rng = np.random.default_rng(seed)
    a = scene.face_areas()
    tri = rng.choice(len(a), size=count, p=a / a.sum())
    u = rng.random((count, 2))
    flip = u.sum(axis=1) > 1
    u[flip] = 1 - u[flip]
    bary = np.stack([1 - u[:, 0] - u[:, 1], u[:, 0], u[:, 1]], axis=1)
    return make_texels(scene, tri, bary, size)


def sphere_scene(subdivisions: int, radius: float, rgb) -> Scene:
    """The inside of a sphere (tests/scenes.py), radial inward normals, albedo ``rgb``."""
    return make_scene([(*inside_sphere(subdivisions, radius), rgb)])


def cornell_scene() -> Scene:
    """The project's Cornell box, flattened by hand (no loader needed)."""
    colors = {"left": cornell.RED, "right": cornell.GREEN}
    box = cornell.cornell_box()
    parts = []
    for name in box.graph.nodes_geometry:
        transform, geom = box.graph[name]
        mesh = box.geometry[geom].copy()
        mesh.apply_transform(transform)
        parts.append((np.asarray(mesh.vertices), np.asarray(mesh.faces), _flat_normals(mesh),
                      colors.get(name, cornell.WHITE)))
    return make_scene(parts)


def _flat_normals(mesh: trimesh.Trimesh) -> np.ndarray:
    """Per-vertex normals for meshes whose faces around a vertex are coplanar."""
    n = np.zeros_like(np.asarray(mesh.vertices, float))
    n[mesh.faces.ravel()] = np.repeat(mesh.face_normals, 3, axis=0)
    return n


# ---------------------------------------------------------------------------------------
# Building blocks


def test_cosine_directions_distribution():
    """Malley's method: unit vectors in the upper hemisphere with E[cosθ] = 2/3 and
    E[cos²θ] = 1/2 (pdf cosθ/π), for normals of every orientation."""
    rng = np.random.default_rng(0)
    for n0 in ([0, 0, 1], [0, 0, -1], [1, 0, 0], [0.3, -0.5, 0.81]):
        n = np.asarray(n0, float) / np.linalg.norm(n0)
        normals = np.broadcast_to(n, (200_000, 3)).copy()
        d = cosine_directions(normals, rng.random((200_000, 2)))
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
        c = d @ n
        assert c.min() >= 0.0
        assert abs(c.mean() - 2 / 3) < 5e-3
        assert abs((c * c).mean() - 0.5) < 5e-3
        # azimuthally symmetric: the mean direction is along the normal
        np.testing.assert_allclose(d.mean(axis=0), n * 2 / 3, atol=5e-3)


def test_texel_regions_are_sampled_uniformly_on_the_texel_triangle():
    """One triangle with TEXCOORD_1 on a 4×4 atlas: world = (2u, 0, 2v), so one texel step
    is 0.5 m. Texel (2, 1) has its centre on the hypotenuse: its path origins must be
    uniform over the half of its square that lies on the triangle; texel (3, 1) has its
    centre off the triangle (its sample is the closest triangle point) and the centre is
    recovered from the sample and the footprint. On a 4×5 atlas, texel (3, 1) covers 2.5 %
    of its square (rejection sampling with a fallback to the sample put most origins on
    the texel's sample) and is sampled as uniformly as a full one."""
    v = np.array([[0, 0, 0], [0, 0, 2], [2, 0, 0]], float)  # CCW seen from +y
    uv1 = np.array([[0, 0], [0, 1], [1, 0]], float)
    scene = make_scene([(v, np.array([[0, 1, 2]]), np.array([[0, 1.0, 0]] * 3),
                         (0.5, 0.5, 0.5))]).replace(uv1=uv1)
    xy = np.array([[2, 1], [3, 1]], np.int32)
    centre_uv = (xy + 0.5) / 4  # (0.625, 0.375) on u + v = 1; (0.875, 0.375) beyond it
    sample_uv = np.array([[0.625, 0.375], [0.75, 0.25]])  # the closest points on the triangle
    # barycentrics of the samples: uv = b1·(0,1) + b2·(1,0)
    bary = np.stack([1 - sample_uv.sum(1), sample_uv[:, 1], sample_uv[:, 0]], axis=1)
    tx = make_texels(scene, np.array([0, 0]), bary, 0.5)
    tx = dataclasses.replace(tx, width=4, height=4, xy=xy, footprint=np.array(
        [[[0.5, 0, 0], [0, 0, 0.5]]] * 2))
    np.testing.assert_allclose(tx.position, [[1.25, 0, 0.75], [1.5, 0, 0.5]], atol=1e-12)
    c = texel_centres(scene, tx)
    np.testing.assert_allclose(c, np.column_stack([2 * centre_uv[:, 0], [0, 0],
                                                   2 * centre_uv[:, 1]]), atol=1e-12)
    regions = texel_regions(scene, tx)
    rng = np.random.default_rng(0)
    n = 40_000
    b = sample_texel_regions(regions, np.zeros(n, np.int64), rng)
    assert b.min() >= 0 and np.allclose(b.sum(axis=1), 1.0)
    p = b @ v
    # inside the texel square [1, 1.5] × [0.5, 1] (world x, z) and on the triangle
    assert p[:, 0].min() >= 1.0 - 1e-12 and p[:, 0].max() <= 1.5 + 1e-12
    assert p[:, 2].min() >= 0.5 - 1e-12 and p[:, 2].max() <= 1.0 + 1e-12
    assert (p[:, 0] + p[:, 2]).max() <= 2.0 + 1e-12
    # uniform over that half square: the mean is its centroid (1+1.5+1, 0.5+0.5+1)/3
    np.testing.assert_allclose(p[:, [0, 2]].mean(axis=0), [7 / 6, 2 / 3], atol=4e-3)
    assert abs(np.mean(p[:, 0] < 1.25) - 0.75) < 0.01  # area left of x = 1.25: 3/4
    # texel (3, 1) touches the triangle in one corner only: every origin is its sample
    b1 = sample_texel_regions(regions, np.ones(50, np.int64), rng)
    np.testing.assert_allclose(b1 @ v, np.broadcast_to(tx.position[1], (50, 3)), atol=1e-12)
    # 4×5 atlas, texel (3, 1): square u ∈ [0.75, 1], v ∈ [0.2, 0.4]; u + v ≤ 1 leaves the
    # corner triangle uv (0.75, 0.2), (0.8, 0.2), (0.75, 0.25) = world (1.5, 0.4),
    # (1.6, 0.4), (1.5, 0.5); its sample is the closest point (0.7875, 0.2125)
    s_uv = np.array([[0.7875, 0.2125]])
    tx2 = make_texels(scene, np.array([0]), np.stack(
        [1 - s_uv.sum(1), s_uv[:, 1], s_uv[:, 0]], axis=1), 0.5)
    tx2 = dataclasses.replace(tx2, width=4, height=5, xy=np.array([[3, 1]], np.int32),
                              footprint=np.array([[[0.5, 0, 0], [0, 0, 0.4]]]))
    np.testing.assert_allclose(texel_centres(scene, tx2), [[1.75, 0, 0.6]], atol=1e-12)
    p2 = sample_texel_regions(texel_regions(scene, tx2), np.zeros(n, np.int64), rng) @ v
    assert (p2[:, 0] + p2[:, 2]).max() <= 2.0 + 1e-12
    assert p2[:, 0].min() >= 1.5 - 1e-12 and p2[:, 2].min() >= 0.4 - 1e-12
    np.testing.assert_allclose(p2[:, [0, 2]].mean(axis=0), [4.6 / 3, 1.3 / 3], atol=1e-3)
    assert len(np.unique(p2.round(9), axis=0)) == n  # no origin piles up on the sample
    # a texel of zero footprint is a point (a camera reference's pixel hit, whose xy are
    # pixel coordinates, not atlas texels): every origin is its sample, TEXCOORD_1 or not
    pts = dataclasses.replace(tx, footprint=np.zeros((2, 2, 3)))
    b3 = sample_texel_regions(texel_regions(scene, pts), np.array([0, 1] * 20), rng)
    np.testing.assert_allclose(b3 @ v, np.tile(tx.position, (20, 1)), atol=1e-12)


# ---------------------------------------------------------------------------------------
# Closed forms


def test_single_plane_has_no_indirect_and_direct_closed_form():
    rho = (0.2, 0.5, 0.8)
    scene = make_scene([quad_part([[-1, 0, 1], [1, 0, 1], [1, 0, -1], [-1, 0, -1]], rho)])
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-0.9, 0.9, 30), np.zeros(30), rng.uniform(-0.9, 0.9, 30)])
    tx = texels_at_points(scene, pts, 0.05)
    light = point_light([0.3, 0.8, -0.2], 2.5, (1.0, 0.5, 0.25))
    ind = reference_lightmap(scene, tx, [light], spp=64, seed=1)
    assert np.array_equal(ind, np.zeros_like(ind))  # every path escapes: exactly 0
    d = light.position - pts
    r = np.linalg.norm(d, axis=1)
    e = 2.5 * (d[:, 1] / r) / r**2
    expected = np.asarray(rho) / math.pi * e[:, None] * light.color
    np.testing.assert_allclose(reference_direct(scene, tx, [light], None), expected,
                               rtol=1e-12)


def test_back_faces_end_paths():
    """A floor under a one-sided lid that faces up (away from the floor), light above the
    lid: the floor is in shadow and its paths only hit the lid's back: no light inside
    geometry, so exactly zero indirect (a tracer shading back hits would see the lit top)."""
    floor = quad_part([[-1, 0, 1], [1, 0, 1], [1, 0, -1], [-1, 0, -1]], (0.5, 0.5, 0.5))
    lid = quad_part([[-3, 1, 3], [3, 1, 3], [3, 1, -3], [-3, 1, -3]], (0.9, 0.9, 0.9))
    scene = make_scene([floor, lid])
    tx = texels_at_points(scene, np.array([[0.0, 0.0, 0.0], [0.5, 0.0, -0.3]]), 0.05)
    light = point_light([0.0, 2.0, 0.0], 5.0)
    assert reference_direct(scene, tx, [light], None).max() == 0.0
    assert reference_lightmap(scene, tx, [light], spp=256, seed=0).max() == 0.0
    # the lid's top is lit, so a back hit shaded as a front hit would not give zero
    lid_tx = texels_at_points(scene, np.array([[0.0, 1.0, 0.0]]), 0.05)
    assert reference_direct(scene, lid_tx, [light], None).min() > 0.0


def test_furnace_sphere_closed_form():
    """Inside a sphere of albedo ρ with a point light at its centre, E_d = I/R² everywhere
    and every bounce sees the uniform sphere: L_ind = ρ/π · E_d · ρ/(1−ρ). The icosphere is
    not a sphere: its faces lie between the inradius r_in and R, so E_d is within
    [1, R²/r_in²]·I/R²; the tolerance is that factor plus 4 standard errors."""
    R, inten = 2.0, 3.0
    rho = np.array([0.3, 0.5, 0.7])
    scene = sphere_scene(4, R, tuple(rho))
    tri = np.random.default_rng(0).choice(len(scene.faces), 96, replace=False)
    tx = make_texels(scene, tri, np.full((96, 3), 1 / 3), 0.02)
    mean, err = reference_lightmap_with_error(scene, tx, [point_light([0, 0, 0], inten)],
                                              spp=128, seed=5)
    expected = rho / math.pi * inten / R**2 * rho / (1 - rho)
    fn = scene.face_normals()
    r_in = np.abs(np.einsum("ij,ij->i", scene.positions[scene.faces[:, 0]], fn)).min()
    facet = R**2 / r_in**2 - 1  # ≈ 0.0023 for 4 subdivisions
    pooled = mean.mean(axis=0)
    pooled_err = np.sqrt((err**2).sum(axis=0)) / len(mean)
    rel = pooled / expected - 1
    assert np.all(np.abs(rel) <= facet + 4 * pooled_err / expected), (rel, pooled_err)
    # per texel as well (each texel's own error bar)
    assert np.all(np.abs(mean / expected - 1) <= facet + 5 * err / expected + 1e-12)


def test_furnace_depth_limited_closed_form_with_and_without_rr():
    """Depth-limited furnace: L = ρ/π · E_d · Σ_{j=1..D} ρ^j, with Russian roulette from the
    first bounce and without any (rr_depth ≥ max_depth)."""
    R, inten, depth = 1.0, 1.0, 4
    rho = np.array([0.4, 0.6, 0.8])
    scene = sphere_scene(4, R, tuple(rho))
    tri = np.random.default_rng(1).choice(len(scene.faces), 64, replace=False)
    tx = make_texels(scene, tri, np.full((64, 3), 1 / 3), 0.02)
    light = [point_light([0, 0, 0], inten)]
    expected = rho / math.pi * inten / R**2 * sum(rho**j for j in range(1, depth + 1))
    r_in = np.abs(np.einsum("ij,ij->i", scene.positions[scene.faces[:, 0]],
                            scene.face_normals())).min()
    facet = R**2 / r_in**2 - 1
    for rr_depth in (1, depth):
        mean, err = reference_lightmap_with_error(scene, tx, light, spp=128, seed=2,
                                                  max_depth=depth, rr_depth=rr_depth)
        pooled = mean.mean(axis=0)
        pooled_err = np.sqrt((err**2).sum(axis=0)) / len(mean)
        assert np.all(np.abs(pooled / expected - 1) <= facet + 4 * pooled_err / expected), \
            (rr_depth, pooled / expected - 1, pooled_err / expected)
        if rr_depth == 1:
            assert pooled_err.min() > 0  # roulette does add variance


def _first_bounce_quadrature(w: np.ndarray, light: np.ndarray, intensity: float,
                             rho_floor: float) -> float:
    """E_ind at a wall point w = (0, h, z) (normal +x) from the lit unit floor
    [0,1]×{0}×[0,1] (normal +y), by adaptive 2-D quadrature of the form-factor kernel:
    E = ∫ ρ_f/π · E_d(y) · cosθ_w cosθ_y / r² dA."""

    def integrand(z: float, x: float) -> float:
        ly = light - np.array([x, 0.0, z])
        rl = math.sqrt(ly @ ly)
        ed = intensity * (ly[1] / rl) / rl**2
        d = np.array([x, 0.0, z]) - w
        r2 = d @ d
        cos_w = d[0] / math.sqrt(r2)
        cos_y = -d[1] / math.sqrt(r2)
        return rho_floor / math.pi * ed * cos_w * cos_y / r2

    val, _ = integrate.dblquad(integrand, 0.0, 1.0, 0.0, 1.0, epsabs=0, epsrel=1e-9)
    return val


def _crosses_plate(a: np.ndarray, b: np.ndarray, plate) -> np.ndarray:
    """Whether segments a→b (broadcast (..., 3)) cross the horizontal rectangle
    plate = (height, x0, x1, z0, z1)."""
    hgt, x0, x1, z0, z1 = plate
    da, db = a[..., 1] - hgt, b[..., 1] - hgt
    opposite = da * db < 0
    s = np.divide(da, da - db, out=np.zeros(np.broadcast(da, db).shape), where=opposite)
    q = a + s[..., None] * (b - a)
    return opposite & (q[..., 0] > x0) & (q[..., 0] < x1) & (q[..., 2] > z0) & (q[..., 2] < z1)


def _first_bounce_grid(w: np.ndarray, light: Light, rho_floor: float, panels: int = 16,
                      order: int = 8, plate=None) -> np.ndarray:
    """E_ind at wall points w (n, 3) (normal +x) from the unit floor lit by any light, by a
    fixed composite Gauss–Legendre rule over the floor. The floor's direct irradiance comes
    from :func:`prtcore.emitters.punctual.unshadowed_irradiance` (tested against closed forms in
    test_lights.py); an optional black ``plate`` (see :func:`_crosses_plate`) blocks both
    the light and the view between wall and floor. Returns (n,)."""
    g, gw = np.polynomial.legendre.leggauss(order)
    edges = np.linspace(0.0, 1.0, panels + 1)
    h = 1.0 / panels
    s = (edges[:-1, None] + h / 2 * (g[None] + 1)).ravel()
    sw = np.tile(gw * h / 2, panels)
    x, z = np.meshgrid(s, s, indexing="ij")
    wts = np.outer(sw, sw)
    y = np.stack([x, np.zeros_like(x), z], axis=-1)
    flat = y.reshape(-1, 3)
    ed = unshadowed_irradiance(light, flat, np.broadcast_to([0.0, 1.0, 0.0], flat.shape)
                               )[0][:, 0].reshape(x.shape)
    if plate is not None and light.type != "directional":
        ed = np.where(_crosses_plate(y, np.asarray(light.position, float), plate), 0.0, ed)
    out = []
    for p in np.atleast_2d(w):
        d = y - p
        r2 = (d * d).sum(axis=-1)
        kern = d[..., 0] * (-d[..., 1]) / r2**2
        if plate is not None:
            kern = np.where(_crosses_plate(y, p, plate), 0.0, kern)
        out.append((wts * rho_floor / math.pi * ed * kern).sum())
    return np.array(out)


def _l_scene(rho_f, rho_w, wall_subdiv: int = 3) -> Scene:
    floor = quad_part([[0, 0, 1], [1, 0, 1], [1, 0, 0], [0, 0, 0]], tuple(rho_f), 3)
    wall = quad_part([[0, 0, 0], [0, 1, 0], [0, 1, 1], [0, 0, 1]], tuple(rho_w), wall_subdiv)
    return make_scene([floor, wall])


def test_l_shape_first_bounce_matches_quadrature():
    """A lit floor and a perpendicular wall: the one-bounce indirect radiance on the wall,
    L = ρ_w/π · E_ind, equals an independent form-factor quadrature over the floor."""
    rho_f = np.array([0.8, 0.5, 0.2])
    rho_w = np.array([0.6, 0.6, 0.6])
    floor = quad_part([[0, 0, 1], [1, 0, 1], [1, 0, 0], [0, 0, 0]], tuple(rho_f), 3)
    wall = quad_part([[0, 0, 0], [0, 1, 0], [0, 1, 1], [0, 0, 1]], tuple(rho_w), 3)
    scene = make_scene([floor, wall])
    np.testing.assert_allclose(scene.face_normals()[scene.face_material == 1], [[1, 0, 0]] * 18,
                               atol=1e-12)
    hz = [(0.25, 0.5), (0.5, 0.5), (0.5, 0.2), (0.8, 0.75), (0.4, 0.9), (0.65, 0.35)]
    pts = np.array([[0.0, h, z] for h, z in hz])
    tx = texels_at_points(scene, pts, 1e-3)
    assert np.all(tx.triangle >= 18)  # on the wall
    lpos, inten = np.array([0.6, 0.7, 0.45]), 2.0
    mean, err = reference_lightmap_with_error(scene, tx, [point_light(lpos, inten)],
                                              spp=4096, seed=11, max_depth=1)
    e_ind = np.array([_first_bounce_quadrature(p, lpos, inten, 1.0) for p in pts])
    expected = rho_w / math.pi * e_ind[:, None] * rho_f
    z = (mean - expected) / err
    assert np.all(np.abs(z) < 4.5), z
    assert np.all(err / expected < 0.04)  # the test has power: error bars of a few %
    # the fixed grid rule used below agrees with adaptive quadrature
    np.testing.assert_allclose(_first_bounce_grid(pts, point_light(lpos, inten), 1.0), e_ind,
                               rtol=1e-6)
    # all bounces add light (the wall and floor see each other)
    full = reference_lightmap(scene, tx, [point_light(lpos, inten)], spp=512, seed=11)
    assert np.all(full.mean(axis=0) > mean.mean(axis=0))


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


@pytest.mark.parametrize("light", [
    point_light([0.3, 0.05, 0.5], 2.0),  # a hot spot on the floor, 5 cm below the light
    Light(type="spot", color=np.ones(3), intensity=3.0, position=np.array([0.5, 0.6, 0.5]),
          direction=_unit([-0.3, -1.0, 0.1]), inner_cone_angle=0.2, outer_cone_angle=0.5),
    Light(type="directional", color=np.ones(3), intensity=1.5,
          direction=_unit([-0.3, -1.0, 0.2])),
], ids=["point-hotspot", "spot", "directional"])
def test_l_shape_light_types_and_strategies(light):
    """One bounce off the floor onto the wall for each light type, with light sampling
    (MIS) and with next-event estimation only: both match the grid quadrature, and light
    sampling gives smaller error bars where the direct light is concentrated."""
    scene = _l_scene((0.7, 0.7, 0.7), (0.5, 0.5, 0.5))
    hz = [(0.05, 0.3), (0.1, 0.5), (0.3, 0.5), (0.5, 0.2), (0.8, 0.75), (0.6, 0.9)]
    pts = np.array([[0.0, h, z] for h, z in hz])
    tx = texels_at_points(scene, pts, 1e-3)
    expected = 0.5 / math.pi * _first_bounce_grid(pts, light, 0.7, panels=64)
    errs = {}
    for mis in (True, False):
        mean, err = reference_lightmap_with_error(scene, tx, [light], spp=8192, seed=4,
                                                  max_depth=1, light_sampling=mis)
        z = (mean[:, 0] - expected) / err[:, 0]
        assert np.all(np.abs(z) < 4.5), (mis, z)
        errs[mis] = err[:, 0] / expected
    assert errs[True].max() < 0.03
    if light.type != "directional":
        assert np.median(errs[False] / errs[True]) > 1.5


def test_l_shape_with_occluder():
    """A black plate hangs between the light, the floor and the wall: it shadows part of
    the floor and hides part of the floor from the wall. Both strategies must respect both
    kinds of visibility (checked against the grid rule with analytic visibility)."""
    plate = (0.3, 0.25, 0.55, 0.3, 0.7)
    hgt, x0, x1, z0, z1 = plate
    black = quad_part([[x0, hgt, z0], [x1, hgt, z0], [x1, hgt, z1], [x0, hgt, z1]], (0, 0, 0), 1)
    floor = quad_part([[0, 0, 1], [1, 0, 1], [1, 0, 0], [0, 0, 0]], (0.7, 0.7, 0.7), 3)
    wall = quad_part([[0, 0, 0], [0, 1, 0], [0, 1, 1], [0, 0, 1]], (0.5, 0.5, 0.5), 3)
    scene = make_scene([floor, wall, black])
    hz = [(0.1, 0.5), (0.25, 0.3), (0.45, 0.5), (0.6, 0.4), (0.85, 0.7), (0.3, 0.8)]
    pts = np.array([[0.0, h, z] for h, z in hz])
    tx = texels_at_points(scene, pts, 1e-3, faces=np.arange(18, 36))
    light = point_light([0.5, 0.7, 0.6], 2.0)
    expected = 0.5 / math.pi * _first_bounce_grid(pts, light, 0.7, panels=128, plate=plate)
    unblocked = 0.5 / math.pi * _first_bounce_grid(pts, light, 0.7, panels=128)
    assert np.all(expected < 0.6 * unblocked)  # the plate matters at every texel
    for mis in (True, False):
        mean, err = reference_lightmap_with_error(scene, tx, [light], spp=8192, seed=6,
                                                  max_depth=1, light_sampling=mis)
        z = (mean[:, 0] - expected) / err[:, 0]
        assert np.all(np.abs(z) < 4.5), (mis, z)
        assert np.all(err[:, 0] < 0.1 * expected), err[:, 0] / expected


def test_origins_jitter_uniformly_over_the_footprint():
    """A wall texel with a large footprint (0.7 × 0.7 in the wall plane, inside the wall's
    one triangle): its one-bounce value is the footprint average of the quadrature above
    (6×6 Gauss–Legendre), which differs clearly from the value at the texel centre."""
    floor = quad_part([[0, 0, 1], [1, 0, 1], [1, 0, 0], [0, 0, 0]], (0.7, 0.7, 0.7), 3)
    # one wall triangle holding the whole footprint (origins stay on the texel's triangle)
    wall = (np.array([[0, 0, -1], [0, 2, 0.5], [0, 0, 2]], float), np.array([[0, 1, 2]]),
            np.array([[1.0, 0, 0]] * 3), (0.5, 0.5, 0.5))
    scene = make_scene([floor, wall])
    centre = np.array([[0.0, 0.45, 0.5]])
    tx = texels_at_points(scene, centre, 0.01)
    side = 0.7
    tx = dataclasses.replace(tx, footprint=np.array([[[0, side, 0], [0, 0, side]]], float))
    lpos, inten = np.array([0.2, 0.1, 0.5]), 1.0
    mean, err = reference_lightmap_with_error(scene, tx, [point_light(lpos, inten)],
                                              spp=160_000, seed=2, max_depth=1)
    nodes, weights = np.polynomial.legendre.leggauss(6)
    fy, fz = np.meshgrid(0.45 + side / 2 * nodes, 0.5 + side / 2 * nodes, indexing="ij")
    pts = np.stack([np.zeros(36), fy.ravel(), fz.ravel()], axis=1)
    avg = (np.outer(weights, weights).ravel() * _first_bounce_grid(
        pts, point_light(lpos, inten), 0.7)).sum() / 4
    at_centre = _first_bounce_quadrature(centre[0], lpos, inten, 0.7)
    # the fixed rule agrees with adaptive quadrature (where it matters: the texel centre)
    assert _first_bounce_grid(centre, point_light(lpos, inten), 0.7)[0] == pytest.approx(
        at_centre, rel=1e-6)
    expected, point_value = 0.5 / math.pi * avg, 0.5 / math.pi * at_centre
    assert abs(mean[0, 0] - expected) < 4 * err[0, 0] + 2e-3 * expected
    assert abs(point_value - expected) > 8 * err[0, 0]  # the footprint matters here


def test_buried_origins_zero_or_excluded():
    """A floor texel half under a block. By default (buried_probes > 0) its buried half is
    left out and it gets what its visible half alone gets; with buried_probes=0 paths from
    its buried half see only back faces and bring 0, so it gets half of that."""
    floor = quad_part([[-1, 0, 1], [1, 0, 1], [1, 0, -1], [-1, 0, -1]], (0.8, 0.8, 0.8), 1)
    box = trimesh.creation.box(extents=(0.4, 0.4, 0.4))
    box.apply_translation([0.2, 0.2, 0.0])  # x ∈ [0, 0.4], standing on the floor
    box.unmerge_vertices()
    scene = make_scene([floor, (np.asarray(box.vertices), np.asarray(box.faces),
                                _flat_normals(box), (0.6, 0.6, 0.6))])
    s = 0.1
    tx = texels_at_points(scene, np.array([[0.4, 0.0, 0.0], [0.425, 0.0, 0.0]]), s,
                          faces=[0, 1])  # on the floor
    # texel 0: square [0.35, 0.45] × [−0.05, 0.05] straddling the block's side;
    # texel 1: its visible half [0.4, 0.45] × [−0.05, 0.05]
    tx = dataclasses.replace(tx, footprint=np.array([[[s, 0, 0], [0, 0, s]],
                                                     [[s / 2, 0, 0], [0, 0, s]]]))
    lights = [point_light([1.0, 1.5, 0.3], 3.0)]
    zero, ez = reference_lightmap_with_error(scene, tx, lights, 3000, seed=1,
                                             buried_probes=0)
    excl, ee = reference_lightmap_with_error(scene, tx, lights, 3000, seed=2)
    g = 1  # green channel (grey scene)
    assert abs(zero[0, g] - 0.5 * zero[1, g]) < 4 * np.hypot(ez[0, g], 0.5 * ez[1, g])
    assert abs(excl[0, g] - excl[1, g]) < 4 * np.hypot(ee[0, g], ee[1, g])
    assert abs(excl[0, g] - zero[0, g]) > 8 * np.hypot(ee[0, g], ez[0, g])
    # the visible half is unaffected by the probes (nothing of it is buried)
    assert abs(excl[1, g] - zero[1, g]) < 4 * np.hypot(ee[1, g], ez[1, g])


# ---------------------------------------------------------------------------------------
# Cornell box: Russian roulette, energy, error bars, determinism


@pytest.fixture(scope="module")
def box():
    scene = cornell_scene()
    return scene, random_texels(scene, 160, 0.01, seed=4), default_tracer(scene)


def test_russian_roulette_is_unbiased(box):
    scene, tx, tracer = box
    lights = [point_light([0.2, 1.5, 0.1], 2.0)]
    a, ea = reference_lightmap_with_error(scene, tx, lights, 48, seed=1, tracer=tracer,
                                          max_depth=6, rr_depth=6)
    b, eb = reference_lightmap_with_error(scene, tx, lights, 48, seed=2, tracer=tracer,
                                          max_depth=6, rr_depth=1)
    diff = a.mean(axis=0) - b.mean(axis=0)
    sigma = np.sqrt((ea**2 + eb**2).sum(axis=0)) / len(a)
    assert np.all(np.abs(diff) < 4 * sigma), (diff, sigma)
    assert np.all(diff != 0)
    # per texel and channel, with each texel's own error bars: the two independent runs
    # differ by N(0, ea² + eb²). Measured (153 lit texels × 3): max |z| 2.82, median |z|
    # 0.703 (0.674 for a standard normal), mean z² 1.01, mean z 0.058.
    lit = (ea + eb > 0).all(axis=1)
    assert lit.sum() > 120, lit.sum()
    assert np.array_equal(a[~lit], b[~lit])  # buried texels: 0 in both
    z = (a[lit] - b[lit]) / np.hypot(ea[lit], eb[lit])
    assert np.abs(z).max() < 4.5, np.abs(z).max()
    assert 0.55 < np.median(np.abs(z)) < 0.85, np.median(np.abs(z))
    assert 0.7 < (z ** 2).mean() < 1.4, (z ** 2).mean()
    assert abs(z.mean()) < 4 / np.sqrt(z.size), z.mean()  # no shift common to all texels


def test_energy_bound_and_error_bars(box):
    """L_ind(x0) = ρ0/π · E_ind(x0) with E_ind ≤ π · sup L_out and
    L_out ≤ ρmax/π · (E_max + E_ind) give L_ind ≤ ρ0 · ρmax/(1−ρmax) · E_max/π, where
    E_max = I/d² and d is the light's distance to the nearest surface."""
    scene, tx, tracer = box
    lpos, inten = np.array([-0.4, 1.2, 0.5]), 3.0
    lights = [point_light(lpos, inten)]
    a, ea = reference_lightmap_with_error(scene, tx, lights, 64, seed=3, tracer=tracer)
    assert np.all(np.isfinite(a)) and np.all(a >= 0) and np.all(np.isfinite(ea))
    mesh = trimesh.Trimesh(scene.positions, scene.faces, process=False)
    _, dist, _ = trimesh.proximity.closest_point(mesh, lpos[None])
    rho_max = max(m.base_color_factor[:3].max() for m in scene.materials)
    bound = tx.albedo * rho_max / (1 - rho_max) * inten / dist[0] ** 2 / math.pi
    assert np.all(a <= bound)
    assert a.max() > 0.02 * bound.max()  # non-trivial: the box does bounce light around
    # error bars are calibrated: two independent runs differ by N(0, ea² + eb²)
    b, eb = reference_lightmap_with_error(scene, tx, lights, 64, seed=4, tracer=tracer)
    # (texels under the blocks are buried: every origin is left out, 0 with no error bar)
    lit = ea[:, 1] + eb[:, 1] > 0
    assert lit.sum() > 100 and np.all(a[~lit] == 0)
    z = (a[lit, 1] - b[lit, 1]) / np.hypot(ea[lit, 1], eb[lit, 1])
    assert 0.5 < np.median(np.abs(z)) < 0.85  # 0.674 for a standard normal


def test_deterministic_and_seeded(box):
    scene, tx, tracer = box
    lights = [point_light([0.0, 1.8, 0.0], 1.0),
              Light(type="spot", color=np.array([1.0, 0.8, 0.6]), intensity=4.0,
                    position=np.array([0.5, 1.5, 0.5]), direction=np.array([-0.3, -1.0, -0.2])
                    / np.linalg.norm([-0.3, -1.0, -0.2]), outer_cone_angle=0.6)]
    a = reference_lightmap(scene, tx, lights, 8, seed=7, tracer=tracer)
    b = reference_lightmap(scene, tx, lights, 8, seed=7, tracer=default_tracer(scene),
                           timer=StageTimer(quiet=True))
    c = reference_lightmap(scene, tx, lights, 8, seed=8, tracer=tracer)
    assert a.dtype == np.float64 and a.shape == (tx.count, 3)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_configurations_share_paths_linearly(box):
    """Configurations traced together: each equals its own single run bit for bit, the
    sum of two lights equals the sum of their results (same paths, linear transport), and
    the thread count changes nothing."""
    scene, tx, tracer = box
    l1 = point_light([0.3, 1.6, -0.2], 1.5, (1.0, 0.9, 0.8))
    l2 = Light(type="directional", color=np.ones(3), intensity=0.7,
               direction=np.array([0.2, -1.0, -0.4]) / np.linalg.norm([0.2, -1.0, -0.4]))
    mean, err = reference_lightmaps(scene, tx, [[l1], [l2], [l1, l2]], 16, seed=3,
                                    tracer=tracer, threads=2)
    assert mean.shape == err.shape == (3, tx.count, 3)
    alone = reference_lightmap(scene, tx, [l1], 16, seed=3, tracer=tracer, threads=1)
    assert np.array_equal(mean[0], alone)
    np.testing.assert_allclose(mean[2], mean[0] + mean[1], rtol=1e-12, atol=1e-300)
    assert mean[1].max() > 0  # the open side of the box lets the sun in


def test_arguments_and_empty_cases(box):
    scene, tx, tracer = box
    light = [point_light([0.0, 1.0, 0.0])]
    with pytest.raises(ValueError, match="spp"):
        reference_lightmap(scene, tx, light, 0)
    with pytest.raises(ValueError, match="max_depth"):
        reference_lightmap(scene, tx, light, 1, max_depth=0)
    with pytest.raises(ValueError, match="buried_probes"):
        reference_lightmap(scene, tx, light, 1, buried_probes=-1)
    assert np.array_equal(reference_lightmap(scene, tx, [], 4, tracer=tracer),
                          np.zeros((tx.count, 3)))
    m, e = reference_lightmap_with_error(scene, tx, light, 1, tracer=tracer)
    assert np.array_equal(e, np.zeros_like(m))


@pytest.mark.slow
def test_furnace_high_albedo_slow():
    """A bright furnace (ρ = 0.95: ~20 bounces on average) still matches ρ/(1−ρ)."""
    rho = np.array([0.95, 0.9, 0.85])
    scene = sphere_scene(4, 1.0, tuple(rho))
    tri = np.random.default_rng(2).choice(len(scene.faces), 128, replace=False)
    tx = make_texels(scene, tri, np.full((128, 3), 1 / 3), 0.02)
    mean, err = reference_lightmap_with_error(scene, tx, [point_light([0, 0, 0], 1.0)],
                                              spp=512, seed=9, max_depth=1000)
    expected = rho / math.pi * rho / (1 - rho)
    r_in = np.abs(np.einsum("ij,ij->i", scene.positions[scene.faces[:, 0]],
                            scene.face_normals())).min()
    facet = 1 / r_in**2 - 1
    pooled_err = np.sqrt((err**2).sum(axis=0)) / len(mean)
    # faceting (E_d on the facets, directions lost below facet planes) acts at every
    # bounce: allow it per bounce, ≈ ρ/(1−ρ) bounces deep
    tol = facet * (1 + rho / (1 - rho)) + 4 * pooled_err / expected
    assert np.all(np.abs(mean.mean(axis=0) / expected - 1) <= tol)
