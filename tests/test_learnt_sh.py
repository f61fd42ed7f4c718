"""Learnt SH transfer σ(p, n̂) (prtcore.fit.learnt_sh, thesis ch. 4) on the Cornell box:
area-uniform training samples, and the network's transfer at fresh points against an
independent ray-traced reference with 16× the rays (not against its own training data)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prtcore.core.raytrace import RayTracer
from prtcore.fit.learnt_sh import (
    SIZES,
    VERTEX_MARGIN,
    area_samples,
    evaluate,
    fit_learnt_sh,
    unit_albedo_transfer,
)
from prtcore.io.gltf.loader import load_asset

CORNELL = Path(__file__).resolve().parents[1] / "examples" / "cornell_box.glb"


@pytest.fixture(scope="module")
def cornell():
    scene = load_asset(CORNELL)
    return scene, RayTracer(scene.positions, scene.faces, scene.radius)


def test_area_samples_avoid_vertex_neighbourhoods_and_stay_uniform_elsewhere():
    """One triangle (0,0,0), (1,0,0), (0,1,0): a sample's barycentrics are (1 − x − y, x, y).
    None may weigh a corner above 1 − VERTEX_MARGIN; the rest of the triangle stays uniform
    (the share of samples with x + y < ½ is that region's share of the allowed area)."""
    from prtcore.core.scene import Material, single_mesh_scene

    pos = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    scene = single_mesh_scene("tri", pos, np.tile([0.0, 0, 1], (3, 1)),
                              np.array([[0, 1, 2]]),
                              Material(name="m", base_color_factor=np.ones(4)))
    n = 40000
    p = area_samples(scene, n, 5).position
    bary = np.stack([1 - p[:, 0] - p[:, 1], p[:, 0], p[:, 1]], axis=1)
    assert bary.max() <= 1 - VERTEX_MARGIN + 1e-12 and bary.min() >= -1e-12
    m = VERTEX_MARGIN
    allowed = 1 - 3 * m * m  # fractions of the triangle's area
    inner = 0.25 - m * m  # x + y < ½ minus the corner at (0, 0)
    share = np.mean(p[:, 0] + p[:, 1] < 0.5)
    assert abs(share - inner / allowed) < 4 * np.sqrt(0.25 / n)
    # a margin of 0 draws plain area-uniform samples
    assert area_samples(scene, 100, 5, vertex_margin=0.0).position.shape == (100, 3)


def test_area_samples_are_uniform_over_the_surface(cornell):
    """Per face orientation (the box's walls, blocks' sides), the share of 20 000 samples
    matches the share of the surface area within 4 standard deviations; normals are
    unit length and samples lie inside the scene's bounds."""
    scene, _ = cornell
    n = 20000
    s = area_samples(scene, n, 3)
    v = scene.positions[scene.faces]
    cross = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    face_dir = np.round(cross / np.maximum(2 * area[:, None], 1e-300), 3)
    sample_dir = np.round(s.geometric_normal, 3)
    assert np.allclose(np.linalg.norm(s.normal, axis=1), 1.0)
    lo, hi = scene.positions.min(axis=0), scene.positions.max(axis=0)
    assert (s.position >= lo - 1e-9).all() and (s.position <= hi + 1e-9).all()
    dirs = np.unique(face_dir[area > 0], axis=0)
    assert len(dirs) >= 6
    for d in dirs:
        share = area[(face_dir == d).all(axis=1)].sum() / area.sum()
        got = np.mean((sample_dir == d).all(axis=1))
        assert abs(got - share) <= 4 * np.sqrt(share * (1 - share) / n) + 1e-4, (d, got, share)


def test_learnt_transfer_matches_a_ray_traced_reference(cornell):
    """Trained on 3000 samples × 16 rays, σ at 300 fresh points is within 50 % (relative
    L2 over all coefficients) of a 256-ray reference — an untrained network is at 100 %;
    training is deterministic (same seed, same weights bit for bit)."""
    scene, tracer = cornell
    kw = {"samples": 3000, "strata": 4, "width": 64, "layers": 4, "steps": 400,
          "batch": 512, "seed": 0}
    model = fit_learnt_sh(scene, tracer, **kw)
    test = area_samples(scene, 300, 99)
    ref = unit_albedo_transfer(scene, tracer, test, 4, 16, 7)
    err = np.linalg.norm(evaluate(model, test.position, test.normal) - ref) / np.linalg.norm(ref)
    assert err < 0.5, err
    assert model.diagnostics["holdout_mse"] < 0.5 * model.diagnostics["holdout_mse_zero"]
    again = fit_learnt_sh(scene, tracer, **{**kw, "steps": 20})
    once = fit_learnt_sh(scene, tracer, **{**kw, "steps": 20})
    assert all(a.tobytes() == b.tobytes() for a, b in zip(again.net.weights,
                                                           once.net.weights, strict=True))
    assert SIZES == {"k64_l4": (64, 4), "k128_l4": (128, 4)}


@pytest.mark.slow
def test_sub_scenes_overlap_band_joins_the_cells(cornell):
    """Two cells along x (thesis 4.1.5): with a δ = 0.25 band each network is trained
    across the boundary, so at held-out points near it the two networks disagree less
    than without the band; one network per cell, each point shaded by its cell's; the
    GLSL picks the same cell and gives the same outputs (1e-4)."""
    from prtcore.fit.subscenes import evaluate_scenes, fit_scenes
    from prtcore.runtime.gl import create_context
    from prtcore.runtime.learnt_sh import gpu_evaluate

    scene, tracer = cornell
    kw = {"samples": 3000, "strata": 4, "width": 32, "layers": 2, "steps": 300,
          "batch": 256, "seed": 0, "cells": (2, 1, 1)}
    banded = fit_scenes(scene, tracer, overlap=0.25, **kw)
    cut = fit_scenes(scene, tracer, overlap=0.0, **kw)
    assert banded.grid.count == 2 and len(banded.models) == 2
    test = area_samples(scene, 4000, 99)
    mid = 0.5 * (banded.grid.lo[0] + banded.grid.hi[0])
    near = np.abs(test.position[:, 0] - mid) < 0.05 * (banded.grid.hi[0] - banded.grid.lo[0])
    p, n = test.position[near], test.normal[near]
    assert near.sum() > 50

    def disagreement(m):
        a, b = (evaluate(net, p, n) for net in m.models)
        return float(np.linalg.norm(a - b) / np.linalg.norm(a + b))

    print(f"cells' disagreement at the boundary: band 0.25 {disagreement(banded):.3f}, "
          f"no band {disagreement(cut):.3f}")
    assert disagreement(banded) < 0.7 * disagreement(cut)
    ctx = create_context()
    try:
        cpu = evaluate_scenes(banded, test.position, test.normal)
        gpu = gpu_evaluate(ctx, banded, test.position, test.normal)
    finally:
        ctx.release()
    cells = banded.grid.cell_of(test.position)
    assert set(np.unique(cells)) == {0, 1}
    np.testing.assert_array_equal(cpu[cells == 0], evaluate(banded.models[0],
                                                            test.position[cells == 0],
                                                            test.normal[cells == 0]))
    assert np.abs(gpu - cpu).max() <= 1e-4 * np.abs(cpu).max()
