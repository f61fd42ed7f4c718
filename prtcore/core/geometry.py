"""Geometric rules used by every stage: one definition each.

* :func:`shading_normals` — the shading normal at a surface point (texels, measurement
  points, keyframe poses, the near field, the path tracers and the GLSL renderer all follow
  this rule; the GLSL renderers do not apply normal maps);
* :func:`uv_tangent_frames` — the tangent frame a normal map is read in;
* :func:`face_normals` — unit geometric normals of triangles;
* :func:`orthonormal_frame` — tangents completing a unit normal to a frame;
* :func:`directions_around` — directions at given polar angles about axes.
"""

from __future__ import annotations

import math

import numpy as np

from prtcore.core.materials import tangent_space_normals, texcoords
from prtcore.core.scene import Scene
from prtcore.core.tolerances import NORMAL_EPS


def face_normals(scene: Scene, triangle: np.ndarray) -> np.ndarray:
    """Unit geometric normals (n, 3) float64 of triangles ``triangle`` (n,) int64, by the
    winding of their corners; zero for a degenerate triangle."""
    v = scene.positions[scene.faces[triangle]]
    gn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    gl = np.linalg.norm(gn, axis=1, keepdims=True)
    return np.divide(gn, gl, out=np.zeros_like(gn), where=gl > 0)


def shading_normals(scene: Scene, triangle: np.ndarray, barycentric: np.ndarray,
                    geometric: np.ndarray | None = None) -> np.ndarray:
    """The shading normal at surface points: the rule every stage uses.

    triangle : (n,) int64; barycentric : (n, 3) float64; geometric : (n, 3) float64 unit
    geometric normals of those triangles (computed by :func:`face_normals` when omitted).
    The interpolated vertex normal, normalised; the geometric normal where the interpolated
    one is degenerate (length ≤ NORMAL_EPS) or does not point into the front hemisphere of
    its face (a shading normal never faces away from the surface it shades).

    Where the face's material has a normal map (``Material.normal_texture``), that
    normal is then perturbed by the map in the tangent frame of
    :func:`uv_tangent_frames`; the perturbed normal is kept only where it too faces the
    front of the face (else the unperturbed one). Materials without a normal map are
    untouched. Ray origins still move along the *geometric* normal
    (:func:`prtcore.core.tolerances.offset_origins`): normal maps change shading only.
    Returns (n, 3) float64.
    """
    gn = face_normals(scene, triangle) if geometric is None else geometric
    ns = np.einsum("nk,nkj->nj", barycentric, scene.normals[scene.faces[triangle]])
    ln = np.linalg.norm(ns, axis=1)
    ok = (ln > NORMAL_EPS) & (np.einsum("ij,ij->i", ns, gn) > 0)
    out = np.array(gn, dtype=np.float64, copy=True)
    out[ok] = ns[ok] / ln[ok, None]
    mapped = [i for i, m in enumerate(scene.materials) if m.normal_texture >= 0]
    if mapped and len(triangle):
        mat_of = scene.face_material[triangle]
        for m in mapped:
            sel = np.flatnonzero(mat_of == m)
            if len(sel):
                out[sel] = _normal_mapped(scene, m, triangle[sel], barycentric[sel],
                                          out[sel], gn[sel])
    return out


