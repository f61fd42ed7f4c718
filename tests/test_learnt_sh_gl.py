"""The learnt SH network in GLSL (prtcore.runtime.learnt_sh: weights as mat4 blocks)
against its numpy evaluation (prtcore.fit.learnt_sh.evaluate), for the thesis' sizes with
seeded random weights: equal to 1e-4 of the largest coefficient."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from prtcore.core.mlp import LEAKY_SLOPE, Mlp
from prtcore.fit.learnt_sh import (
    NORMAL_FREQUENCIES,
    POSITION_FREQUENCIES,
    SIZES,
    LearntSh,
    evaluate,
)
from prtcore.runtime.gl import create_context
from prtcore.runtime.learnt_sh import gpu_evaluate, packed, shader


@pytest.fixture(scope="module")
def ctx():
    c = create_context()
    yield c
    c.release()


def random_model(width: int, layers: int, seed: int) -> LearntSh:
    rng = np.random.default_rng(seed)
    d_in = 3 * (1 + 2 * POSITION_FREQUENCIES) + 3 * (1 + 2 * NORMAL_FREQUENCIES)
    sizes = (d_in, *(width,) * layers, 16)
    ws = tuple(rng.standard_normal((o, i)) * np.sqrt(2.0 / i)
               for i, o in itertools.pairwise(sizes))
    bs = tuple(0.1 * rng.standard_normal(o) for o in sizes[1:])
    return LearntSh(Mlp(ws, bs, LEAKY_SLOPE, "tanh"), np.array([0.1, -0.2, 0.3]), 2.0,
                    0.7, 4, POSITION_FREQUENCIES, NORMAL_FREQUENCIES, {})


@pytest.mark.parametrize("size", sorted(SIZES))
def test_glsl_learnt_sh_is_the_numpy_one(ctx, size):
    width, layers = SIZES[size]
    model = random_model(width, layers, 1)
    rng = np.random.default_rng(2)
    p = rng.uniform(-2.0, 2.0, (300, 3))
    n = rng.standard_normal((300, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    cpu = evaluate(model, p, n)
    gpu = gpu_evaluate(ctx, model, p, n)
    assert np.abs(cpu).max() > 0.1  # the outputs are not all squashed to 0 or ±scale
    assert np.abs(gpu - cpu).max() <= 1e-4 * np.abs(cpu).max(), np.abs(gpu - cpu).max()
    mats, _, table, scale, frame = packed(model)
    assert np.allclose(scale.ravel()[:16], 0.7)
    assert np.allclose(frame, [[0.1, -0.2, 0.3, 0.5]])
    assert len(mats) == sum(int(i4 * o4) for i4, o4, _, _ in table)
    assert f"#define LAYERS {layers + 1}" in shader(model)


def test_glsl_picks_each_points_sub_scene_network(ctx):
    """Four cells (2 × 1 × 2) of different seeded networks: the GLSL picks the cell of
    each point as prtcore.fit.subscenes.Grid.cell_of does and gives that network's
    outputs (1e-4 of the largest)."""
    from prtcore.fit.subscenes import Grid, LearntShScenes, evaluate_scenes

    models = tuple(random_model(16, 2, seed) for seed in range(4))
    grid = Grid((2, 1, 2), np.array([-2.0, -2.0, -2.0]), np.array([2.0, 2.0, 2.0]), 0.1)
    scenes = LearntShScenes(grid, models)
    rng = np.random.default_rng(5)
    p = rng.uniform(-1.9, 1.9, (400, 3))
    n = rng.standard_normal((400, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    cpu = evaluate_scenes(scenes, p, n)
    assert sorted(np.unique(grid.cell_of(p))) == [0, 1, 2, 3]
    assert np.abs(cpu - evaluate(models[0], p, n)).max() > 0.1  # the cells differ
    gpu = gpu_evaluate(ctx, scenes, p, n)
    assert np.abs(gpu - cpu).max() <= 1e-4 * np.abs(cpu).max()
