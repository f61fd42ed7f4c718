"""Skins (joints, inverse bind matrices) and node animations."""

from __future__ import annotations

import numpy as np

from prtcore.core.scene import (
    Animation,
    AnimationChannel,
    Skin,
)
from prtcore.io.gltf.accessors import (
    ANIM_OUT_CT,
    FLOAT_CT,
    accessor_layout,
    finite_floats,
    read_accessor,
)
from prtcore.io.gltf.schema import (
    Ctx,
    get_dict,
    get_index,
    get_int,
    get_items,
    get_list,
    get_str,
    index_list,
    show,
)


def parse_skins(ctx: Ctx, doc: dict, buffers: list) -> list[Skin]:
    """glTF skins: joint node indices, inverse bind matrices (identity when absent)."""
    out = []
    n_nodes = len(get_items(ctx, doc, "nodes"))
    for i, sj in enumerate(get_items(ctx, doc, "skins")):
        where = f"skins[{i}]"
        ctx.where = where
        get_list(ctx, sj, "joints", where)  # required
        joints = index_list(ctx, sj, "joints", where, n_nodes, "a node index")
        if not joints:
            raise ctx.fail(f"{where}.joints", "is empty")
        ibm = np.broadcast_to(np.eye(4), (len(joints), 4, 4)).copy()
        if "inverseBindMatrices" in sj:
            lay = accessor_layout(ctx, doc, get_index(ctx, sj, "inverseBindMatrices", where,
                                                      "accessors"),
                                  f"{where}.inverseBindMatrices", ("MAT4",), FLOAT_CT)
            if lay.count < len(joints):
                raise ctx.fail(lay.where, f"{lay.count} matrices for {len(joints)} joints")
            mats = finite_floats(ctx, read_accessor(ctx, lay, buffers), lay)
            ibm = mats[: len(joints)].reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
        out.append(Skin(
            name=get_str(ctx, sj, "name", where, default=""),
            joints=np.array(joints, dtype=np.int64), inverse_bind=ibm,
            skeleton=get_int(ctx, sj, "skeleton", where, default=-1, lo=-1, hi=n_nodes - 1),
        ))
    return out


_PATH_WIDTH = {"translation": 3, "rotation": 4, "scale": 3}


def parse_animations(ctx: Ctx, doc: dict, buffers: list) -> tuple[Animation, ...]:
    """glTF animations → channels with (k,) times and (k, c) values (3k rows for
    CUBICSPLINE); channels without a node target or with other paths are skipped."""
    out = []
    n_nodes = len(get_items(ctx, doc, "nodes"))
    for a, aj in enumerate(get_items(ctx, doc, "animations")):
        where = f"animations[{a}]"
        ctx.where = where
        samplers = get_list(ctx, aj, "samplers", where)
        channels = []
        for c, ch in enumerate(get_list(ctx, aj, "channels", where)):
            cw = f"{where}.channels[{c}]"
            ctx.where = cw
            if not isinstance(ch, dict):
                raise ctx.fail(cw, f"must be an object, got {show(ch)}")
            target = get_dict(ctx, ch, "target", cw)
            path = get_str(ctx, target, "path", f"{cw}.target")
            node = get_int(ctx, target, "node", f"{cw}.target", default=-1,
                           hi=n_nodes - 1)
            if node < 0 or path not in (*_PATH_WIDTH, "weights"):
                ctx.warn(cw, f"channel targeting {show(path)} without a node is skipped")
                continue
            s = get_int(ctx, ch, "sampler", cw, hi=len(samplers) - 1)
            sw = f"{where}.samplers[{s}]"
            sj = samplers[s]
            if not isinstance(sj, dict):
                raise ctx.fail(sw, f"must be an object, got {show(sj)}")
            interp = get_str(ctx, sj, "interpolation", sw, default="LINEAR")
            if interp not in ("LINEAR", "STEP", "CUBICSPLINE"):
                raise ctx.fail(f"{sw}.interpolation", f"unknown interpolation {show(interp)}")
            tin = accessor_layout(ctx, doc, get_index(ctx, sj, "input", sw, "accessors"),
                                  f"{sw}.input", ("SCALAR",), FLOAT_CT)
            width = _PATH_WIDTH.get(path, 1)
            types = ("SCALAR",) if path == "weights" else (("VEC3",) if width == 3 else
                                                           ("VEC4",))
            tout = accessor_layout(ctx, doc, get_index(ctx, sj, "output", sw, "accessors"),
                                   f"{sw}.output", types, ANIM_OUT_CT)
            rows = tin.count * (3 if interp == "CUBICSPLINE" else 1)
            if tout.count % rows:
                raise ctx.fail(tout.where, f"count {tout.count} does not match {tin.count} "
                                           f"keyframes ({interp})")
            times = finite_floats(ctx, read_accessor(ctx, tin, buffers), tin)[:, 0]
            if np.any(np.diff(times) < 0):
                raise ctx.fail(tin.where, "keyframe times decrease")
            values = finite_floats(ctx, read_accessor(ctx, tout, buffers), tout)
            values = values.reshape(rows, -1)
            channels.append(AnimationChannel(node=node, path=path, times=times,
                                             values=values, interpolation=interp))
        out.append(Animation(name=get_str(ctx, aj, "name", where, default=""),
                             channels=tuple(channels)))
    return tuple(out)
