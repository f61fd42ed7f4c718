"""Mesh primitives: planned from the JSON alone (accessors, counts against the limits),
decoded, triangulated and flattened to world space."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prtcore.core.scene import (
    Node,
    PrimitiveInstance,
    Skin,
)
from prtcore.core.tolerances import NORMAL_EPS
from prtcore.io.gltf.accessors import (
    INDEX_CT,
    JOINTS_CT,
    NORMAL_CT,
    POSITION_CT,
    TEXCOORD_CT,
    WEIGHTS_CT,
    AccessorLayout,
    accessor_layout,
    finite_floats,
    read_accessor,
    to_float,
)
from prtcore.io.gltf.compression import DRACO, DracoPlan, decode_draco, plan_draco
from prtcore.io.gltf.nodes import apply_linear, normal_matrix, normalize_rows
from prtcore.io.gltf.schema import (
    Ctx,
    get_dict,
    get_extension,
    get_index,
    get_int,
    get_items,
    get_list,
    show,
)

MODE_NAMES = {
    0: "POINTS",
    1: "LINES",
    2: "LINE_LOOP",
    3: "LINE_STRIP",
    4: "TRIANGLES",
    5: "TRIANGLE_STRIP",
    6: "TRIANGLE_FAN",
}


@dataclass(frozen=True)
class PrimitivePlan:
    """One mesh primitive, validated from the JSON alone (no buffer read yet)."""

    mesh: int
    primitive: int
    where: str
    mode: int
    material: int
    position: AccessorLayout | None  # None: no POSITION, the primitive is skipped
    indices: AccessorLayout | None
    attributes: dict  # semantic → AccessorLayout for NORMAL, TEXCOORD_0/1, JOINTS_0, WEIGHTS_0
    vertex_count: int  # vertices the loader makes: 3 per triangle when NORMAL is absent
    triangle_count: int  # upper bound (degenerate strip/fan triangles are dropped later)
    draco: DracoPlan | None = None


def triangle_count(mode: int, n: int) -> int:
    """Triangles produced by ``n`` vertices/indices in a glTF primitive ``mode``."""
    if mode == 4:
        return n // 3
    if mode in (5, 6):
        return max(n - 2, 0)
    return 0


_ATTRIBUTES = {
    "NORMAL": (("VEC3",), NORMAL_CT),
    "TEXCOORD_0": (("VEC2",), TEXCOORD_CT),
    "TEXCOORD_1": (("VEC2",), TEXCOORD_CT),
    "JOINTS_0": (("VEC4",), JOINTS_CT),
    "WEIGHTS_0": (("VEC4",), WEIGHTS_CT),
}


def plan_primitive(ctx: Ctx, doc: dict, m: int, p: int, prim: dict) -> PrimitivePlan:
    """Validate one primitive's mode, accessors and material from the JSON."""
    where = f"meshes[{m}].primitives[{p}]"
    ctx.where = where
    mode = get_int(ctx, prim, "mode", where, default=4)
    if mode not in MODE_NAMES:
        raise ctx.fail(f"{where}.mode", f"unknown primitive mode {mode}")
    attrs = get_dict(ctx, prim, "attributes", where)
    aw = f"{where}.attributes"
    material = get_index(ctx, prim, "material", where, "materials", default=-1)
    if "POSITION" not in attrs:  # valid: "client implementations SHOULD skip" it
        ctx.warn(where, "primitive without POSITION skipped")
        return PrimitivePlan(m, p, where, mode, material, None, None, {}, 0, 0)
    ext = get_extension(ctx, prim, DRACO, where)
    draco = None if ext is None else plan_draco(ctx, doc, ext, where)
    pos = accessor_layout(ctx, doc, get_index(ctx, attrs, "POSITION", aw, "accessors"),
                          f"{aw}.POSITION", ("VEC3",), POSITION_CT)
    layouts = {}
    for sem, (types, comps) in _ATTRIBUTES.items():
        if sem in attrs:
            lay = accessor_layout(ctx, doc, get_index(ctx, attrs, sem, aw, "accessors"),
                                  f"{aw}.{sem}", types, comps)
            if lay.count != pos.count:
                raise ctx.fail(lay.where, f"count {lay.count} differs from POSITION count "
                                          f"{pos.count}")
            layouts[sem] = lay
    indices = None
    if "indices" in prim:
        indices = accessor_layout(ctx, doc, get_index(ctx, prim, "indices", where, "accessors"),
                                  f"{where}.indices", ("SCALAR",), INDEX_CT)
        if indices.normalized:
            raise ctx.fail(indices.where, "indices must not be normalized")
    if draco is not None and mode not in (4, 5):
        raise ctx.fail(f"{where}.mode", f"{MODE_NAMES[mode]} with {DRACO} (only TRIANGLES "
                                        "and TRIANGLE_STRIP may be Draco-compressed)")
    n = indices.count if indices is not None else pos.count
    if draco is not None:  # Draco decodes to a triangle list (a strip's own indices unused)
        mode, n = 4, 3 * triangle_count(mode, n)
    if mode < 4:
        ctx.warn(where, f"{MODE_NAMES[mode]} primitive skipped (only triangles are baked)")
    elif mode == 4 and n % 3:
        ctx.warn(where, f"{n} indices is not a multiple of 3; the last {n % 3} ignored")
    if "targets" in prim:
        ctx.warn(where, "morph targets ignored (rest shape used)")
    tris = triangle_count(mode, n)
    verts = pos.count if "NORMAL" in layouts else 3 * tris  # flat normals: one per corner
    return PrimitivePlan(m, p, where, mode, material, pos, indices, layouts, verts, tris,
                         draco)


