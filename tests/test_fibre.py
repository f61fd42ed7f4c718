"""The diffuse-fibre transport (prtcore/transport/fibre.py): direct light against the closed
form, self-shadowing, and the fibre-to-fibre operator."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prtcore.core.hair import make_hair
from prtcore.core.scene import Light
from prtcore.core.spec import TransportSpec, parse_spec
from prtcore.intake.hair import hair_scene
from prtcore.intake.points import place_measurement_points
from prtcore.receivers.strands import build_strand_space
from prtcore.scenes.hair import hairball, head_lights
from prtcore.transport import hair as hair_transport
from prtcore.transport.base import operator_for
from prtcore.transport.fibre import (
    fibre_direct,
    fibre_gather,
    hair_tracer,
    harmonic_receivers,
    stratified_rays,
)


def _sun(direction, lux=3.0):
    d = np.asarray(direction, float)
    return Light(type="directional", color=np.ones(3), intensity=lux,
                 direction=d / np.linalg.norm(d))


@pytest.mark.parametrize("theta_deg", [90.0, 60.0, 20.0])
def test_single_fibre_direct_is_the_radially_averaged_closed_form(theta_deg):
    """One fibre along z under a sun at θ to it: L̄ = ρ E⊥ sin θ / π²."""
    rho = np.array([0.8, 0.5, 0.2])
    h = make_hair([np.array([[0, 0, -1], [0, 0, 0], [0, 0, 1.0]])], 0.01, color=rho)
    s = build_strand_space(h, 5)
    tracer, _ = hair_tracer(s)
    th = math.radians(theta_deg)
    light = _sun([-math.sin(th), 0.0, -math.cos(th)])
    got = fibre_direct(s, tracer, [light], samples=64, seed=1).mean[:, 0]
    expect = rho * 3.0 * math.sin(th) / math.pi ** 2
    np.testing.assert_allclose(got, np.tile(expect, (s.count, 1)), rtol=2e-3)


@pytest.mark.parametrize("offset, lo, hi", [(0.0, 0.0, 0.25), (0.005, 0.3, 0.7)])
def test_a_fibre_in_front_shadows_the_one_behind(offset, lo, hi):
    """Two parallel fibres of radius r = 5 mm, 3 diameters apart along the sun's direction:
    the front one casts a shadow column 2r wide, so the one behind, shifted sideways by
    ``offset``, receives the power of its unshadowed width — none in line (up to the
    triangle tube's corners), half when shifted by r."""
    h = make_hair([np.array([[0, 0, -1], [0, 0, 1.0]]),
                   np.array([[0.03, offset, -1], [0.03, offset, 1.0]])], 0.01)
    s = build_strand_space(h, 2)
    tracer, _ = hair_tracer(s)
    d = fibre_direct(s, tracer, [_sun([1.0, 0, 0])], samples=256, seed=2).mean[:, 0, 0]
    front, back = d[:2].mean(), d[2:].mean()
    assert front == pytest.approx(0.5 * 3 / math.pi ** 2, rel=5e-3)
    assert lo * front <= back <= hi * front


def test_gather_rows_are_hit_fractions_and_a_lone_fibre_sees_nothing():
    lone = build_strand_space(make_hair([np.array([[0, 0, 0], [0, 0, 1.0]])], 0.01), 4)
    tracer, mesh = hair_tracer(lone)
    term = fibre_gather(lone, tracer, mesh, 0, rays=32, seed=0)
    assert term.matrix.nnz == 0 and term.stats["misses"] == 4 * 32

    s = build_strand_space(hairball(strands=300, segments=8, seed=4), 4)
    tracer, mesh = hair_tracer(s)
    term = operator_for("fibre").build(None, s, tracer,
                                       type("S", (), {"gather_rays": 16, "seed": 5})())
    g = term.matrix
    rows = np.asarray(g.sum(axis=1)).ravel()
    assert g.shape == (s.count, s.count) and (rows <= 1 + 1e-6).all()
    assert term.stats["fibre_hits"] == pytest.approx(rows.sum() * 16, rel=1e-5)
    assert 0.05 < rows.mean() < 0.95  # a tangle: some rays hit other fibres, some escape
    # no texel gathers from itself through its own straight segment
    assert np.abs(g.diagonal()).max() < 0.5


def test_direct_harmonics_follow_the_lit_side():
    """A sun across a lone fibre: L(φ) = ρE/π max(0, cos(φ − φ_sun)) has first harmonic
    ρE/(2π) (cos φ_sun, sin φ_sun) in the fibre's frame."""
    h = make_hair([np.array([[0, 0, -1], [0, 0, 1.0]])], 0.01, color=(0.5, 0.5, 0.5))
    s = build_strand_space(h, 2)
    tracer, _ = hair_tracer(s)
    to_sun = np.array([0.6, 0.8, 0.0])
    d = fibre_direct(s, tracer, [_sun(-to_sun)], samples=128, seed=4, harmonics=2)
    u = s.normal[0]
    v = np.cross(s.tangent[0], u)
    expect = 0.5 * 3 / (2 * math.pi) * np.array([to_sun @ u, to_sun @ v])
    np.testing.assert_allclose(d.harmonics[:2, :, 0, 0].T, np.tile(expect, (2, 1)),
                               atol=2e-3 * 0.5 * 3 / math.pi)
    # second harmonic of max(0, cos): 2/(3π) · ρE/π along 2φ_sun
    c2 = 2 / (3 * math.pi) * 0.5 * 3 / math.pi
    ang = 2 * math.atan2(to_sun @ v, to_sun @ u)
    np.testing.assert_allclose(d.harmonics[2:, 0, 0, 0], c2 * np.array([math.cos(ang),
                                                                        math.sin(ang)]),
                               atol=2e-3 * 0.5 * 3 / math.pi)


def test_harmonic_first_bounce_sums_the_harmonics_from_first():
    """``first = 2`` keeps only the second harmonic's ``G_2 · L_2``: with both harmonics
    carried the full correction is the first harmonic's plus that; with one harmonic the
    second-harmonic part is empty."""
    from dataclasses import replace

    from prtcore.transport.fibre import harmonic_first_bounce

    s = build_strand_space(hairball(strands=120, segments=6, seed=3), 3)
    tracer, mesh = hair_tracer(s)
    sun = [_sun([0.3, -1.0, 0.2])]
    direct = fibre_direct(s, tracer, sun, samples=8, seed=1, harmonics=2)
    term = fibre_gather(s, tracer, mesh, 0, rays=16, seed=2, harmonics=2)
    one = replace(term, harmonics=term.harmonics[:2])
    _, both = harmonic_first_bounce(term, direct)
    _, h1 = harmonic_first_bounce(one, direct)
    rows, h2 = harmonic_first_bounce(term, direct, first=2)
    assert np.array_equal(rows, np.arange(s.count)) and np.abs(h2).max() > 0
    np.testing.assert_allclose(both, h1 + h2, rtol=1e-5, atol=1e-6 * np.abs(both).max())
    assert not harmonic_first_bounce(one, direct, first=2)[1].any()


def test_turn_bounces_for_hair_alone_is_all_bounces_where_every_texel_is_straight(
        monkeypatch):
    """Hair alone with ``hair.harmonics = "turn_bounces"``: with a threshold every texel
    passes it is all_bounces bit for bit; with one none passes, no harmonic row takes
    other fibres' light, and the result differs."""
    h = hairball(200, seed=0)
    space = build_strand_space(h, 6)
    points = place_measurement_points(hair_scene(h), parse_spec(
        {"measurement_points": {"count": 8, "placement": "hull"}}).measurement_points)
    spec = TransportSpec(gather_rays=32, seed=3)

    def bake(harmonics):
        return hair_transport.bake_hair_dataset(space, points, hair_tracer(space)[0],
                                                head_lights(), (), spec,
                                                harmonics=harmonics).indirect

    every = bake("all_bounces")
    monkeypatch.setattr(hair_transport, "harmonic_receivers",
                        lambda h, s, *share: harmonic_receivers(h, s, 181.0, *share))
    np.testing.assert_array_equal(bake("turn_bounces"), every)
    monkeypatch.setattr(hair_transport, "harmonic_receivers",
                        lambda h, s, *share: harmonic_receivers(h, s, -1.0, *share))
    none = bake("turn_bounces")
    assert np.isfinite(none).all() and np.abs(none - every).max() > 0


def test_stratified_gather_rays_are_uniform_and_cover_each_texel_evenly():
    """stratified_rays (the Chiang gather's): every ray is uniform (averaged over texels,
    each coordinate's mean is 1/2 and its arc inside its texel), and a texel's M rays
    cover each coordinate far more evenly than independent draws: the spread of a texel's
    mean of u is under a quarter of the independent draws' sqrt(1/(12 M))."""
    space = build_strand_space(hairball(200), 10)
    m = 64
    arc, phi, direction_at = stratified_rays(space, m, seed=3)
    t = space.count
    arc = arc.reshape(t, m)
    assert ((arc >= space.arc[:, :1]) & (arc <= space.arc[:, 1:])).all()
    u, psi = direction_at(np.arange(t * m))
    frac = (arc - space.arc[:, :1]) / (space.arc[:, 1:] - space.arc[:, :1])
    iid = math.sqrt(1 / (12 * m))
    for x in (frac, phi.reshape(t, m) / (2 * np.pi), u.reshape(t, m),
              psi.reshape(t, m) / (2 * np.pi)):
        per_texel = x.mean(axis=1)
        assert abs(per_texel.mean() - 0.5) < 3 * iid / math.sqrt(t)
        assert per_texel.std() < 0.25 * iid, per_texel.std() / iid
    again = stratified_rays(space, m, seed=3)
    np.testing.assert_array_equal(again[0], arc.reshape(-1))
