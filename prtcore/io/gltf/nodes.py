"""Node hierarchy, TRS and matrix transforms, the scene's roots and traversal order, and the
transform math shared by the geometry (normal matrix, row normalisation)."""

from __future__ import annotations

import numpy as np

from prtcore.core.scene import Node
from prtcore.core.tolerances import NORMAL_EPS
from prtcore.io.gltf.lights import light_definitions
from prtcore.io.gltf.schema import (
    Ctx,
    get_extension,
    get_index,
    get_int,
    get_items,
    get_nums,
    get_str,
    index_list,
)


def trs_matrix(translation: np.ndarray, rotation: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Local matrix T·R·S. rotation : (4,) unit quaternion xyzw. Returns (4, 4) float64."""
    from scipy.spatial.transform import Rotation

    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(rotation).as_matrix() * scale[None, :]
    m[:3, 3] = translation
    return m


def decompose_matrix(m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(4, 4) affine → translation (3,), rotation xyzw (4,), scale (3,) float64.

    Exact for T·R·S matrices; with shear the rotation is the nearest one (for the record
    only: ``Node.matrix`` stays authoritative).
    """
    from scipy.spatial.transform import Rotation

    lin = m[:3, :3]
    scale = np.linalg.norm(lin, axis=0)
    if np.linalg.det(lin) < 0:
        scale[0] = -scale[0]
    if np.all(np.abs(scale) > 0):
        rot = Rotation.from_matrix(lin / scale[None, :]).as_quat()
    else:
        rot = np.array([0.0, 0.0, 0.0, 1.0])
    return m[:3, 3].copy(), rot, scale


def normalize_rows(n: np.ndarray, fallback=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(k, 3) rows scaled to unit length; rows shorter than NORMAL_EPS become ``fallback``."""
    length = np.sqrt(np.einsum("ij,ij->i", n, n))
    ok = length > NORMAL_EPS
    out = n / np.where(ok, length, 1.0)[:, None]
    if not ok.all():
        out[~ok] = fallback
    return out


def apply_linear(rows: np.ndarray, lin: np.ndarray) -> np.ndarray:
    """rows (k, 3) float64 mapped by lin (3, 3): ``rows @ lin.T`` without a BLAS call
    (a (k, 3)·(3, 3) product is memory-bound; BLAS threading only slows it down)."""
    return rows[:, 0:1] * lin[:, 0] + rows[:, 1:2] * lin[:, 1] + rows[:, 2:3] * lin[:, 2]


def normal_matrix(lin: np.ndarray) -> np.ndarray:
    """Normal transform for linear part(s) ``lin`` (..., 3, 3): the inverse-transpose up to a
    positive factor, as sign(det)·cofactor (defined even for singular matrices)."""
    a, b, c = lin[..., :, 0], lin[..., :, 1], lin[..., :, 2]
    cof = np.stack([np.cross(b, c), np.cross(c, a), np.cross(a, b)], axis=-1)
    det = np.einsum("...i,...i->...", a, np.cross(b, c))
    return cof * np.where(det < 0, -1.0, 1.0)[..., None, None]


def _local_transform(ctx: Ctx, nd: dict, where: str):
    if "matrix" in nd:
        matrix = get_nums(ctx, nd, "matrix", where, 16, None).reshape(4, 4).T  # column-major
        if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0]):
            raise ctx.fail(f"{where}.matrix", "is not an affine transform (last row != 0 0 0 1)")
        t, r, s = decompose_matrix(matrix)
        return t, r, s, matrix
    t = get_nums(ctx, nd, "translation", where, 3, [0.0, 0.0, 0.0])
    r = get_nums(ctx, nd, "rotation", where, 4, [0.0, 0.0, 0.0, 1.0])
    s = get_nums(ctx, nd, "scale", where, 3, [1.0, 1.0, 1.0])
    norm = float(np.linalg.norm(r))
    if norm < 1e-6:
        raise ctx.fail(f"{where}.rotation", "quaternion has zero length")
    r = r / norm
    return t, r, s, trs_matrix(t, r, s)


def parse_nodes(ctx: Ctx, doc: dict) -> tuple[list[Node], list[int]]:
    """All nodes with parents and rest ``world_from_node``; plus each node's light index.

    Enforces a forest: a node has at most one parent and no cycles. Returns the nodes and,
    per node, its ``KHR_lights_punctual.light`` index (−1 when none).
    """
    nodes_json = get_items(ctx, doc, "nodes")
    n = len(nodes_json)
    parent = [-1] * n
    kids: list[tuple[int, ...]] = []
    local, trs, meshes, skins, lights = [], [], [], [], []
    n_lights = len(light_definitions(ctx, doc))
    for i, nd in enumerate(nodes_json):
        where = f"nodes[{i}]"
        ctx.where = where
        children = index_list(ctx, nd, "children", where, n, "a node index")
        for k, c in enumerate(children):
            cw = f"{where}.children[{k}]"
            if c == i or parent[c] != -1:
                raise ctx.fail(cw, f"nodes[{c}] already has a parent (the hierarchy must be "
                                   "a tree)")
            parent[c] = i
        kids.append(tuple(children))
        meshes.append(get_index(ctx, nd, "mesh", where, "meshes", default=-1))
        skins.append(get_index(ctx, nd, "skin", where, "skins", default=-1))
        t, r, s, m = _local_transform(ctx, nd, where)
        trs.append((t, r, s))
        local.append(m)
        ext = get_extension(ctx, nd, "KHR_lights_punctual", where)
        light = -1
        if ext is not None:
            lw = f"{where}.extensions.KHR_lights_punctual"
            light = get_int(ctx, ext, "light", lw)
            if light >= n_lights:
                raise ctx.fail(f"{lw}.light", f"refers to light {light} but there are "
                                              f"{n_lights}")
        lights.append(light)
    world = [None] * n
    order = [i for i in range(n) if parent[i] == -1]
    for i in order:
        world[i] = local[i]
    k = 0
    while k < len(order):
        i = order[k]
        for c in kids[i]:
            world[c] = world[i] @ local[c]
            order.append(c)
        k += 1
    if len(order) != n:
        bad = next(i for i in range(n) if world[i] is None)
        raise ctx.fail(f"nodes[{bad}]", "is part of a cycle in the node hierarchy")
    nodes = [
        Node(
            name=get_str(ctx, nd, "name", f"nodes[{i}]", default=""),
            parent=parent[i], children=kids[i],
            translation=trs[i][0], rotation=trs[i][1], scale=trs[i][2],
            matrix=local[i], world_from_node=world[i], mesh=meshes[i], skin=skins[i],
        )
        for i, nd in enumerate(nodes_json)
    ]
    return nodes, lights


def scene_roots(ctx: Ctx, doc: dict, nodes: list[Node]) -> tuple[list[int], str]:
    """Root nodes of the scene to flatten (``scene`` or 0; all roots when no scenes), and
    the glTF path naming that scene (for messages)."""
    scenes = get_items(ctx, doc, "scenes")
    if not scenes:
        if "scene" in doc:
            raise ctx.fail("scene", "refers to a scene but there are no scenes")
        return [i for i, nd in enumerate(nodes) if nd.parent == -1], "nodes"
    s = get_index(ctx, doc, "scene", "", "scenes", default=0)
    where = f"scenes[{s}]"
    roots = []
    for k, r in enumerate(index_list(ctx, scenes[s], "nodes", where, len(nodes), "a node index")):
        rw = f"{where}.nodes[{k}]"
        if nodes[r].parent != -1:
            raise ctx.fail(rw, f"nodes[{r}] is not a root node")
        if r in roots:
            raise ctx.fail(rw, f"nodes[{r}] is listed twice")
        roots.append(r)
    return roots, where


def traverse(nodes: list[Node], roots: list[int]) -> list[int]:
    """Node indices of the scene in depth-first pre-order (children in listed order)."""
    out, stack = [], list(reversed(roots))
    while stack:
        i = stack.pop()
        out.append(i)
        stack.extend(reversed(nodes[i].children))
    return out
