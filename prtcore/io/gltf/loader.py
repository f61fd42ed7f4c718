"""Asset intake: glTF 2.0 (``.glb``/``.gltf``) and OBJ/PLY → a flattened :class:`Scene`.

Untrusted input is the normal case. The glTF JSON is parsed here with :mod:`json` and typed
getters rather than with pygltflib, so that no library ever follows a URI or allocates a
buffer before the checks below have passed. Order of work for glTF:

1. file size (``os.stat``) → GLB container (header, chunks) → JSON → ``asset.version`` and
   ``extensionsRequired`` (every one must be supported);
2. element counts (nodes, meshes, materials, images, animations) against the limits;
3. node hierarchy (single parent, no cycles) and world transforms at rest;
4. every primitive of every mesh instance in the scene is *planned* from the JSON alone:
   accessor byte ranges must fit their bufferView and buffer (Python ints), vertex and
   triangle totals over all instances are compared with the limits;
5. only then buffers are read (URIs confined to the asset's folder, sizes checked first),
   meshopt-compressed bufferViews and Draco-compressed primitives decoded (counts checked
   first, :mod:`.compression`), accessors decoded, images decoded (header dimensions
   checked before pixels), and the geometry flattened to world space.

The work is split along those steps: :mod:`.container` (GLB, JSON, header, counts),
:mod:`.nodes` (hierarchy, transforms), :mod:`.meshes` (primitive plans, decoding,
flattening), :mod:`.accessors` (buffers, bufferViews, accessors), :mod:`.uris`,
:mod:`.compression`, :mod:`.materials`, :mod:`.lights` and :mod:`.animation`, all reading
the JSON through the typed readers of :mod:`.schema`. This module is the orchestrator.

Every refusal is a :class:`~prtcore.core.errors.AssetError` (or its subclasses
:class:`~prtcore.core.errors.LimitExceeded`, :class:`~prtcore.core.errors.UnsupportedAsset`) whose
one-line message names the file, the glTF path and, where one applies, the limit. Any other
exception raised while parsing malformed data is turned into an ``AssetError`` naming the
best glTF path known at that point; ``MemoryError`` passes through unchanged.
"""

from __future__ import annotations

import io
import os
import stat

import numpy as np

from prtcore.core.errors import AssetError, PrtError, UnsupportedAsset
from prtcore.core.limits import IntakeLimits
from prtcore.core.scene import Material, Scene, single_mesh_scene
from prtcore.io.gltf.accessors import buffer_lengths, load_buffers
from prtcore.io.gltf.animation import parse_animations, parse_skins
from prtcore.io.gltf.compression import decode_meshopt_views
from prtcore.io.gltf.container import GLB_MAGIC, check_counts, check_header, parse_json, read_glb
from prtcore.io.gltf.lights import parse_lights
from prtcore.io.gltf.materials import DEFAULT_GREY, parse_materials, texture_transform_matrix
from prtcore.io.gltf.meshes import check_totals, flatten, plan_mesh
from prtcore.io.gltf.nodes import (
    normal_matrix,
    normalize_rows,
    parse_nodes,
    scene_roots,
    traverse,
    trs_matrix,
)
from prtcore.io.gltf.schema import Ctx
from prtcore.io.sdf import is_sdf_file, load_sdf, sdf_mesh_scene

#: ``trs_matrix``, ``normal_matrix`` and ``texture_transform_matrix`` live in :mod:`.nodes` and
#: :mod:`.materials`; they are re-exported here for the code that imports them from the loader.
__all__ = ["load_asset", "normal_matrix", "texture_transform_matrix", "trs_matrix"]


def load_gltf(ctx: Ctx, data: bytes) -> Scene:
    """A GLB or glTF JSON file's bytes → the flattened :class:`Scene` (see module doc)."""
    if data[:4] == GLB_MAGIC or ctx.file.lower().endswith(".glb"):
        doc, bin_chunk = read_glb(ctx, data)
    else:
        doc, bin_chunk = parse_json(ctx, data), None
    ctx.doc = doc
    check_header(ctx, doc)
    check_counts(ctx, doc)
    buffer_lengths(ctx, doc)
    nodes, node_light = parse_nodes(ctx, doc)
    roots, scene_where = scene_roots(ctx, doc, nodes)
    order = traverse(nodes, roots)
    plans = {}
    for i in order:
        m = nodes[i].mesh
        if m >= 0 and m not in plans:
            plans[m] = plan_mesh(ctx, doc, m)
    check_totals(ctx, scene_where, nodes, order, plans)

    buffers = load_buffers(ctx, doc, bin_chunk)
    decode_meshopt_views(ctx, doc, buffers)
    materials, textures = parse_materials(ctx, doc, buffers)
    skins = parse_skins(ctx, doc, buffers)
    geo = flatten(ctx, nodes, order, plans, buffers, skins, default_material=len(materials))
    if geo.uses_default_material:
        materials.append(Material(name="default", base_color_factor=np.array(
            [DEFAULT_GREY, DEFAULT_GREY, DEFAULT_GREY, 1.0])))
    lights = parse_lights(ctx, doc, nodes, node_light, order)
    animations = parse_animations(ctx, doc, buffers)
    return Scene(
        source=ctx.file, positions=geo.positions, normals=geo.normals, uv0=geo.uv0,
        uv1=geo.uv1, faces=geo.faces, face_material=geo.face_material,
        face_instance=geo.face_instance, materials=tuple(materials), textures=tuple(textures),
        lights=lights, nodes=tuple(nodes), instances=geo.instances, animations=animations,
        skins=tuple(skins), has_uv0=geo.has_uv0, warnings=tuple(ctx.warnings),
    )


