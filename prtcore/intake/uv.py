"""Lightmap UVs (TEXCOORD_1): the atlas check and generation with xatlas.

Conventions (docs/bundle.md): texel (x, y) of a W × W atlas, y counted from the image's top
row, is the square [x, x+1] × [y, y+1] in *texel units* ``TEXCOORD_1 × W`` and has its
centre at TEXCOORD_1 = ((x + 0.5) / W, (y + 0.5) / W). xatlas lays charts out in the same
texel units (its image row y is our row y), so its output is used without any flip.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass

import numpy as np

from prtcore.core.errors import AssetError, SpecError
from prtcore.core.scene import Scene
from prtcore.core.tolerances import DEGENERATE_AREA_REL, UV_TEXEL_EPS, WELD_DISTANCE_REL
from prtcore.core.uvraster import expand_spans, raster_spans, span_blocks
from prtcore.intake.mesh import (
    assemble,
    instance_spans,
    quantise,
    row_ids,
    scene_scale,
    take_part,
    weld_ids,
)

# ---------------------------------------------------------------------------------------
# UV checks: charts, rasterisation (:mod:`prtcore.core.uvraster`), gaps


def _chart_texels(tri: np.ndarray, chart: np.ndarray, size: int, half: float,
                  block: int = 1 << 22) -> tuple[int, int]:
    """(texels hit, texels hit by 2+ charts) for triangles ``tri`` labelled ``chart``."""
    cmin = np.full(size * size, np.iinfo(np.int32).max, dtype=np.int32)
    cmax = np.full(size * size, -1, dtype=np.int32)
    c32 = chart.astype(np.int32)
    for f, y, x0, x1 in raster_spans(tri, size, size, half):
        for sl in span_blocks(x0, x1, block):  # bound the expanded size
            ff, t = expand_spans(f[sl], y[sl], x0[sl], x1[sl], size)
            np.minimum.at(cmin, t, c32[ff])
            np.maximum.at(cmax, t, c32[ff])
    hit = cmax >= 0
    return int(hit.sum()), int((hit & (cmax > cmin)).sum())


@dataclass(frozen=True)
class UVCheck:
    """Is TEXCOORD_1 usable as a lightmap atlas at ``resolution`` × ``resolution``?

    present : the scene has TEXCOORD_1; valid : usable as is; reason : one line, the first
        failed criterion ("missing", "out of range", "overlap", "collapsed", "padding") or
        "valid: …"
    out_of_range : vertices (used by faces) whose TEXCOORD_1 is outside [0, 1] or not finite
    overlapping_texels : texels that the conservative rasterisations of 2+ charts touch
    min_padding_texels : smallest distance between two charts, in texels (exact, from the
        chart boundaries; 0.0 when charts share texels; None with fewer than two charts)
    utilisation : covered texels (conservative) / resolution²
    texel_density : sqrt(UV area in texels² / world area in m²), texels per metre
    charts : connected components of triangles sharing a corner (same TEXCOORD_1 and same
        welded position, so instanced copies with identical UVs are separate charts)
    folded_edges : UV edges whose two triangles lie on the same side (a chart folding over
        itself; counts as overlap)
    collapsed_faces : triangles with ~zero UV area (< UV_TEXEL_EPS² texels²) that should
        cover ≥ ¼ texel at the texel density of the other faces (all non-degenerate faces
        when no face has UV area)
    bleeding_texels : texels that bilinear lookups of 2+ charts read (footprint = texels
        whose centre is within one texel, per axis, of the chart); nonzero means charts
        are too close for bilinear filtering. Zero implies a gap ≥ 1 texel.
    """

    present: bool
    valid: bool
    reason: str
    out_of_range: int = 0
    overlapping_texels: int = 0
    min_padding_texels: float | None = None
    utilisation: float = 0.0
    texel_density: float = 0.0
    charts: int = 0
    folded_edges: int = 0
    collapsed_faces: int = 0
    bleeding_texels: int = 0
    resolution: int = 0
    padding: int = 0


def _uv_keys(scene: Scene, uv_t: np.ndarray) -> np.ndarray:
    """(v,) int64 corner identity: same quantised TEXCOORD_1 and same welded position."""
    q = quantise(np.clip(np.nan_to_num(uv_t), -1e9, 1e9), UV_TEXEL_EPS)
    pid = weld_ids(scene.positions, WELD_DISTANCE_REL * scene_scale(scene))
    return row_ids(np.column_stack([q, pid]))


def _charts(faces_k: np.ndarray, nkeys: int) -> tuple[np.ndarray, int]:
    """(f,) chart label of each face from its corner keys (f, 3), and the chart count."""
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    nf = len(faces_k)
    rows = np.repeat(np.arange(nf), 3)
    cols = nf + faces_k.reshape(-1)
    g = sparse.coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)),
                          shape=(nf + nkeys, nf + nkeys))
    _, labels = connected_components(g, directed=False)
    _, chart = np.unique(labels[:nf], return_inverse=True)
    chart = chart.reshape(-1).astype(np.int64)
    return chart, int(chart.max() + 1) if nf else 0


def _edge_table(fk: np.ndarray):
    """Half-edges of faces with corner keys fk (f, 3): canonical (lo, hi) key order.

    Returns face (3f,), corner index of the lo end (3f,), of the hi end (3f,), of the
    opposite corner (3f,), edge id (3f,), count per edge id.
    """
    nf = len(fk)
    i0 = np.repeat(np.array([[0, 1, 2]]), nf, axis=0).T.reshape(-1)   # corner a
    i1 = (i0 + 1) % 3
    i2 = (i0 + 2) % 3
    face = np.tile(np.arange(nf), 3)
    ka, kb = fk[face, i0], fk[face, i1]
    swap = ka > kb
    lo_c = np.where(swap, i1, i0)
    hi_c = np.where(swap, i0, i1)
    klo, khi = np.minimum(ka, kb), np.maximum(ka, kb)
    code = klo * (int(fk.max()) + 1) + khi
    _, eid, counts = np.unique(code, return_inverse=True, return_counts=True)
    return face, lo_c, hi_c, i2, eid.reshape(-1), counts


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n,) distances from points p (n, 2) to segments [a, b] (n, 2)."""
    d = b - a
    dd = (d * d).sum(1)
    t = np.divide(((p - a) * d).sum(1), dd, out=np.zeros(len(p)), where=dd > 0)
    q = a + np.clip(t, 0.0, 1.0)[:, None] * d
    return np.linalg.norm(p - q, axis=1)


