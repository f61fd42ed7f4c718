"""Procedural test hair (prtcore/scenes/hair.py) and the Hair data (prtcore/core/hair.py)."""

from __future__ import annotations

import numpy as np
import pytest

from prtcore.io.gltf.loader import load_asset
from prtcore.scenes.hair import hairball, head_hair, write_head


def test_hairball_is_seeded_and_stays_in_its_ball():
    a, b = hairball(strands=10_000, seed=1), hairball(strands=10_000, seed=1)
    assert a.strand_count == 10_000 and a.point_count == 10_000 * 17
    np.testing.assert_array_equal(a.points, b.points)
    assert not np.array_equal(a.points, hairball(strands=10_000, seed=2).points)
    step = 0.15 / 16
    assert np.linalg.norm(a.points, axis=1).max() <= 0.1 + step
    np.testing.assert_allclose(a.strand_length, 0.15, rtol=1e-9)
    # per-strand colour: constant along a strand, varying between strands
    col = a.color.reshape(10_000, 17, 3)
    assert np.ptp(col, axis=1).max() == 0 and np.ptp(col[:, 0, 0]) > 0.05


@pytest.mark.parametrize("style", ["straight", "curly"])
def test_head_hair_grows_outside_the_head(style):
    h = head_hair(strands=10_000, style=style, seed=0)
    assert h.strand_count == 10_000
    r = np.linalg.norm(h.points, axis=1)
    assert r.min() >= 0.1 * (1 - 1e-9)
    roots = h.points[h.offsets[:-1]]
    assert (roots[:, 1] > -0.2 * 0.1 * 1.03).all()
    tips = h.points[h.offsets[1:] - 1]
    assert tips[:, 1].mean() < roots[:, 1].mean()  # hair falls
    if style == "curly":  # curls make strands longer than their straight counterparts
        straight = head_hair(strands=10_000, style="straight", seed=0)
        assert h.strand_length.mean() > 1.2 * straight.strand_length.mean()


def test_head_mesh_loads_as_a_scene(tmp_path):
    scene = load_asset(write_head(tmp_path / "head.glb"))
    r = np.linalg.norm(scene.positions, axis=1)
    np.testing.assert_allclose(r, 0.1, rtol=1e-3)
