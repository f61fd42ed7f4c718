"""Texel space: rasterisation of TEXCOORD_1, samples, coverage, dilation, ordering.

Every expectation is computed independently of prtcore.receivers.texels: closed-form maps of
parallelograms, an exact scalar Sutherland–Hodgman clipper for coverage, brute-force
nearest points and nearest covered texels, integer-exact containment for centres on edges.
"""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest

from prtcore.core.errors import AssetError, SpecError
from prtcore.core.materials import srgb_to_linear
from prtcore.core.progress import StageTimer
from prtcore.core.scene import Material, PrimitiveInstance, Scene, Texture
from prtcore.receivers import texels as tx
from prtcore.receivers.texels import (
    MIN_COVERAGE,
    build_texel_space,
    image_to_texels,
    morton_order,
    texels_to_image,
    uv_degenerate_faces,
)

GREY = Material("grey", np.array([0.5, 0.5, 0.5, 1.0]))


def make_scene(positions, faces, uv1, uv0=None, normals=None, materials=(GREY,),
               textures=(), face_material=None) -> Scene:
    """A Scene straight from arrays, one PrimitiveInstance covering everything.

    Vertex normals default to area-weighted face normals.
    """
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    nv, nf = len(positions), len(faces)
    if normals is None:
        v = positions[faces]
        fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        normals = np.zeros_like(positions)
        for k in range(3):
            np.add.at(normals, faces[:, k], fn)
        ln = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.divide(normals, ln, out=np.zeros_like(normals), where=ln > 0)
    normals = np.asarray(normals, dtype=np.float64)
    inst = PrimitiveInstance(
        node=0, mesh=0, primitive=0, vertex_start=0, vertex_count=nv, face_start=0,
        face_count=nf, object_positions=positions, object_normals=normals,
        joints=np.zeros((0, 4), np.int32), weights=np.zeros((0, 4)))
    return Scene(
        source="test.glb", positions=positions, normals=normals,
        uv0=np.zeros((nv, 2)) if uv0 is None else np.asarray(uv0, dtype=np.float64),
        uv1=None if uv1 is None else np.asarray(uv1, dtype=np.float64), faces=faces,
        face_material=(np.zeros(nf, np.int32) if face_material is None
                       else np.asarray(face_material, np.int32)),
        face_instance=np.zeros(nf, np.int32), materials=tuple(materials),
        textures=tuple(textures), instances=(inst,),
        has_uv0=np.full(nv, uv0 is not None))


# --- independent references -----------------------------------------------------------

def clip_area(tri_xy: np.ndarray, x: int, y: int) -> float:
    """Area of triangle ∩ square [x, x+1] × [y, y+1] by scalar Sutherland–Hodgman."""
    poly = [tuple(p) for p in tri_xy]
    for axis, bound, keep_ge in ((0, x, True), (0, x + 1, False), (1, y, True),
                                 (1, y + 1, False)):
        out = []
        for i in range(len(poly)):
            a, b = poly[i], poly[(i + 1) % len(poly)]
            ina = (a[axis] >= bound) if keep_ge else (a[axis] <= bound)
            inb = (b[axis] >= bound) if keep_ge else (b[axis] <= bound)
            if ina:
                out.append(a)
            if ina != inb:
                s = (bound - a[axis]) / (b[axis] - a[axis])
                out.append((a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1])))
        poly = out
        if not poly:
            return 0.0
    p = np.array(poly)
    return 0.5 * abs(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(p[:, 1], np.roll(p[:, 0], -1)))