def _min_gap(seg_a: np.ndarray, seg_b: np.ndarray, seg_chart: np.ndarray,
             radius: float) -> float | None:
    """Smallest distance between boundary segments of different charts, if ≤ ``radius``.

    seg_a, seg_b : (e, 2) texel-unit endpoints; seg_chart : (e,) chart of each segment.
    For disjoint charts the minimum is reached at an endpoint of one boundary against a
    segment of the other, so endpoints are queried against segment pieces of length ≤ L
    (a KD-tree on piece midpoints finds every piece within radius + L / 2).
    """
    from scipy.spatial import cKDTree

    if len(seg_a) == 0:
        return None
    piece = max(1.0, radius / 2.0)
    length = np.linalg.norm(seg_b - seg_a, axis=1)
    m = np.maximum(np.ceil(length / piece), 1).astype(np.int64)
    owner = np.repeat(np.arange(len(seg_a)), m)
    j = np.arange(m.sum()) - np.repeat(np.cumsum(m) - m, m)
    t0, t1 = j / m[owner], (j + 1) / m[owner]
    d = (seg_b - seg_a)[owner]
    pa = seg_a[owner] + t0[:, None] * d
    pb = seg_a[owner] + t1[:, None] * d
    pchart = seg_chart[owner]
    tree = cKDTree(0.5 * (pa + pb))
    pts = np.concatenate([seg_a, seg_b])
    pts_chart = np.concatenate([seg_chart, seg_chart])
    pts = np.unique(np.column_stack([pts, pts_chart]), axis=0)
    pts_chart = pts[:, 2].astype(np.int64)
    pts = pts[:, :2]
    best = np.inf
    step = 1 << 15
    for s in range(0, len(pts), step):
        sub = cKDTree(pts[s:s + step])
        pairs = sub.sparse_distance_matrix(tree, radius + 0.5 * piece, output_type="ndarray")
        if len(pairs) == 0:
            continue
        i = pairs["i"].astype(np.int64) + s
        k = pairs["j"].astype(np.int64)
        other = pts_chart[i] != pchart[k]
        if not other.any():
            continue
        i, k = i[other], k[other]
        dist = _point_segment_distance(pts[i], pa[k], pb[k])
        best = min(best, float(dist.min()))
    return best if best <= radius else None


