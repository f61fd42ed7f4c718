"""prtcore.emitters.punctual against the KHR_lights_punctual closed forms, the light-file contract
(DESIGN 3.2) and the random light families of the bake spec."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from prtcore.core.errors import LightFileError
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.core.spec import parse_spec
from prtcore.emitters.families import sample_configurations
from prtcore.emitters.lightfile import load_light_file, save_light_file
from prtcore.emitters.point import range_window
from prtcore.emitters.punctual import irradiance, unshadowed_irradiance
from prtcore.emitters.spot import spot_factor

UP = np.array([0.0, 1.0, 0.0])


def _points(n: int, seed: int = 0, half: float = 1.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-half, half, n), np.zeros(n),
                            rng.uniform(-half, half, n)])


def _spot(position, direction, inner, outer, intensity=1.0, rng=None) -> Light:
    d = np.asarray(direction, float)
    return Light(type="spot", color=np.ones(3), intensity=intensity,
                 position=np.asarray(position, float), direction=d / np.linalg.norm(d),
                 inner_cone_angle=inner, outer_cone_angle=outer, range=rng)


# ---------------------------------------------------------------------------------------
# Evaluation: closed forms


def test_point_light_inverse_square_cosine():
    pts = _points(50)
    normals = np.broadcast_to(UP, pts.shape).copy()
    pos, inten, color = np.array([0.3, 1.7, -0.4]), 4.0, np.array([1.0, 0.5, 0.2])
    light = Light(type="point", color=color, intensity=inten, position=pos)
    d = pos - pts
    r = np.linalg.norm(d, axis=1)
    cos = d[:, 1] / r
    expected = (inten * cos / r**2)[:, None] * color
    e, w, dist = unshadowed_irradiance(light, pts, normals)
    np.testing.assert_allclose(e, expected, rtol=1e-12)
    np.testing.assert_allclose(w, d / r[:, None], rtol=1e-12)
    np.testing.assert_allclose(dist, r, rtol=1e-12)
    np.testing.assert_allclose(irradiance(light, pts, normals, None), expected, rtol=1e-12)
    # a surface facing away receives nothing
    assert np.all(irradiance(light, pts, -normals, None) == 0)
    # tilted normals: the cosine is taken with the normal, not with the vertical
    n2 = np.array([[1.0, 1.0, 0.0]]) / math.sqrt(2)
    p2 = np.array([[0.0, 0.0, 0.0]])
    light2 = Light(type="point", color=np.ones(3), intensity=2.0,
                   position=np.array([3.0, 3.0, 0.0]))
    np.testing.assert_allclose(irradiance(light2, p2, n2, None), 2.0 / 18.0, rtol=1e-12)


def test_spot_factor_khr_formula():
    inner, outer = 0.2, 0.5
    light = _spot([0, 2, 0], [0, -1, 0], inner, outer)
    ci, co = math.cos(inner), math.cos(outer)
    # on the axis and inside the inner cone: 1; outside the outer cone: 0
    np.testing.assert_array_equal(spot_factor(light, np.array([1.0, math.cos(0.1)])), 1.0)
    np.testing.assert_array_equal(spot_factor(light, np.array([math.cos(0.6), co - 1e-9,
                                                               -1.0])), 0.0)
    # between: KHR  t = (cos − cos_outer) / (cos_inner − cos_outer), factor t²
    angles = np.linspace(inner, outer, 7)
    t = (np.cos(angles) - co) / (ci - co)
    np.testing.assert_allclose(spot_factor(light, np.cos(angles)), t**2, rtol=1e-10,
                               atol=1e-14)
    # non-spot lights have no cone
    pl = Light(type="point", color=np.ones(3), intensity=1.0)
    np.testing.assert_array_equal(spot_factor(pl, np.array([-1.0, 0.0, 1.0])), 1.0)
    # inner == outer: the KHR scale floor 1/max(1e-3, Δcos) keeps it finite (a hard edge)
    hard = _spot([0, 2, 0], [0, -1, 0], 0.4, 0.4)
    assert spot_factor(hard, np.array([math.cos(0.3)]))[0] == 1.0
    assert spot_factor(hard, np.array([math.cos(0.5)]))[0] == 0.0


def test_spot_irradiance_end_to_end():
    """A spot above a floor: E = I cosθ/r² · spot(θ) at each point (θ the angle from the
    spot axis, here equal to the angle of incidence)."""
    inner, outer, inten = 0.3, 0.7, 5.0
    light = _spot([0.0, 1.0, 0.0], [0, -1, 0], inner, outer, inten)
    x = np.array([0.0, 0.2, math.tan(0.5), math.tan(0.69), math.tan(0.71), 3.0])
    pts = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    theta = np.arctan(x)
    r = 1 / np.cos(theta)
    spot = np.clip((np.cos(theta) - math.cos(outer)) / (math.cos(inner) - math.cos(outer)),
                   0, 1) ** 2
    expected = inten * np.cos(theta) / r**2 * spot
    e = irradiance(light, pts, np.broadcast_to(UP, pts.shape).copy(), None)
    np.testing.assert_allclose(e[:, 0], expected, rtol=1e-10, atol=1e-15)
    assert e[0, 0] == pytest.approx(inten) and e[-1, 0] == 0 and e[-2, 0] == 0
    assert 0 < e[3, 0] < e[2, 0] < e[1, 0]


def test_range_window():
    light = Light(type="point", color=np.ones(3), intensity=1.0, range=2.0)
    r = np.array([0.0, 0.5, 1.0, 1.9, 2.0, 3.0])
    np.testing.assert_allclose(range_window(light, r),
                               np.clip(1 - (r / 2.0) ** 4, 0, 1) ** 2, rtol=1e-12)
    assert range_window(light, np.array([2.0, 5.0])).max() == 0
    inf = Light(type="point", color=np.ones(3), intensity=1.0)
    np.testing.assert_array_equal(range_window(inf, r), 1.0)
    # end to end: beyond range, nothing; inside, the window multiplies I cosθ/r²
    lit = Light(type="point", color=np.ones(3), intensity=1.0,
                position=np.array([0.0, 1.0, 0.0]), range=1.5)
    pts = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1.2, 0.0, 0.0]])
    d = np.linalg.norm(lit.position - pts, axis=1)
    expected = (1.0 / d) / d**2 * np.clip(1 - (d / 1.5) ** 4, 0, 1) ** 2
    e = irradiance(lit, pts, np.broadcast_to(UP, pts.shape).copy(), None)
    np.testing.assert_allclose(e[:, 1], expected, rtol=1e-12)
    assert e[2].max() == 0  # d = √2.44 > 1.5


def test_directional_light():
    d = np.array([1.0, -2.0, 0.5])
    d /= np.linalg.norm(d)
    light = Light(type="directional", color=np.array([0.5, 1.0, 2.0]), intensity=3.0,
                  direction=d)
    pts = _points(20, 1, half=100.0)  # no distance falloff, anywhere
    normals = np.broadcast_to(UP, pts.shape).copy()
    e, w, dist = unshadowed_irradiance(light, pts, normals)
    np.testing.assert_allclose(e, np.broadcast_to(3.0 * (-d[1]) * light.color, e.shape),
                               rtol=1e-12)
    np.testing.assert_allclose(w, np.broadcast_to(-d, w.shape), rtol=1e-12)
    assert np.all(np.isinf(dist))
    assert np.all(irradiance(light, pts, -normals, None) == 0)


# ---------------------------------------------------------------------------------------
# Shadows


def _floor_and_blocker() -> RayTracer:
    floor = np.array([[-2, 0, -2], [2, 0, -2], [2, 0, 2], [-2, 0, 2]], float)
    block = np.array([[-0.25, 1, -0.25], [0.25, 1, -0.25], [0.25, 1, 0.25], [-0.25, 1, 0.25]],
                     float)
    faces = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]])
    return RayTracer(np.vstack([floor, block]), faces, scale=2.0 * math.sqrt(2))


def test_shadows_from_a_blocker():
    tracer = _floor_and_blocker()
    pts = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, -0.1], [0.8, 0.0, 0.8], [-1.5, 0.0, 0.2]])
    normals = np.broadcast_to(UP, pts.shape).copy()
    occluded = np.array([True, True, False, False])
    for light in (Light(type="point", color=np.ones(3), intensity=2.0,
                        position=np.array([0.0, 2.0, 0.0])),
                  _spot([0.0, 2.0, 0.0], [0, -1, 0], 0.5, 1.2, 2.0),
                  Light(type="directional", color=np.ones(3), intensity=1.0,
                        direction=np.array([0.0, -1.0, 0.0]))):
        free = irradiance(light, pts, normals, None)
        shadowed = irradiance(light, pts, normals, tracer)
        assert np.all(free.max(axis=1) > 0)
        assert np.all(shadowed[occluded] == 0), light.type
        np.testing.assert_array_equal(shadowed[~occluded], free[~occluded])
    # a light between the blocker and the floor is not shadowed by it
    below = Light(type="point", color=np.ones(3), intensity=1.0,
                  position=np.array([0.0, 0.5, 0.0]))
    np.testing.assert_array_equal(irradiance(below, pts, normals, tracer),
                                  irradiance(below, pts, normals, None))


# ---------------------------------------------------------------------------------------
# Light files


def test_light_file_round_trip(tmp_path):
    lights = (
        Light(type="point", color=np.array([1.0, 0.5, 0.25]), intensity=3.5,
              position=np.array([1.0, 2.0, 3.0]), range=4.0, name="bulb"),
        _spot([0.0, 2.0, 0.0], [0.1, -1.0, 0.2], 0.25, 0.6, 7.0),
        Light(type="directional", color=np.ones(3), intensity=0.5,
              direction=np.array([0.0, -1.0, 0.0])),
    )
    path = tmp_path / "lights.json"
    save_light_file(lights, path)
    back = load_light_file(path)
    assert len(back) == 3
    for a, b in zip(lights, back, strict=True):
        assert (a.type, a.intensity, a.range, a.name) == (b.type, b.intensity, b.range, b.name)
        np.testing.assert_allclose(b.color, a.color, rtol=1e-15)
        if a.type != "directional":
            np.testing.assert_allclose(b.position, a.position, rtol=1e-15)
        if a.type != "point":
            np.testing.assert_allclose(b.direction, a.direction, rtol=1e-15)
    assert (back[1].inner_cone_angle, back[1].outer_cone_angle) == (0.25, 0.6)
    # a single light object (not wrapped in {"lights": [...]}) is accepted, and a
    # non-unit direction is normalised
    one = tmp_path / "one.json"
    one.write_text(json.dumps({"type": "directional", "direction": [0, -3, 4]}))
    (lt,) = load_light_file(one)
    np.testing.assert_allclose(lt.direction, [0, -0.6, 0.8], rtol=1e-15)
    np.testing.assert_array_equal(lt.color, 1.0)


@pytest.mark.parametrize("light, where", [
    ({"type": "point", "position": [0, 1, 0], "colour": [1, 1, 1]}, "lights[1].colour"),
    ({"type": "area", "position": [0, 1, 0]}, "lights[1].type"),
    ({"type": "point"}, "lights[1].position"),
    ({"type": "spot", "position": [0, 1, 0]}, "lights[1].direction"),
    ({"type": "directional", "direction": [0, 0, 0]}, "lights[1].direction"),
    ({"type": "spot", "position": [0, 1, 0], "direction": [0, -1, 0],
      "spot": {"innerConeAngle": 0.5, "outerConeAngle": 0.5}}, "lights[1].spot"),
    ({"type": "spot", "position": [0, 1, 0], "direction": [0, -1, 0],
      "spot": {"innerConeAngle": 0.7, "outerConeAngle": 0.4}}, "lights[1].spot"),
    ({"type": "point", "position": [0, 1]}, "lights[1].position"),
    ({"type": "point", "position": [0, 1, 0], "intensity": -1}, "lights[1].intensity"),
    ({"type": "point", "position": [0, 1, 0], "range": 0}, "lights[1].range"),
])
def test_light_file_errors_name_the_key(tmp_path, light, where):
    path = tmp_path / "bad.json"
    good = {"type": "point", "position": [0, 1, 0]}
    path.write_text(json.dumps({"lights": [good, light]}))
    with pytest.raises(LightFileError) as info:
        load_light_file(path)
    msg = str(info.value)
    assert where in msg and str(path) in msg
    assert "\n" not in msg


def test_light_file_unreadable_or_not_json(tmp_path):
    with pytest.raises(LightFileError, match="cannot read"):
        load_light_file(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{\"type\": ")
    with pytest.raises(LightFileError, match="line 1"):
        load_light_file(bad)
    empty = tmp_path / "empty.json"
    empty.write_text(json.dumps({"lights": []}))
    with pytest.raises(LightFileError, match="at least one"):
        load_light_file(empty)


# ---------------------------------------------------------------------------------------
# Random families


def _lights_spec(families, count=200, holdout=20, seed=2):
    return parse_spec({"lights": {"count": count, "holdout": holdout, "seed": seed,
                                  "families": families}}).lights


SPOT = {"type": "spot", "position": {"shell": [1.5, 3.0]}, "aim": {"jitter": 0.3},
        "intensity": {"log_uniform": [1, 100]}, "color": "white",
        "outer_cone_angle": {"uniform": [0.3, 0.8]}}
POINT = {"type": "point", "position": {"box": [[-1, 0, -1], [1, 2, 1]]},
         "intensity": {"uniform": [1, 5]}, "color": "random"}
CENTER, RADIUS = np.array([0.5, 1.0, -0.25]), 2.0


def test_sample_configurations_deterministic_and_holdout_independent():
    spec = _lights_spec([SPOT, POINT])
    a_train, a_hold = sample_configurations(spec, CENTER, RADIUS)
    b_train, b_hold = sample_configurations(spec, CENTER, RADIUS)
    assert (len(a_train), len(a_hold)) == (200, 20)

    def same(x, y):
        return all(p.type == q.type and p.intensity == q.intensity and
                   np.array_equal(p.position, q.position) and
                   np.array_equal(p.direction, q.direction) and
                   np.array_equal(p.color, q.color) for p, q in zip(x, y, strict=True))

    assert same(a_train, b_train) and same(a_hold, b_hold)
    c_train, c_hold = sample_configurations(_lights_spec([SPOT, POINT], holdout=50),
                                            CENTER, RADIUS)
    assert same(a_train, c_train) and len(c_hold) == 50
    assert same(a_hold, c_hold[:20])  # the held-out stream does not depend on the count
    d_train, _ = sample_configurations(_lights_spec([SPOT, POINT], seed=3), CENTER, RADIUS)
    assert not same(a_train, d_train)
    assert not same(a_train[:20], a_hold)


def test_family_weights():
    fams = [dict(SPOT, weight=3.0), dict(POINT, weight=1.0)]
    train, _ = sample_configurations(_lights_spec(fams, count=800), CENTER, RADIUS)
    frac = np.mean([lt.type == "spot" for lt in train])
    assert abs(frac - 0.75) < 0.06  # binomial sd ≈ 0.015


def test_shell_spots_aim_and_intensity():
    train, hold = sample_configurations(_lights_spec([SPOT]), CENTER, RADIUS)
    lights = train + hold
    pos = np.array([lt.position for lt in lights])
    r = np.linalg.norm(pos - CENTER, axis=1) / RADIUS
    assert r.min() >= 1.5 and r.max() <= 3.0
    assert r.max() - r.min() > 1.0  # it does spread over the shell
    # the aim line passes within jitter·radius of the centre, pointing toward it
    dirs = np.array([lt.direction for lt in lights])
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, rtol=1e-12)
    to_c = CENTER - pos
    miss = np.linalg.norm(to_c - np.einsum("ij,ij->i", to_c, dirs)[:, None] * dirs, axis=1)
    assert miss.max() <= 0.3 * RADIUS * (1 + 1e-9)
    assert miss.max() > 0.05 * RADIUS  # jitter is applied
    assert np.all(np.einsum("ij,ij->i", to_c, dirs) > 0)
    inten = np.array([lt.intensity for lt in lights])
    assert inten.min() >= 1 and inten.max() <= 100
    # log-uniform: log I is uniform on [0, ln 100], mean ln(100)/2 (sd of the mean ≈ 0.09)
    assert abs(np.log(inten).mean() - math.log(100) / 2) < 0.4
    outer = np.array([lt.outer_cone_angle for lt in lights])
    assert outer.min() >= 0.3 and outer.max() <= 0.8
    assert all(lt.type == "spot" and lt.inner_cone_angle < lt.outer_cone_angle
               for lt in lights)
    assert all(np.array_equal(lt.color, np.ones(3)) for lt in lights)


def test_box_points_and_random_colour():
    train, hold = sample_configurations(_lights_spec([POINT]), CENTER, RADIUS)
    pos = np.array([lt.position for lt in train + hold])
    assert np.all(pos >= [-1, 0, -1]) and np.all(pos <= [1, 2, 1])
    assert np.all(pos.max(axis=0) - pos.min(axis=0) > 1.5)  # spread over the box
    inten = np.array([lt.intensity for lt in train + hold])
    assert inten.min() >= 1 and inten.max() <= 5
    col = np.array([lt.color for lt in train + hold])
    np.testing.assert_allclose(col.max(axis=1), 1.0)
    assert col.min() >= 0 and col.std() > 0.1


def test_directional_lights_have_no_range(tmp_path):
    import json

    from prtcore.core.errors import LightFileError
    from prtcore.emitters.lightfile import load_light_file

    p = tmp_path / "sun.json"
    p.write_text(json.dumps({"type": "directional", "direction": [0, -1, 0], "range": 5}))
    with pytest.raises(LightFileError, match=r"light\.range"):
        load_light_file(p)
