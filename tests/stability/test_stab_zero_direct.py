"""Configurations whose direct vector is zero (issue 8): a light behind the asset, one
inside a closed block, a spot aimed out of the room, intensity 0.

The fit must not divide by their zero norm: they are excluded, listed with their reason in
the diagnostics and counted in a warning; held-out ones are skipped by the error table and
counted there. A bake where every configuration is zero is refused, naming the cause.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from stab_helpers import CORNELL, ROOM_BOX, assert_bundle_finite, bake, spec_with

from prtcore.core.errors import PrtError
from prtcore.core.raytrace import RayTracer
from prtcore.core.spec import parse_spec
from prtcore.emitters.families import sample_configurations
from prtcore.emitters.punctual import irradiance
from prtcore.io.bundle import load_runtime
from prtcore.io.gltf.loader import load_asset
from prtcore.runtime.cpu import relight

ROOM = {"type": "point", "weight": 3.0, "position": {"box": ROOM_BOX},
        "intensity": {"uniform": [0.5, 3.0]}}
DARK = [
    # behind the back wall (z = −1), the room's walls are single-sided but still occlude
    {"type": "point", "position": {"fixed": [0.0, 1.0, -3.0]}},
    # inside the tall block (centre [−0.33, 0.6, −0.3])
    {"type": "point", "position": {"fixed": [-0.33, 0.6, -0.3]}},
    # spot at the open front, aimed out of the room
    {"type": "spot", "position": {"fixed": [0.0, 1.0, 0.95]}, "aim": {"direction": [0, 0, 1]},
     "outer_cone_angle": {"constant": 0.3}},
    # intensity 0 inside the room
    {"type": "point", "position": {"box": ROOM_BOX}, "intensity": {"constant": 0.0}},
]


def _spec(families) -> dict:
    return spec_with(lights={"count": 32, "holdout": 8, "seed": 5, "families": families})


def _zero_direct(spec: dict, scene) -> tuple[np.ndarray, np.ndarray]:
    """(train, holdout) bool masks: the sampled light reaches no measurement point,
    computed independently of the bake from the lights and the bundle's clusters."""
    s = parse_spec(spec)
    train, hold = sample_configurations(s.lights, scene.center, scene.radius)
    return tuple(np.array([lt.intensity == 0 or _is_dark_light(lt) for lt in ls])
                 for ls in (train, hold))


def _is_dark_light(light) -> bool:
    return any(np.allclose(light.position, f["position"]["fixed"])
               for f in DARK if "fixed" in f["position"])


@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    return bake(CORNELL, _spec([ROOM, *DARK]), tmp_path_factory.mktemp("mixed") / "b")


def test_dark_lights_reach_no_measurement_point(mixed):
    """The premise: every DARK light gives an exactly zero direct vector."""
    data = load_runtime(mixed)
    scene = load_asset(mixed / "asset.glb")
    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    s = parse_spec(_spec([ROOM, *DARK]))
    train, _ = sample_configurations(s.lights, scene.center, scene.radius)
    dark_train, _ = _zero_direct(_spec([ROOM, *DARK]), scene)
    assert 0 < dark_train.sum() < len(train)
    for lt, dark in zip(train, dark_train, strict=True):
        e = irradiance(lt, data.cluster_position.astype(np.float64),
                       data.cluster_normal.astype(np.float64), tracer)
        assert (e.max() == 0.0) == bool(dark), lt


def test_zero_direct_configurations_are_excluded_and_reported(mixed):
    m = assert_bundle_finite(mixed)
    scene = load_asset(mixed / "asset.glb")
    dark_train, dark_hold = _zero_direct(_spec([ROOM, *DARK]), scene)
    diag = m["diagnostics"]
    assert [e["index"] for e in diag["excluded"]] == np.flatnonzero(dark_train).tolist()
    assert {e["reason"] for e in diag["excluded"]} == {"zero direct"}
    assert m["fit"]["used"] == len(dark_train) - dark_train.sum()
    assert any(f"{dark_train.sum()} of {len(dark_train)} configurations excluded" in w
               for w in m["fit"]["warnings"])
    table = json.loads((mixed / "report.json").read_text())["table"]
    assert dark_hold.any()
    assert table["heldout_skipped"] == [
        {"index": int(h), "reason": "zero direct"} for h in np.flatnonzero(dark_hold)]


@pytest.mark.parametrize("gamma", [None, 2.2])
def test_relighting_with_a_dark_light_is_exactly_zero(mixed, gamma):
    import dataclasses

    data = load_runtime(mixed)
    data = dataclasses.replace(data, gamma=gamma)
    scene = load_asset(mixed / "asset.glb")
    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    s = parse_spec(_spec([ROOM, *DARK]))
    train, _ = sample_configurations(s.lights, scene.center, scene.radius)
    dark_train, _ = _zero_direct(_spec([ROOM, *DARK]), scene)
    for lt in np.asarray(train, dtype=object)[dark_train]:
        out = relight(data, [lt], tracer)
        assert np.isfinite(out).all()
        assert np.abs(out[:, :, :3]).max() == 0.0


def test_all_dark_dataset_is_refused_with_the_cause(tmp_path):
    out = tmp_path / "b"
    with pytest.raises(PrtError, match=r"only 0 usable lighting configurations of 32 "
                                       r"\(zero or non-finite direct"):
        bake(CORNELL, _spec(DARK), out)
    assert not out.exists()