def solve_bary(tri_xy: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Barycentrics of 2-D point q in triangle tri_xy (3, 2) by a linear solve."""
    m = np.array([[tri_xy[0, 0], tri_xy[1, 0], tri_xy[2, 0]],
                  [tri_xy[0, 1], tri_xy[1, 1], tri_xy[2, 1]],
                  [1.0, 1.0, 1.0]])
    return np.linalg.solve(m, np.array([q[0], q[1], 1.0]))


def dense_triangle_points(tri: np.ndarray, n: int = 300) -> np.ndarray:
    """Points on a regular barycentric grid of a triangle (k, d)."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    a, b = i[keep] / n, j[keep] / n
    w = np.stack([1 - a - b, a, b], axis=1)
    return w @ tri


def texel_table(ts) -> dict:
    return {(int(x), int(y)): i for i, (x, y) in enumerate(ts.xy)}


# --- tests ----------------------------------------------------------------------------

def _parallelogram_quad(rect, w, h, origin, a, b):
    """Quad whose pixel-space rectangle ``rect`` = (x0, x1, y0, y1) maps affinely to world:
    P(px, py) = origin + a * px + b * py. Returns (scene, world map)."""
    x0, x1, y0, y1 = rect
    pix = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)

    def world(p):
        p = np.atleast_2d(p)
        return origin + p[:, :1] * a + p[:, 1:2] * b

    scene = make_scene(world(pix), [[0, 1, 2], [0, 2, 3]], pix / [w, h])
    return scene, world


