"""The Embree boundary: float32 rays in, float64 hit records out.

The only module that talks to embreex. Queries are split into chunks run on a thread
pool (embreex releases the GIL inside ``scene.run``), so both cores trace at once.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numba
import numpy as np
from embreex import mesh_construction, rtcore_scene

from prtcore.core.tolerances import RAY_TFAR_REL, ray_offset

#: Rays per embreex call; large enough to amortise the call, small enough to bound memory.
CHUNK = 1 << 17


def default_threads() -> int:
    """Worker threads for ray queries (``PRT_THREADS`` overrides; default: all cores)."""
    env = os.environ.get("PRT_THREADS")
    return max(1, int(env)) if env else max(1, os.cpu_count() or 1)


@numba.njit(cache=True, nogil=True)
def _hit_records(prim, u, v, tfar, d, normals, tri, t, bary, front):  # pragma: no cover
    """Embree's closest-hit outputs of one chunk (prim (n,) int32, u, v, tfar (n,) float32)
    and its directions d (n, 3) float32 → the :class:`Hits` arrays' rows (written): tri
    (n,) int64, t (n,) float64, bary (n, 3) float64, front (n,) bool against the faces'
    normals (f, 3) float64. Rounds as numpy did: (1 − u) − v; the front test's float64 dot
    product as numpy's einsum sums three terms on AVX2, (x₀y₀ + x₂y₂) + x₁y₁ (einsum's
    order is its SIMD kernel's and may differ on other CPUs; only the sign is used, which
    differs only for rays within rounding of the face's plane), no fused multiply-add.
    Compiled, releases the GIL: each ray thread converts its own chunk."""
    for i in range(len(prim)):
        p = prim[i]
        if p < 0:
            tri[i] = -1
            t[i] = np.inf
            bary[i, 0] = 0.0
            bary[i, 1] = 0.0
            bary[i, 2] = 0.0
            front[i] = False
            continue
        uu = np.float64(u[i])
        vv = np.float64(v[i])
        tri[i] = p
        t[i] = np.float64(tfar[i])
        bary[i, 0] = 1.0 - uu - vv
        bary[i, 1] = uu
        bary[i, 2] = vv
        dot = normals[p, 0] * np.float64(d[i, 0]) + normals[p, 2] * np.float64(d[i, 2])
        dot += normals[p, 1] * np.float64(d[i, 1])
        front[i] = dot < 0


@dataclass(frozen=True)
class Hits:
    """Closest hits of n rays.

    triangle : (n,) int64 face index, -1 for a miss
    t : (n,) float64 distance along the (unit) direction; inf for a miss
    barycentric : (n, 3) float64 weights of the face's vertices (rows of a miss are 0)
    front : (n,) bool — the ray hit the face's front side (against its geometric normal)
    """

    triangle: np.ndarray
    t: np.ndarray
    barycentric: np.ndarray
    front: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.triangle >= 0


class RayTracer:
    """Closest-hit and occlusion queries against one triangle mesh.

    positions : (v, 3) float (world), faces : (f, 3) int, scale : scene radius (sets the
    ray offset and the "infinite" distance, see :mod:`prtcore.core.tolerances`).
    """

    def __init__(self, positions: np.ndarray, faces: np.ndarray, scale: float,
                 threads: int | None = None):
        self.positions = np.asarray(positions, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        self.scale = float(scale)
        self.offset = ray_offset(self.scale)
        self.tfar = float(RAY_TFAR_REL * max(self.scale, 1e-30))
        self.threads = threads or default_threads()
        v = self.positions[self.faces]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        ln = np.linalg.norm(n, axis=1, keepdims=True)
        #: (f, 3) float64 unit geometric normals (zero for degenerate faces)
        self.face_normals = np.divide(n, ln, out=np.zeros_like(n), where=ln > 0)
        self._scene = rtcore_scene.EmbreeScene()
        mesh_construction.TriangleMesh(self._scene, self.positions.astype(np.float32),
                                       self.faces.astype(np.int32))
        self.rays_traced = 0
        self._count_lock = threading.Lock()  # queries may come from several threads

    # -- internals -------------------------------------------------------------------
    def _count(self, n: int) -> None:
        with self._count_lock:
            self.rays_traced += n

    def _chunks(self, n: int) -> list[slice]:
        return [slice(i, min(i + CHUNK, n)) for i in range(0, n, CHUNK)]

    def _map(self, fn, n: int) -> list:
        chunks = self._chunks(n)
        if self.threads == 1 or len(chunks) == 1:
            return [fn(s) for s in chunks]
        with ThreadPoolExecutor(self.threads) as ex:
            return list(ex.map(fn, chunks))

    @staticmethod
    def _prep(origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        return o, d

    # -- queries ---------------------------------------------------------------------
    def intersect(self, origins: np.ndarray, directions: np.ndarray,
                  tmax: np.ndarray | float | None = None) -> Hits:
        """Closest hits. origins, directions : (n, 3); directions need not be unit but
        ``t`` is reported in units of the direction's length (pass unit vectors)."""
        o, d = self._prep(origins, directions)
        n = len(o)
        tm = self._tmax(tmax, n)
        tri = np.empty(n, dtype=np.int64)
        t = np.empty(n)
        bary = np.empty((n, 3))
        front = np.empty(n, dtype=bool)

        def run(s: slice):
            res = self._scene.run(o[s], d[s], dists=tm[s].copy(), output=1)
            _hit_records(res["primID"], res["u"], res["v"], res["tfar"], d[s],
                         self.face_normals, tri[s], t[s], bary[s], front[s])

        self._map(run, n)
        self._count(n)
        return Hits(triangle=tri, t=t, barycentric=bary, front=front)

    def occluded(self, origins: np.ndarray, directions: np.ndarray,
                 tmax: np.ndarray | float | None = None) -> np.ndarray:
        """(n,) bool: something lies along the ray within (0, tmax)."""
        o, d = self._prep(origins, directions)
        n = len(o)
        tm = self._tmax(tmax, n)

        def run(s: slice):
            return self._scene.run(o[s], d[s], dists=tm[s].copy(), query="OCCLUDED")

        parts = self._map(run, n)
        self._count(n)
        if not parts:
            return np.zeros(0, dtype=bool)
        return np.concatenate(parts) != -1

    def visible(self, points: np.ndarray, normals: np.ndarray, targets: np.ndarray) -> \
            np.ndarray:
        """(n,) bool: the segment from each surface point (offset along its normal, on
        the side facing the target) to its target point is unobstructed."""
        side = np.sign(np.einsum("ij,ij->i", targets - points, normals))[:, None]
        origins = points + normals * side * self.offset
        delta = targets - origins
        dist = np.sqrt(np.einsum("ij,ij->i", delta, delta))
        dirs = np.divide(delta, dist[:, None], out=np.zeros_like(delta),
                         where=dist[:, None] > 0)
        return ~self.occluded(origins, dirs, np.maximum(dist - self.offset, 0.0))

    def unoccluded_towards(self, points: np.ndarray, normals: np.ndarray,
                           directions: np.ndarray) -> np.ndarray:
        """(n,) bool: nothing blocks the infinite ray from each surface point along
        ``directions`` (unit, pointing away from the surface toward a distant light)."""
        side = np.sign(np.einsum("ij,ij->i", directions, normals))[:, None]
        origins = points + normals * side * self.offset
        return ~self.occluded(origins, directions, self.tfar)

    def _tmax(self, tmax, n: int) -> np.ndarray:
        if tmax is None:
            return np.full(n, self.tfar, dtype=np.float32)
        tm = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (n,))
        return np.minimum(tm, self.tfar).astype(np.float32)

    def surface_point(self, triangle: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
        """(n, 3) float64 world positions of (triangle, barycentric) pairs."""
        return np.einsum("nk,nkj->nj", barycentric, self.positions[self.faces[triangle]])
