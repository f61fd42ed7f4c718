"""Mesh health, repair and remeshing on a :class:`prtcore.core.scene.Scene`.

Every function takes and returns a Scene and keeps its invariants: per-vertex arrays stay
aligned, faces index them, ``face_material``/``face_instance`` stay aligned with faces, and
every :class:`PrimitiveInstance` keeps a contiguous vertex range and face range with
``object_positions``/``object_normals``/``joints``/``weights`` aligned with its vertices (so
keyframes can re-pose it later). Topology changes are made per instance.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from prtcore.core.errors import AssetError, SpecError
from prtcore.core.scene import PrimitiveInstance, Scene
from prtcore.core.tolerances import DEGENERATE_AREA_REL, NORMAL_EPS, WELD_DISTANCE_REL

# ---------------------------------------------------------------------------------------
# Instance layout and small helpers


def scene_scale(scene: Scene) -> float:
    """Scene radius used to scale tolerances (positive even for an empty scene)."""
    if len(scene.positions) == 0:
        return 1.0
    r = scene.radius
    return float(r) if np.isfinite(r) and r > 0 else 1.0


def instance_spans(scene: Scene) -> list[tuple[int, int, int, int]]:
    """(vertex_start, vertex_stop, face_start, face_stop) per instance.

    A scene without instances counts as one instance covering everything. Raises
    :class:`AssetError` when the instance ranges do not tile the vertex and face arrays in
    order or when an instance's faces reference vertices outside its own range.
    """
    nv, nf = len(scene.positions), len(scene.faces)
    if not scene.instances:
        spans = [(0, nv, 0, nf)]
    else:
        spans = [(i.vertex_start, i.vertex_start + i.vertex_count,
                  i.face_start, i.face_start + i.face_count) for i in scene.instances]
    v_next = f_next = 0
    for k, (v0, v1, f0, f1) in enumerate(spans):
        if v0 != v_next or f0 != f_next or v1 < v0 or f1 < f0:
            raise AssetError(scene.source, f"instances[{k}]",
                             "vertex/face ranges are not contiguous with the previous instance")
        if f1 > f0:
            idx = scene.faces[f0:f1]
            if idx.min() < v0 or idx.max() >= v1:
                raise AssetError(scene.source, f"instances[{k}]",
                                 "faces reference vertices outside the instance's range")
        v_next, f_next = v1, f1
    if v_next != nv or f_next != nf:
        raise AssetError(scene.source, "instances",
                         f"instances cover {v_next} of {nv} vertices and {f_next} of {nf} faces")
    return spans


def face_instance(scene: Scene, spans: list[tuple[int, int, int, int]]) -> np.ndarray:
    """(f,) int64 instance index of every face, from the spans (not trusting face_instance)."""
    counts = np.array([f1 - f0 for _, _, f0, f1 in spans], dtype=np.int64)
    return np.repeat(np.arange(len(spans), dtype=np.int64), counts)


def quantise(points: np.ndarray, step: float) -> np.ndarray:
    """(n, d) float → (n, d) int64 grid cells of size ``step`` (non-finite → a far cell)."""
    q = np.nan_to_num(np.asarray(points, dtype=np.float64) / step, nan=4e18, posinf=4e18,
                      neginf=-4e18)
    return np.round(np.clip(q, -4e18, 4e18)).astype(np.int64)


def row_ids(q: np.ndarray) -> np.ndarray:
    """(n,) int64 ids of the distinct rows of an (n, d) int64 array (ids sorted by row)."""
    n, d = q.shape
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    ranks, sizes = [], []
    for j in range(d):  # per-column ranks, then one mixed-radix key (1-D sorts are fast)
        u, r = np.unique(q[:, j], return_inverse=True)
        ranks.append(r.reshape(-1).astype(np.int64))
        sizes.append(len(u))
    if float(np.prod(np.array(sizes, dtype=np.float64))) < 2.0 ** 62:
        key = ranks[0]
        for r, size in zip(ranks[1:], sizes[1:], strict=True):
            key = key * size + r
        _, inv = np.unique(key, return_inverse=True)
    else:
        _, inv = np.unique(np.column_stack(ranks), axis=0, return_inverse=True)
    return inv.reshape(-1).astype(np.int64)


def weld_ids(points: np.ndarray, step: float) -> np.ndarray:
    """(n,) int64 ids, equal for points in the same ``step``-sized grid cell."""
    return row_ids(quantise(np.asarray(points).reshape(len(points), -1), step))


def canonical_rotation(tri: np.ndarray) -> np.ndarray:
    """(f, 3) int → same cyclic order, rotated so the smallest id comes first."""
    r = np.argmin(tri, axis=1)
    rows = np.arange(len(tri))
    return np.stack([tri[rows, r], tri[rows, (r + 1) % 3], tri[rows, (r + 2) % 3]], axis=1)


def subset(scene: Scene, keep_face: np.ndarray, keep_vertex: np.ndarray) -> Scene:
    """The scene restricted to ``keep_face`` (f,) bool and ``keep_vertex`` (v,) bool.

    Every vertex referenced by a kept face must be kept. Order is preserved, so instance
    ranges stay contiguous; their per-vertex arrays are filtered alongside.
    """
    spans = instance_spans(scene)
    new_index = np.cumsum(keep_vertex) - 1
    faces = new_index[scene.faces[keep_face]]
    vcum = np.concatenate([[0], np.cumsum(keep_vertex)])
    fcum = np.concatenate([[0], np.cumsum(keep_face)])
    instances = []
    for inst, (v0, v1, f0, f1) in zip(scene.instances, spans, strict=False):
        kv = keep_vertex[v0:v1]
        instances.append(dataclasses.replace(
            inst, vertex_start=int(vcum[v0]), vertex_count=int(vcum[v1] - vcum[v0]),
            face_start=int(fcum[f0]), face_count=int(fcum[f1] - fcum[f0]),
            object_positions=inst.object_positions[kv], object_normals=inst.object_normals[kv],
            joints=inst.joints[kv] if len(inst.joints) == len(kv) else inst.joints,
            weights=inst.weights[kv] if len(inst.weights) == len(kv) else inst.weights))
    return scene.replace(
        positions=scene.positions[keep_vertex], normals=scene.normals[keep_vertex],
        uv0=scene.uv0[keep_vertex], uv1=None if scene.uv1 is None else scene.uv1[keep_vertex],
        has_uv0=None if scene.has_uv0 is None else scene.has_uv0[keep_vertex],
        faces=faces.astype(np.int64), face_material=scene.face_material[keep_face],
        face_instance=scene.face_instance[keep_face], instances=tuple(instances))


@dataclass
class Part:
    """One instance's rebuilt geometry (local vertex indices), for :func:`assemble`."""

    positions: np.ndarray
    normals: np.ndarray
    uv0: np.ndarray
    uv1: np.ndarray | None
    has_uv0: np.ndarray | None
    faces: np.ndarray
    face_material: np.ndarray
    object_positions: np.ndarray
    object_normals: np.ndarray
    joints: np.ndarray
    weights: np.ndarray


