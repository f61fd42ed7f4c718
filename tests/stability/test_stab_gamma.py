"""The gamma option with zero and negative reconstructed values (issue 8).

Runtime with gamma g: ``y = max(y', 0)^g`` — gamma-space values below zero have no
radiance meaning and are clamped to 0 (deringing by clamping; documented in the README).
g is limited to [1, 10]: g < 1 expands the dynamic range and overflowed (NaN lightmaps).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from stab_helpers import CORNELL, ROOM_BOX, assert_bundle_finite, bake, spec_with

from prtcore.core.errors import SpecError
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.core.spec import parse_spec
from prtcore.emitters.lightfile import load_light_file
from prtcore.fit.model import GAMMA_RANGE
from prtcore.fit.transfer import fit_transfer, reconstruct
from prtcore.io.bundle import load_runtime
from prtcore.io.gltf.loader import load_asset
from prtcore.runtime.cpu import plane_weights, relight, shade_points

LINEAR_RTOL = 1e-5


@pytest.fixture(scope="module")
def gamma_bundle(tmp_path_factory):
    fam = {"type": "point", "position": {"box": ROOM_BOX},
           "intensity": {"log_uniform": [1e-6, 1e6]}}
    spec = spec_with(lights={"families": [fam]}, fit={"basis": 8, "gamma": 2.2})
    return bake(CORNELL, spec, tmp_path_factory.mktemp("gamma") / "b")


@pytest.fixture(scope="module")
def tracer(gamma_bundle):
    scene = load_asset(gamma_bundle / "asset.glb")
    return RayTracer(scene.positions, scene.faces, scene.radius)


def test_gamma_bundle_is_finite(gamma_bundle):
    m = assert_bundle_finite(gamma_bundle)
    assert m["fit"]["gamma"] == 2.2


# lights outside the training family: near a wall, low in a corner, a spot into a corner,
# a blue light just above the floor, a directional light through the open front
ODD_LIGHTS = [
    Light(type="point", color=np.array([0.0, 0.0, 1.0]), intensity=1.0,
          position=np.array([0.6, 0.1, 0.6])),
    Light(type="directional", color=np.ones(3), intensity=1.0,
          direction=np.array([0.3, -0.5, -1.0]) / np.linalg.norm([0.3, -0.5, -1.0])),
    Light(type="point", color=np.ones(3), intensity=5.0, position=np.array([0.9, 0.2, 0.8])),
    Light(type="point", color=np.array([1.0, 0.1, 0.0]), intensity=1e6,
          position=np.array([-0.95, 1.95, -0.95])),
    Light(type="spot", color=np.ones(3), intensity=1e-6, position=np.array([0.0, 1.9, 0.0]),
          direction=np.array([-0.6, -0.5, -0.6]) / np.linalg.norm([-0.6, -0.5, -0.6]),
          outer_cone_angle=0.2, inner_cone_angle=0.0),
]


def test_negative_gamma_space_values_are_clamped_to_zero(gamma_bundle, tracer):
    data = load_runtime(gamma_bundle)
    negatives = 0
    for light in ODD_LIGHTS:
        out = relight(data, [light], tracer)[:, :, :3]
        assert np.isfinite(out).all() and (out >= 0).all()
        # the unclamped gamma-space blend, in float64
        x = shade_points(data, [light], tracer)
        w = plane_weights(data, x)
        h, wd, q = data.planes.shape
        y = (data.planes.reshape(-1, q).astype(np.float64) @ w).reshape(h, wd, 3)
        neg = y < 0
        negatives += int(neg.sum())
        assert (out[neg] == 0).all()
        pos = y > 0
        np.testing.assert_allclose(out[pos], y[pos] ** 2.2, rtol=1e-4,
                                   atol=1e-6 * float(np.abs(y).max()) ** 2.2)
    assert negatives > 0, "no light produced negative gamma-space values: premise lost"


@pytest.mark.parametrize("a", [1e-6, 1e6])
def test_gamma_relight_scales_linearly(gamma_bundle, tracer, a):
    data = load_runtime(gamma_bundle)
    light = load_light_file(gamma_bundle / "holdout_lights.json")[0]
    ref = relight(data, [light], tracer)[:, :, :3].astype(np.float64)
    got = relight(data, [dataclasses.replace(light, intensity=light.intensity * a)], tracer)
    err = np.linalg.norm(got[:, :, :3] - a * ref) / np.linalg.norm(a * ref)
    assert err <= LINEAR_RTOL, err


@pytest.mark.parametrize("g", [0.05, 0.5, 0.999, 10.5])
def test_gamma_outside_range_is_refused(g):
    """Before: gamma 0.05 fitted a model whose reconstruction of a 1e6 light was NaN."""
    with pytest.raises(SpecError, match=r"spec fit\.gamma: must be"):
        parse_spec(spec_with(fit={"gamma": g}))
    rng = np.random.default_rng(0)
    D = np.abs(rng.normal(size=(5, 12, 3)))
    with pytest.raises(ValueError, match=r"gamma must be None or in \[1, 10\]"):
        fit_transfer(D, np.abs(rng.normal(size=(20, 12, 3))), basis=3, ridge=1e-3, gamma=g)


@pytest.mark.parametrize("g", GAMMA_RANGE)
def test_gamma_at_range_ends_with_twelve_decades_is_finite(g):
    rng = np.random.default_rng(1)
    T, P, K = 100, 10, 30
    op = np.abs(rng.normal(size=(T, P)))
    D = np.abs(rng.normal(size=(P, K, 3))) * 10.0 ** rng.uniform(-6, 6, size=(1, K, 1))
    I = np.einsum("tp,pkc->tkc", op, D)
    m = fit_transfer(D, I, basis=5, ridge=1e-3, gamma=g)
    assert m.diagnostics.used == K
    for scale in (1e-6, 1.0, 1e6):
        y = reconstruct(m, D[:, 0] * scale)
        assert np.isfinite(y).all() and (y >= 0).all()
    # zero direct: exactly zero, not NaN (0^g, s = 0)
    assert (reconstruct(m, np.zeros((P, 3))) == 0).all()
