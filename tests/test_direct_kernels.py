"""The compiled direct light (prtcore/emitters/compiled.py) against the emitters' numpy
evaluation (prtcore.emitters.punctual.irradiance): bit-equal for point and directional
lights, to a few ulp for spots and ranged lights (see the module's docstring)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.emitters.punctual import irradiance
from prtcore.transport.direct import direct_radiance


def _tracer() -> RayTracer:
    """A floor (y = 0, 4 × 4) with a small occluding square at y = 0.5 over its middle."""
    pos = np.array([[-2, 0, -2], [2, 0, -2], [2, 0, 2], [-2, 0, 2],
                    [-0.4, 0.5, -0.4], [0.4, 0.5, -0.4], [0.4, 0.5, 0.4], [-0.4, 0.5, 0.4]],
                   dtype=np.float64)
    faces = np.array([[0, 2, 1], [0, 3, 2], [4, 6, 5], [4, 7, 6]])
    return RayTracer(pos, faces, scale=3.0, threads=2)


def _points(rng, n: int, per: int):
    """Rows of ``per`` points on the floor (some behind the light's reach: normals tilted
    away), unit normals, albedo."""
    p = np.zeros((n, per, 3))
    p[..., 0] = rng.uniform(-1.9, 1.9, (n, per))
    p[..., 2] = rng.uniform(-1.9, 1.9, (n, per))
    nrm = np.tile([0.0, 1.0, 0.0], (n, 1)) + rng.normal(0, 0.3, (n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    albedo = rng.uniform(0.0, 1.2, (n, 3))  # some above 1: clamped
    return (p[:, 0] if per == 1 else p), nrm, albedo


def _numpy_direct(tracer, lights, positions, normals, albedo):
    """The direct light as numpy computes it: irradiance per light, the mean over each
    row's points in order, times clamp(ρ)/π."""
    from prtcore.core.materials import clamp_albedo

    per = 1 if positions.ndim == 2 else positions.shape[1]
    rho, _ = clamp_albedo(albedo)
    out = np.empty((len(normals), len(lights), 3), dtype=np.float32)
    for k, light in enumerate(lights):
        e = irradiance(light, positions.reshape(-1, 3), np.repeat(normals, per, axis=0),
                       tracer).reshape(len(normals), per, 3)
        acc = e[:, 0].copy()
        for j in range(1, per):
            acc += e[:, j]
        out[:, k] = (acc / per if per > 1 else acc) * (rho / math.pi)
    return out


def _lights(kind: str, rng, count: int = 4):
    out = []
    for _ in range(count):
        col = rng.uniform(0.2, 1.0, 3)
        if kind == "directional":
            d = rng.normal(size=3)
            d[1] = -abs(d[1]) - 0.3
            out.append(Light(type="directional", color=col, intensity=2.0, direction=d))
        else:
            p = np.array([rng.uniform(-1, 1), rng.uniform(0.8, 2.0), rng.uniform(-1, 1)])
            extra = {}
            if kind == "spot":
                extra = {"direction": np.array([0.1, -1.0, 0.2]), "inner_cone_angle": 0.3,
                         "outer_cone_angle": 0.7}
            if kind == "ranged":
                extra = {"range": 2.5}
            out.append(Light(type="spot" if kind == "spot" else "point", color=col,
                             intensity=3.0, position=p, **extra))
    return out


@pytest.mark.parametrize("per", [1, 4])
@pytest.mark.parametrize("kind", ["point", "directional"])
def test_compiled_direct_is_bit_equal(kind, per):
    rng = np.random.default_rng(7)
    tracer = _tracer()
    lights = _lights(kind, rng)
    pos, nrm, alb = _points(rng, 5000, per)
    got = direct_radiance(None, tracer, lights, pos, nrm, alb)
    want = _numpy_direct(tracer, lights, pos, nrm, alb)
    assert (want == 0).any() and (want > 0).any()  # shadows and light both present
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("kind", ["spot", "ranged"])
def test_compiled_spot_and_range_agree_to_ulps(kind):
    rng = np.random.default_rng(8)
    tracer = _tracer()
    lights = _lights(kind, rng)
    pos, nrm, alb = _points(rng, 5000, 4)
    got = direct_radiance(None, tracer, lights, pos, nrm, alb)
    want = _numpy_direct(tracer, lights, pos, nrm, alb)
    assert (want == 0).any() and (want > 0).any()
    assert np.array_equal(got == 0, want == 0)  # the same shadow rays
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=0)


def test_rays_counted_as_traced():
    rng = np.random.default_rng(9)
    tracer = _tracer()
    lights = _lights("point", rng, 2)
    pos, nrm, alb = _points(rng, 1000, 1)
    direct_radiance(None, tracer, lights, pos, nrm, alb)
    lit = sum(int((irradiance(li, pos, nrm, None).sum(axis=1) > 0).sum()) for li in lights)
    assert tracer.rays_traced == lit
