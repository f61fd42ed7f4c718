"""The subsurface operator (prtcore/transport/subsurface.py, docs/subsurface.md): energy
conservation in a closed non-absorbing medium, per-channel weights from one set of walks,
determinism, memory model, the one solve with the surface gather."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from prtcore.core.raytrace import RayTracer
from prtcore.core.spec import TransportSpec, parse_spec
from prtcore.intake.prepare import prepare_scene
from prtcore.io.gltf.loader import load_asset
from prtcore.receivers.texels import build_texel_space
from prtcore.transport.dataset import (
    TRANSLUCENT_OPERATORS,
    estimate_bake_bytes,
    operators_for,
)
from prtcore.transport.subsurface import sample_hg, subsurface_operator


def _sphere(tmp_path, albedo=None, floor=False, res=48, **kw):
    from prtcore.scenes.translucent import write_translucent_sphere

    spec = parse_spec({"atlas": {"resolution": res, "padding": 2}})
    scene, _ = prepare_scene(load_asset(write_translucent_sphere(
        tmp_path / "s.glb", floor=floor, subdivisions=3, **kw)), spec)
    if albedo is not None:
        mats = tuple(dataclasses.replace(m, subsurface=dataclasses.replace(
            m.subsurface, albedo=np.asarray(albedo, np.float64)))
            if m.subsurface is not None else m for m in scene.materials)
        scene = scene.replace(materials=mats)
    texels = build_texel_space(scene, res, res, padding=2)
    return scene, texels, RayTracer(scene.positions, scene.faces, scene.radius)


def test_hg_sampling_has_mean_cosine_g():
    rng = np.random.default_rng(0)
    axis = np.tile([0.0, 0.0, 1.0], (200_000, 1))
    for g in (0.0, 0.5, -0.7):
        d = sample_hg(axis, g, rng.random((len(axis), 2)))
        # E[cos] = g; standard error ≤ 1/sqrt(n)
        assert d[:, 2].mean() == pytest.approx(g, abs=5 / np.sqrt(len(axis)))
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)


def test_closed_non_absorbing_medium_returns_all_light_and_channels_share_walks(tmp_path):
    scene, texels, tracer = _sphere(tmp_path, albedo=[1.0, 0.99, 0.9], mean_free_path=0.1)
    term = subsurface_operator(scene, texels, tracer, 16, 3, 4096)
    st = term.stats
    assert st["capped"] == 0 and st["front_or_other"] == 0
    rows = [np.asarray(m.sum(axis=1)).ravel() for m in term.channel_matrices]
    # α = 1: every walk that starts inward leaves again (energy conservation); the walks
    # whose cosine direction about the shading normal pointed out of the face count as 0
    lost = st["outward_start"] / st["walks"]
    assert rows[0].mean() == pytest.approx(1.0 - lost, abs=1e-6)
    assert lost < 2e-3
    # one set of walks: the same (receiver, source) entries, weights α_c^n, so absorbing
    # channels are strictly darker, entry by entry
    a, b, c = term.channel_matrices
    assert (a.indices == b.indices).all() and (a.indptr == c.indptr).all()
    assert (b.data <= a.data).all() and (c.data <= b.data).all() and c.sum() < 0.9 * a.sum()
    again = subsurface_operator(scene, texels, tracer, 16, 3, 4096)
    assert all((x != y).nnz == 0 for x, y in zip(term.channel_matrices,
                                                    again.channel_matrices, strict=True))


def test_operator_selection_and_memory(tmp_path):
    scene, _, _ = _sphere(tmp_path, floor=True)
    assert operators_for(scene) == TRANSLUCENT_OPERATORS
    spec = TransportSpec(subsurface_walks=64)
    with_walks = estimate_bake_bytes(1000, 10, spec, TRANSLUCENT_OPERATORS)
    assert with_walks - estimate_bake_bytes(1000, 10, spec) >= 1000 * 64 * 160


def test_one_solve_carries_light_through_the_sphere_to_its_dark_side(tmp_path):
    from prtcore.core.scene import Light
    from prtcore.intake.points import place_measurement_points
    from prtcore.transport.dataset import bake_dataset

    scene, texels, tracer = _sphere(tmp_path, floor=True, mean_free_path=0.3, res=48)
    spec = parse_spec({"measurement_points": {"count": 8}})
    points = place_measurement_points(scene, spec.measurement_points)
    light = Light(type="point", color=np.ones(3), intensity=50.0,
                  position=np.array([0.0, 3.0, 0.0]))
    ts = TransportSpec(gather_rays=16, subsurface_walks=8)
    data = bake_dataset(scene, texels, points, [light], spec=ts, tracer=tracer)
    assert data.stats["solve"]["converged"]
    skin = scene.face_material[texels.triangle] == 0
    under = skin & (texels.position[:, 1] < -0.5)  # the sphere's underside: no direct light
    assert data.direct_texels[under, 0].max() == 0
    opaque = bake_dataset(scene, texels, points, [light], spec=ts, tracer=tracer,
                          operators=("surface",))
    # through the medium the underside gets far more than the floor's bounce alone
    assert data.indirect[under, 0].mean() > 2 * opaque.indirect[under, 0].mean()
