"""Lights: evaluation (the one formula used everywhere), light files, random families.

Conventions (DESIGN 3.1): KHR_lights_punctual; ``color`` linear RGB; ``intensity`` in cd
(point/spot) or lux (directional), used directly as radiometric units. Irradiance at a
surface point with unit normal n:

* point/spot: ``E = color · I · max(0, n·ω) / r² · spot(ω) · window(r)``, ω unit vector
  from the point to the light, r the distance;
* directional: ``E = color · I · max(0, n·(−d))``, d the direction light travels.

``spot`` and ``window`` are the KHR_lights_punctual reference formulas: the angular
attenuation ``saturate(cosθ·scale + offset)²`` with ``scale = 1/max(1e-3, cos(inner) −
cos(outer))``, ``offset = −cos(outer)·scale``, and the range window
``saturate(1 − (r/range)⁴)²`` (1 when range is None).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from prtcore.core.errors import LightFileError
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.core.spec import LightFamily, LightsSpec

# ---------------------------------------------------------------------------------------
# Evaluation


def spot_factor(light: Light, cos_angle: np.ndarray) -> np.ndarray:
    """KHR angular attenuation for a spot light. cos_angle : (n,) cosine between the
    spot axis and the direction from the light to the point. Returns (n,) float64."""
    if light.type != "spot":
        return np.ones_like(cos_angle)
    ci, co = math.cos(light.inner_cone_angle), math.cos(light.outer_cone_angle)
    scale = 1.0 / max(1e-3, ci - co)
    offset = -co * scale
    a = np.clip(cos_angle * scale + offset, 0.0, 1.0)
    return a * a


def range_window(light: Light, dist: np.ndarray) -> np.ndarray:
    """KHR range window ``saturate(1 − (r/range)⁴)²``; ones when range is None."""
    if light.range is None:
        return np.ones_like(dist)
    x = np.clip(1.0 - (dist / light.range) ** 4, 0.0, 1.0)
    return x * x


def unshadowed_irradiance(light: Light, points: np.ndarray, normals: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Irradiance without visibility.

    points, normals : (n, 3) float64. Returns ``E`` (n, 3) float64 RGB irradiance,
    ``to_light`` (n, 3) unit directions toward the light, and ``dist`` (n,) distances
    (inf for directional lights).
    """
    points = np.asarray(points, dtype=np.float64)
    color = np.asarray(light.color, dtype=np.float64) * float(light.intensity)
    if light.type == "directional":
        d = np.asarray(light.direction, dtype=np.float64)
        w = np.broadcast_to(-d / np.linalg.norm(d), points.shape).copy()
        cos = np.einsum("ij,ij->i", normals, w)
        e = np.clip(cos, 0.0, None)[:, None] * color
        return e, w, np.full(len(points), np.inf)
    delta = np.asarray(light.position, dtype=np.float64) - points
    r2 = np.einsum("ij,ij->i", delta, delta)
    dist = np.sqrt(r2)
    w = np.divide(delta, dist[:, None], out=np.zeros_like(delta), where=dist[:, None] > 0)
    cos = np.clip(np.einsum("ij,ij->i", normals, w), 0.0, None)
    att = cos * range_window(light, dist)
    if light.type == "spot":
        axis = np.asarray(light.direction, dtype=np.float64)
        axis = axis / np.linalg.norm(axis)
        att = att * spot_factor(light, -(w @ axis))
    att = np.divide(att, r2, out=np.zeros_like(att), where=r2 > 0)
    return att[:, None] * color, w, dist


def irradiance(light: Light, points: np.ndarray, normals: np.ndarray,
               tracer: RayTracer | None) -> np.ndarray:
    """Direct irradiance with shadows (occlusion rays) when ``tracer`` is given.

    points, normals : (n, 3) float64. Returns (n, 3) float64. Only points that receive
    light at all are traced.
    """
    e, w, _ = unshadowed_irradiance(light, points, normals)
    if tracer is None:
        return e
    lit = np.flatnonzero(e[:, 0] + e[:, 1] + e[:, 2] > 0)  # e ≥ 0: any channel lit
    if len(lit):
        if light.type == "directional":
            vis = tracer.unoccluded_towards(points[lit], normals[lit], w[lit])
        else:
            target = np.broadcast_to(np.asarray(light.position, dtype=np.float64),
                                     (len(lit), 3))
            vis = tracer.visible(points[lit], normals[lit], target)
        e[lit[~vis]] = 0.0
    return e


# ---------------------------------------------------------------------------------------
# Light files (DESIGN 3.2)


def _vec(v: Any, where: str, file: str) -> np.ndarray:
    if not isinstance(v, list | tuple) or len(v) != 3 or not all(
            isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
            for x in v):
        raise LightFileError(f"{file}: {where}: expected [x, y, z] of finite numbers, got {v!r}")
    return np.asarray(v, dtype=np.float64)