def take_part(scene: Scene, span: tuple[int, int, int, int], inst: PrimitiveInstance | None,
               vmap: np.ndarray, faces_local: np.ndarray, uv1: np.ndarray | None) -> Part:
    """Instance geometry re-indexed by ``vmap`` (new vertex → old local vertex)."""
    v0, v1, f0, f1 = span
    def sub(a):
        return a[v0:v1][vmap]
    if inst is None:
        op, on = sub(scene.positions), sub(scene.normals)
        jo, we = np.zeros((0, 4), np.int32), np.zeros((0, 4))
    else:
        op, on = inst.object_positions[vmap], inst.object_normals[vmap]
        jo = inst.joints[vmap] if len(inst.joints) == v1 - v0 else inst.joints
        we = inst.weights[vmap] if len(inst.weights) == v1 - v0 else inst.weights
    return Part(positions=sub(scene.positions), normals=sub(scene.normals), uv0=sub(scene.uv0),
                 uv1=uv1, has_uv0=None if scene.has_uv0 is None else sub(scene.has_uv0),
                 faces=faces_local, face_material=scene.face_material[f0:f1],
                 object_positions=op, object_normals=on, joints=jo, weights=we)


def assemble(scene: Scene, parts: list[Part], with_uv1: bool) -> Scene:
    """Concatenate per-instance parts back into a scene with fresh contiguous ranges."""
    instances, faces, inst_of_face = [], [], []
    v_start = f_start = 0
    for k, p in enumerate(parts):
        faces.append(p.faces.astype(np.int64) + v_start)
        inst_of_face.append(np.full(len(p.faces), k, dtype=np.int32))
        if scene.instances:
            instances.append(dataclasses.replace(
                scene.instances[k], vertex_start=v_start, vertex_count=len(p.positions),
                face_start=f_start, face_count=len(p.faces), object_positions=p.object_positions,
                object_normals=p.object_normals, joints=p.joints, weights=p.weights))
        v_start += len(p.positions)
        f_start += len(p.faces)
    def cat(name, width, dtype):
        arrs = [getattr(p, name) for p in parts]
        return np.concatenate(arrs) if arrs else np.zeros((0, width), dtype)
    has_uv0 = None if scene.has_uv0 is None else np.concatenate([p.has_uv0 for p in parts])
    face_instance = (np.concatenate(inst_of_face) if scene.instances
                     else np.zeros(f_start, dtype=np.int32))
    return scene.replace(
        positions=cat("positions", 3, np.float64), normals=cat("normals", 3, np.float64),
        uv0=cat("uv0", 2, np.float64),
        uv1=cat("uv1", 2, np.float64).astype(np.float64) if with_uv1 else None,
        has_uv0=has_uv0, faces=np.concatenate(faces) if faces else np.zeros((0, 3), np.int64),
        face_material=np.concatenate([p.face_material for p in parts]).astype(np.int32),
        face_instance=face_instance.astype(np.int32), instances=tuple(instances))


