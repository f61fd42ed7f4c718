"""Light intensities from 1e-6 to 1e6, in one dataset and across bakes (issue 8).

The fit divides every configuration by the norm of its direct vector, so a dataset whose
intensities span twelve decades must fit exactly as one with intensities near 1; the
runtime is positively homogeneous, so relighting scales linearly.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from stab_helpers import CORNELL, ROOM_BOX, assert_bundle_finite, bake, spec_with

from prtcore.core.raytrace import RayTracer
from prtcore.core.spec import parse_spec
from prtcore.emitters.families import sample_configurations
from prtcore.emitters.lightfile import load_light_file
from prtcore.io.bundle import load_runtime, read_manifest
from prtcore.io.gltf.loader import load_asset
from prtcore.runtime.cpu import relight

WIDE = {"log_uniform": [1e-6, 1e6]}
#: relight(a·L) = a·relight(L), Frobenius relative over the atlas.
LINEAR_RTOL = 1e-5
#: Held-out relative RMSE of a wide-intensity bake vs the same lights at intensity ~1
#: (same positions: both distributions draw one uniform number per light).
INVARIANCE_RTOL = 1e-5


def _spec(intensity: dict, **kw) -> dict:
    fam = {"type": "point", "position": {"box": ROOM_BOX}, "intensity": intensity}
    return spec_with(lights={"families": [fam]}, **kw)


@pytest.fixture(scope="module")
def wide(tmp_path_factory):
    return bake(CORNELL, _spec(WIDE), tmp_path_factory.mktemp("wide") / "b")


@pytest.fixture(scope="module")
def narrow(tmp_path_factory):
    return bake(CORNELL, _spec({"uniform": [0.5, 3.0]}), tmp_path_factory.mktemp("nar") / "b")


def test_wide_intensity_dataset_spans_twelve_decades_and_is_finite(wide):
    spec = parse_spec(_spec(WIDE))
    scene = load_asset(wide / "asset.glb")
    train, hold = sample_configurations(spec.lights, scene.center, scene.radius)
    inten = np.array([lt.intensity for lt in (*train, *hold)])
    assert inten.min() < 1e-4 and inten.max() > 1e4, inten
    m = assert_bundle_finite(wide)
    assert m["fit"]["used"] == m["fit"]["configurations"] == 24


def test_fit_is_invariant_to_per_configuration_intensity(wide, narrow):
    """Same positions, intensities 1e-6..1e6 vs 0.5..3: the same held-out relative error
    at every n, the same ridge choice and nearly the same basis planes."""
    a, b = read_manifest(wide), read_manifest(narrow)
    la = load_light_file(wide / "holdout_lights.json")
    lb = load_light_file(narrow / "holdout_lights.json")
    for x, y in zip(la, lb, strict=True):
        np.testing.assert_array_equal(x.position, y.position)
    ra = {r["n"]: r["heldout_rmse_mean"] for r in a["metrics"]["error_vs_runtime"]}
    rb = {r["n"]: r["heldout_rmse_mean"] for r in b["metrics"]["error_vs_runtime"]}
    assert ra.keys() == rb.keys()
    for n in ra:
        assert ra[n] == pytest.approx(rb[n], rel=INVARIANCE_RTOL), n
    assert a["fit"]["ridge"] == pytest.approx(b["fit"]["ridge"], rel=INVARIANCE_RTOL)
    pa, pb = load_runtime(wide).planes, load_runtime(narrow).planes
    # element 0 (the mean) is well separated from the rest: compare it directly
    mean_a, mean_b = pa[:, :, :3], pb[:, :, :3]
    assert np.linalg.norm(mean_a - mean_b) <= INVARIANCE_RTOL * np.linalg.norm(mean_b)


@pytest.mark.parametrize("base", [1e-6, 1.0, 1e6])
@pytest.mark.parametrize("a", [1e-6, 3.7e-2, 1e6])
def test_relight_scales_linearly(wide, base, a):
    data = load_runtime(wide)
    scene = load_asset(wide / "asset.glb")
    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    light = load_light_file(wide / "holdout_lights.json")[0]
    light = dataclasses.replace(light, intensity=base)
    ref = relight(data, [light], tracer)[:, :, :3].astype(np.float64)
    got = relight(data, [dataclasses.replace(light, intensity=base * a)], tracer)
    assert np.isfinite(got).all()
    assert np.abs(ref).max() > 0
    err = np.linalg.norm(got[:, :, :3] - a * ref) / np.linalg.norm(a * ref)
    assert err <= LINEAR_RTOL, err
