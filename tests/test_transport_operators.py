"""The transport-operator seam (issue 12): the registry, the per-operator memory estimate,
and a solver that runs over a list of operators — two operators that each carry half of
the surface gather (its matrix and its near-field first bounce) give the one operator's
indirect light.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scenes import point_light

from prtcore.core.raytrace import RayTracer
from prtcore.core.spec import TransportSpec
from prtcore.receivers.texels import build_texel_space
from prtcore.transport.base import TransportOperator, names, operator_for, register
from prtcore.transport.dataset import (
    DEFAULT_OPERATORS,
    MEM_PER_TEXEL,
    MEM_PER_TEXEL_CONFIG,
    MEM_PROCESS,
    STAGES,
    Traced,
    estimate_bake_bytes,
    light_texels,
    operator_matrix,
    trace_operators,
)
from prtcore.transport.gather import GATHER_BATCH, GATHER_WORKERS, Gather
from prtcore.transport.solve import SOLVE_BLOCK_BYTES, SOLVE_WORK_ARRAYS
from prtcore.transport.surface import (
    MEM_PER_GATHER_RAY_IN_FLIGHT,
    MEM_PER_TEXEL_RAY,
    SurfaceGather,
)

HALF = np.float32(0.5)


class HalfSurface(SurfaceGather):
    """The surface gather with half its matrix and half its near-field correction (not
    registered: the solver takes operators, the registry only names them)."""

    name = "half surface"
    stats_key = "half"

    def build(self, scene, receiver, tracer, spec, timer=None):
        g = super().build(scene, receiver, tracer, spec, timer)
        return dataclasses.replace(g, matrix=(g.matrix * HALF).astype(np.float32))

    def first_bounce(self, term, scene, tracer, lights, direct, timer):
        fb = super().first_bounce(term, scene, tracer, lights, direct, timer)
        return None if fb is None else (fb[0], fb[1] * HALF)


@pytest.fixture(scope="module")
def cornell32(tmp_path_factory):
    from prtcore.intake.uv import generate_uv1
    from prtcore.io.gltf.loader import load_asset
    from prtcore.scenes.cornell import write_cornell_box

    path = write_cornell_box(tmp_path_factory.mktemp("cornell") / "cornell.glb")
    scene = generate_uv1(load_asset(path), 32, 2)
    texels = build_texel_space(scene, 32, padding=2)
    return scene, texels, RayTracer(scene.positions, scene.faces, scene.radius)


def test_registry():
    assert {"surface", "subsurface"} <= set(names()) and DEFAULT_OPERATORS == ("surface",)
    op = operator_for("surface")
    assert isinstance(op, SurfaceGather) and isinstance(op, TransportOperator)
    assert STAGES[0] == op.stage == "gather operator"
    with pytest.raises(KeyError, match=r"known: .*surface"):
        operator_for("no such operator")
    with pytest.raises(ValueError, match="registered twice"):
        register(SurfaceGather)


def test_memory_estimate_is_the_stage_plus_each_operator():
    t, k, rays = 12345, 37, 16
    surface = MEM_PER_TEXEL_RAY * t * rays \
        + GATHER_WORKERS * GATHER_BATCH * MEM_PER_GATHER_RAY_IN_FLIGHT
    own = MEM_PROCESS + t * MEM_PER_TEXEL + t * k * MEM_PER_TEXEL_CONFIG + min(
        SOLVE_WORK_ARRAYS * t * k * 12, SOLVE_BLOCK_BYTES)
    assert operator_for("surface").estimate_bytes(t, k, TransportSpec(gather_rays=rays)) \
        == surface
    assert estimate_bake_bytes(t, k, rays) == own + surface
    assert estimate_bake_bytes(t, k, TransportSpec(gather_rays=rays)) == own + surface
    assert estimate_bake_bytes(t, k, rays, operators=("surface", "surface")) \
        == own + 2 * surface
    # on the coarse grid the solve holds SOLVE_WORK_ARRAYS_COARSE full-resolution arrays
    from prtcore.transport.dataset import solve_uses_grid
    from prtcore.transport.solve import SOLVE_WORK_ARRAYS_COARSE

    assert own + surface - estimate_bake_bytes(t, k, rays, coarse=True) == \
        (SOLVE_WORK_ARRAYS - SOLVE_WORK_ARRAYS_COARSE) * t * k * 12
    spec = TransportSpec()  # coarse_grid "auto": a grid from 256² up, never with the walks
    assert [solve_uses_grid(spec, w, ("surface",)) for w in (128, 256, 1024)] == \
        [False, True, True]
    assert not solve_uses_grid(spec, 1024, ("surface", "subsurface"))
    assert not solve_uses_grid(TransportSpec(coarse_grid=1), 1024, ("surface",))


def test_solver_runs_over_a_list_of_operators(cornell32):
    scene, texels, tracer = cornell32
    spec = TransportSpec(gather_rays=16, max_bounces=30, tolerance=1e-6)
    lights = [point_light([0.0, 1.7, 0.2], 2.0), point_light([-0.5, 0.4, 0.5], 1.0)]
    (one,) = trace_operators(scene, texels, tracer, spec)
    assert isinstance(one.term, Gather) and one.term.near is not None and one.term.near.count
    assert operator_matrix([one]) is one.term.matrix  # one operator: used as it is
    half = HalfSurface()
    term = half.build(scene, texels, tracer, spec)
    two = [Traced(half, term, 0), Traced(half, term, 0)]
    summed = operator_matrix(two)
    assert summed.dtype == np.float32 and summed.has_sorted_indices
    np.testing.assert_array_equal(summed.toarray(), one.term.matrix.toarray())
    ref = light_texels(scene, texels, tracer, [one], lights, spec)
    got = light_texels(scene, texels, tracer, two, lights, spec)
    np.testing.assert_array_equal(got.direct, ref.direct)
    # the same operator and first bounce, summed: equal up to float32 summation order
    np.testing.assert_allclose(got.indirect, ref.indirect, rtol=1e-5,
                               atol=1e-6 * np.abs(ref.indirect).max())
    assert np.abs(ref.indirect).max() > 0