# ---------------------------------------------------------------------------------------
# Mesh health


@dataclass(frozen=True)
class MeshHealth:
    """Counts of mesh problems (topology measured per instance on welded positions).

    degenerate_faces : area ≤ DEGENERATE_AREA_REL × radius², or two corners at the same
        (welded) position
    duplicate_faces : same three welded positions in the same cyclic order as an earlier
        face of the same instance (back-to-back faces with opposite winding are legitimate
        two-sided geometry and are not counted)
    unreferenced_vertices : vertices no face uses
    nonmanifold_edges : welded edges shared by more than two faces (kept: xatlas gives each
        fin its own chart)
    boundary_edges : welded edges used by exactly one face (open borders; informative)
    """

    degenerate_faces: int
    duplicate_faces: int
    unreferenced_vertices: int
    nonmanifold_edges: int
    boundary_edges: int
    vertices: int = 0
    faces: int = 0
    instances: int = 0

    @property
    def needs_repair(self) -> bool:
        """True when :func:`repair_scene` would remove something."""
        return bool(self.degenerate_faces or self.duplicate_faces or self.unreferenced_vertices)

    def describe(self) -> str:
        """Short human summary of what repair would fix, or ``"mesh clean"``."""
        parts = [f"{n} {what}" for n, what in (
            (self.degenerate_faces, "degenerate faces"),
            (self.duplicate_faces, "duplicate faces"),
            (self.unreferenced_vertices, "unreferenced vertices")) if n]
        return ", ".join(parts) if parts else "mesh clean"


def _problems(scene: Scene, spans) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """degenerate (f,) bool, duplicate (f,) bool, referenced (v,) bool, welded faces (f, 3)."""
    scale = scene_scale(scene)
    nf = len(scene.faces)
    pid = weld_ids(scene.positions, WELD_DISTANCE_REL * scale)
    wf = pid[scene.faces] if nf else np.zeros((0, 3), dtype=np.int64)
    area = scene.face_areas() if nf else np.zeros(0)
    degenerate = ((~np.isfinite(area)) | (area <= DEGENERATE_AREA_REL * scale * scale)
                  | (wf[:, 0] == wf[:, 1]) | (wf[:, 1] == wf[:, 2]) | (wf[:, 2] == wf[:, 0]))
    duplicate = np.zeros(nf, dtype=bool)
    ok = np.flatnonzero(~degenerate)
    if len(ok):
        inst = face_instance(scene, spans)[ok]
        rows = np.column_stack([inst, canonical_rotation(wf[ok])])
        _, first = np.unique(rows, axis=0, return_index=True)
        dup = np.ones(len(ok), dtype=bool)
        dup[first] = False
        duplicate[ok[dup]] = True
    referenced = np.zeros(len(scene.positions), dtype=bool)
    referenced[scene.faces.reshape(-1)] = True
    return degenerate, duplicate, referenced, wf


