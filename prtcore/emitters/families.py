"""Random light families (the bake spec's ``lights`` section): K training and H held-out
configurations drawn from seeded streams."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from prtcore.core.errors import LightFileError
from prtcore.core.scene import Light
from prtcore.core.spec import LightFamily, LightsSpec
from prtcore.emitters.base import emitter_for


def _unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _ball(rng: np.random.Generator) -> np.ndarray:
    return _unit_vectors(rng, 1)[0] * rng.random() ** (1.0 / 3.0)


def _scalar(dist: dict, rng: np.random.Generator) -> float:
    (kind, arg), = dist.items()
    if kind == "constant":
        return float(arg)
    if kind == "log_uniform":
        return float(math.exp(rng.uniform(math.log(arg[0]), math.log(arg[1]))))
    return float(rng.uniform(arg[0], arg[1]))


def _color(spec: Any, rng: np.random.Generator) -> np.ndarray:
    if spec == "white":
        return np.ones(3)
    if spec == "random":
        c = rng.random(3)
        return c / c.max()
    return np.asarray(spec, dtype=np.float64)


def sample_light(family: LightFamily, center: np.ndarray, radius: float,
                 asset_lights: tuple[Light, ...], rng: np.random.Generator) -> Light:
    """Draw one light of a family around an asset (centre (3,), bounding radius).

    Position: ``shell`` [a, b] → centre + radius·r·ω with r ~ U(a, b), ω uniform on the
    sphere; ``box`` → uniform in world box; ``fixed``. Aim (spot, directional): toward
    ``centre + jitter·radius·b`` with b uniform in the unit ball (or a given target /
    direction). ``from_asset``: position and direction jittered around a randomly chosen
    asset light of the same type; the intensity distribution multiplies its intensity.
    """
    base = None
    if family.from_asset:
        same = [lt for lt in asset_lights if lt.type == family.type]
        if not same:
            raise LightFileError(f"lights family {family.type}: from_asset is set but the "
                                 f"asset has no {family.type} light")
        base = same[int(rng.integers(len(same)))]
    pos_spec = family.position
    if base is not None:
        pos = base.position + family.aim.get("jitter", 0.0) * radius * _ball(rng)
    elif "shell" in pos_spec:
        a, b = pos_spec["shell"]
        pos = center + radius * rng.uniform(a, b) * _unit_vectors(rng, 1)[0]
    elif "box" in pos_spec:
        lo, hi = np.asarray(pos_spec["box"][0]), np.asarray(pos_spec["box"][1])
        pos = lo + (hi - lo) * rng.random(3)
    else:
        pos = np.asarray(pos_spec["fixed"], dtype=np.float64)
    jitter = family.aim.get("jitter", 0.0)
    if base is not None and emitter_for(family.type).directed:
        aim_point = pos + base.direction * radius + jitter * radius * _ball(rng)
        direction = aim_point - pos
    elif "direction" in family.aim:
        direction = np.asarray(family.aim["direction"], dtype=np.float64)
    else:
        target = np.asarray(family.aim.get("target", center), dtype=np.float64)
        direction = target + jitter * radius * _ball(rng) - pos
    norm = np.linalg.norm(direction)
    direction = direction / norm if norm > 0 else np.array([0.0, -1.0, 0.0])
    intensity = _scalar(family.intensity, rng)
    if base is not None:
        intensity *= base.intensity
    color = _color(family.color, rng)
    kw: dict[str, Any] = {"type": family.type, "color": color, "intensity": intensity,
                          "position": pos, "direction": direction, "range": family.range}
    if family.environment is not None:
        kw["environment"] = family.environment
    if emitter_for(family.type).coned:
        outer = _scalar(family.outer_cone_angle, rng)
        inner = _scalar(family.inner_cone_angle, rng) if family.inner_cone_angle else 0.0
        kw["outer_cone_angle"] = outer
        kw["inner_cone_angle"] = min(inner, outer * 0.999)
    return Light(**kw)


def sample_configurations(spec: LightsSpec, center: np.ndarray, radius: float,
                          asset_lights: tuple[Light, ...] = ()
                          ) -> tuple[tuple[Light, ...], tuple[Light, ...]]:
    """Draw the K training and H held-out configurations (one light each) from the spec.

    Families are chosen by weight. Training and held-out lights come from independent
    streams of ``spec.seed``, so changing ``holdout`` never changes the training set.
    """
    if not isinstance(spec.count, int):
        raise ValueError(f"sample_configurations: lights.count {spec.count!r} must be "
                         "resolved to a number first (intake/plan.py decide_sizing)")
    train_ss, hold_ss = np.random.SeedSequence(spec.seed).spawn(2)
    weights = np.array([f.weight for f in spec.families], dtype=np.float64)
    weights /= weights.sum()

    def draw(ss: np.random.SeedSequence, count: int) -> tuple[Light, ...]:
        rng = np.random.default_rng(ss)
        out = []
        for _ in range(count):
            fam = spec.families[int(rng.choice(len(weights), p=weights))]
            out.append(sample_light(fam, np.asarray(center, np.float64), float(radius),
                                    asset_lights, rng))
        return tuple(out)

    return draw(train_ss, spec.count), draw(hold_ss, spec.holdout)
