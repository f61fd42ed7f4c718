"""The strand receiver (prtcore/receivers/strands.py) and the fibre triangles
(prtcore/core/fibres.py) it is traced against."""

from __future__ import annotations

import numpy as np
import pytest

from prtcore.core.fibres import (
    MITER_LIMIT,
    circumradius_scale,
    fibre_ribbons,
    fibre_tubes,
    miter,
    outside_offset,
    transported_frames,
)
from prtcore.core.hair import make_hair
from prtcore.core.raytrace import RayTracer
from prtcore.receivers.base import Receiver
from prtcore.receivers.strands import (
    build_strand_space,
    strands_per_row,
    texel_of_hit,
    texel_turn,
)
from prtcore.scenes.hair import hairball


def test_paper_layout_100k_strands_fill_1000_squared():
    assert strands_per_row(100_000, 10) == 100
    s = build_strand_space(hairball(strands=1000, segments=8), 10)
    assert (s.width, s.height) == (100, 100) and s.count == 10_000
    assert isinstance(s, Receiver)
    # every texel is used once
    assert len(np.unique(s.xy[:, 1] * s.width + s.xy[:, 0])) == s.count


def test_sampling_rule_never_mixes_strands():
    h = hairball(strands=37, segments=5, seed=1)
    s = build_strand_space(h, 7)  # 37 strands, r = 3: a partly empty last row
    n, r = s.texels_per_strand, s.strands_per_row
    owner = np.full((s.height, s.width), -1)
    owner[s.xy[:, 1], s.xy[:, 0]] = s.strand
    rng = np.random.default_rng(0)
    strand = rng.integers(0, h.strand_count, 5000)
    a = np.concatenate([rng.random(4996), [0, 1, 0.5 / n, 1 - 0.5 / n]])
    px = (strand % r) * n + np.clip(a * n, 0.5, n - 0.5)
    py = strand // r + 0.5
    x0 = np.floor(px - 0.5).astype(int)
    y0 = np.floor(py - 0.5).astype(int)
    fx = px - 0.5 - x0
    fy = py - 0.5 - y0
    assert np.all(fy == 0)  # rows are never mixed
    for dx, w in ((0, 1 - fx), (1, fx)):
        tap = owner[y0, np.minimum(x0 + dx, s.width - 1)]
        assert np.all((tap == strand) | (w == 0))
    assert s.layout()["sample"].startswith("strand s at arc fraction a")