def plan_mesh(ctx: Ctx, doc: dict, m: int) -> list[PrimitivePlan]:
    """Plans of every primitive of mesh ``m``."""
    where = f"meshes[{m}]"
    ctx.where = where
    prims = get_list(ctx, get_items(ctx, doc, "meshes")[m], "primitives", where)
    if not prims:
        raise ctx.fail(f"{where}.primitives", "is empty")
    out = []
    for p, prim in enumerate(prims):
        if not isinstance(prim, dict):
            raise ctx.fail(f"{where}.primitives[{p}]", f"must be an object, got {show(prim)}")
        out.append(plan_primitive(ctx, doc, m, p, prim))
    return out


def check_totals(ctx: Ctx, scene_where: str, nodes: list[Node], order: list[int],
                 plans: dict[int, list[PrimitivePlan]]) -> None:
    """Vertex and triangle totals summed over every instance, against the limits."""
    tris = verts = instances = 0
    for i in order:
        m = nodes[i].mesh
        if m < 0:
            continue
        instances += 1
        for plan in plans[m]:
            if plan.triangle_count:
                tris += plan.triangle_count
                verts += plan.vertex_count
    if verts > ctx.limits.max_vertices:
        raise ctx.over(scene_where, f"{verts} vertices over {instances} mesh instances",
                       "max_vertices")
    if tris > ctx.limits.max_triangles:
        raise ctx.over(scene_where, f"{tris} triangles over {instances} mesh instances",
                       "max_triangles")
    if tris == 0:
        raise ctx.fail(scene_where, "no triangles: the scene has no triangle primitives")


def triangulate(mode: int, idx: np.ndarray) -> np.ndarray:
    """Vertex indices (n,) int64 of a TRIANGLES/STRIP/FAN primitive → faces (f, 3) int64.

    Strip triangle i is (v_i, v_{i+1+i%2}, v_{i+2−i%2}) and fan triangle i is
    (v_{i+1}, v_{i+2}, v_0), as in the glTF spec; strip/fan triangles that repeat a vertex
    (used as restarts) are dropped.
    """
    n = len(idx)
    if mode == 4:
        return idx[: n - n % 3].reshape(-1, 3)
    i = np.arange(max(n - 2, 0))
    if mode == 5:
        odd = i % 2
        f = np.stack([idx[i], idx[i + 1 + odd], idx[i + 2 - odd]], axis=1)
    else:
        f = np.stack([idx[i + 1], idx[i + 2], np.full_like(i, idx[0] if n else 0)], axis=1)
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    return f[keep]


def area_weighted_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Vertex normals as the area-weighted sum of adjacent face normals.

    positions : (v, 3) float64; faces : (f, 3) int64. Returns (v, 3) float64 unit vectors;
    vertices with no non-degenerate face get +Z.
    """
    v = positions[faces]
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])  # length = 2 × area
    corner = faces.ravel()
    acc = np.stack([np.bincount(corner, weights=np.repeat(fn[:, c], 3),
                                minlength=len(positions)) for c in range(3)], axis=1)
    return normalize_rows(acc)


@dataclass(frozen=True)
class DecodedPrimitive:
    """Object-space data of one primitive.

    positions, normals (v, 3) float64; uv0, uv1 (v, 2) float64 or None; joints (v, 4) int32
    and weights (v, 4) float64 or None; faces (f, 3) int64 in the file's winding.
    """

    positions: np.ndarray
    normals: np.ndarray
    uv0: np.ndarray | None
    uv1: np.ndarray | None
    joints: np.ndarray | None
    weights: np.ndarray | None
    faces: np.ndarray


def flat_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit geometric normals (f, 3) of triangles (right-handed winding); +Z for degenerate
    ones."""
    v = positions[faces]
    return normalize_rows(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]))


