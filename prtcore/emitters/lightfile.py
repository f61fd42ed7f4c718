"""Light files (``--light FILE``, docs/lights.md): one light or ``{"lights": [...]}``.

Each light is validated against what its emitter uses (position, direction, cone, range)
and every refusal names the file and the place (``lights[2].direction``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from prtcore.core.errors import LightFileError
from prtcore.core.jsonfile import read_json
from prtcore.core.scene import Light
from prtcore.emitters.base import emitter_for, types


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
    allowed = {"type", "color", "intensity", "position", "direction", "spot", "range", "name",
               "environment"}
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise LightFileError(f"{file}: {where}.{unknown[0]}: unknown key")
    t = d.get("type")
    if t not in types():
        raise LightFileError(f"{file}: {where}.type: must be {' or '.join(types())}, "
                             f"got {t!r}")
    em = emitter_for(t)
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
    if "environment" in d:
        if t != "environment" or not isinstance(d["environment"], str) or \
                not d["environment"]:
            raise LightFileError(f"{file}: {where}.environment: only an environment light "
                                 f"has one: \"sky\" or a map file")
        kw["environment"] = d["environment"]
    if em.positioned:
        if "position" not in d:
            raise LightFileError(f"{file}: {where}.position: required for a {t} light")
        kw["position"] = _vec(d["position"], f"{where}.position", file)
    if em.directed:
        if "direction" not in d:
            raise LightFileError(f"{file}: {where}.direction: required for a {t} light")
        dv = _vec(d["direction"], f"{where}.direction", file)
        n = np.linalg.norm(dv)
        if n == 0:
            raise LightFileError(f"{file}: {where}.direction: must not be zero")
        kw["direction"] = dv / n
    if em.coned:
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
        if not em.ranged:
            raise LightFileError(f"{file}: {where}.range: {t} lights have no range "
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
    em = emitter_for(light)
    if em.positioned:
        d["position"] = [float(c) for c in light.position]
    if em.directed:
        d["direction"] = [float(c) for c in light.direction]
    if em.coned:
        d["spot"] = {"innerConeAngle": float(light.inner_cone_angle),
                     "outerConeAngle": float(light.outer_cone_angle)}
    if light.range is not None:
        d["range"] = float(light.range)
    if light.name:
        d["name"] = light.name
    if light.environment:
        d["environment"] = light.environment
    return d


def load_light_file(path: str | Path) -> tuple[Light, ...]:
    """Read a light file: one light object or ``{"lights": [...]}``."""
    file = str(path)
    data = read_json(path, lambda what: LightFileError(f"{file}: {what}"))
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