def test_texels_cover_equal_arc_intervals_on_the_polyline():
    h = make_hair([np.array([[0, 0, 0], [0, 1, 0], [0, 1, 3]], float)], 0.02,
                  color=(0.2, 0.4, 0.6))
    s = build_strand_space(h, 4)
    np.testing.assert_allclose(s.arc[:, 1] - s.arc[:, 0], 1.0)
    np.testing.assert_allclose(s.position, [[0, 0.5, 0], [0, 1, 0.5], [0, 1, 1.5],
                                            [0, 1, 2.5]], atol=1e-12)
    np.testing.assert_allclose(s.tangent[2], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(s.radius, 0.01)
    np.testing.assert_allclose(s.albedo, np.tile([0.2, 0.4, 0.6], (4, 1)))
    np.testing.assert_array_equal(s.texel_of(np.zeros(3, int), np.array([0.0, 2.5, 4.0])),
                                  [0, 2, 3])
    img = s.to_image(np.arange(4.0))
    np.testing.assert_array_equal(img[0, :, 0], [0, 1, 2, 3])
    np.testing.assert_array_equal(img[0, :, 1], 1)


def test_pieces_tile_their_texel_and_average_back_into_it():
    """subdivided(S): texel i's pieces are S·i … S·i + S − 1, S equal arc intervals of
    its own; coarsen averages them (a value linear in arc length gives back the texel's
    value at its middle), and refuses rows that are not whole texels."""
    h = make_hair([np.array([[0, 0, 0], [0, 1, 0], [0, 1, 3]], float)], 0.02)
    s = build_strand_space(h, 4)
    assert s.subdivided(1) is s
    f = s.subdivided(3)
    assert f.count == 12 and f.texels_per_strand == 12
    np.testing.assert_allclose(f.arc.reshape(4, 3, 2)[:, 0, 0], s.arc[:, 0])
    np.testing.assert_allclose(f.arc.reshape(4, 3, 2)[:, 2, 1], s.arc[:, 1])
    values = np.stack([f.arc.mean(axis=1), 2 * f.arc.mean(axis=1)], axis=1)
    back = type(s).coarsen(values.astype(np.float32), 3)
    assert back.dtype == np.float32
    np.testing.assert_allclose(back[:, 0], s.arc.mean(axis=1), rtol=1e-6)
    np.testing.assert_allclose(back[:, 1], 2 * s.arc.mean(axis=1), rtol=1e-6)
    with pytest.raises(ValueError, match="not 3 pieces per texel"):
        type(s).coarsen(values[:11], 3)


def test_surface_samples_lie_on_the_circumscribed_cylinder():
    h = make_hair([np.array([[0, 0, 0], [0, 0, 1.0]])], 0.02)
    s = build_strand_space(h, 2)
    origin, normal, axis, phi = s.surface_samples(8, seed=3)
    np.testing.assert_allclose(np.abs(normal[..., 2]), 0, atol=1e-12)  # ⟂ the fibre
    np.testing.assert_allclose(np.linalg.norm(origin - axis, axis=2),
                               0.01 * circumradius_scale(3) * 1.001)
    # azimuths stratified: one per 45° sector, so the mean normal of 8 samples vanishes
    step = np.sort(np.mod(phi - phi[:, :1], 2 * np.pi), axis=1)
    np.testing.assert_allclose(step, np.tile(np.arange(8) * np.pi / 4, (2, 1)), atol=1e-12)
    np.testing.assert_allclose(normal.mean(axis=1), 0, atol=1e-12)
    assert (axis[0, :, 2] <= 0.5).all() and (axis[1, :, 2] >= 0.5).all()


@pytest.mark.parametrize("sides", [3, 4, 6])
def test_tube_blocks_on_average_as_much_as_the_cylinder(sides):
    """Rays across a straight fibre from many azimuths: the fraction blocked over a slab of
    width w is the mean projected width / w = 2r / w (Cauchy), whatever the sides."""
    r, w = 0.01, 0.1
    h = make_hair([np.array([[0, 0, -1], [0, 0, 0], [0, 0, 1.0]])], 2 * r)
    mesh = fibre_tubes(h, sides)
    tracer = RayTracer(mesh.positions, mesh.faces, scale=1.0)
    rng = np.random.default_rng(1)
    m = 200_000
    phi = rng.random(m) * 2 * np.pi
    d = np.stack([np.cos(phi), np.sin(phi), np.zeros(m)], axis=1)
    across = np.stack([-np.sin(phi), np.cos(phi), np.zeros(m)], axis=1)
    o = -0.5 * d + (rng.random(m) - 0.5)[:, None] * w * across
    o[:, 2] = rng.uniform(-0.9, 0.9, m)
    blocked = tracer.occluded(o, d, 1.0).mean()
    assert blocked == pytest.approx(2 * r / w, rel=0.02)


@pytest.mark.parametrize("bend_deg", [0, 60, 90])
def test_a_bent_tube_is_as_wide_as_the_cylinder_at_its_joint(bend_deg):
    """Two segments meeting at a bend of θ: rays crossing the second segment just past the
    joint, in the bend's plane (where an unmitred ring pinches the tube to cos(θ/2) of
    its width), are blocked over 2r of a slab, as by a straight cylinder."""
    r, w = 0.01, 0.1
    a = np.radians(bend_deg)
    d_out = np.array([np.sin(a), 0.0, np.cos(a)])  # bends toward +x
    h = make_hair([np.array([[0, 0, -1.0], [0, 0, 0], d_out])], 2 * r)
    bend, stretch = miter(h)
    np.testing.assert_allclose(stretch[1], 1 / np.cos(a / 2))
    if bend_deg:
        np.testing.assert_allclose(bend[1], [np.cos(a / 2), 0, -np.sin(a / 2)], atol=1e-12)
    mesh = fibre_tubes(h, 12)
    tracer = RayTracer(mesh.positions, mesh.faces, scale=1.0)
    rng = np.random.default_rng(2)
    m = 100_000
    # across the second segment, at 2 % of its length, in the plane of the bend
    c = 0.02 * d_out
    across = np.array([np.cos(a), 0.0, -np.sin(a)])
    o = c + (rng.random(m) - 0.5)[:, None] * w * across - 0.5 * np.array([0, 1.0, 0])
    blocked = tracer.occluded(o, np.tile([0, 1.0, 0], (m, 1)), 1.0).mean()
    # a 12-gon is 2R · cos(15°) … 2R wide (R = 1.0115 r); unmitred, 60° would read 13 %
    # and 90° 29 % less
    assert blocked == pytest.approx(2 * r * circumradius_scale(12) / w, rel=0.04)
    # rays leave from beyond the mitred ring
    ring = mesh.positions[:len(h.points) * 12].reshape(-1, 12, 3) - h.points[:, None, :]
    assert np.all(np.linalg.norm(ring, axis=2).max(axis=1) < outside_offset(h, 12))


def test_a_fold_is_mitred_no_more_than_the_limit():
    h = make_hair([np.array([[0, 0, 0], [0, 0, 1.0], [0.01, 0, 0.0]])], 0.02)
    assert miter(h)[1][1] == MITER_LIMIT and miter(h)[1][0] == miter(h)[1][2] == 1


@pytest.mark.parametrize("kind", ["tubes", "ribbons"])
def test_hits_map_to_the_texel_of_their_arc_length(kind):
    h = make_hair([np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2.0]]),
                   np.array([[1, 0, 0], [1, 0, 2.0]])], 0.02)
    s = build_strand_space(h, 4)
    mesh = fibre_tubes(h) if kind == "tubes" else fibre_ribbons(h)
    tracer = RayTracer(mesh.positions, mesh.faces, scale=2.0)
    z = 0.025 + 0.05 * np.arange(40)  # away from the texel boundaries
    axis = np.concatenate([np.stack([np.full_like(z, x), np.zeros_like(z), z], axis=1)
                           for x in (0.0, 1.0)])
    # across the fibre: any direction ⟂ the axis for tubes; the ribbon's normal v for ribbons
    _, _, v = transported_frames(h)
    d = np.repeat(v[[0, 3]], len(z), axis=0) if kind == "ribbons" else \
        np.tile([0.0, 1.0, 0.0], (len(axis), 1))
    o = axis - d
    hits = tracer.intersect(o, d)
    assert hits.hit.all()
    texel = texel_of_hit(s, mesh, hits.triangle, hits.barycentric)
    strand = np.repeat([0, 1], len(z))
    expect = strand * 4 + np.minimum(np.floor(np.tile(z, 2) / 0.5), 3).astype(int)
    np.testing.assert_array_equal(texel, expect)