def _raw_attributes(ctx: Ctx, plan: PrimitivePlan, buffers: list
                    ) -> tuple[dict, np.ndarray]:
    """({semantic: raw accessor values}, vertex indices (n,) int64) of a planned primitive,
    from its accessors or its Draco bitstream."""
    if plan.draco is not None:
        return decode_draco(ctx, plan.draco, buffers, plan.position, plan.attributes,
                            plan.triangle_count)
    raw = {"POSITION": read_accessor(ctx, plan.position, buffers)}
    for sem, lay in plan.attributes.items():
        raw[sem] = read_accessor(ctx, lay, buffers)
    if plan.indices is None:
        return raw, np.arange(plan.position.count, dtype=np.int64)
    idx = read_accessor(ctx, plan.indices, buffers)[:, 0].astype(np.int64)
    if len(idx) and idx.max() >= plan.position.count:
        raise ctx.fail(plan.indices.where, f"index {int(idx.max())} out of range for "
                                           f"{plan.position.count} vertices")
    return raw, idx


def decode_primitive(ctx: Ctx, plan: PrimitivePlan, buffers: list) -> DecodedPrimitive:
    """Decode a planned triangle primitive (positions checked finite, indices in range).

    Without NORMAL the primitive gets flat normals, as the glTF specification requires
    ("client implementations MUST calculate flat normals"): every triangle gets its own three
    vertices whose normal is the triangle's geometric normal. Unusable NORMAL values (zero,
    NaN) are replaced by area-weighted vertex normals, with a warning.
    """
    ctx.where = plan.where
    raw, idx = _raw_attributes(ctx, plan, buffers)
    positions = finite_floats(ctx, raw["POSITION"], plan.position)
    faces = triangulate(plan.mode, idx)
    attrs = plan.attributes

    def floats(sem: str) -> np.ndarray | None:
        return None if sem not in attrs else finite_floats(ctx, raw[sem], attrs[sem])

    uv0, uv1 = floats("TEXCOORD_0"), floats("TEXCOORD_1")
    joints = weights = None
    if "JOINTS_0" in attrs and "WEIGHTS_0" in attrs:
        joints, weights = raw["JOINTS_0"].astype(np.int32), floats("WEIGHTS_0")
    if "NORMAL" not in attrs:
        corner = faces.reshape(-1)
        normals = np.repeat(flat_normals(positions, faces), 3, axis=0)
        positions, faces = positions[corner], np.arange(len(corner)).reshape(-1, 3)
        uv0, uv1, joints, weights = (None if a is None else a[corner]
                                     for a in (uv0, uv1, joints, weights))
    else:
        normals = to_float(raw["NORMAL"], attrs["NORMAL"])
        length = np.linalg.norm(normals, axis=1)
        bad = ~np.isfinite(length) | (length <= NORMAL_EPS)
        if bad.any():
            ctx.warn(attrs["NORMAL"].where, f"{int(bad.sum())} unusable normals replaced by "
                                            "area-weighted ones")
            normals[bad] = area_weighted_normals(positions, faces)[bad]
        normals = normalize_rows(normals)
    return DecodedPrimitive(positions, normals, uv0, uv1, joints, weights, faces)