def uv_tangent_frames(scene: Scene, triangle: np.ndarray, texcoord: int,
                      normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangent frames (t, b), each (n, 3) float64 unit, for a normal map read through UV
    set ``texcoord`` on triangles ``triangle`` (n,) around unit shading ``normals`` (n, 3).

    Generated per triangle from its UVs (the TANGENT attribute is not read): ``t`` is
    ∂P/∂u, ``b`` points up the image, i.e. −∂P/∂v (glTF v runs down the image), both from
    solving the triangle's two edges in UV; ``t`` is then made orthogonal to the normal
    (Gram–Schmidt) and ``b = w · n × t`` with the handedness ``w = sign((n × t) · b)``, the
    construction MikkTSpace makes per triangle (without its per-vertex averaging, which
    matters only where one UV chart bends across triangles). A triangle whose UVs are
    degenerate gets :func:`orthonormal_frame` of the normal.
    """
    p = scene.positions[scene.faces[triangle]]
    uv = texcoords(scene, texcoord)[scene.faces[triangle]]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    good = np.abs(det) > NORMAL_EPS
    safe = np.where(good, det, 1.0)[:, None]
    dpdu = (d2[:, 1, None] * e1 - d1[:, 1, None] * e2) / safe
    dpdv = (d1[:, 0, None] * e2 - d2[:, 0, None] * e1) / safe
    t = dpdu - normals * np.einsum("ij,ij->i", normals, dpdu)[:, None]
    lt = np.linalg.norm(t, axis=1)
    good &= lt > NORMAL_EPS
    ft, _ = orthonormal_frame(normals)
    t = np.where(good[:, None], t / np.where(good, lt, 1.0)[:, None], ft)
    nxt = np.cross(normals, t)
    w = np.where(np.einsum("ij,ij->i", nxt, -dpdv) < 0.0, -1.0, 1.0)
    return t, nxt * np.where(good, w, 1.0)[:, None]


def _normal_mapped(scene: Scene, material: int, triangle: np.ndarray,
                   barycentric: np.ndarray, normals: np.ndarray, geometric: np.ndarray
                   ) -> np.ndarray:
    """``normals`` (n, 3) perturbed by material ``material``'s normal map."""
    mat = scene.materials[material]
    ts = tangent_space_normals(scene, material, triangle, barycentric)
    t, b = uv_tangent_frames(scene, triangle, mat.normal_texcoord, normals)
    m = ts[:, :1] * t + ts[:, 1:2] * b + ts[:, 2:3] * normals
    lm = np.linalg.norm(m, axis=1)
    ok = (lm > NORMAL_EPS) & (np.einsum("ij,ij->i", m, geometric) > 0)
    out = np.array(normals, dtype=np.float64, copy=True)
    out[ok] = m[ok] / lm[ok, None]
    return out


def orthonormal_frame(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (t, s), each (n, 3) float64, completing unit ``normals`` (n, 3) to a
    right-handed orthonormal basis (Duff et al. 2017, "Building an orthonormal basis,
    revisited", branchless)."""
    nx, ny, nz = normals[:, 0], normals[:, 1], normals[:, 2]
    sign = np.where(nz >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    t = np.stack([1.0 + sign * nx * nx * a, sign * b, -sign * nx], axis=1)
    s = np.stack([b, sign + ny * ny * a, -ny], axis=1)
    return t, s


def directions_around(axes: np.ndarray, cos_theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Unit directions (n, 3) at polar angle acos(cos_theta) and azimuth phi (n,) about
    unit axes (n, 3)."""
    t, s = orthonormal_frame(axes)
    sin_theta = np.sqrt(np.clip(1.0 - cos_theta * cos_theta, 0.0, None))
    d = ((sin_theta * np.cos(phi))[:, None] * t + (sin_theta * np.sin(phi))[:, None] * s
         + cos_theta[:, None] * axes)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def stratified_cosine_directions(normals: np.ndarray, strata: int, rng: np.random.Generator
                                 ) -> np.ndarray:
    """(m, strata², 3) cosine-distributed unit directions about unit ``normals`` (m, 3):
    one jittered sample per cell of a strata × strata grid on the unit square (Malley's
    method), the jitter drawn from ``rng``."""
    m = len(normals)
    s = strata * strata
    cell = np.arange(s)
    u = (np.stack([cell // strata, cell % strata], axis=1)[None, :, :]
         + rng.random((m, s, 2))) / strata
    axes = np.repeat(normals, s, axis=0)
    u = u.reshape(-1, 2)
    d = directions_around(axes, np.sqrt(np.clip(1.0 - u[:, 0], 0.0, None)),
                          2.0 * math.pi * u[:, 1])
    return d.reshape(m, s, 3)