def light_from_dict(d: Any, where: str = "light", file: str = "<light>") -> Light:
    """Validate one light object of the light-file contract and build a :class:`Light`."""
    if not isinstance(d, dict):
        raise LightFileError(f"{file}: {where}: expected an object")
    allowed = {"type", "color", "intensity", "position", "direction", "spot", "range", "name"}
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise LightFileError(f"{file}: {where}.{unknown[0]}: unknown key")
    t = d.get("type")
    if t not in ("point", "spot", "directional"):
        raise LightFileError(f"{file}: {where}.type: must be point, spot or directional, "
                             f"got {t!r}")
    color = _vec(d.get("color", [1.0, 1.0, 1.0]), f"{where}.color", file)
    if (color < 0).any():
        raise LightFileError(f"{file}: {where}.color: components must be ≥ 0")
    inten = d.get("intensity", 1.0)
    if not isinstance(inten, int | float) or isinstance(inten, bool) or \
            not math.isfinite(inten) or inten < 0:
        raise LightFileError(f"{file}: {where}.intensity: expected a finite number ≥ 0, "
                             f"got {inten!r}")
    kw: dict[str, Any] = {"type": t, "color": color, "intensity": float(inten),
                          "name": str(d.get("name", ""))}
    if t in ("point", "spot"):
        if "position" not in d:
            raise LightFileError(f"{file}: {where}.position: required for a {t} light")
        kw["position"] = _vec(d["position"], f"{where}.position", file)
    if t in ("spot", "directional"):
        if "direction" not in d:
            raise LightFileError(f"{file}: {where}.direction: required for a {t} light")
        dv = _vec(d["direction"], f"{where}.direction", file)
        n = np.linalg.norm(dv)
        if n == 0:
            raise LightFileError(f"{file}: {where}.direction: must not be zero")
        kw["direction"] = dv / n
    if t == "spot":
        sp = d.get("spot", {})
        if not isinstance(sp, dict) or set(sp) - {"innerConeAngle", "outerConeAngle"}:
            raise LightFileError(f"{file}: {where}.spot: expected {{innerConeAngle, "
                                 f"outerConeAngle}}")
        inner = float(sp.get("innerConeAngle", 0.0))
        outer = float(sp.get("outerConeAngle", math.pi / 4))
        if not (0 <= inner < outer <= math.pi / 2):
            raise LightFileError(f"{file}: {where}.spot: need 0 ≤ innerConeAngle < "
                                 f"outerConeAngle ≤ π/2, got {inner}, {outer}")
        kw["inner_cone_angle"], kw["outer_cone_angle"] = inner, outer
    if d.get("range") is not None:
        if t == "directional":
            raise LightFileError(f"{file}: {where}.range: directional lights have no range "
                                 f"(KHR_lights_punctual)")
        r = d["range"]
        if not isinstance(r, int | float) or isinstance(r, bool) or not r > 0:
            raise LightFileError(f"{file}: {where}.range: expected a number > 0, got {r!r}")
        kw["range"] = float(r)
    return Light(**kw)


def light_to_dict(light: Light) -> dict:
    """The light-file form of a light (inverse of :func:`light_from_dict`)."""
    d: dict[str, Any] = {"type": light.type, "color": [float(c) for c in light.color],
                         "intensity": float(light.intensity)}
    if light.type != "directional":
        d["position"] = [float(c) for c in light.position]
    if light.type != "point":
        d["direction"] = [float(c) for c in light.direction]
    if light.type == "spot":
        d["spot"] = {"innerConeAngle": float(light.inner_cone_angle),
                     "outerConeAngle": float(light.outer_cone_angle)}
    if light.range is not None:
        d["range"] = float(light.range)
    if light.name:
        d["name"] = light.name
    return d


def load_light_file(path: str | Path) -> tuple[Light, ...]:
    """Read a light file: one light object or ``{"lights": [...]}``."""
    path = Path(path)
    file = str(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise LightFileError(f"{file}: cannot read: {e.strerror}") from None
    except json.JSONDecodeError as e:
        raise LightFileError(f"{file}: not valid JSON at line {e.lineno} column {e.colno}: "
                             f"{e.msg}") from None
    if isinstance(data, dict) and "lights" in data:
        if set(data) != {"lights"} or not isinstance(data["lights"], list) or \
                not data["lights"]:
            raise LightFileError(f"{file}: expected {{\"lights\": [ ... ]}} with at least "
                                 f"one light")
        return tuple(light_from_dict(x, f"lights[{i}]", file)
                     for i, x in enumerate(data["lights"]))
    return (light_from_dict(data, "light", file),)


def save_light_file(lights: tuple[Light, ...] | list[Light], path: str | Path) -> None:
    data = {"lights": [light_to_dict(lt) for lt in lights]}
    Path(path).write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")


# ---------------------------------------------------------------------------------------
# Random families (bake spec "lights")


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
    if base is not None and family.type != "point":
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
    if family.type == "spot":
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