def place_primitive(world_from_node: np.ndarray, prim: DecodedPrimitive
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Object → world: positions by the matrix, normals by its inverse-transpose
    (renormalised); winding flipped when det < 0. Returns positions (v, 3), normals (v, 3),
    faces (f, 3)."""
    lin = world_from_node[:3, :3]
    pos = apply_linear(prim.positions, lin) + world_from_node[:3, 3]
    nrm = normalize_rows(apply_linear(prim.normals, normal_matrix(lin)))
    faces = prim.faces[:, [0, 2, 1]] if np.linalg.det(lin) < 0 else prim.faces
    return pos, nrm, faces


def place_skinned(ctx: Ctx, where: str, world_from_node: np.ndarray, skin: Skin,
                  nodes: list[Node], prim: DecodedPrimitive
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rest pose of a skinned primitive by linear blend skinning: each vertex moved by
    Σ_k w_k · world_from_joint_k · inverse_bind_k (the mesh node's own transform is ignored,
    as glTF specifies). Vertices with zero total weight use ``world_from_node``."""
    if prim.joints.size and prim.joints.max() >= len(skin.joints):
        raise ctx.fail(f"{where}.attributes.JOINTS_0",
                       f"joint {int(prim.joints.max())} out of range for a skin of "
                       f"{len(skin.joints)} joints")
    joint_mats = np.stack([nodes[j].world_from_node for j in skin.joints]) @ skin.inverse_bind
    w = prim.weights
    total = w.sum(axis=1, keepdims=True)
    unweighted = total[:, 0] <= 0
    w = np.divide(w, total, out=np.zeros_like(w), where=total > 0)
    per_vertex = np.einsum("vk,vkij->vij", w, joint_mats[prim.joints])
    per_vertex[unweighted] = world_from_node
    lin = per_vertex[:, :3, :3]
    pos = np.einsum("vij,vj->vi", lin, prim.positions) + per_vertex[:, :3, 3]
    nrm = normalize_rows(np.einsum("vij,vj->vi", normal_matrix(lin), prim.normals))
    det = np.linalg.det(lin)
    flip = det[prim.faces].mean(axis=1) < 0
    faces = prim.faces.copy()
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return pos, nrm, faces


@dataclass(frozen=True)
class FlatGeometry:
    """Concatenated world-space geometry of all instances (see :class:`Scene`)."""

    positions: np.ndarray
    normals: np.ndarray
    uv0: np.ndarray
    has_uv0: np.ndarray
    uv1: np.ndarray | None
    faces: np.ndarray
    face_material: np.ndarray
    face_instance: np.ndarray
    instances: tuple[PrimitiveInstance, ...]
    uses_default_material: bool


def flatten(ctx: Ctx, nodes: list[Node], order: list[int], plans: dict, buffers: list,
            skins: list[Skin], default_material: int) -> FlatGeometry:
    """Place every triangle primitive of every mesh instance in world space."""
    cache: dict[tuple[int, int], DecodedPrimitive] = {}
    chunks = []
    v0 = f0 = 0
    for i in order:
        node = nodes[i]
        if node.mesh < 0:
            continue
        for plan in plans[node.mesh]:
            if plan.mode < 4 or plan.position is None:
                continue
            key = (plan.mesh, plan.primitive)
            if key not in cache:
                cache[key] = decode_primitive(ctx, plan, buffers)
            prim = cache[key]
            ctx.where = f"nodes[{i}] {plan.where}"
            if node.skin >= 0 and prim.joints is not None:
                pos, nrm, faces = place_skinned(ctx, plan.where, node.world_from_node,
                                                skins[node.skin], nodes, prim)
            else:
                pos, nrm, faces = place_primitive(node.world_from_node, prim)
            nv, nf = len(pos), len(faces)
            empty4 = np.zeros((0, 4))
            inst = PrimitiveInstance(
                node=i, mesh=plan.mesh, primitive=plan.primitive,
                vertex_start=v0, vertex_count=nv, face_start=f0, face_count=nf,
                object_positions=prim.positions, object_normals=prim.normals,
                joints=prim.joints if prim.joints is not None else empty4.astype(np.int32),
                weights=prim.weights if prim.weights is not None else empty4,
            )
            mat = plan.material if plan.material >= 0 else default_material
            chunks.append((inst, pos, nrm, faces + v0, prim.uv0, prim.uv1, mat))
            v0, f0 = v0 + nv, f0 + nf
    insts = tuple(c[0] for c in chunks)
    n_uv1 = sum(c[5] is not None for c in chunks)
    uv1 = None
    if n_uv1:
        if n_uv1 < len(chunks):
            ctx.warn("", f"TEXCOORD_1 present on {n_uv1} of {len(chunks)} primitive instances;"
                         " zeros filled in elsewhere")
        uv1 = np.concatenate([c[5] if c[5] is not None else np.zeros((c[0].vertex_count, 2))
                              for c in chunks])
    faces = np.concatenate([c[3] for c in chunks]).astype(np.int64)
    if len(faces) == 0:
        raise ctx.fail("", "no triangles: every triangle primitive is degenerate")
    return FlatGeometry(
        positions=np.concatenate([c[1] for c in chunks]),
        normals=np.concatenate([c[2] for c in chunks]),
        uv0=np.concatenate([c[4] if c[4] is not None else np.zeros((c[0].vertex_count, 2))
                            for c in chunks]),
        has_uv0=np.concatenate([np.full(c[0].vertex_count, c[4] is not None) for c in chunks]),
        uv1=uv1,
        faces=faces,
        face_material=np.concatenate([np.full(len(c[3]), c[6], dtype=np.int32)
                                      for c in chunks]),
        face_instance=np.concatenate([np.full(len(c[3]), k, dtype=np.int32)
                                      for k, c in enumerate(chunks)]),
        instances=insts,
        uses_default_material=any(c[6] == default_material for c in chunks),
    )
