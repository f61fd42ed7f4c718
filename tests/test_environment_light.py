"""Environment lights for the data-driven bake (prtcore/emitters/environment_light.py).

Direct irradiance from the shared cosine-sampled directions is checked against the
environment path tracer (:mod:`prtcore.reference.environment`: environment + cosine
sampling, balance heuristic, its own streams), one bounce, noise removed from two halves.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from prtcore.core.errors import LightFileError, SpecError
from prtcore.core.materials import clamp_albedo
from prtcore.core.scene import Light
from prtcore.core.spec import parse_spec
from prtcore.emitters import environment_light as el
from prtcore.emitters.base import emitter_for
from prtcore.emitters.families import sample_configurations
from prtcore.emitters.lightfile import light_from_dict, light_to_dict
from prtcore.emitters.punctual import irradiance
from prtcore.pipeline import run_intake
from prtcore.reference.environment import reference_environment
from prtcore.reference.pathtracer import default_tracer
from prtcore.scenes import floor_object


def _sky(to_sun, intensity=1.0, environment="sky") -> Light:
    d = -np.asarray(to_sun, float) / np.linalg.norm(to_sun)
    return Light(type="environment", color=np.ones(3), intensity=intensity, direction=d,
                 environment=environment)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = floor_object.write_floor_object(tmp_path_factory.mktemp("fo") / "fo.glb")
    spec = dict(floor_object.SPEC, atlas={"resolution": 24, "padding": 2})
    intake = run_intake(path, parse_spec(spec), quiet=True)
    return intake.scene, intake.texels, default_tracer(intake.scene)


def test_direct_light_matches_the_environment_path_tracer(scene):
    """ρ/π · E from the shared directions vs the path tracer's one-bounce radiance under
    the same sky (its map's own pixels), over the floor and the block, shadows included."""
    sc, tx, tracer = scene
    light = _sky([0.5, 0.6, -0.4], 1.0)
    env = el.environment_of(light)
    rho, _ = clamp_albedo(tx.albedo)
    ours = rho / math.pi * irradiance(light, tx.position, tx.normal, tracer)
    ref = reference_environment(sc, tracer, env, tx.position, tx.normal,
                                tx.geometric_normal, tx.albedo, 256, seed=3, max_depth=1)
    fine = el.STRATA
    try:  # the same estimator with 16× the directions: its own noise, measured
        el.STRATA = 4 * fine
        dense = rho / math.pi * el.EnvironmentEmitter().irradiance(light, tx.position,
                                                                   tx.normal, tracer)
    finally:
        el.STRATA = fine

    def corrected(pred):
        raw2 = ((pred - ref.mean) ** 2).mean(axis=1).mean()
        return math.sqrt(max(0.0, raw2 - ref.noise2.mean()))
    err, err_dense = corrected(ours), corrected(dense)
    own = math.sqrt(((ours - dense) ** 2).mean())
    mean = float(ref.mean.mean())
    print(f"\nenvironment light vs path tracer (mean radiance {mean:.3f}, ref noise "
          f"{math.sqrt(ref.noise2.mean()):.4f}): {fine ** 2} directions/point corrected rms "
          f"{err:.4f}, {16 * fine ** 2} directions {err_dense:.4f}; the default estimate's "
          f"own noise (vs {16 * fine ** 2}) {own:.4f}")
    assert err_dense < 0.015 * mean  # the estimator converges to the path tracer
    assert err <= own + 0.01 * mean  # and the default one's error is its own noise
    shadow = ours.sum(axis=1) < 0.5 * np.median(ours.sum(axis=1))
    assert shadow.any()  # the block shadows part of the floor


def test_directions_and_visibility_are_shared_across_the_family(scene):
    _, tx, tracer = scene
    calls = []

    class Counting:
        offset = tracer.offset

        def unoccluded_towards(self, *a):
            calls.append(len(a[0]))
            return tracer.unoccluded_towards(*a)

    em = el.EnvironmentEmitter()
    counting = Counting()
    lights = [_sky(d) for d in ([0.5, 0.6, -0.4], [-0.3, 0.8, 0.2], [0.0, 0.3, 1.0])]
    e = [em.irradiance(lt, tx.position, tx.normal, counting) for lt in lights]
    assert len(calls) == 1 and calls[0] == tx.count * el.STRATA ** 2  # traced once
    again = el.EnvironmentEmitter().irradiance(lights[1], tx.position, tx.normal, tracer)
    np.testing.assert_array_equal(e[1], again)  # the same seeded directions
    # a rotated map: the same light turned by 90° about y is the map turned by 90°
    assert np.abs(e[0] - e[1]).max() > 0.05 * np.abs(e[0]).max()


def test_a_map_file_turns_with_the_drawn_direction(tmp_path):
    from prtcore.io.imageio import write_exr
    h = 16
    img = np.zeros((h, 2 * h, 3), np.float32)
    img[:, h // 4: 3 * h // 4] = 1.0  # a quarter of the azimuths, centred on u = 1/4
    path = tmp_path / "map.exr"
    write_exr(path, img)
    a = _sky([0.0, 0.0, -1.0], environment=str(path))
    b = _sky([1.0, 0.0, 0.0], environment=str(path))
    dirs = np.array([[0.0, 0.0, -1.0], [1.0, 0, 0], [0, 0, 1.0], [-1.0, 0, 0]])
    ra, rb = el.environment_radiance(a, dirs), el.environment_radiance(b, dirs)
    # turning by 90° moves the bright quarter by one of the four axis directions
    assert ra.sum() > 0 and any(np.array_equal(np.roll(ra, k, axis=0), rb) for k in (1, 3))


def test_spec_and_light_file_accept_environment_lights():
    spec = parse_spec({"lights": {"count": 6, "holdout": 2, "families": [
        {"type": "environment", "position": {"shell": [1.5, 3.0]}}]}})
    fam = spec.lights.families[0]
    assert fam.environment == "sky"
    train, held = sample_configurations(spec.lights, np.zeros(3), 1.0)
    assert all(lt.type == "environment" and lt.environment == "sky" for lt in train + held)
    with pytest.raises(SpecError, match="families"):
        parse_spec({"lights": {"families": [{"type": "point", "environment": "sky"}]}})
    d = light_to_dict(train[0])
    back = light_from_dict(d)
    assert back.environment == "sky" and np.allclose(back.direction, train[0].direction)
    with pytest.raises(LightFileError, match="environment"):
        light_from_dict({"type": "point", "position": [0, 1, 0], "environment": "sky"})
    assert emitter_for("environment").directed and not emitter_for("environment").positioned


def test_a_sky_family_bakes_with_the_data_driven_method(tmp_path):
    """`lights.families: [{"type": "environment"}]` through the whole data-driven bake:
    training and held-out skies, the held-out verdict against the fast transport."""
    import json

    from prtcore.pipeline import bake
    path = floor_object.write_floor_object(tmp_path / "fo.glb")
    spec = parse_spec({
        "atlas": {"resolution": 32, "padding": 2},
        "measurement_points": {"count": 64, "supersample": 2, "seed": 1},
        "lights": {"count": 24, "holdout": 4, "seed": 2, "families": [
            {"type": "environment", "environment": "sky",
             "position": {"box": [[-6.0, 1.6, -6.0], [6.0, 6.0, 6.0]]},
             "aim": {"target": [0.0, 0.0, 0.0], "jitter": 0.0},
             "intensity": {"uniform": [0.5, 1.5]}}]},
        "transport": {"gather_rays": 32, "max_bounces": 4},
        "fit": {"basis": 8}})
    out = bake(path, spec, tmp_path / "bundle", quiet=True)
    report = json.loads((out / "report.json").read_text())
    verdict = report["verdict"]
    print(f"\nsky family bake: {verdict['line']}; stages {report['stage_seconds']}")
    assert verdict["status"] == "pass", verdict["line"]


def test_ambient_term_is_pi_l_where_the_sky_is_open_and_less_beside_the_block(scene):
    """``"environment": "ambient"``: uniform radiance L, so E = π·L exactly at an open
    upward point (every shared direction sees the sky: the estimate has no quadrature
    error there), and less on the floor beside the block (ambient occlusion)."""
    _sc, tx, tracer = scene
    light = Light(type="environment", color=np.array([1.0, 0.5, 0.25]), intensity=0.2,
                  direction=np.array([0.0, -1.0, 0.0]), environment="ambient")
    e = irradiance(light, tx.position, tx.normal, tracer)
    top = (tx.normal[:, 1] > 0.999) & (tx.position[:, 1] > tx.position[:, 1].max() - 1e-6)
    assert top.sum() >= 4
    expect = np.pi * 0.2 * np.array([1.0, 0.5, 0.25])
    np.testing.assert_allclose(e[top], np.broadcast_to(expect, e[top].shape), rtol=1e-9)
    floor = (tx.normal[:, 1] > 0.999) & (tx.position[:, 1] < 1e-3)
    near = floor & (np.linalg.norm(tx.position[:, [0, 2]], axis=1) < 0.8)
    assert near.sum() >= 4 and (e[near, 0] < 0.95 * np.pi * 0.2).any()
    assert (e[floor, 0] <= np.pi * 0.2 * (1 + 1e-9)).all()


@pytest.mark.slow  # automatic sizing of P and K (~15 s)
def test_directional_lights_plus_an_ambient_term_bake(tmp_path):
    """The issue's third family: random directional lights plus an ambient term, as two
    families of one spec with P and K left to automatic sizing (with fixed P = 32, K = 96
    the directional family alone fails its gate at 2.9×: sharp shadows need more); both
    kinds among the lights, and the verdict passes (measured 1.11× at P = 256, K = 128)."""
    import json

    from prtcore.pipeline import bake
    path = floor_object.write_floor_object(tmp_path / "fo.glb")
    spec = parse_spec({
        "atlas": {"resolution": 32, "padding": 2},
        "lights": {"holdout": 8, "seed": 2, "families": [
            {"type": "directional", "weight": 2.0,
             "position": {"box": [[-6.0, 1.6, -6.0], [6.0, 6.0, 6.0]]},
             "aim": {"target": [0.0, 0.0, 0.0], "jitter": 0.0},
             "intensity": {"uniform": [1.0, 3.0]}},
            {"type": "environment", "environment": "ambient",
             "intensity": {"uniform": [0.05, 0.3]}}]},
        "transport": {"gather_rays": 32, "max_bounces": 4},
        "fit": {"basis": 8}})
    train, held = sample_configurations(dataclasses.replace(spec.lights, count=128),
                                        np.zeros(3), 3.0)
    kinds = {lt.type for lt in train + held}
    assert kinds == {"directional", "environment"}
    out = bake(path, spec, tmp_path / "bundle", quiet=True)
    verdict = json.loads((out / "report.json").read_text())["verdict"]
    assert verdict["status"] == "pass", verdict["line"]
    with pytest.raises(SpecError, match="ambient"):
        parse_spec({"lights": {"families": [{"type": "environment", "environment": ""}]}})