def _precount_obj(data: bytes) -> tuple[int, int]:
    """(vertices, triangles) an OBJ declares, counted from its ``v`` and ``f`` lines."""
    verts = tris = 0
    for line in data.splitlines():
        if line.startswith(b"v "):
            verts += 1
        elif line.startswith(b"f "):
            tris += max(len(line.split()) - 3, 0)
    return verts, tris


def _precount_ply(ctx: Ctx, data: bytes) -> tuple[int, int]:
    """(vertices, faces) declared by a PLY header."""
    end = data.find(b"end_header", 0, 1 << 16)
    if not data.startswith(b"ply") or end < 0:
        raise ctx.fail("header", "not a PLY file (no 'ply' ... 'end_header' header)")
    counts = {}
    for line in data[:end].splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0] == b"element":
            if not parts[2].isdigit():
                raise ctx.fail("header", f"bad element count {parts[2][:20]!r}")
            counts[parts[1]] = int(parts[2])
    return counts.get(b"vertex", 0), counts.get(b"face", 0)


def load_trimesh_asset(ctx: Ctx, data: bytes, kind: str) -> Scene:
    """OBJ/PLY through trimesh: one flattened mesh, one default grey material, trimesh's
    vertex normals, uv0 (flipped to glTF's top-left origin) when the file has UVs.

    Loaded from memory without a resolver, so ``mtllib``/texture references are never
    followed. Declared vertex/face counts are checked against the limits first.
    """
    import trimesh

    verts, tris = _precount_obj(data) if kind == "obj" else _precount_ply(ctx, data)
    if verts > ctx.limits.max_vertices:
        raise ctx.over("vertices", f"{verts} vertices", "max_vertices")
    if tris > ctx.limits.max_triangles:
        raise ctx.over("faces", f"at least {tris} triangles", "max_triangles")
    ctx.where = "mesh"
    mesh = trimesh.load(io.BytesIO(data), file_type=kind, force="mesh", process=False)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ctx.fail("faces", "no triangles")
    if len(mesh.faces) > ctx.limits.max_triangles:
        raise ctx.over("faces", f"{len(mesh.faces)} triangles", "max_triangles")
    positions = np.asarray(mesh.vertices, dtype=np.float64)
    if not np.isfinite(positions).all():
        bad = "NaN" if np.isnan(positions).any() else "Inf"
        raise ctx.fail("vertices", f"contains {bad}")
    faces = np.asarray(mesh.faces, dtype=np.int64)
    normals = normalize_rows(np.asarray(mesh.vertex_normals, dtype=np.float64))
    uv = getattr(mesh.visual, "uv", None)
    nv = len(positions)
    uv0 = has_uv0 = None
    if uv is not None and np.shape(uv) == (nv, 2) and np.isfinite(uv).all():
        uv0 = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]).astype(np.float64)
        has_uv0 = np.ones(nv, dtype=bool)
    grey = Material(name="default",
                    base_color_factor=np.array([DEFAULT_GREY, DEFAULT_GREY, DEFAULT_GREY, 1.0]))
    return single_mesh_scene(ctx.file, positions, normals, faces, grey, uv0=uv0,
                             has_uv0=has_uv0, warnings=tuple(ctx.warnings))


def _read_asset_file(ctx: Ctx, path: str) -> bytes:
    try:
        st = os.stat(path)
    except OSError as e:
        raise ctx.fail("", f"cannot read asset: {e.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        raise ctx.fail("", "is not a regular file")
    if st.st_size > ctx.limits.max_file_bytes:
        raise ctx.over("", f"file of {st.st_size} bytes", "max_file_bytes")
    with open(path, "rb") as f:
        return f.read(ctx.limits.max_file_bytes + 1)


def load_asset(path: str | os.PathLike, limits: IntakeLimits | None = None) -> Scene:
    """Load a ``.glb``/``.gltf`` (external buffers/images next to it) or ``.obj``/``.ply``
    into a flattened world-space :class:`Scene`; an ``.sdf.json`` SDF scene gives its
    marching-cubes mesh (:mod:`prtcore.io.sdf`).

    limits : intake limits, checked before allocation (default
        :meth:`IntakeLimits.from_env`).

    Raises :class:`AssetError` (:class:`LimitExceeded`, :class:`UnsupportedAsset`) with a
    one-line message naming the file, the glTF path and the limit.
    """
    limits = IntakeLimits.from_env() if limits is None else limits
    file = os.fspath(path)
    ctx = Ctx(file=file, folder=os.path.realpath(os.path.dirname(os.path.abspath(file))),
              limits=limits)
    suffix = os.path.splitext(file)[1].lower()
    if is_sdf_file(file):  # analytic SDF scene: its marching-cubes mesh (prtcore.io.sdf)
        return sdf_mesh_scene(load_sdf(file), file)
    if suffix not in (".glb", ".gltf", ".obj", ".ply"):
        raise UnsupportedAsset(file, "", f"unsupported file type {suffix or '(none)'!r} "
                                         "(expected .glb, .gltf, .obj, .ply or .sdf.json)")
    try:
        data = _read_asset_file(ctx, file)
        if suffix in (".glb", ".gltf"):
            return load_gltf(ctx, data)
        return load_trimesh_asset(ctx, data, suffix[1:])
    except PrtError:
        raise
    except MemoryError:
        raise
    except Exception as e:
        detail = f"{type(e).__name__}: {e}"
        raise AssetError(file, ctx.where, f"malformed asset ({detail[:160]})") from e
