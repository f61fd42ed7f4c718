"""Fast transport against closed forms, conservation laws and the reference path tracer.

Analytic scenes are built here with one lightmap chart per triangle (a grid of cells in
TEXCOORD_1), so they depend only on the texel rasteriser, the tracer and the lights; the
comparison with the reference uses the real pipeline (loader, UV generation).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import trimesh
from scenes import inside_sphere, point_light, quad

from prtcore.core.materials import clamp_albedo
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light, Material, Scene
from prtcore.core.sparse import permute_csr
from prtcore.core.spec import LightFamily, LightsSpec, TransportSpec
from prtcore.emitters.families import sample_configurations
from prtcore.intake.points import MeasurementPoints
from prtcore.receivers.texels import TexelSpace, build_texel_space
from prtcore.transport import gather as gather_module
from prtcore.transport import solve as solve_module
from prtcore.transport.dataset import bake_dataset, light_texels, trace_operators
from prtcore.transport.direct import direct_radiance
from prtcore.transport.gather import build_gather_operator, gather_operator
from prtcore.transport.solve import solve_indirect

# ---------------------------------------------------------------------------------------
# Scene builders


def grid_uv(n_faces: int, res: int) -> np.ndarray:
    """One chart per face: face i is a right triangle inside cell i of a square grid,
    one texel of margin on every side. Returns (3 n_faces, 2) float64 TEXCOORD_1."""
    cols = math.ceil(math.sqrt(n_faces))
    cell = res // cols
    assert cell >= 5, "atlas too small for one chart per face"
    i = np.arange(n_faces)
    ox, oy = (i % cols) * cell + 1.0, (i // cols) * cell + 1.0
    leg = cell - 2.0
    corners = np.stack([np.stack([ox, oy], 1), np.stack([ox + leg, oy], 1),
                        np.stack([ox, oy + leg], 1)], axis=1)
    return corners.reshape(-1, 2) / res


def make_scene(parts, res: int, smooth: bool = False) -> Scene:
    """parts: (vertices (v, 3), faces (f, 3) counter-clockwise front, rgb albedo).
    Vertices are unwelded (flat normals unless ``smooth``: then the normal of the
    welded mesh's vertex, i.e. interpolated shading normals) and every face is its own
    chart in a res × res atlas."""
    pos, nor, mat_of, mats = [], [], [], []
    for k, (v, f, rgb) in enumerate(parts):
        mesh = trimesh.Trimesh(np.asarray(v, float), np.asarray(f, np.int64), process=False)
        tri = mesh.vertices[mesh.faces]
        pos.append(tri.reshape(-1, 3))
        if smooth:
            nor.append(mesh.vertex_normals[mesh.faces].reshape(-1, 3))
        else:
            nor.append(np.repeat(mesh.face_normals, 3, axis=0))
        mat_of.append(np.full(len(mesh.faces), k, np.int32))
        mats.append(Material(f"m{k}", np.array([*rgb, 1.0])))
    positions = np.concatenate(pos)
    n = len(positions) // 3
    return Scene(source="test", positions=positions, normals=np.concatenate(nor),
                 uv0=np.zeros((len(positions), 2)), uv1=grid_uv(n, res),
                 faces=np.arange(3 * n, dtype=np.int64).reshape(n, 3),
                 face_material=np.concatenate(mat_of),
                 face_instance=np.zeros(n, np.int32), materials=tuple(mats))


FLOOR = [[-1, 0, 1], [1, 0, 1], [1, 0, -1], [-1, 0, -1]]  # y = 0, facing +y


def box(extents, center, angle=0.0):
    m = trimesh.creation.box(extents=extents)
    m.apply_transform(trimesh.transformations.rotation_matrix(angle, [0, 1, 0]))
    m.apply_translation(center)
    return m.vertices, m.faces


def spot_light(pos, target, outer, intensity=1.0) -> Light:
    d = np.asarray(target, float) - np.asarray(pos, float)
    return Light(type="spot", color=np.ones(3), intensity=float(intensity),
                 position=np.asarray(pos, float), direction=d / np.linalg.norm(d),
                 outer_cone_angle=float(outer))


def tracer_of(scene: Scene) -> RayTracer:
    return RayTracer(scene.positions, scene.faces, scene.radius)


def points_on(scene: Scene, texels: TexelSpace, idx: np.ndarray, per: int
              ) -> MeasurementPoints:
    """Measurement points at texel samples idx[::per], each clustered with the next
    per − 1 texel samples of idx."""
    idx = np.asarray(idx).reshape(-1, per)
    flat = idx.reshape(-1)
    own = idx[:, 0]
    return MeasurementPoints(
        position=texels.position[own], normal=texels.normal[own], albedo=texels.albedo[own],
        triangle=texels.triangle[own], barycentric=texels.barycentric[own],
        cluster_position=texels.position[flat], cluster_normal=texels.normal[flat],
        cluster_albedo=texels.albedo[flat], cluster_triangle=texels.triangle[flat],
        cluster_barycentric=texels.barycentric[flat],
        cluster_owner=np.repeat(np.arange(len(idx)), per).astype(np.int32))


def texel_area(texels: TexelSpace) -> np.ndarray:
    """(T,) world area covered by each texel."""
    return texels.coverage * np.linalg.norm(np.cross(texels.footprint[:, 0],
                                                     texels.footprint[:, 1]), axis=1)


# ---------------------------------------------------------------------------------------
# (1) A lone plane under a point light: closed-form direct light, no indirect at all


def test_plane_direct_closed_form_and_no_indirect():
    rgb = (0.5, 0.6, 0.7)
    scene = make_scene([(*quad(FLOOR), rgb)], res=64)
    texels = build_texel_space(scene, 64, padding=1)
    tracer = tracer_of(scene)
    light = point_light([0.3, 1.2, -0.2], 2.0, (1.0, 0.8, 0.6))
    gather = gather_operator(scene, texels, tracer, rays=16, seed=1)
    assert gather.matrix.nnz == 0  # every gather ray escapes
    assert gather.stats["misses"] == gather.stats["rays_traced"] == 16 * texels.count
    # direct light is evaluated at the texel sample, except on partly covered texels,
    # where it moves to a jittered origin strictly inside the texel's triangle
    partial = texels.coverage < 1 - gather_module.PARTIAL_COVERAGE_EPS
    assert partial.any() and (gather.moved == partial).all()
    np.testing.assert_array_equal(gather.sample_position[~partial], texels.position[~partial])
    tri = scene.positions[scene.faces[texels.triangle[partial]]]
    inner = np.linalg.solve(np.stack([tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0],
                                      np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])],
                                     axis=2), (gather.sample_position[partial] - tri[:, 0])[
                                         :, :, None])[:, :, 0]
    assert (inner[:, :2] > 0).all() and (inner[:, :2].sum(axis=1) < 1).all()
    assert np.abs(inner[:, 2]).max() < 1e-12

    def closed_form(p):  # ρ/π · I · cosθ / r², the plane's normal is +y
        delta = light.position - p
        r2 = (delta ** 2).sum(axis=1)
        cos = delta[:, 1] / np.sqrt(r2)
        return np.array(rgb) / math.pi * light.intensity * light.color * (cos / r2)[:, None]

    p = gather.sample_position
    expect = closed_form(p)
    got = direct_radiance(scene, tracer, [light], p, texels.normal, texels.albedo)
    assert got.shape == (texels.count, 1, 3) and got.dtype == np.float32
    np.testing.assert_allclose(got[:, 0], expect, rtol=1e-6)

    # the whole stage, with a held-out light and clustered measurement points
    hold = point_light([-0.5, 0.7, 0.4], 1.0)
    pts = points_on(scene, texels, np.arange(12), per=3)
    spec = TransportSpec(gather_rays=8)
    ds = bake_dataset(scene, texels, pts, [light], [hold], spec, tracer=tracer)
    assert ds.lights == (light, hold) and ds.stats["train"] == 1
    # a texel's direct light is the mean over its direct samples: J = min(4, S = 2) here
    g = gather_operator(scene, texels, tracer, 8, spec.seed, direct_samples=4)
    assert g.direct_position.shape == (texels.count, 2, 3) and ds.stats["direct_samples"] == 2
    mean = closed_form(g.direct_position.reshape(-1, 3)).reshape(-1, 2, 3).mean(axis=1)
    np.testing.assert_allclose(ds.direct_texels[:, 0], mean, rtol=1e-6)
    np.testing.assert_array_equal(ds.indirect, 0.0)
    cl = closed_form(texels.position[:12]).reshape(4, 3, 3).mean(axis=1)
    np.testing.assert_allclose(ds.direct_points[:, 0], cl, rtol=1e-6)


# ---------------------------------------------------------------------------------------
# (2) Furnace: inside a closed sphere of albedo ρ every bounce keeps a fraction ρ


def sphere_room(rho: float, res: int = 128) -> Scene:
    """The inside of a sphere (tests/scenes.py) of albedo ρ, one chart per face."""
    v, f, _ = inside_sphere(2)
    return make_scene([(v, f, (rho, rho, rho))], res=res)


@pytest.fixture(scope="module")
def sphere_gather():
    """The gather operator of the inside of a sphere (geometry only, albedo-free)."""
    scene = sphere_room(0.5)
    texels = build_texel_space(scene, 128, padding=1)
    return scene, texels, gather_operator(scene, texels, tracer_of(scene), 64, seed=3)


@pytest.mark.parametrize("rho", [0.3, 0.5, 0.8])
@pytest.mark.parametrize("method", ["chebyshev", "neumann"])
def test_furnace_uniform(sphere_gather, rho, method):
    # Every gather ray hits the sphere, so G is row-stochastic and a uniform E0 stays
    # uniform: E_ind = (ρ + ρ² + …) E0 = ρ/(1 − ρ) E0 exactly, whatever M.
    _scene, texels, gather = sphere_gather
    g = gather.matrix
    np.testing.assert_allclose(np.asarray(g.sum(axis=1)).ravel(), 1.0, atol=1e-6)
    assert gather.stats["misses"] == gather.stats["back_face_hits"] == 0
    albedo = np.full((texels.count, 3), rho)
    e0 = np.array([[1.0, 1.0, 1.0], [2.0, 1.0, 0.5]])  # two configurations
    direct = np.broadcast_to(rho / math.pi * e0, (texels.count, 2, 3)).astype(np.float32)
    ind, n, resid, stats = solve_indirect(g, albedo, direct, 400, 1e-6, method=method)
    assert stats["converged"] and resid < 1e-6 and n < 400
    np.testing.assert_allclose(ind / direct, rho / (1 - rho), rtol=2e-4)


@pytest.mark.parametrize("rho", [0.3, 0.5, 0.8])
def test_furnace_half_lit(sphere_gather, rho):
    # Inside a sphere every surface element sees every other with the same form factor
    # A_j / A (dF = dA / A), so light injected on the upper half spreads evenly:
    # E_ind(x) = ρ/(1 − ρ) · Σ_j A_j E_d,j / Σ_j A_j at every x. The icosphere is not a
    # sphere, and M = 64 rays per texel give Monte Carlo noise; stated tolerances: the
    # mean within 1 %, the texel-to-texel scatter (RMS, measured 1–4 %) within 6 %.
    _scene, texels, gather = sphere_gather
    area = texel_area(texels)
    upper = texels.position[:, 1] > 0
    e_d = np.where(upper, 1.0, 0.0)
    expect = rho / (1 - rho) * (area * e_d).sum() / area.sum()
    albedo = np.full((texels.count, 3), rho)
    direct = (rho / math.pi * e_d)[:, None, None] * np.ones((1, 1, 3))
    ind, *_ = solve_indirect(gather.matrix, albedo, direct.astype(np.float32), 400, 1e-6)
    e_ind = ind[:, 0, 0] * math.pi / rho
    mean = (area * e_ind).sum() / area.sum()
    assert mean == pytest.approx(expect, rel=0.01)
    assert np.sqrt((area * (e_ind / expect - 1) ** 2).sum() / area.sum()) < 0.06


# ---------------------------------------------------------------------------------------
# (3) Energy is never created


def random_scene(seed: int) -> tuple[Scene, list[Light]]:
    rng = np.random.default_rng(seed)
    parts = [(*quad(FLOOR, 2), tuple(rng.uniform(0.05, 1.2, 3)))]  # > 0.99: clamped
    for _ in range(3):
        v, f = box(rng.uniform(0.2, 0.8, 3), [*rng.uniform(-0.6, 0.6, 1), rng.uniform(0, .5),
                                               *rng.uniform(-0.6, 0.6, 1)], rng.uniform(0, 3))
        parts.append((v, f, tuple(rng.uniform(0.05, 1.2, 3))))
    lights = [point_light(rng.uniform([-1, 0.8, -1], [1, 2, 1]), rng.uniform(0.5, 3)),
              spot_light(rng.uniform([-1, 1, -1], [1, 2, 1]), rng.uniform(-0.5, 0.5, 3),
                         rng.uniform(0.3, 1.0), rng.uniform(0.5, 3))]
    return make_scene(parts, res=64), lights


@pytest.mark.parametrize("seed", range(4))
def test_energy_is_never_created(seed):
    scene, lights = random_scene(seed)
    texels = build_texel_space(scene, 64, padding=1)
    tracer = tracer_of(scene)
    gather = gather_operator(scene, texels, tracer, 32, seed=seed)
    g = gather.matrix
    assert g.data.min() > 0
    assert np.asarray(g.sum(axis=1)).max() <= 1.0 + 1e-6
    direct = direct_radiance(scene, tracer, lights, gather.sample_position, texels.normal,
                             texels.albedo)
    ind, _, _resid, stats = solve_indirect(g, texels.albedo, direct, 100, 1e-5)
    assert stats["converged"]
    assert ind.min() >= 0
    rho, clamped = clamp_albedo(texels.albedo)
    assert clamped > 0 and rho.max() <= 0.99
    # in irradiance: ‖E_ind‖∞ ≤ Σ_n ‖(Gρ)ⁿ‖∞ ‖E_d‖∞ ≤ ρmax/(1 − ρmax) ‖E_d‖∞ (rows ≤ 1)
    e_d = math.pi * direct / rho[:, None, :]
    e_ind = math.pi * ind / rho[:, None, :]
    rmax = rho.max(axis=0)
    bound = rmax / (1 - rmax) * e_d.max(axis=0)  # (K, 3)
    assert (e_ind.max(axis=0) <= bound * (1 + 1e-4)).all()
    # in power (area-weighted): the light leaving surfaces after n + 1 bounces is at most
    # ρmax times that after n; Monte Carlo reciprocity is only statistical: 3 % slack.
    area = texel_area(texels)[:, None, None]
    power_ind = (area * rho[:, None, :] * e_ind).sum(axis=0)
    power_d = (area * rho[:, None, :] * e_d).sum(axis=0)
    assert (power_ind <= 1.03 * rmax / (1 - rmax) * power_d).all()


# ---------------------------------------------------------------------------------------
# (4) Back faces and buried texels


@pytest.fixture(scope="module")
def block_on_floor():
    floor = (*quad(FLOOR, 4), (0.7, 0.7, 0.7))
    block = (*box([0.6, 0.6, 0.6], [0, 0.3, 0]), (0.7, 0.7, 0.7))
    scene = make_scene([floor, block], res=128)
    texels = build_texel_space(scene, 128, padding=1)
    tracer = tracer_of(scene)
    return scene, texels, tracer, gather_operator(scene, texels, tracer, 64, seed=5)


def test_buried_texels_get_nothing(block_on_floor):
    scene, texels, tracer, gather = block_on_floor
    on_floor = scene.face_material[texels.triangle] == 0
    reach = np.abs(texels.footprint).sum(axis=(1, 2))  # ≥ half the texel's extent … ×2
    x, z = np.abs(texels.position[:, 0]), np.abs(texels.position[:, 2])
    under = on_floor & (x + reach < 0.3) & (z + reach < 0.3)
    clear = on_floor & ((x - reach > 0.3) | (z - reach > 0.3))
    straddle = on_floor & ~under & ~clear
    assert under.sum() > 20 and straddle.sum() > 20
    # fully under the block: every origin is inside → no rays, zero row, no light
    assert (gather.valid_rays[under] == 0).all() and gather.buried[under].all()
    g = gather.matrix
    assert (np.diff(g.indptr)[under] == 0).all()
    assert gather.stats["buried_texels"] == int(gather.buried.sum())
    light = point_light([0.5, 1.5, 0.3], 2.0)
    direct = direct_radiance(scene, tracer, [light], gather.sample_position, texels.normal,
                             texels.albedo)
    ind, *_ = solve_indirect(g, texels.albedo, direct, 50, 1e-4)
    assert (direct[under] == 0).all() and (ind[under] == 0).all()
    # clear of the block: all origins visible
    assert (gather.valid_rays[clear] == 64).all()
    assert (ind[clear & (x < 0.5) & (z < 0.5)] > 0).all()  # light from the block's walls
    # straddling texels: buried origins dropped (fewer valid rays), the direct sample
    # moved onto the visible part, never into the block
    part_buried = (gather.valid_rays > 0) & (gather.valid_rays < 64)
    assert part_buried[straddle].sum() > 10 and not part_buried[clear].any()
    assert gather.moved[part_buried].all()
    sp = gather.sample_position[part_buried & on_floor]
    assert ((np.abs(sp[:, 0]) >= 0.3 - 1e-9) | (np.abs(sp[:, 2]) >= 0.3 - 1e-9)).all()
    rows = np.asarray(g.sum(axis=1)).ravel()
    assert rows.max() <= 1 + 1e-6


def test_back_faces_bring_no_light():
    # A texel inside a closed box (its inward-facing floor) sees only the box's back
    # faces: nothing reaches it, although a light inside the box lights it directly.
    floor = (*quad([[-.2, .1, .2], [.2, .1, .2], [.2, .1, -.2], [-.2, .1, -.2]], 1), (.8,) * 3)
    shell = (*box([1, 1, 1], [0, 0.4, 0]), (0.8, 0.8, 0.8))  # outward faces
    scene = make_scene([floor, shell], res=64)
    texels = build_texel_space(scene, 64, padding=1)
    tracer = tracer_of(scene)
    gather = gather_operator(scene, texels, tracer, 32, seed=2)
    inner = scene.face_material[texels.triangle] == 0
    # the floor's rays hit the shell from inside (back faces); most origins are then
    # classified buried; either way nothing is gathered
    assert np.diff(gather.matrix.indptr)[inner].max() == 0
    light = point_light([0, 0.5, 0], 1.0)
    direct = direct_radiance(scene, tracer, [light], gather.sample_position, texels.normal,
                             texels.albedo)
    ind, *_ = solve_indirect(gather.matrix, texels.albedo, direct, 20, 1e-4)
    assert (direct[inner] > 0).any() and (ind[inner] == 0).all()


# ---------------------------------------------------------------------------------------
# (5) Determinism, (6) convergence


def test_deterministic_and_seeded(block_on_floor):
    scene, texels, tracer, gather = block_on_floor
    again = gather_operator(scene, texels, tracer_of(scene), 64, seed=5)
    for a, b in ((gather.matrix.data, again.matrix.data),
                 (gather.matrix.indices, again.matrix.indices),
                 (gather.matrix.indptr, again.matrix.indptr),
                 (gather.sample_position, again.sample_position)):
        np.testing.assert_array_equal(a, b)
    other = build_gather_operator(scene, texels, tracer, 64, seed=6)
    assert other.nnz != gather.matrix.nnz or not np.array_equal(other.data,
                                                                  gather.matrix.data)
    lights = [point_light([0.5, 1.5, 0.3], 2.0), spot_light([-.5, 1, .5], [0, 0, 0], 0.5)]
    pts = points_on(scene, texels, np.arange(8), per=2)
    spec = TransportSpec(gather_rays=16, max_bounces=8, tolerance=1e-3, seed=9)
    d1 = bake_dataset(scene, texels, pts, lights, (), spec)
    d2 = bake_dataset(scene, texels, pts, lights, (), spec)
    for name in ("direct_points", "direct_texels", "indirect"):
        np.testing.assert_array_equal(getattr(d1, name), getattr(d2, name))
    assert d1.iterations == d2.iterations and d1.residual == d2.residual


@pytest.fixture(scope="module")
def block_problem(block_on_floor):
    scene, texels, tracer, gather = block_on_floor
    lights = [point_light([0.5, 1.5, 0.3], 2.0), spot_light([-.5, 1, .5], [0, 0, 0], 0.5),
              point_light([-0.7, 0.4, -0.6], 1.0, (1.0, 0.2, 0.1))]
    albedo = np.where(texels.position[:, :1] > 0, [0.9, 0.5, 0.2], [0.3, 0.8, 0.95])
    direct = direct_radiance(scene, tracer, lights, gather.sample_position, texels.normal,
                             albedo)
    return gather.matrix, albedo, direct


def test_convergence_and_residual(block_problem):
    g, albedo, direct = block_problem
    rho, _ = clamp_albedo(albedo)
    exact, _n_exact, _, st = solve_indirect(g, albedo, direct, 500, 1e-9, method="neumann")
    assert st["converged"]
    scale = np.linalg.norm(exact, axis=0)  # (K, 3)
    for method in ("chebyshev", "neumann"):
        ind, n, resid, stats = solve_indirect(g, albedo, direct, 60, 1e-4, method=method)
        assert stats["converged"] and resid < 1e-4 and 2 < n < 60
        err = np.linalg.norm(ind - exact, axis=0) / scale
        assert err.max() < 5e-4
        # fixed-point residual E − G ρ (E_d + E), in irradiance
        e, e_d = math.pi * ind / rho[:, None, :], math.pi * direct / rho[:, None, :]
        t = e.shape[0]
        fixed = (g @ (rho[:, None, :] * (e_d + e)).reshape(t, -1)).reshape(e.shape)
        assert (np.linalg.norm(e - fixed, axis=0) / np.linalg.norm(e, axis=0)).max() < 1e-3
    cheb = solve_indirect(g, albedo, direct, 60, 1e-4)[1]
    neum = solve_indirect(g, albedo, direct, 60, 1e-4, method="neumann")[1]
    assert cheb < neum  # the point of the Chebyshev iteration
    # stopped by max_bounces: reported, and Neumann is then exactly the truncated series
    ind2, n2, resid2, st2 = solve_indirect(g, albedo, direct, 2, 1e-4, method="neumann")
    assert n2 == 2 and not st2["converged"] and resid2 >= 1e-4
    one, n1, resid1, _ = solve_indirect(g, albedo, direct, 1, 1e-4)
    t, _k = direct.shape[:2]
    first = (g @ direct.reshape(t, -1)).reshape(direct.shape) * rho[:, None, :]
    np.testing.assert_allclose(one, first, rtol=1e-5, atol=1e-9)
    # L₂ = ρ/π · G(ρ E₁) with E₁ = π L₁/ρ, i.e. ρ · G L₁
    second = (g @ first.reshape(t, -1)).reshape(direct.shape) * rho[:, None, :]
    np.testing.assert_allclose(ind2, first + second, rtol=1e-5, atol=1e-9)
    assert n1 == 1 and resid1 == 1.0


def test_column_blocks_and_threads_do_not_change_the_result(block_problem, monkeypatch):
    g, albedo, direct = block_problem
    whole = solve_indirect(g, albedo, direct, 30, 1e-4, threads=1)[0]
    np.testing.assert_array_equal(solve_indirect(g, albedo, direct, 30, 1e-4, threads=2)[0],
                                  whole)  # rows split over threads: the same sums
    monkeypatch.setattr(solve_module, "SOLVE_BLOCK_BYTES",
                        solve_module.SOLVE_WORK_ARRAYS * 4 * 3 * g.shape[0])  # 1 light
    blocks = solve_indirect(g, albedo, direct, 30, 1e-4, threads=2)
    assert len(blocks[3]["blocks"]) == direct.shape[1]
    # each block stops on its own convergence test: equal within the tolerance
    diff = np.linalg.norm(blocks[0] - whole, axis=0) / np.linalg.norm(whole, axis=0)
    assert diff.max() < 5e-4


def test_bad_arguments(block_problem):
    g, albedo, direct = block_problem
    with pytest.raises(ValueError, match="method"):
        solve_indirect(g, albedo, direct, 4, 1e-3, method="magic")
    scene = make_scene([(*quad(FLOOR, 1), (0.5,) * 3)], res=16)
    texels = build_texel_space(scene, 16, padding=1)
    with pytest.raises(ValueError, match="rays"):
        gather_operator(scene, texels, tracer_of(scene), 0, seed=0)
    with pytest.raises(ValueError, match="TEXCOORD_1"):
        gather_operator(dataclasses.replace(scene, uv1=None), texels, tracer_of(scene), 4, 0)


def test_timer_records_sub_stages(block_on_floor):
    scene, texels, _tracer, _ = block_on_floor
    timer = StageTimer(quiet=True)
    pts = points_on(scene, texels, np.arange(4), per=2)
    lights = sample_configurations(
        LightsSpec(count=3, holdout=1, families=(LightFamily(type="point"),)),
        scene.center, scene.radius)
    ds = bake_dataset(scene, texels, pts, *lights, TransportSpec(gather_rays=8), timer)
    for name in ("gather operator", "direct texels", "direct points", "indirect solve"):
        assert name in timer.seconds and name in ds.stats["seconds"]
    assert ds.stats["rays"]["gather"] == ds.stats["gather"]["rays_traced"] > 0
    assert ds.direct_texels.shape == ds.indirect.shape == (texels.count, 4, 3)
    assert ds.direct_points.shape == (2, 4, 3)


def test_a_bake_need_not_keep_the_texels_direct_light(block_on_floor):
    """What the pipeline does to save memory — the solve written over the direct light,
    the operators dropped before the noise stage's second trace — changes no number."""
    from prtcore.transport.dataset import add_training, light_configurations, open_transport

    scene, texels, _tracer, _ = block_on_floor
    pts = points_on(scene, texels, np.arange(4), per=2)
    train, hold = sample_configurations(
        LightsSpec(count=3, holdout=1, families=(LightFamily(type="point"),)),
        scene.center, scene.radius)
    tr = open_transport(scene, texels, pts, TransportSpec(gather_rays=8))
    full = light_configurations(tr, (*train, *hold), 3)
    lean = light_configurations(tr, (*train, *hold), 3, keep_direct_texels=False)
    assert lean.direct_texels is None
    np.testing.assert_array_equal(lean.indirect, full.indirect)
    np.testing.assert_array_equal(lean.direct_points, full.direct_points)
    more = add_training(lean, light_configurations(tr, train[:1], 1))
    assert more.direct_texels is None and more.indirect.shape[1] == 5
    bare = tr.without_operators()
    assert bare.traced == () and bare.operators == tr.operators == ("surface",)


# ---------------------------------------------------------------------------------------
# (7) Against the reference path tracer (prtcore.reference.pathtracer), real pipeline


CORNELL_LIGHTS = [spot_light([0.0, 1.8, 0.3], [0.2, 0.0, -0.2], 0.6, 3.0),
                  point_light([0.3, 1.5, 0.5], 2.0),
                  spot_light([-0.6, 1.2, 0.7], [0.9, 0.8, -0.6], 0.5, 3.0)]


def asset_texels(path, resolution: int, padding: int = 2):
    from prtcore.intake.uv import generate_uv1
    from prtcore.io.gltf.loader import load_asset

    scene = generate_uv1(load_asset(path), resolution, padding)
    return scene, build_texel_space(scene, resolution, padding=padding), None


@pytest.fixture(scope="module")
def cornell64(tmp_path_factory):
    from prtcore.scenes.cornell import write_cornell_box

    scene, texels, _ = asset_texels(
        write_cornell_box(tmp_path_factory.mktemp("cornell") / "cornell.glb"), 64)
    return scene, texels, tracer_of(scene)


def compare(fast: np.ndarray, ref: np.ndarray, err: np.ndarray) -> tuple[float, float]:
    """Relative RMSE of a (T, 3) lightmap with the reference's own Monte Carlo variance
    (its squared standard errors) subtracted, and the relative bias of the mean."""
    ms = float(((fast - ref) ** 2).mean())
    noise = float((err ** 2).mean())
    rmse = math.sqrt(max(ms - noise, 0.0) / float((ref ** 2).mean()))
    return rmse, float(fast.mean() / ref.mean() - 1.0)


def fast_and_reference(scene, texels, tracer, lights, rays, spp, seed=0):
    """The bake's transport (default TransportSpec but ``rays`` gather rays) and the
    reference, for one light per configuration."""
    from prtcore.reference.pathtracer import reference_lightmaps

    spec = TransportSpec(gather_rays=rays, seed=seed, max_bounces=64, tolerance=1e-4)
    traced = trace_operators(scene, texels, tracer, spec)
    fast = light_texels(scene, texels, tracer, traced, lights, spec).indirect
    ref, err = reference_lightmaps(scene, texels, [[lt] for lt in lights], spp=spp,
                                   seed=seed + 1, tracer=tracer)
    return fast.astype(np.float64), ref, err


def test_matches_reference_cornell_quick(cornell64):
    # Default-run variant (~15 s): 64² atlas, 2 configurations, reference at 256 spp
    # (its own noise is subtracted), fast path with M = 1024 rays so that its Monte Carlo
    # noise is small. At 64² (11 cm texels) the piecewise-constant lightmap is coarse at
    # the blocks' contact with the floor, so the stated tolerances are looser than the
    # acceptance's: relative RMSE ≤ 10 %, mean bias ≤ 2 % (measured 2.2 %, 3.9 %; 0.7 %, −1.5 %).
    scene, texels, tracer = cornell64
    fast, ref, err = fast_and_reference(scene, texels, tracer, CORNELL_LIGHTS[1:], 1024, 256)
    for k in range(2):
        rmse, bias = compare(fast[:, k], ref[k], err[k])
        assert rmse <= 0.10 and abs(bias) <= 0.02, (k, rmse, bias)


@pytest.mark.slow
def test_matches_reference_cornell(tmp_path):
    # Acceptance: Cornell box at 128² (5.5 cm texels), 3 configurations (two spots, one
    # point light), reference at 2048 spp: per configuration relative RMSE ≤ 5 % and mean
    # bias ≤ 1 % (measured 2.9 %, 3.2 %, 2.3 % and ≤ 0.35 %; without the near field and
    # the stratified direct samples 6.0 %, 3.2 %, 2.6 % and +1.1 %). ~2 min.
    from prtcore.scenes.cornell import write_cornell_box

    scene, texels, _ = asset_texels(write_cornell_box(tmp_path / "cornell.glb"), 128)
    fast, ref, err = fast_and_reference(scene, texels, tracer_of(scene), CORNELL_LIGHTS,
                                        2048, 2048)
    for k in range(3):
        rmse, bias = compare(fast[:, k], ref[k], err[k])
        assert rmse <= 0.05 and abs(bias) <= 0.01, (k, rmse, bias)


@pytest.mark.slow
def test_matches_reference_shared_asset(shared_assets):
    # Acceptance on a shared asset: Suzanne (monkey.glb, eyes, ears and brows that light
    # each other) at 256², a point light above and a spot from the side, reference at
    # 512 spp: relative RMSE ≤ 5 %, bias ≤ 1 % (measured 1.6 %, 1.4 % and ≤ 0.2 % at
    # 1024 spp; without the near field and the stratified direct samples 3.4 %, 2.2 %).
    # The milk truck's crevices and one-texel strips are harder: see the issue note.
    scene, texels, _ = asset_texels(shared_assets / "monkey.glb", 256)
    c, r = np.asarray(scene.center), scene.radius
    lights = [point_light(c + r * np.array([0.3, 1.2, 0.5]), r * r),
              spot_light(c + r * np.array([-0.8, 0.9, 0.6]), c, 0.6, r * r)]
    fast, ref, err = fast_and_reference(scene, texels, tracer_of(scene), lights, 1024, 512)
    for k in range(2):
        rmse, bias = compare(fast[:, k], ref[k], err[k])
        assert rmse <= 0.05 and abs(bias) <= 0.01, (k, rmse, bias)


# ---------------------------------------------------------------------------------------
# The coarse grid of the later bounces (prtcore.transport.coarse)


def coarsen(texels: TexelSpace, factor: int):
    from prtcore.transport.coarse import coarsen_texels

    return coarsen_texels(texels.xy, texels.position, texels.normal, texels.footprint,
                          texels.coverage, factor)


def test_coarse_cells_hold_neighbours_only(block_on_floor):
    from prtcore.transport.coarse import CELL_REACH, grid_factor

    _scene, texels, *_ = block_on_floor
    c = coarsen(texels, 4)
    assert c.cell.shape == (texels.count,) and c.cell.min() == 0
    assert c.cells == c.cell.max() + 1 < texels.count / 8
    assert (c.cell[c.representative] == np.arange(c.cells)).all()
    np.testing.assert_allclose(np.asarray(c.restriction.sum(axis=1)).ravel(), 1.0, rtol=1e-6)
    # no cell spans the block's edge: members face their representative's way, and lie
    # within reach of it on the surface
    rep = c.representative[c.cell]
    assert (np.einsum("ij,ij->i", texels.normal, texels.normal[rep]) > 0.5).all()
    step = np.linalg.norm(texels.footprint, axis=2).max(axis=1)
    reach = CELL_REACH * 4 * np.maximum(step, step[rep])
    assert (np.linalg.norm(texels.position - texels.position[rep], axis=1) <= reach).all()
    assert coarsen(texels, 1) is None
    assert [grid_factor("auto", w) for w in (64, 128, 256, 512, 1024, 4096)] == \
        [1, 1, 2, 4, 8, 8]
    assert grid_factor(3, 512) == 3


@pytest.mark.parametrize("rho", [0.3, 0.8])
def test_coarse_grid_furnace_uniform(sphere_gather, rho):
    # Rows of G sum to 1 inside the sphere, and so do the coarse operator's (a
    # representative's row with its columns summed into cells): the furnace stays exact.
    _scene, texels, gather = sphere_gather
    albedo = np.full((texels.count, 3), rho)
    direct = np.full((texels.count, 2, 3), rho / math.pi, dtype=np.float32)
    ind, _n, _r, stats = solve_indirect(gather.matrix, albedo, direct, 400, 1e-6,
                                        coarse=coarsen(texels, 4))
    assert stats["coarse"]["cells"] < texels.count / 3 and stats["converged"]
    np.testing.assert_allclose(ind / direct, rho / (1 - rho), rtol=1e-3)


def test_coarse_grid_against_the_full_solve(block_on_floor, block_problem, monkeypatch):
    # The same discrete system solved at full resolution and on the grid: the first bounce
    # is the same, the later ones differ by the grid's error, which the full-resolution
    # closing steps damp. Measured at 128² (where "auto" uses no grid): 2 × 2 cells 0.5 %,
    # 4 × 4 cells 2.0 %; one closing step instead of two: 1.8 %, 5.3 %.
    _scene, texels, *_ = block_on_floor
    g, albedo, direct = block_problem
    exact = solve_indirect(g, albedo, direct, 500, 1e-7)[0].astype(np.float64)

    def error(factor: int) -> float:
        ind, _n, _r, stats = solve_indirect(g, albedo, direct, 60, 1e-4,
                                           coarse=coarsen(texels, factor))
        assert stats["converged"] and stats["coarse"]["factor"] == factor
        return float(np.linalg.norm(ind - exact) / np.linalg.norm(exact))

    two, four = error(2), error(4)
    assert two < 0.01 and four < 0.03, (two, four)
    monkeypatch.setattr(solve_module, "FINE_STEPS", 1)
    once = error(4)
    assert once > 1.5 * four, (once, four)  # the closing steps make the grid accurate
    one = solve_indirect(g, albedo, direct, 1, 1e-4, coarse=coarsen(texels, 4))[0]
    np.testing.assert_array_equal(one, solve_indirect(g, albedo, direct, 1, 1e-4)[0])


def test_the_solve_may_write_over_the_direct_light(block_on_floor, block_problem, monkeypatch):
    """``out=direct``: the same result, bit for bit, in the direct light's own array (each
    block of configurations is read whole before its result is written; one light per
    block here, so a wrong order would show), on the grid as at full resolution."""
    _scene, texels, *_ = block_on_floor
    g, albedo, direct = block_problem
    monkeypatch.setattr(solve_module, "SOLVE_BLOCK_BYTES",
                        solve_module.SOLVE_WORK_ARRAYS * 4 * 3 * g.shape[0])  # 1 light
    for coarse in (None, coarsen(texels, 2)):
        want = solve_indirect(g, albedo, direct, 30, 1e-4, coarse=coarse)[0]
        mine = np.array(direct, dtype=np.float32, order="C")
        got = solve_indirect(g, albedo, mine, 30, 1e-4, coarse=coarse, out=mine)[0]
        assert got is mine
        np.testing.assert_array_equal(got, want)
    with pytest.raises(ValueError, match="out must be"):
        solve_indirect(g, albedo, direct, 30, 1e-4, out=np.zeros((2, 2, 3), np.float32))


@pytest.mark.parametrize("method", ["chebyshev", "neumann"])
def test_a_solve_in_another_row_order_is_the_same_solve(block_problem, monkeypatch, method):
    """``order``: the operator given with its rows permuted (P G Pᵀ, permute_csr) and
    everything else in the caller's order gives the caller's rows back in that order,
    equal to the plain solve up to float32 summation order, with a first-bounce
    correction on some rows and written over the direct light one configuration at a time
    (a block read wrongly would show)."""
    g, albedo, direct = block_problem
    t = g.shape[0]
    monkeypatch.setattr(solve_module, "SOLVE_BLOCK_BYTES",
                        solve_module.SOLVE_WORK_ARRAYS * 4 * 3 * t)  # 1 light
    rows = np.arange(0, t, 3)
    extra = (rows, np.abs(direct[rows]) * np.float32(0.5))
    want = solve_indirect(g, albedo, direct, 40, 1e-6, method=method, first_bounce=extra)[0]
    order = np.random.default_rng(3).permutation(t)
    mine = np.array(direct, dtype=np.float32, order="C")
    got = solve_indirect(permute_csr(g, order), albedo, mine, 40, 1e-6, method=method,
                         first_bounce=extra, out=mine, order=order)[0]
    assert got is mine
    np.testing.assert_allclose(got, want, rtol=2e-5, atol=1e-6 * np.abs(want).max())
    assert not np.array_equal(order, np.arange(t))
    with pytest.raises(ValueError, match="order works with a plain matrix"):
        solve_indirect(g, albedo, direct, 4, 1e-3, order=order, product=lambda x: x)