def test_arc_weights_read_a_linear_profile_exactly_and_the_root_s_slope():
    """StrandSpace.arc_weights: a value linear in arc length, stored at the texel centres,
    is read back exactly anywhere between the first and last centre, and before the
    root's centre too (extrapolated along the first two); past the last centre it is
    held (the manifest's rule). "clamp" holds at the root as well."""
    h = make_hair([np.array([[0, 0, 0], [0, 0, 2.0]]), np.array([[1, 0, 0], [1, 0, 1.0]])],
                  0.02)
    s = build_strand_space(h, 4)
    centre = (np.arange(8) % 4 + 0.5) / 4  # arc fraction of every texel's centre
    value = np.where(np.arange(8) < 4, 1.0 + 3.0 * centre, 5.0 - 2.0 * centre)
    frac = np.array([0.0, 0.05, 0.125, 0.3, 0.5, 0.8, 0.875, 0.95, 1.0])
    for strand, (a, b) in enumerate(((1.0, 3.0), (5.0, -2.0))):
        texel = s.texel_of(np.full(len(frac), strand), frac * h.strand_length[strand])
        cols, w = s.arc_weights(texel, frac)
        assert (cols // 4 == strand).all()  # never another strand's texels
        np.testing.assert_allclose(w.sum(axis=1), 1.0)
        got = (w * value[cols]).sum(axis=1)
        expect = a + b * np.minimum(frac, 0.875)  # held past the last centre
        np.testing.assert_allclose(got, expect, atol=1e-12)
        assert w.min() >= -0.5 - 1e-12
        cols, w = s.arc_weights(texel, frac, root="clamp")
        np.testing.assert_allclose((w * value[cols]).sum(axis=1),
                                   a + b * np.clip(frac, 0.125, 0.875), atol=1e-12)
    one = build_strand_space(h, 1)  # a single texel per strand: its own value
    cols, w = one.arc_weights(np.array([0, 1]), np.array([0.0, 0.7]))
    np.testing.assert_array_equal(cols[:, 0], [0, 1])
    np.testing.assert_allclose(w, [[1, 0], [1, 0]])


def test_texel_turn_is_the_angle_between_the_texel_s_end_tangents():
    """A straight strand turns 0°; one bent by 90° inside its single texel turns 90°; a
    helix of pitch angle α turns by its tangent's angle over the texel's arc."""
    h = make_hair([np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2.0]]),
                   np.array([[0, 0, 0], [0, 0, 1], [1, 0, 1.0]])], 0.02)
    np.testing.assert_allclose(texel_turn(build_strand_space(h, 1)), [0.0, 90.0],
                               atol=1e-9)
    two = texel_turn(build_strand_space(h, 2))  # the bend at the texels' shared end
    assert two[0] == two[1] == 0.0 and two[2] + two[3] <= 90 + 1e-9
    s = np.linspace(0, 4 * np.pi, 2001)  # a helix of radius 1, pitch 1 per radian
    helix = make_hair([np.stack([np.cos(s), np.sin(s), s], axis=1)], 0.02)
    turn = texel_turn(build_strand_space(helix, 8))  # each texel a quarter turn
    # tangents (−sin, cos, 1)/√2 a quarter turn apart: cos θ = 1/2
    np.testing.assert_allclose(turn, 60.0, atol=0.5)  # the tip: its last chord's