def test_quad_covered_set_positions_coverage_and_footprint():
    w = h = 16
    x0, x1, y0, y1 = 2.25, 9.75, 3.375, 7.125
    origin = np.array([1.0, -2.0, 0.5])
    a = np.array([0.3, 0.1, -0.2])
    b = np.array([0.05, -0.1, 0.4])
    scene, world = _parallelogram_quad((x0, x1, y0, y1), w, h, origin, a, b)
    ts = build_texel_space(scene, w, padding=0)

    expected = {(x, y) for x in range(2, 10) for y in range(3, 8)}
    got = set(texel_table(ts))
    assert got == expected
    assert ts.count == len(expected)  # each texel once

    for i, (x, y) in enumerate(ts.xy):
        ox = min(x + 1, x1) - max(x, x0)
        oy = min(y + 1, y1) - max(y, y0)
        assert ts.coverage[i] == pytest.approx(ox * oy, abs=1e-6)
        c = np.array([x + 0.5, y + 0.5])
        # closest point of an axis-aligned rectangle: clamp (also the centre when inside)
        q = np.clip(c, [x0, y0], [x1, y1])
        np.testing.assert_allclose(ts.position[i], world(q)[0], atol=1e-12)
    interior = (ts.xy[:, 0] >= 3) & (ts.xy[:, 0] <= 8) & (ts.xy[:, 1] >= 4) & (ts.xy[:, 1] <= 6)
    assert interior.sum() == 18 and np.all(ts.coverage[interior] == 1.0)
    border = ~interior
    assert np.all((ts.coverage[border] > 0) & (ts.coverage[border] < 1))

    np.testing.assert_allclose(ts.footprint[:, 0], np.broadcast_to(a, (ts.count, 3)), atol=1e-12)
    np.testing.assert_allclose(ts.footprint[:, 1], np.broadcast_to(b, (ts.count, 3)), atol=1e-12)
    n = np.cross(a, b)
    n /= np.linalg.norm(n)
    np.testing.assert_allclose(ts.geometric_normal, np.broadcast_to(n, (ts.count, 3)), atol=1e-12)
    np.testing.assert_allclose(ts.normal, ts.geometric_normal, atol=1e-12)
    # barycentrics reproduce the position on the stored face
    rec = np.einsum("nk,nkj->nj", ts.barycentric, scene.positions[scene.faces[ts.triangle]])
    np.testing.assert_allclose(rec, ts.position, atol=1e-12)
    assert np.all(ts.barycentric >= 0)
    np.testing.assert_allclose(ts.barycentric.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(ts.albedo, 0.5)
    assert ts.xy.dtype == np.int32 and ts.triangle.dtype == np.int64
    assert ts.coverage.dtype == np.float32 and ts.footprint.shape == (ts.count, 2, 3)


def test_orientation_top_left_quarter_is_top_left_of_image():
    w, h = 32, 16  # non-square: catches x/y or W/H swaps
    uv = np.array([[0.05, 0.1], [0.45, 0.05], [0.2, 0.45]])
    pos = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.5], [0.5, 1.0, 2.0]])
    ts = build_texel_space(make_scene(pos, [[0, 1, 2]], uv), w, h, padding=0)
    assert ts.count > 20
    assert np.all(ts.xy[:, 0] < w // 2) and np.all(ts.xy[:, 1] < h // 2)
    img = texels_to_image(ts, np.ones((ts.count, 1)))
    rows = np.flatnonzero(img[:, :, 1].any(axis=1))
    assert rows.max() < h // 2  # row 0 of the image is texel y = 0 = top of the atlas
    tri_pix = uv * [w, h]
    checked = 0
    for i, (x, y) in enumerate(ts.xy):
        c = np.array([x + 0.5, y + 0.5])
        lam = solve_bary(tri_pix, c)  # analytic inverse of the affine UV map
        if lam.min() > 1e-9:
            np.testing.assert_allclose(ts.position[i], lam @ pos, atol=1e-12)
            checked += 1
    assert checked > 10


def test_random_triangles_against_exact_clipper_and_brute_force_nearest():
    rng = np.random.default_rng(7)
    w = h = 8
    for trial in range(25):
        if trial % 5 == 0:  # slivers
            p0 = rng.uniform(0.1, 0.9, 2)
            d = rng.normal(size=2)
            d /= np.linalg.norm(d)
            p1 = np.clip(p0 + d * rng.uniform(0.2, 0.5), 0.0, 1.0)
            p2 = (p0 + p1) / 2 + np.array([-d[1], d[0]]) * rng.uniform(0.002, 0.02)
            uv = np.stack([p0, p1, p2])
        else:
            uv = rng.uniform(0.0, 1.0, (3, 2))
        pos = rng.normal(size=(3, 3))
        scene = make_scene(pos, [[0, 1, 2]], uv)
        ts = build_texel_space(scene, w, h, padding=0)
        tri_pix = uv * [w, h]
        area = {(x, y): clip_area(tri_pix, x, y) for x in range(w) for y in range(h)}
        got = texel_table(ts)
        must = {k for k, v in area.items() if v > 1.5e-3}  # penetrates beyond the tolerance
        may = {k for k, v in area.items() if v > 0}
        assert must <= set(got) <= may, trial
        pts = dense_triangle_points(tri_pix)
        for (x, y), i in got.items():
            assert ts.coverage[i] == pytest.approx(max(area[(x, y)], MIN_COVERAGE), abs=2e-6)
            q = ts.barycentric[i] @ tri_pix  # the sample in texel space
            c = np.array([x + 0.5, y + 0.5])
            lam = solve_bary(tri_pix, c)
            if lam.min() >= 0:
                np.testing.assert_allclose(q, c, atol=1e-9)
            else:  # exact closest point: never farther than the best of a dense sampling
                dist = np.linalg.norm(q - c)
                brute = np.linalg.norm(pts - c, axis=1).min()
                assert dist <= brute + 1e-9
                assert dist >= brute - 0.02  # and close to it (grid spacing bound)
            assert ts.barycentric[i].min() >= 0
            np.testing.assert_allclose(ts.position[i], ts.barycentric[i] @ pos, atol=1e-12)


def _assert_on_triangle(point, tri3):
    """point lies on the 3-D triangle: in its plane and with non-negative barycentrics."""
    n = np.cross(tri3[1] - tri3[0], tri3[2] - tri3[0])
    n /= np.linalg.norm(n)
    assert abs(np.dot(point - tri3[0], n)) < 1e-12
    m = np.stack([tri3[1] - tri3[0], tri3[2] - tri3[0]], axis=1)
    st, *_ = np.linalg.lstsq(m, point - tri3[0], rcond=None)
    assert st.min() >= -1e-9 and st.sum() <= 1 + 1e-9


def test_thin_sliver_without_texel_centre_still_gets_texels_on_the_triangle():
    w = h = 16
    pix = np.array([[3.1, 2.2], [3.3, 2.3], [3.2, 6.8]])  # x in [3.1, 3.3]: no centre (3.5)
    pos = np.array([[0.0, 0.0, 0.0], [0.2, 0.05, 0.1], [0.1, 1.5, -0.3]])
    scene = make_scene(pos, [[0, 1, 2]], pix / [w, h])
    ts = build_texel_space(scene, w, padding=0)
    assert set(texel_table(ts)) == {(3, y) for y in range(2, 7)}
    for i in range(ts.count):
        _assert_on_triangle(ts.position[i], pos)
        assert MIN_COVERAGE <= ts.coverage[i] < 0.2


def test_sliver_along_a_texel_border_thinner_than_tolerance_gets_one_texel():
    w = h = 16
    pix = np.array([[5.0, 2.0], [5.0004, 4.0], [5.0, 6.0]])  # hugs x = 5, 4e-4 wide
    pos = np.array([[0.0, 0.0, 0.0], [0.001, 1.0, 0.0], [0.0, 2.0, 0.0]])
    scene = make_scene(pos, [[0, 2, 1]], pix / [w, h])
    assert len(uv_degenerate_faces(scene)) == 0
    ts = build_texel_space(scene, w, padding=0)
    assert ts.count >= 1
    for i in range(ts.count):
        _assert_on_triangle(ts.position[i], pos)
    assert np.all(ts.coverage == np.float32(MIN_COVERAGE))


def _grid_chart(n: int, w: int, origin_pix: float):
    """n × n cells, vertices at pixel (origin + i, origin + j), cells split alternately along
    both diagonals; world = pixel coords mapped onto a tilted plane."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    pix = np.stack([i.ravel(), j.ravel()], axis=1).astype(np.float64) + origin_pix
    vid = (i * (n + 1) + j)
    faces = []
    for a, b in itertools.product(range(n), range(n)):
        v00, v10, v01, v11 = vid[a, b], vid[a + 1, b], vid[a, b + 1], vid[a + 1, b + 1]
        if (a + b) % 2:
            faces += [[v00, v10, v11], [v00, v11, v01]]
        else:
            faces += [[v00, v10, v01], [v10, v11, v01]]
    world = np.stack([pix[:, 0] * 0.1, pix[:, 0] * 0.02 + pix[:, 1] * 0.05, pix[:, 1] * 0.1],
                     axis=1)
    return pix, np.array(faces), world


def test_closed_chart_centres_on_shared_edges_are_claimed_exactly_once():
    w = h = 16
    n = 8
    pix, faces, world = _grid_chart(n, w, 0.5)  # every vertex sits on a texel centre
    scene = make_scene(world, faces, pix / [w, h])
    ts = build_texel_space(scene, w, padding=0)
    table = texel_table(ts)
    assert ts.count == len(table) == (n + 1) ** 2  # unique, none missed
    assert set(table) == {(x, y) for x in range(n + 1) for y in range(n + 1)}
    tri2 = (pix[faces] * 2).astype(np.int64)  # doubled pixel coords are integers: exact tests
    for (x, y), i in table.items():
        c = np.array([2 * x + 1, 2 * y + 1])
        containing = []
        for f, t in enumerate(tri2):
            e = [int((t[(k + 1) % 3][0] - t[k][0]) * (c[1] - t[k][1])
                     - (t[(k + 1) % 3][1] - t[k][1]) * (c[0] - t[k][0])) for k in range(3)]
            if all(v >= 0 for v in e) or all(v <= 0 for v in e):
                containing.append(f)
        assert containing, (x, y)
        assert ts.triangle[i] == min(containing)  # documented tie-break: lowest index
        px, py = x + 0.5, y + 0.5
        expect = np.array([px * 0.1, px * 0.02 + py * 0.05, py * 0.1])
        np.testing.assert_allclose(ts.position[i], expect, atol=1e-12)
        edge_x = x in (0, n)
        edge_y = y in (0, n)
        want = 0.25 if edge_x and edge_y else 0.5 if edge_x or edge_y else 1.0
        assert ts.coverage[i] == pytest.approx(want, abs=1e-6)
    assert np.all(ts.coverage[(ts.xy[:, 0] % n != 0) & (ts.xy[:, 1] % n != 0)] == 1.0)


@pytest.mark.parametrize("swap", [False, True])
def test_centre_on_a_shared_boundary_goes_to_the_lowest_index_even_if_it_covers_less(swap):
    small = [[2.5, 2.5], [3.5, 3.5], [2.5, 3.5]]  # covers 1/8 of texel (2, 2), vertex at centre
    big = [[0.5, 0.5], [3.5, 0.5], [3.5, 3.5]]  # covers 1/2 of it, centre on its hypotenuse
    pix = np.array(big + small if swap else small + big, dtype=np.float64)

    def world(p):
        return np.c_[p[:, 0] * 0.2, p[:, 1] * 0.1 + p[:, 0] * 0.05, -p[:, 1] * 0.3]

    ts = build_texel_space(make_scene(world(pix), [[0, 1, 2], [3, 4, 5]], pix / 8), 8,
                           padding=0)
    table = texel_table(ts)
    for xy in ((2, 2), (3, 3)):
        i = table[xy]
        assert ts.triangle[i] == 0
        np.testing.assert_allclose(ts.position[i], world(np.array([xy]) + 0.5)[0], atol=1e-12)


def _two_chart_scene(w):
    """A triangle chart and a quad chart far apart in the atlas."""
    tri_pix = np.array([[3.3, 2.6], [14.2, 5.1], [6.7, 12.4]])
    quad_pix = np.array([[20.5, 18.25], [27.75, 18.25], [27.75, 25.5], [20.5, 25.5]])
    pix = np.concatenate([tri_pix, quad_pix])
    pos = np.concatenate([np.c_[tri_pix, np.zeros(3)], np.c_[quad_pix, np.ones(4)]]) * 0.1
    faces = [[0, 1, 2], [3, 4, 5], [3, 5, 6]]
    return make_scene(pos, faces, pix / [w, w])


@pytest.mark.parametrize("padding", [1, 3])
def test_dilation_copies_nearest_covered_texel_within_padding(padding):
    w = 32
    ts = build_texel_space(_two_chart_scene(w), w, padding=padding)
    rng = np.random.default_rng(3)
    values = rng.uniform(0.1, 1.0, (ts.count, 3)).astype(np.float32)
    img = texels_to_image(ts, values, dilate=True)
    plain = texels_to_image(ts, values, dilate=False)
    assert img.shape == (w, w, 4) and img.dtype == np.float32
    cov = ts.xy.astype(np.int64)
    filled = 0
    for y, x in itertools.product(range(w), range(w)):
        d = cov - [x, y]
        cheb = np.abs(d).max(axis=1)
        if cheb.min() == 0:
            continue
        assert img[y, x, 3] == 0 and np.all(plain[y, x] == 0)
        if cheb.min() <= padding:
            eu = (d ** 2).sum(axis=1)
            nearest = np.flatnonzero(eu == eu.min())
            assert any(np.array_equal(img[y, x, :3], values[k]) for k in nearest), (x, y)
            filled += 1
        else:
            assert np.all(img[y, x] == 0), (x, y)
    assert filled == len(ts.dilate_xy) > 0
    assert np.all(img[ts.xy[:, 1], ts.xy[:, 0], 3] == 1)


def test_dilation_in_bands_matches_whole_atlas(monkeypatch):
    w = 32
    scene = _two_chart_scene(w)
    whole = build_texel_space(scene, w, padding=4)
    monkeypatch.setattr(tx, "_DILATE_BAND_TEXELS", 3 * w)  # 3-row bands
    banded = build_texel_space(scene, w, padding=4)
    np.testing.assert_array_equal(whole.dilate_xy, banded.dilate_xy)

    def dist(ts):
        return ((ts.xy[ts.dilate_src] - ts.dilate_xy) ** 2).sum(axis=1)

    np.testing.assert_array_equal(dist(whole), dist(banded))


def test_image_round_trip_and_gather():
    w = 32
    ts = build_texel_space(_two_chart_scene(w), w, padding=2)
    rng = np.random.default_rng(11)
    values = rng.normal(size=(ts.count, 5)).astype(np.float32)
    back = image_to_texels(ts, texels_to_image(ts, values))
    np.testing.assert_array_equal(back[:, :5], values)
    np.testing.assert_array_equal(back[:, 5], 1.0)
    image = rng.normal(size=(w, w, 2))
    got = image_to_texels(ts, image)
    for i in range(0, ts.count, 7):
        x, y = ts.xy[i]
        np.testing.assert_array_equal(got[i], image[y, x])
    with pytest.raises(ValueError):
        texels_to_image(ts, values[:-1])
    with pytest.raises(ValueError):
        image_to_texels(ts, image[:-1])


def _interleave(qx: int, qy: int, qz: int, bits: int) -> int:
    code = 0
    for b in range(bits):
        code |= ((qx >> b) & 1) << (3 * b) | ((qy >> b) & 1) << (3 * b + 1)
        code |= ((qz >> b) & 1) << (3 * b + 2)
    return code


def test_morton_order_matches_bitwise_interleaving():
    rng = np.random.default_rng(5)
    lattice = np.array(list(itertools.product(range(8), repeat=3)), dtype=np.float64)
    pts = lattice[rng.permutation(len(lattice))]
    order = morton_order(pts, np.array([[0.0, 0.0, 0.0], [8.0, 8.0, 8.0]]))
    assert order.dtype == np.int64
    assert sorted(order.tolist()) == list(range(len(pts)))
    # with bounds [0, 8] and 21 bits, lattice coordinate k quantises to k << 18
    codes = [_interleave(int(x) << 18, int(y) << 18, int(z) << 18, 21) for x, y, z in pts]
    assert [codes[k] for k in order] == sorted(codes)
    # random points: codes along the order never decrease
    p = rng.uniform(-3, 5, (500, 3))
    b = np.stack([p.min(axis=0), p.max(axis=0)])
    q = np.clip(np.floor((p - b[0]) / (b[1] - b[0]) * 2 ** 21), 0, 2 ** 21 - 1).astype(int)
    c = np.array([_interleave(*map(int, r), 21) for r in q], dtype=object)
    assert all(c[i] <= c[j] for i, j in itertools.pairwise(morton_order(p, b)))


def test_texel_order_is_spatially_coherent():
    # a bumpy 24 × 24-cell surface whose cells are scattered over the atlas at random
    rng = np.random.default_rng(9)
    n, w = 24, 128
    cells = [(a, b) for a in range(n) for b in range(n)]
    slots = rng.permutation(len(cells))
    pos, uv, faces = [], [], []
    for c, (a, b) in enumerate(cells):
        sx, sy = slots[c] % 25, slots[c] // 25
        for da, db in ((0, 0), (1, 0), (1, 1), (0, 1)):
            xw, zw = (a + da) / n, (b + db) / n
            pos.append([xw, 0.2 * np.sin(6 * xw) * np.cos(5 * zw), zw])
            uv.append([(sx * 5 + 0.5 + 4 * da) / w, (sy * 5 + 0.5 + 4 * db) / w])
        faces += [[4 * c, 4 * c + 2, 4 * c + 1], [4 * c, 4 * c + 3, 4 * c + 2]]
    ts = build_texel_space(make_scene(pos, faces, uv), w, padding=1)
    assert ts.count > 5000

    def mean_step(p):
        return np.linalg.norm(np.diff(p, axis=0), axis=1).mean()

    ordered = mean_step(ts.position)
    shuffled = mean_step(ts.position[rng.permutation(ts.count)])
    row_major = mean_step(ts.position[np.lexsort((ts.xy[:, 0], ts.xy[:, 1]))])
    assert ordered < 0.1 * shuffled
    assert ordered < 0.5 * row_major  # better than the atlas scan order


def test_albedo_through_texcoord0_from_a_2x2_texture():
    srgb = np.array([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                     [[0.0, 0.0, 1.0], [0.5, 0.5, 0.5]]])
    pixels = np.concatenate([srgb_to_linear(srgb), np.ones((2, 2, 1), np.float32)], axis=2)
    factor = np.array([0.8, 0.6, 1.0, 1.0])
    mat = Material("tex", factor, texture=0)
    quad = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    uv0 = np.c_[1.0 - quad[:, 0], quad[:, 1]]  # mirrored: TEXCOORD_0 ≠ TEXCOORD_1
    pos = np.c_[quad, np.zeros(4)]
    scene = make_scene(pos, [[0, 1, 2], [0, 2, 3]], quad, uv0=uv0, materials=(mat,),
                       textures=(Texture(pixels.astype(np.float32)),))
    ts = build_texel_space(scene, 2, padding=0)
    assert ts.count == 4
    for i, (x, y) in enumerate(ts.xy):
        expect = factor[:3] * srgb_to_linear(srgb[y, 1 - x])
        np.testing.assert_allclose(ts.albedo[i], expect, rtol=1e-6)


def test_normals_follow_the_geometric_hemisphere_and_fallback():
    pix = np.array([[1.0, 1.0], [7.0, 1.0], [1.0, 7.0]])
    pos = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    faces = [[0, 1, 2]]
    geo = np.cross(pos[1] - pos[0], pos[2] - pos[0])
    geo /= np.linalg.norm(geo)
    tilted = np.array([[0.3, 1.0, 0.0], [0.0, 1.0, 0.3], [-0.3, 1.0, -0.3]])
    tilted /= np.linalg.norm(tilted, axis=1, keepdims=True)
    # the one shading-normal rule (prtcore.core.geometry.shading_normals): the interpolated
    # normal when it faces the front of its face, else the geometric normal
    for normals, facing in ((tilted * np.sign(geo[1]), True), (-tilted * np.sign(geo[1]), False)):
        ts = build_texel_space(make_scene(pos, faces, pix / 8, normals=normals), 8, padding=0)
        interp = ts.barycentric @ normals
        interp /= np.linalg.norm(interp, axis=1, keepdims=True)
        want = interp if facing else np.broadcast_to(geo, (ts.count, 3))
        np.testing.assert_allclose(ts.normal, want, atol=1e-12)
        assert np.all(ts.normal @ geo > 0)
        np.testing.assert_allclose(ts.geometric_normal, np.broadcast_to(geo, (ts.count, 3)))
    ts = build_texel_space(make_scene(pos, faces, pix / 8, normals=np.zeros((3, 3))), 8)
    np.testing.assert_allclose(ts.normal, np.broadcast_to(geo, (ts.count, 3)))


def test_degenerate_faces_get_no_texels_and_errors_are_typed():
    pos = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 2, 0], [1, 2, 1]])
    uv = np.array([[0.1, 0.1], [0.4, 0.1], [0.1, 0.4],
                   [0.6, 0.6], [0.7, 0.7], [0.8, 0.8]])  # face 1 collinear in UV
    faces = [[0, 1, 2], [3, 4, 5]]
    scene = make_scene(pos, faces, uv)
    np.testing.assert_array_equal(uv_degenerate_faces(scene), [1])
    ts = build_texel_space(scene, 16)
    assert set(ts.triangle.tolist()) == {0}
    assert not np.any((ts.xy >= 9).all(axis=1))
    # zero world area (all three vertices at one point) with a valid UV triangle
    pos0 = np.concatenate([pos, [[5.0, 5.0, 5.0]] * 3])
    uv0 = np.concatenate([uv, [[0.6, 0.1], [0.9, 0.1], [0.6, 0.4]]])
    scene0 = make_scene(pos0, [[0, 1, 2], [6, 7, 8]], uv0)
    np.testing.assert_array_equal(tx.world_degenerate_faces(scene0), [1])
    assert len(uv_degenerate_faces(scene0)) == 0
    assert set(build_texel_space(scene0, 16).triangle.tolist()) == {0}
    with pytest.raises(AssetError, match="TEXCOORD_1"):
        build_texel_space(make_scene(pos, faces, None), 16)
    with pytest.raises(AssetError, match="covers no texel"):
        build_texel_space(make_scene(pos, [[3, 4, 5]], uv), 16)
    with pytest.raises(SpecError, match=r"atlas\.resolution"):
        build_texel_space(scene, 0)
    with pytest.raises(SpecError, match=r"atlas\.padding"):
        build_texel_space(scene, 16, padding=-1)


def test_uvs_outside_the_unit_square_are_clipped_to_the_atlas():
    w, h = 16, 8
    # pixel rectangle x in [-6, 5.5], y in [2.5, 11]: only its part inside the atlas counts
    origin, a, b = np.zeros(3), np.array([0.1, 0.0, 0.0]), np.array([0.0, 0.0, 0.1])
    scene, world = _parallelogram_quad((-6.0, 5.5, 2.5, 11.0), w, h, origin, a, b)
    ts = build_texel_space(scene, w, h, padding=0)
    assert set(texel_table(ts)) == {(x, y) for x in range(6) for y in range(2, 8)}
    for i, (x, y) in enumerate(ts.xy):
        q = np.clip([x + 0.5, y + 0.5], [-6.0, 2.5], [5.5, 11.0])
        np.testing.assert_allclose(ts.position[i], world(q)[0], atol=1e-12)


def test_deterministic_and_timed():
    scene = _two_chart_scene(32)
    timer = StageTimer(quiet=True)
    a = build_texel_space(scene, 32, 24, padding=3, timer=timer)
    assert timer.seconds["texels"] > 0
    b = build_texel_space(scene, 32, 24, padding=3)
    for name in ("xy", "position", "normal", "geometric_normal", "albedo", "triangle",
                 "barycentric", "coverage", "footprint", "dilate_xy", "dilate_src"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def _cell_grid(n_cells_side: int, atlas: int):
    """n² quads of a bumpy grid, each its own 3 × 3-texel chart in a 4-texel slot."""
    n = n_cells_side
    slots_per_row = atlas // 4
    c = np.arange(n * n)
    ci, cj = c % n, c // n
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]])
    p = np.zeros((n * n, 4, 3))
    p[:, :, 0] = ci[:, None] + corners[:, 0]
    p[:, :, 2] = cj[:, None] + corners[:, 1]
    p[:, :, 1] = 0.3 * np.sin(0.3 * p[:, :, 0]) * np.cos(0.2 * p[:, :, 2])
    sx, sy = c % slots_per_row, c // slots_per_row
    uvp = np.zeros((n * n, 4, 2))
    uvp[:, :, 0] = 4 * sx[:, None] + 0.5 + 3 * corners[:, 0]
    uvp[:, :, 1] = 4 * sy[:, None] + 0.5 + 3 * corners[:, 1]
    faces = (c[:, None, None] * 4 + np.array([[0, 2, 1], [0, 3, 2]])[None]).reshape(-1, 3)
    return make_scene(p.reshape(-1, 3), faces, uvp.reshape(-1, 2) / atlas), uvp, p


def test_100k_triangles_at_1024():
    n, atlas = 224, 1024
    scene, uvp, p = _cell_grid(n, atlas)
    assert scene.triangle_count == 2 * n * n >= 100_000
    t0 = time.perf_counter()
    ts = build_texel_space(scene, atlas, padding=2)
    elapsed = time.perf_counter() - t0
    # each 3 × 3-texel chart spans texel centres 4s..4s+3 on its closed border: 16 texels
    assert ts.count == 16 * n * n
    assert len(np.unique(ts.xy[:, 1].astype(np.int64) * atlas + ts.xy[:, 0])) == ts.count
    # spot-check the samples against the bilinear map of each cell's chart
    rng = np.random.default_rng(1)
    for i in rng.choice(ts.count, 200, replace=False):
        x, y = ts.xy[i]
        cell = (y // 4) * (atlas // 4) + x // 4
        s = (x + 0.5 - uvp[cell, 0, 0]) / 3
        t = (y + 0.5 - uvp[cell, 0, 1]) / 3
        q = p[cell]
        on_diag_lower = t <= s  # face [0, 2, 1] covers s ≥ t, face [0, 3, 2] covers t ≥ s
        expect = (q[0] + s * (q[1] - q[0]) + t * (q[2] - q[1]) if on_diag_lower
                  else q[0] + t * (q[3] - q[0]) + s * (q[2] - q[3]))
        np.testing.assert_allclose(ts.position[i], expect, atol=1e-9)
    assert elapsed < 30.0, f"{elapsed:.1f} s"
