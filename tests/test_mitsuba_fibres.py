"""Mitsuba 3 spot checks of the diffuse-fibre model (prtcore/reference/mitsuba_fibres.py):
Mitsuba's round curves, BSDF and path tracer against prtcore's fibre path tracer and fast
transport, noise of both sides removed. Slow (Mitsuba's scalar variant traces one ray per
Python call): runs with ``pytest -m ""``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from prtcore.receivers.strands import build_strand_space
from prtcore.reference.fibres import fibre_reference, noise_corrected_error
from prtcore.scenes.hair import tangle, tangle_lights
from prtcore.transport.fibre import (
    fibre_direct,
    fibre_gather,
    hair_tracer,
    harmonic_first_bounce,
)
from prtcore.transport.solve import solve_indirect

pytest.importorskip("mitsuba")
pytestmark = pytest.mark.slow


def test_mitsuba_agrees_with_the_fibre_path_tracer_and_the_fast_path():
    from prtcore.reference.mitsuba_fibres import mitsuba_fibre_indirect

    hair = tangle(1000)
    hair = dataclasses.replace(hair, color=np.tile([0.8, 0.6, 0.4], (hair.point_count, 1)))
    space = build_strand_space(hair, 12)
    tracer, mesh = hair_tracer(space)
    lights = tangle_lights()
    direct = fibre_direct(space, tracer, lights, 8, seed=1)
    term = fibre_gather(space, tracer, mesh, 0, rays=128, seed=2)
    fast, *_ = solve_indirect(term.matrix, space.albedo, direct.mean, 64, 1e-4,
                              first_bounce=harmonic_first_bounce(term, direct))
    sel = np.random.default_rng(0).choice(space.count, 300, replace=False)
    mit = mitsuba_fibre_indirect(space, lights, sel, 1024, seed=5)
    ours = fibre_reference(space, tracer, mesh, 0, lights, sel, 1024, seed=7)
    pt = noise_corrected_error(ours, *mit)
    fa = noise_corrected_error(fast[sel].astype(float), *mit)
    # benchmarks/hair_mitsuba.py (600 texels × 2048 Mitsuba rays, 2048 paths): the path
    # tracer through 3-sided tubes is +1.7 ± 0.3 % of Mitsuba's round fibres, rRMSE 3.9 %
    # (the tubes' doing: +0.5 % with 6 sides); the issue's bound is 2 % and 8 %. Here with
    # a quarter of the samples: within 2 % plus three standard errors, and 8 %
    assert abs(pt["bias"]) < 0.02 + 3 * pt["bias_se"], pt
    assert pt["rrmse"] < 0.08, pt
    # the fast path as bakes run it (first-bounce harmonic), M = 128, J = 8: −0.8 % at
    # M = 256 in the benchmark; its rRMSE is the gather's noise (≈ 11 %), not bounded here
    assert abs(fa["bias"]) < 0.05 + 3 * fa["bias_se"], fa


@pytest.mark.parametrize("color", [(0.8, 0.6, 0.4), (0.3, 0.2, 0.1)])
def test_mitsuba_hair_bsdf_agrees_with_the_chiang_path_tracer(color):
    """Mitsuba's own `hair` BSDF (Chiang et al. 2016, on B-spline curves that are our
    polylines) against prtcore.reference.chiang. Measured (100–300 texels × 1024 rays,
    2048 paths): light hair +2.1 ± 2.2 %, rRMSE 1.5 %; dark hair −0.1 ± 1.4 %, 4.2 %;
    with this test's 150 texels × 2048 rays and 4096 paths: −1.2 ± 1.1 % and +2.8 ± 1.3 %,
    rRMSE within the noise (at 1024 rays and 2048 paths the noise-corrected rRMSE, a
    difference of two near-equal noise terms, came out 4 % or 8 % by the draw).
    A BCSDF wrong in its tilt, lobes or σ units fails by far more."""
    from prtcore.core.spec import ChiangSpec
    from prtcore.reference.chiang import chiang_reference
    from prtcore.reference.mitsuba_fibres import mitsuba_fibre_indirect
    from prtcore.transport.fibre_chiang import chiang_fibre

    hair = tangle(1000)
    hair = dataclasses.replace(hair, color=np.tile(color, (hair.point_count, 1)))
    space = build_strand_space(hair, 12)
    tracer, mesh = hair_tracer(space)
    lights = tangle_lights()
    fibre = chiang_fibre(ChiangSpec(), space)
    sel = np.random.default_rng(5).choice(space.count, 150, replace=False)
    ours = chiang_reference(space, tracer, mesh, 0, lights, sel, 4096, 7, fibre.params,
                            fibre.sigma_points)
    mit = mitsuba_fibre_indirect(space, lights, sel, 2048, 9, chiang=dataclasses.replace(
        fibre.params, sigma_a=tuple(fibre.sigma_texels[0])))
    e = noise_corrected_error(ours, *mit)
    assert abs(e["bias"]) < 0.02 + 3 * e["bias_se"], e
    assert e["rrmse"] < 0.08, e


def test_mitsuba_with_a_mesh_lights_a_fibre_from_below_as_the_closed_form(tmp_path):
    """mitsuba_fibre_indirect(scene=): a horizontal fibre 5 cm above a grey square of 1 m
    under a sun straight down. Its indirect light is the floor's, one bounce (the thin
    fibre returns almost nothing): L = ρ_f/π · ∫ L_floor · sin θ_axis/π · cos θ_floor / d² dA,
    the circumference's mean of max(0, n·ω) being sin θ_axis / π, the floor's radiance
    ρ_p E/π outside the fibre's shadow strip; the integral by a 2000² midpoint rule. A
    mesh missing from Mitsuba's scene gives 0, one with the wrong albedo or facing down
    is off by its factor. Measured: 0.974, 1.001, 0.977, 0.984 of the closed form, ± 0.5–2.4 %."""
    import trimesh

    from prtcore.core.hair import make_hair
    from prtcore.core.scene import Light
    from prtcore.core.spec import parse_spec
    from prtcore.pipeline import run_intake
    from prtcore.reference.mitsuba_fibres import mitsuba_fibre_indirect
    from prtcore.scenes.parts import material_scene, write_glb

    a, h, r, rho_p, rho_f = 0.5, 0.05, 0.25e-3, 0.5, 0.8
    floor = trimesh.Trimesh([[-a, 0, -a], [a, 0, -a], [a, 0, a], [-a, 0, a]],
                            [[0, 2, 1], [0, 3, 2]])
    assert floor.face_normals[:, 1].min() > 0.99  # facing the fibre
    glb = write_glb(material_scene({"floor": floor}, {"floor": (rho_p,) * 3}),
                    tmp_path / "floor.glb")
    scene = run_intake(glb, parse_spec({"atlas": {"resolution": 16},
                                        "measurement_points": {"count": 4}}),
                       quiet=True).scene
    x = np.linspace(-0.01, 0.01, 5)
    hair = make_hair([np.stack([x, np.full(5, h), np.zeros(5)], axis=1)], 2 * r,
                     color=(rho_f,) * 3)
    space = build_strand_space(hair, 4)
    sun = Light(type="directional", color=np.ones(3), intensity=1.0,
                direction=np.array([0.0, -1.0, 0.0]))
    sel = np.arange(space.count)
    ma, mb = mitsuba_fibre_indirect(space, [sun], sel, 2048, seed=3, scene=scene)
    n = 2000
    g = (np.arange(n) + 0.5) / n * 2 * a - a
    X, Z = np.meshgrid(g, g, indexing="ij")
    lit = ~((np.abs(Z) < r) & (np.abs(X) < 0.01))  # the fibre's shadow strip
    for i, p in enumerate(space.position):
        d = np.stack([X - p[0], np.full_like(X, -p[1]), Z - p[2]], axis=-1)
        d2 = (d ** 2).sum(axis=-1)
        w = d / np.sqrt(d2)[..., None]
        sin_axis = np.sqrt(np.maximum(0.0, 1 - w[..., 0] ** 2))
        e = (rho_p / np.pi * lit * sin_axis / np.pi * (p[1] / np.sqrt(d2)) / d2).sum() \
            * (2 * a / n) ** 2
        expect = rho_f / np.pi * e
        got = (ma[i, 0] + mb[i, 0]) / 2
        se = np.abs(ma[i, 0] - mb[i, 0]) / 2 + 1e-12  # ≈ the mean's standard error
        assert np.all(np.abs(got / expect - 1) < 0.03 + 3 * se / expect), (i, got, expect)


def test_mitsuba_on_the_scalp_agrees_with_the_hair_mesh_path_tracer(tmp_path):
    """mitsuba_mesh_indirect: atlas texels of the test head under 2000 curly strands, whose
    indirect light all comes off the hair (the head alone is convex), against prtcore's
    hair + mesh path tracer, both sides' noise removed. A query that misses its texel,
    starts under the surface or takes the wrong albedo is off by far more (a query pointed
    away from its surface reads +45 %)."""
    from prtcore.core.spec import parse_spec
    from prtcore.pipeline import run_intake
    from prtcore.reference.hair_mesh import hair_mesh_reference
    from prtcore.reference.mitsuba_fibres import mitsuba_mesh_indirect
    from prtcore.scenes.hair import head_hair, head_lights, write_head

    intake = run_intake(write_head(tmp_path / "head.glb"), parse_spec(
        {"atlas": {"resolution": 32}, "measurement_points": {"count": 8}}), quiet=True)
    scene, texels = intake.scene, intake.texels
    hair = head_hair(2000, "curly", seed=0)
    hair = dataclasses.replace(hair, color=np.tile([0.8, 0.6, 0.4], (hair.point_count, 1)))
    space = build_strand_space(hair, 8)
    lights = head_lights()
    rows = np.sort(np.random.default_rng(2).choice(texels.count, 60, replace=False))
    mit = mitsuba_mesh_indirect(space, scene, texels, lights, rows, 1024, seed=4)
    tracer, fibres = hair_tracer(space, scene)
    ours = hair_mesh_reference(scene, texels, space, tracer, fibres, lights, rows, 1024,
                               seed=6)
    e = noise_corrected_error(ours, *mit)
    assert abs(e["bias"]) < 0.03 + 3 * e["bias_se"], e
    assert e["rrmse"] < 0.15, e
