"""The Embree boundary against closed-form ray/triangle answers."""

import numpy as np
import pytest
import trimesh

from prtcore.core.raytrace import CHUNK, RayTracer
from prtcore.core.tolerances import ray_offset


def _tri_tracer(scale=1.0):
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float) * scale
    return RayTracer(pos, np.array([[0, 1, 2]]), scale=scale)


def test_closest_hit_barycentrics_and_facing():
    rt = _tri_tracer()
    o = np.array([[0.2, 0.3, 2.0], [0.2, 0.3, -1.0], [2.0, 2.0, 1.0]])
    d = np.array([[0, 0, -1.0], [0, 0, 1.0], [0, 0, -1.0]])
    h = rt.intersect(o, d)
    np.testing.assert_array_equal(h.triangle, [0, 0, -1])
    np.testing.assert_allclose(h.t[:2], [2.0, 1.0], rtol=1e-6)
    assert np.isinf(h.t[2])
    np.testing.assert_allclose(h.barycentric[0], [0.5, 0.2, 0.3], atol=1e-6)
    np.testing.assert_allclose(rt.surface_point(h.triangle[:2], h.barycentric[:2]),
                               [[0.2, 0.3, 0.0]] * 2, atol=1e-6)
    np.testing.assert_array_equal(h.front, [True, False, False])


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e4])
def test_visibility_scales_with_the_scene(scale):
    # A blocker triangle between a surface point and a light, at every scene scale.
    floor = np.array([[-1, 0, -1], [1, 0, -1], [0, 0, 1]], float)
    blocker = np.array([[-1, 1, -1], [0, 1, 1], [1, 1, -1]], float)
    rt = RayTracer(np.vstack([floor, blocker]) * scale, np.array([[0, 2, 1], [3, 4, 5]]),
                   scale=scale)
    p = np.array([[0, 0, 0], [0, 0, 0]], float) * scale
    n = np.array([[0, 1, 0], [0, 1, 0]], float)
    targets = np.array([[0, 2, 0], [0, 0.5, 0]]) * scale
    np.testing.assert_array_equal(rt.visible(p, n, targets), [False, True])
    assert rt.offset == pytest.approx(ray_offset(scale))


def test_points_exactly_on_the_surface_do_not_self_shadow():
    m = trimesh.creation.icosphere(3)
    rt = RayTracer(m.vertices, m.faces, scale=1.0)
    rng = np.random.default_rng(0)
    pts, fi = trimesh.sample.sample_surface(m, 2000, seed=1)
    normals = m.face_normals[fi]
    # Light outside along the normal: every point sees it (no self-intersection).
    vis = rt.visible(pts, normals, pts + normals * 3.0)
    assert vis.all()
    dirs = normals + 0.2 * rng.normal(size=normals.shape)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs[np.einsum("ij,ij->i", dirs, normals) < 0] *= -1
    assert rt.unoccluded_towards(pts, normals, dirs).all()


def test_chunked_threaded_queries_match_single_thread():
    m = trimesh.creation.icosphere(2)
    rng = np.random.default_rng(3)
    n = CHUNK + 1234
    o = rng.uniform(-0.5, 0.5, size=(n, 3))  # well inside the unit icosphere
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a = RayTracer(m.vertices, m.faces, 1.0, threads=1).intersect(o, d)
    b = RayTracer(m.vertices, m.faces, 1.0, threads=2).intersect(o, d)
    np.testing.assert_array_equal(a.triangle, b.triangle)
    np.testing.assert_array_equal(a.t, b.t)
    assert (a.triangle >= 0).all()  # origins inside the sphere always hit it
    assert not a.front.any()  # ... from the inside, i.e. on back faces