def test_segments_cut_into_pieces_are_the_same_tubes():
    """Cutting each segment into collinear sub-prisms (for the BVH) keeps the surface: rays
    through a mitred hairball hit at the same distance, on the same segment, at the same
    parameter along it; the triangles double per piece."""
    from prtcore.core.fibres import segment_hits

    h = hairball(300, seed=3)
    rng = np.random.default_rng(0)
    o = rng.normal(size=(20000, 3)) * 0.05
    d = rng.normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    found = {}
    for pieces in (1, 2, 3):
        mesh = fibre_tubes(h, pieces=pieces)
        assert len(mesh.faces) == len(h.segment_start) * 6 * pieces
        hits = RayTracer(mesh.positions, mesh.faces, scale=0.2).intersect(o, d)
        seg, t = segment_hits(mesh, hits.triangle, hits.barycentric)
        found[pieces] = hits.hit, hits.t, seg, t
    hit1, t1, seg1, u1 = found[1]
    assert hit1.sum() > 1000
    for pieces in (2, 3):
        hit, t, seg, u = found[pieces]
        # a twisted (non-planar) quad is triangulated along other diagonals: the surface
        # moves by a fraction of a micrometre, which a grazing ray sees stretched along it
        same = hit & hit1
        assert same.sum() >= 0.995 * hit1.sum()
        dt = np.abs(t[same] - t1[same])
        assert np.median(dt) < 1e-6 and np.quantile(dt, 0.99) < h.thickness.mean() / 8
        assert np.mean(seg[same] == seg1[same]) > 0.995
        ok = seg[same] == seg1[same]
        du = np.abs(u[same][ok] - u1[same][ok])
        assert np.median(du) < 1e-3 and np.quantile(du, 0.99) < 0.02


def test_degenerate_strands_give_finite_texels_and_tubes():
    """Real files hold repeated points and zero-length strands: no NaN may come out."""
    strands = [np.repeat([[0.0, 0, 0]], 4, axis=0),  # zero length
               np.array([[1.0, 0, 0], [1, 1, 0], [1, 1, 0], [1, 2, 0]]),  # repeated point
               np.array([[2.0, 0, 0], [2, 0, 1]])]  # one segment
    s = build_strand_space(make_hair(strands, 0.01), 3)
    for a in (s.position, s.tangent, s.normal, s.footprint):
        assert np.isfinite(a).all()
    origin, normal, _, phi = s.surface_samples(4, seed=0)
    assert np.isfinite(origin).all() and np.isfinite(normal).all() and np.isfinite(phi).all()
    np.testing.assert_allclose(np.linalg.norm(normal, axis=2), 1.0)
    mesh = fibre_tubes(s.hair)
    assert np.isfinite(mesh.positions).all()
    turn = texel_turn(s)  # turn_bounces' rule: a zero-length strand does not turn
    assert np.isfinite(turn).all() and (turn[:3] == 0).all()
    cols, w = s.arc_weights(np.arange(9), np.zeros(9))
    assert np.isfinite(w).all() and (cols // 3 == np.arange(9)[:, None] // 3).all()