def inspect_mesh(scene: Scene) -> MeshHealth:
    """Count what :func:`repair_scene` would fix, plus non-manifold and boundary edges.

    Vectorised numpy; O(f log f). See :class:`MeshHealth` for the definitions.
    """
    spans = instance_spans(scene)
    degenerate, duplicate, referenced, wf = _problems(scene, spans)
    good = ~(degenerate | duplicate)
    nonmanifold = boundary = 0
    if good.any():
        inst = face_instance(scene, spans)[good]
        g = wf[good]
        e = np.concatenate([g[:, [0, 1]], g[:, [1, 2]], g[:, [2, 0]]])
        e.sort(axis=1)
        rows = np.column_stack([np.tile(inst, 3), e])
        _, counts = np.unique(rows, axis=0, return_counts=True)
        nonmanifold, boundary = int((counts > 2).sum()), int((counts == 1).sum())
    return MeshHealth(degenerate_faces=int(degenerate.sum()), duplicate_faces=int(duplicate.sum()),
                      unreferenced_vertices=int((~referenced).sum()),
                      nonmanifold_edges=nonmanifold, boundary_edges=boundary,
                      vertices=len(scene.positions), faces=len(scene.faces),
                      instances=len(spans))


# ---------------------------------------------------------------------------------------
# Repair


def repair_scene(scene: Scene, force: bool = False) -> tuple[Scene, dict]:
    """Remove degenerate faces, duplicate faces and unreferenced vertices, per instance.

    Definitions are those of :class:`MeshHealth` (tolerances scaled to the scene radius).
    Faces and vertices are only *removed*, never reordered or merged, so every kept vertex
    keeps its attributes (uv0 seams, normals, skinning) and instance ranges stay contiguous.
    When nothing needs repair the scene is returned unchanged unless ``force``.

    Non-manifold edges are counted but kept: xatlas splits them into separate charts (see
    ``tests/test_prepare.py::test_nonmanifold_fins_get_valid_uvs``), and splitting or
    deleting faces would change the lit surface.

    Returns (scene, counts) with counts: degenerate_faces, duplicate_faces,
    unreferenced_vertices (unused in the input), orphaned_vertices (used only by removed
    faces), faces_before, faces_after, vertices_before, vertices_after.
    """
    spans = instance_spans(scene)
    degenerate, duplicate, referenced, _ = _problems(scene, spans)
    nv, nf = len(scene.positions), len(scene.faces)
    counts = {"degenerate_faces": int(degenerate.sum()), "duplicate_faces": int(duplicate.sum()),
              "unreferenced_vertices": int((~referenced).sum()), "orphaned_vertices": 0,
              "faces_before": nf, "faces_after": nf, "vertices_before": nv, "vertices_after": nv}
    needed = counts["degenerate_faces"] or counts["duplicate_faces"] or \
        counts["unreferenced_vertices"]
    if not needed and not force:
        return scene, counts
    keep_face = ~(degenerate | duplicate)
    keep_vertex = np.zeros(nv, dtype=bool)
    keep_vertex[scene.faces[keep_face].reshape(-1)] = True
    counts["orphaned_vertices"] = int((referenced & ~keep_vertex).sum())
    out = subset(scene, keep_face, keep_vertex)
    counts["faces_after"], counts["vertices_after"] = len(out.faces), len(out.positions)
    return out, counts


# ---------------------------------------------------------------------------------------
# Remesh