def check_uv1(scene: Scene, resolution: int, padding: int) -> UVCheck:
    """Check TEXCOORD_1 as a lightmap atlas of ``resolution`` × ``resolution`` texels.

    Valid means, in this order: present; every TEXCOORD_1 used by a face inside [0, 1];
    no texel touched by the conservative rasterisations of two charts and no chart folding
    over itself ("overlap"); no triangle that should cover texels collapsed to zero UV
    area ("collapsed"); no texel read by bilinear lookups of two charts ("padding": charts
    closer than bilinear filtering allows, which also guarantees a gap of at least one
    texel). Triangles sharing a UV edge or corner belong to the same chart and may share
    texels. The measured minimum gap between charts is reported; a gap below the requested
    ``padding`` is mentioned in the reason but does not invalidate the atlas.

    Vectorised: (triangle, texel) pairs over each triangle's footprint bounding box in
    bounded chunks (100k triangles at 1024² take a few seconds on one core).
    """
    R = int(resolution)
    gap_cap = float(max(4.0, 2.0 * padding + 2.0))  # first gap search radius, texels
    if scene.uv1 is None:
        return UVCheck(present=False, valid=False, reason="TEXCOORD_1 missing",
                       resolution=R, padding=int(padding))
    faces = scene.faces
    nf = len(faces)
    uv_t = np.asarray(scene.uv1, dtype=np.float64) * R
    used = np.zeros(len(uv_t), dtype=bool)
    used[faces.reshape(-1)] = True
    tol = UV_TEXEL_EPS
    finite = np.isfinite(uv_t).all(axis=1)
    inside = finite & (uv_t >= -tol).all(axis=1) & (uv_t <= R + tol).all(axis=1)
    out_of_range = int((used & ~inside).sum())

    # charts, folds, boundary segments
    keys = _uv_keys(scene, uv_t)
    fk = keys[faces] if nf else np.zeros((0, 3), np.int64)
    chart, n_charts = _charts(fk, int(keys.max()) + 1 if len(keys) else 0) if nf else \
        (np.zeros(0, np.int64), 0)
    tri = uv_t[faces] if nf else np.zeros((0, 3, 2))
    tri = np.nan_to_num(tri)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    folded = 0
    seg_a = seg_b = np.zeros((0, 2))
    seg_chart = np.zeros(0, np.int64)
    if nf:
        face, lo_c, hi_c, op_c, eid, ecount = _edge_table(fk)
        pa, pb, pc = tri[face, lo_c], tri[face, hi_c], tri[face, op_c]
        cr = (pb - pa)[:, 0] * (pc - pa)[:, 1] - (pb - pa)[:, 1] * (pc - pa)[:, 0]
        side = np.where(np.abs(cr) > 1e-9, np.sign(cr), 0.0)
        two = ecount[eid] == 2
        order = np.argsort(eid[two], kind="stable")
        s2 = side[two][order].reshape(-1, 2)
        folded = int(((s2[:, 0] == s2[:, 1]) & (s2[:, 0] != 0)).sum())
        bnd = ecount[eid] == 1
        seg_a, seg_b, seg_chart = pa[bnd], pb[bnd], chart[face[bnd]]

    # rasterise in-range triangles: conservative (0.5) and bilinear footprint (1.0)
    tri_ok = inside[faces].all(axis=1) if nf else np.zeros(0, bool)
    covered, overlapping = _chart_texels(tri[tri_ok], chart[tri_ok], R, 0.5)
    _, bleeding = _chart_texels(tri[tri_ok], chart[tri_ok], R, 1.0)

    world = scene.face_areas() if nf else np.zeros(0)
    world_total = float(world.sum())
    density = float(np.sqrt(uv_area.sum() / world_total)) if world_total > 0 else 0.0
    flat = uv_area < UV_TEXEL_EPS ** 2
    if (~flat).any() and world[~flat].sum() > 0:  # density of the faces that have UV area
        ref = float(np.sqrt(uv_area[~flat].sum() / world[~flat].sum()))
        collapsed = int((flat & (world * ref ** 2 >= 0.25)).sum())
    else:  # nothing has UV area: every face with world area is collapsed
        scale = scene_scale(scene)
        collapsed = int((flat & (world > DEGENERATE_AREA_REL * scale * scale)).sum())

    if n_charts < 2:
        gap = None
    elif overlapping:
        gap = 0.0
    else:  # search near first (cheap), then farther until some other chart is found
        radius, gap = gap_cap, None
        while gap is None and len(seg_a):
            gap = _min_gap(seg_a, seg_b, seg_chart, radius)
            if radius > 2.0 * R:
                break
            radius *= 4.0
    util = covered / float(R * R)
    if out_of_range:
        reason = f"out of range: {out_of_range} TEXCOORD_1 values outside [0, 1]"
    elif overlapping:
        reason = f"overlap: {overlapping} texels claimed by 2+ charts"
    elif folded:
        reason = f"overlap: {folded} UV edges where a chart folds over itself"
    elif collapsed:
        reason = f"collapsed: {collapsed} triangles have zero UV area"
    elif bleeding:
        reason = (f"padding: {bleeding} texels read by 2+ charts under bilinear filtering "
                  f"(min gap {gap:.2f} texels)")
    else:
        gap_txt = "n/a" if gap is None else f"{gap:.2f}"
        reason = (f"valid: {n_charts} charts, min gap {gap_txt} texels, "
                  f"utilisation {util:.0%}")
        if gap is not None and gap < padding:
            reason += f" (gap below requested padding {padding})"
    valid = not (out_of_range or overlapping or folded or collapsed or bleeding)
    return UVCheck(present=True, valid=valid, reason=reason, out_of_range=out_of_range,
                   overlapping_texels=overlapping, min_padding_texels=gap, utilisation=util,
                   texel_density=density, charts=n_charts, folded_edges=folded,
                   collapsed_faces=collapsed, bleeding_texels=bleeding, resolution=R,
                   padding=int(padding))


