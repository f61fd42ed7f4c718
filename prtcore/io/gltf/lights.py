"""``KHR_lights_punctual`` lights placed in world space by their nodes."""

from __future__ import annotations

import numpy as np

from prtcore.core.scene import (
    Light,
    Node,
)
from prtcore.core.tolerances import NORMAL_EPS
from prtcore.io.gltf.schema import (
    Ctx,
    get_dict,
    get_extension,
    get_list,
    get_num,
    get_nums,
    get_str,
    show,
)


def light_definitions(ctx: Ctx, doc: dict) -> list:
    ext = get_extension(ctx, doc, "KHR_lights_punctual", "")
    if ext is None:
        return []
    return get_list(ctx, ext, "lights", "extensions.KHR_lights_punctual", default=[])


def parse_lights(ctx: Ctx, doc: dict, nodes: list[Node], node_light: list[int],
                 order: list[int]) -> tuple[Light, ...]:
    """KHR_lights_punctual lights placed by the scene's nodes, in world space.

    position = world_from_node · (0, 0, 0, 1); direction = the node's −Z axis transformed
    and normalised. Spot cone angles default to 0 and π/4; ``range`` stays None when absent.
    """
    defs = light_definitions(ctx, doc)
    out = []
    for i in order:
        k = node_light[i]
        if k < 0:
            continue
        where = f"extensions.KHR_lights_punctual.lights[{k}]"
        ctx.where = where
        lj = defs[k]
        if not isinstance(lj, dict):
            raise ctx.fail(where, f"must be an object, got {show(lj)}")
        kind = get_str(ctx, lj, "type", where)
        if kind not in ("point", "spot", "directional"):
            raise ctx.fail(f"{where}.type", f"unknown light type {show(kind)}")
        color = get_nums(ctx, lj, "color", where, 3, [1.0, 1.0, 1.0])
        intensity = get_num(ctx, lj, "intensity", where, default=1.0)
        rng = get_num(ctx, lj, "range", where, default=None)
        if rng is not None and rng <= 0:
            raise ctx.fail(f"{where}.range", f"must be > 0, got {rng}")
        inner, outer = 0.0, np.pi / 4
        if kind == "spot":
            spot = get_dict(ctx, lj, "spot", where, default={})
            inner = get_num(ctx, spot, "innerConeAngle", f"{where}.spot", default=0.0)
            outer = get_num(ctx, spot, "outerConeAngle", f"{where}.spot", default=np.pi / 4)
            if not 0.0 <= inner < outer <= np.pi / 2:
                raise ctx.fail(f"{where}.spot", "cone angles must satisfy 0 <= inner < outer "
                                                "<= pi/2")
        m = nodes[i].world_from_node
        direction = m[:3, :3] @ np.array([0.0, 0.0, -1.0])
        norm = float(np.linalg.norm(direction))
        if norm <= NORMAL_EPS and kind != "point":
            raise ctx.fail(f"nodes[{i}]", "light node transform collapses its direction")
        out.append(Light(
            type=kind, color=color, intensity=intensity, position=m[:3, 3].copy(),
            direction=direction / norm if norm > NORMAL_EPS else np.array([0.0, 0.0, -1.0]),
            inner_cone_angle=inner, outer_cone_angle=outer, range=rng,
            name=get_str(ctx, lj, "name", where, default=""),
        ))
    return tuple(out)