def remesh_scene(scene: Scene, target_edge_rel: float,
                 iterations: int = 10) -> Scene:
    """Isotropic explicit remeshing (pymeshlab), per instance, target edge length
    ``target_edge_rel`` × the scene's bounding-box diagonal.

    Each instance is welded (WELD_DISTANCE_REL × radius), remeshed with feature edges above
    30° preserved, and its attributes are transferred from the *closest point* of the
    original instance surface (exact barycentric interpolation on the closest triangle):
    uv0, normals (renormalised), object_positions and object_normals (so the instance can
    still be re-posed), has_uv0 (all three corners must have it); joints and weights come
    from the closest triangle's corner with the largest barycentric weight; a face's
    material is that of the original triangle closest to its centroid.

    TEXCOORD_1 is dropped (it must be regenerated) and a warning says so. uv0 is kept by the
    closest-point transfer (textures stay), with a warning that new triangles crossing a
    texture seam interpolate across it.
    """
    import pymeshlab
    import trimesh

    spans = instance_spans(scene)
    b = scene.bounds
    diag = float(np.linalg.norm(b[1] - b[0])) if len(scene.faces) else 0.0
    target = float(target_edge_rel) * diag
    if not np.isfinite(target) or target <= 0:
        raise SpecError("prepare.remesh", f"target edge length {target} is not positive "
                        "(empty or flat scene?)")
    scale = scene_scale(scene)
    parts = []
    textured = False
    for k, span in enumerate(spans):
        v0, v1, f0, f1 = span
        inst = scene.instances[k] if scene.instances else None
        faces = scene.faces[f0:f1] - v0
        if len(faces) == 0:
            parts.append(take_part(scene, span, inst, np.zeros(0, np.int64),
                                    np.zeros((0, 3), np.int64), None))
            continue
        pos = scene.positions[v0:v1]
        # weld for remeshing (the originals stay for the attribute transfer)
        wid = weld_ids(pos, WELD_DISTANCE_REL * scale)
        first = np.zeros(wid.max() + 1, dtype=np.int64)
        first[wid[::-1]] = np.arange(len(wid))[::-1]
        wfaces = wid[faces]
        ok = (wfaces[:, 0] != wfaces[:, 1]) & (wfaces[:, 1] != wfaces[:, 2]) & \
            (wfaces[:, 2] != wfaces[:, 0])
        if not ok.any():  # nothing but collapsed triangles: the instance becomes empty
            parts.append(take_part(scene, span, inst, np.zeros(0, np.int64),
                                    np.zeros((0, 3), np.int64), None))
            continue
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=pos[first],
                                   face_matrix=wfaces[ok].astype(np.int32)))
        ms.meshing_remove_unreferenced_vertices()
        ms.meshing_isotropic_explicit_remeshing(
            iterations=int(iterations), targetlen=pymeshlab.PureValue(target),
            featuredeg=30.0, checksurfdist=True, maxsurfdist=pymeshlab.PureValue(target))
        m = ms.current_mesh()
        new_pos = np.asarray(m.vertex_matrix(), dtype=np.float64)
        new_faces = np.asarray(m.face_matrix(), dtype=np.int64)
        # closest-point transfer from the original (unwelded) instance surface
        src = trimesh.Trimesh(pos, faces, process=False)
        cp, _, tri = trimesh.proximity.closest_point(src, new_pos)
        bary = trimesh.triangles.points_to_barycentric(src.triangles[tri], cp)
        corners = faces[tri]  # (n, 3) local vertex indices of the closest triangles

        def interp(a, corners=corners, bary=bary):
            return np.einsum("nk,nkd->nd", bary, a[corners])

        def unit(a):
            n = np.linalg.norm(a, axis=1, keepdims=True)
            return np.divide(a, n, out=np.zeros_like(a), where=n > NORMAL_EPS)

        best = corners[np.arange(len(corners)), np.argmax(bary, axis=1)]
        uv0 = scene.uv0[v0:v1]
        has = None if scene.has_uv0 is None else scene.has_uv0[v0:v1][corners].all(axis=1)
        textured = textured or bool(scene.has_uv0 is None or scene.has_uv0[v0:v1].any())
        if inst is None:
            op, on = new_pos.copy(), unit(interp(scene.normals[v0:v1]))
            jo, we = np.zeros((0, 4), np.int32), np.zeros((0, 4))
        else:
            op, on = interp(inst.object_positions), unit(interp(inst.object_normals))
            skinned = len(inst.joints) == v1 - v0 and len(inst.joints) > 0
            jo = inst.joints[best] if skinned else inst.joints
            we = inst.weights[best] if skinned else inst.weights
        centroids = new_pos[new_faces].mean(axis=1)
        _, _, ftri = trimesh.proximity.closest_point(src, centroids)
        parts.append(Part(positions=new_pos, normals=unit(interp(scene.normals[v0:v1])),
                           uv0=interp(uv0), uv1=None, has_uv0=has, faces=new_faces,
                           face_material=scene.face_material[f0:f1][ftri],
                           object_positions=op, object_normals=on, joints=jo, weights=we))
    out = assemble(scene, parts, with_uv1=False)
    warnings = list(scene.warnings)
    warnings.append(f"remesh: isotropic remeshing to {target:.4g} m edges "
                    f"({target_edge_rel:g} × bbox diagonal); TEXCOORD_1 dropped, regenerate it")
    if textured:
        warnings.append("remesh: TEXCOORD_0 transferred from the closest original surface "
                        "point; new triangles crossing a texture seam interpolate across it")
    return out.replace(warnings=tuple(warnings))