# ---------------------------------------------------------------------------------------
# UV generation (xatlas, in a child process)

#: Fraction of the atlas area the packer is first asked to fill (bounding boxes of charts
#: plus their padding); the search then grows or shrinks texels-per-metre until the charts
#: just fit in one atlas.
_PACK_FILL = 0.75
_PACK_TRIES = 24
#: Stop the search when the largest fitting and smallest failing scales are this close.
_PACK_PRECISION = 1.03


def _chart_boxes(atlas, k: int, indices: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(c, 2) width/height of the charts of mesh ``k`` of an xatlas atlas (uv (v, 2))."""
    boxes = []
    for c in range(atlas.get_mesh_chart_count(k)):
        corners = uv[indices[np.asarray(atlas.get_mesh_chart(k, c).faces, np.int64)]]
        corners = corners.reshape(-1, 2)
        if len(corners):
            boxes.append(corners.max(axis=0) - corners.min(axis=0))
    return np.array(boxes).reshape(-1, 2)


def _xatlas_solve(meshes: list[tuple[np.ndarray, np.ndarray, np.ndarray]], resolution: int,
                  padding: int) -> dict:
    """Chart once, then pack into exactly one ``resolution``² atlas (runs in the child).

    meshes : per instance (positions (v, 3) float32, faces (f, 3) uint32, normals (v, 3)
    float32). Charts are computed with default ChartOptions; packing (bilinear=True,
    padding) is repeated on the fixed charts (as UV meshes) while searching the largest
    texels-per-unit that fits in a single atlas of exactly ``resolution``².
    Returns {"fits", "vmap_k", "faces_k", "uv_k" (normalised), "charts", "tpu", "packs",
    "utilization"}.
    """
    import xatlas

    area = 0.0
    for p, f, _ in meshes:
        t = p[f].astype(np.float64)
        area += 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum()
    tpu0 = float(np.sqrt(0.5 * resolution ** 2 / max(area, 1e-300)))
    atlas = xatlas.Atlas()
    for p, f, n in meshes:
        atlas.add_mesh(p, f, normals=n)
    po = xatlas.PackOptions()
    po.resolution = 0
    po.padding = 0
    po.bilinear = False
    po.texels_per_unit = tpu0
    atlas.generate(xatlas.ChartOptions(), po)
    first = [atlas.get_mesh(k) for k in range(len(meshes))]
    wA, hA = atlas.width, atlas.height
    unit_uv = [uv.astype(np.float64) * [wA, hA] / tpu0 for _, _, uv in first]
    boxes = np.concatenate([_chart_boxes(atlas, k, first[k][1].astype(np.int64), unit_uv[k])
                            for k in range(len(first))])
    n_charts = len(boxes)
    g = padding + 3.0
    A = float((boxes[:, 0] * boxes[:, 1]).sum())
    B = float(g * boxes.sum())
    C = n_charts * g * g - _PACK_FILL * resolution ** 2
    if A > 0:
        t = (-B + np.sqrt(max(B * B - 4 * A * C, 0.0))) / (2 * A)
    else:
        t = tpu0
    t = float(t) if t > 0 else tpu0 * 1e-3

    def pack(tpu):
        a = xatlas.Atlas()
        for (_, idx, _), uv in zip(first, unit_uv, strict=True):
            a.add_uv_mesh(np.ascontiguousarray(uv, np.float32),
                          np.ascontiguousarray(idx, np.uint32))
        p = xatlas.PackOptions()
        p.resolution = int(resolution)
        p.padding = int(padding)
        p.bilinear = True
        p.texels_per_unit = float(tpu)
        a.generate(xatlas.ChartOptions(), p)
        ok = a.atlas_count == 1 and a.width == resolution and a.height == resolution
        return ok, a

    packs = 0
    fit_t, fit_atlas, fail_t = None, None, None
    if n_charts * (padding + 1) ** 2 > resolution ** 2:  # padding alone cannot fit
        return {"fits": False, "charts": n_charts, "packs": 0, "tpu": 0.0}
    while packs < _PACK_TRIES:
        ok, a = pack(t)
        packs += 1
        if ok:
            fit_t, fit_atlas = t, a
        else:
            fail_t = t
        if fit_t is None:
            if t * float(boxes.max(initial=0.0)) < 0.5:  # charts already below a texel
                break
            t *= 0.8
        elif fail_t is None:
            t *= 1.25
        elif fail_t / fit_t < _PACK_PRECISION:
            break
        else:
            t = float(np.sqrt(fit_t * fail_t))
    out: dict = {"fits": fit_atlas is not None, "charts": n_charts, "packs": packs,
                 "tpu": fit_t if fit_t is not None else t}
    if fit_atlas is None:
        return out
    out["utilization"] = float(fit_atlas.get_utilization(0))
    for k, (vmA, _, _) in enumerate(first):
        vm, idx, uv = fit_atlas.get_mesh(k)
        out[f"vmap_{k}"] = vmA.astype(np.int64)[vm.astype(np.int64)]
        out[f"faces_{k}"] = idx.astype(np.int64)
        out[f"uv_{k}"] = uv.astype(np.float64)
    return out


#: Runs of the xatlas child before an asset is refused, when it is killed by a signal or
#: does not finish in time.
XATLAS_TRIES = 2
#: How long one xatlas child may run: this plus :data:`XATLAS_SECONDS_PER_TRIANGLE` per
#: triangle. Its worker threads have deadlocked once (a child asleep on a futex for 12
#: minutes, at no CPU, during a test run; the same input mapped at once when it was run
#: again), and a bake or a service worker then waited for ever. An 82k-triangle mesh maps
#: in 27 s on this 2-core machine (0.3 ms a triangle), so the limit is 10× that, plus a
#: minute.
XATLAS_SECONDS = 60.0
XATLAS_SECONDS_PER_TRIANGLE = 3e-3


def _xatlas_child(inp: str, outp: str) -> None:
    """Entry point of the child process: read meshes from ``inp`` (npz), write ``outp``."""
    data = np.load(inp)
    n = int(data["count"])
    meshes = [(data[f"p{k}"], data[f"f{k}"], data[f"n{k}"]) for k in range(n)]
    res = _xatlas_solve(meshes, int(data["resolution"]), int(data["padding"]))
    np.savez(outp, **{k: np.asarray(v) for k, v in res.items()})


def _run_xatlas(source: str, meshes, resolution: int, padding: int) -> dict:
    """Run :func:`_xatlas_solve` in a child Python process.

    xatlas crashes (segfaults) on some inputs (e.g. a perfectly regular 80k-triangle
    icosphere); isolating it turns a crash into an :class:`AssetError` instead of killing
    the CLI or a service worker. It has also died by a signal, once, on an input it maps
    every other time (the bundled Cornell box, during a benchmark: its worker threads
    race), so a child killed by a signal is run :data:`XATLAS_TRIES` times in all before
    the asset is refused; a child that exits with an error is not retried. A child that
    has not finished after :data:`XATLAS_SECONDS` + :data:`XATLAS_SECONDS_PER_TRIANGLE` per
    triangle is killed and counts as one of those runs.
    """
    pkg_root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with tempfile.TemporaryDirectory(prefix="prt-xatlas-") as tmp:
        inp, outp = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.npz")
        arrays = {"count": np.array(len(meshes)), "resolution": np.array(resolution),
                  "padding": np.array(padding)}
        for k, (p, f, n) in enumerate(meshes):
            arrays[f"p{k}"], arrays[f"f{k}"], arrays[f"n{k}"] = p, f, n
        np.savez(inp, **arrays)
        env = dict(os.environ)
        env["PYTHONPATH"] = pkg_root + (os.pathsep + env["PYTHONPATH"]
                                        if env.get("PYTHONPATH") else "")
        limit = XATLAS_SECONDS + XATLAS_SECONDS_PER_TRIANGLE * sum(
            len(f) for _, f, _ in meshes)
        for _ in range(XATLAS_TRIES):
            try:
                proc = subprocess.run([sys.executable, "-m", "prtcore.intake.uv",
                                       "--xatlas", inp, outp],
                                      capture_output=True, env=env, check=False,
                                      timeout=limit)
            except subprocess.TimeoutExpired:  # killed by run(); tried again
                proc = None
                continue
            if proc.returncode >= 0:  # done, or failed by itself: the same again
                break
        if proc is None:
            raise AssetError(source, "TEXCOORD_1", f"xatlas did not finish generating "
                             f"lightmap UVs in {limit:.0f} s ({XATLAS_TRIES} tries); supply "
                             "a valid TEXCOORD_1 or try prepare.remesh")
        if proc.returncode != 0 or not os.path.exists(outp):
            tail = proc.stderr.decode("utf-8", "replace").strip().splitlines()
            detail = f"exit status {proc.returncode}" + (f", {tail[-1][:120]}" if tail else "")
            raise AssetError(source, "TEXCOORD_1", f"xatlas failed to generate lightmap UVs "
                             f"({detail}); supply a valid TEXCOORD_1 or try prepare.remesh")
        with np.load(outp) as d:
            return {k: d[k] for k in d.files}


def generate_uv1(scene: Scene, resolution: int, padding: int, seed: int = 0) -> Scene:
    """Generate TEXCOORD_1 with xatlas: one shared atlas of exactly ``resolution``².

    Every instance is added to one xatlas atlas as its own mesh (world positions, so the
    texel density is uniform across instances; world normals, so hard edges become
    seams). Charts are computed once with default ChartOptions; packing uses
    ``padding`` texels and ``bilinear=True`` and searches the largest texels-per-metre
    that fits everything into a single atlas of exactly resolution × resolution.
    Each instance's per-vertex arrays (and its object positions/normals, joints, weights)
    are re-indexed by xatlas's vertex mapping (vertices on seams are duplicated); face order
    is kept. TEXCOORD_1 = xatlas texel coordinates / resolution, no flip (see module doc).

    xatlas is deterministic for a given input, so ``seed`` is not needed; it is accepted for
    API symmetry. Raises :class:`SpecError` (atlas.resolution) when the charts cannot fit
    even at a tiny scale, :class:`AssetError` when xatlas fails.
    """
    del seed  # xatlas has no random state of its own to seed (fixed internal RNG)
    spans = instance_spans(scene)
    meshes, which = [], []
    # xatlas sees the scene centred and divided by its radius: its charting and packing
    # have absolute thresholds, so world units made the atlas depend on the scene's scale
    # (11 % fewer covered texels for the Cornell box in millimetres; tests/stability)
    centre = np.asarray(scene.center, np.float64) if len(scene.positions) else np.zeros(3)
    unit = 1.0 / scene_scale(scene)
    for k, (v0, v1, f0, f1) in enumerate(spans):
        if f1 > f0:
            meshes.append((np.ascontiguousarray((scene.positions[v0:v1] - centre) * unit,
                                                np.float32),
                           np.ascontiguousarray(scene.faces[f0:f1] - v0, np.uint32),
                           np.ascontiguousarray(scene.normals[v0:v1], np.float32)))
            which.append(k)
    if not meshes:
        raise AssetError(scene.source, "", "no triangles to generate TEXCOORD_1 for")
    res = _run_xatlas(scene.source, meshes, int(resolution), int(padding))
    if not bool(res["fits"]):
        raise SpecError("atlas.resolution", f"{int(res['charts'])} UV charts do not fit in a "
                        f"{resolution}×{resolution} atlas with padding {padding}; raise the "
                        "resolution or lower the padding")
    parts = []
    slot = {k: j for j, k in enumerate(which)}
    for k, span in enumerate(spans):
        inst = scene.instances[k] if scene.instances else None
        if k not in slot:
            parts.append(take_part(scene, span, inst, np.zeros(0, np.int64),
                                    np.zeros((0, 3), np.int64), np.zeros((0, 2))))
            continue
        j = slot[k]
        vmap, faces, uv = res[f"vmap_{j}"], res[f"faces_{j}"], res[f"uv_{j}"]
        if len(faces) != span[3] - span[2]:
            raise AssetError(scene.source, f"instances[{k}]",
                             f"xatlas returned {len(faces)} faces for {span[3] - span[2]}")
        parts.append(take_part(scene, span, inst, vmap, faces, uv))
    return assemble(scene, parts, with_uv1=True)



if __name__ == "__main__":  # the xatlas child process (see _run_xatlas)
    if len(sys.argv) == 4 and sys.argv[1] == "--xatlas":
        _xatlas_child(sys.argv[2], sys.argv[3])
    else:
        sys.exit("usage: python -m prtcore.intake.uv --xatlas IN.npz OUT.npz")

