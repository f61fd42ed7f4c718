"""Geometric rules used by every stage: one definition each.

* :func:`shading_normals` — the shading normal at a surface point (texels, measurement
  points, keyframe poses, the near field, the path tracer and the GLSL renderer all follow
  this rule);
* :func:`face_normals` — unit geometric normals of triangles;
* :func:`orthonormal_frame` — tangents completing a unit normal to a frame;
* :func:`directions_around` — directions at given polar angles about axes.
"""

from __future__ import annotations

import numpy as np

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
    Returns (n, 3) float64.
    """
    gn = face_normals(scene, triangle) if geometric is None else geometric
    ns = np.einsum("nk,nkj->nj", barycentric, scene.normals[scene.faces[triangle]])
    ln = np.linalg.norm(ns, axis=1)
    ok = (ln > NORMAL_EPS) & (np.einsum("ij,ij->i", ns, gn) > 0)
    out = np.array(gn, dtype=np.float64, copy=True)
    out[ok] = ns[ok] / ln[ok, None]
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
