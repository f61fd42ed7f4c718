"""Analytic signed distance fields: primitives joined by a smooth union (the SDF scenes of
the learnt transfer, issue 18, docs/learnt_sh.md "SDF scenes").

A scene is a list of primitives and one smooth-union radius k; its field is the left fold

    f = smin(… smin(smin(d_0, d_1), d_2) …, d_{n−1})
    smin(a, b) = min(a, b) − h² k / 4,   h = max(k − |a − b|, 0) / k   (k = 0: min)

(Quilez's polynomial smooth minimum), negative inside. Primitives (``params`` by kind):

* ``sphere``    centre (3), radius
* ``ellipsoid`` centre (3), radii (3) — Quilez's bound, not an exact distance
* ``box``       centre (3), half_size (3), rounding (edges rounded by this radius)
* ``capsule``   a (3), b (3), radius
* ``torus``     centre (3), major, minor, axis ("x" | "y" | "z", the ring's normal)

The same fold runs in GLSL (``learnt_sh_sdf.glsl``) from :func:`packed`. Also here:
gradients by central differences (:data:`GRADIENT_STEP` × the scene's size), projection
of points onto the zero level set, sphere tracing, and marching cubes (scikit-image) to a
mesh whose vertex normals are the field's gradient.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: primitive kinds and their codes in the packed GLSL buffer
KINDS = {"sphere": 0, "ellipsoid": 1, "box": 2, "capsule": 3, "torus": 4}
AXES = {"x": 0, "y": 1, "z": 2}
#: central-difference step of the gradient, relative to the scene's bounding radius
GRADIENT_STEP = 1e-3
#: sphere tracing: a hit is a step below this × the bounding radius; at most MAX_STEPS
HIT_EPSILON = 1e-5
MAX_STEPS = 256


@dataclass(frozen=True)
class Primitive:
    """One primitive: ``kind`` (a key of :data:`KINDS`) and its parameters (module
    docstring), vectors as (3,) float64 tuples."""

    kind: str
    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 0.0
    radii: tuple[float, float, float] = (0.0, 0.0, 0.0)
    half_size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rounding: float = 0.0
    a: tuple[float, float, float] = (0.0, 0.0, 0.0)
    b: tuple[float, float, float] = (0.0, 0.0, 0.0)
    major: float = 0.0
    minor: float = 0.0
    axis: str = "y"

    def distance(self, p: np.ndarray) -> np.ndarray:
        """Signed distance (n,) float64 at points (n, 3)."""
        c = np.asarray(self.centre, np.float64)
        if self.kind == "sphere":
            return np.linalg.norm(p - c, axis=1) - self.radius
        if self.kind == "ellipsoid":
            r = np.asarray(self.radii, np.float64)
            k0 = np.linalg.norm((p - c) / r, axis=1)
            k1 = np.linalg.norm((p - c) / (r * r), axis=1)
            return k0 * (k0 - 1.0) / np.maximum(k1, 1e-300)
        if self.kind == "box":
            q = np.abs(p - c) - (np.asarray(self.half_size, np.float64) - self.rounding)
            outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
            return outside + np.minimum(q.max(axis=1), 0.0) - self.rounding
        if self.kind == "capsule":
            a, b = np.asarray(self.a, np.float64), np.asarray(self.b, np.float64)
            pa, ba = p - a, b - a
            h = np.clip(pa @ ba / float(ba @ ba), 0.0, 1.0)
            return np.linalg.norm(pa - h[:, None] * ba, axis=1) - self.radius
        if self.kind == "torus":
            q = p - c
            ax = AXES[self.axis]
            plane = np.delete(q, ax, axis=1)
            ring = np.linalg.norm(plane, axis=1) - self.major
            return np.hypot(ring, q[:, ax]) - self.minor
        raise ValueError(f"sdf: unknown primitive kind {self.kind!r}")

    def extent(self) -> tuple[np.ndarray, np.ndarray]:
        """An axis-aligned box (lo (3,), hi (3,)) around the primitive."""
        c = np.asarray(self.centre, np.float64)
        if self.kind == "sphere":
            return c - self.radius, c + self.radius
        if self.kind == "ellipsoid":
            return c - np.asarray(self.radii), c + np.asarray(self.radii)
        if self.kind == "box":
            return c - np.asarray(self.half_size), c + np.asarray(self.half_size)
        if self.kind == "capsule":
            ends = np.array([self.a, self.b], np.float64)
            return ends.min(axis=0) - self.radius, ends.max(axis=0) + self.radius
        r = self.major + self.minor
        half = np.full(3, r)
        half[AXES[self.axis]] = self.minor
        return c - half, c + half


@dataclass(frozen=True)
class SdfScene:
    """Primitives joined by a smooth union of radius ``smooth``; ``albedo`` (3,) linear
    RGB of the whole surface; ``resolution``: marching-cubes cells along the longest side
    of the bounds."""

    primitives: tuple[Primitive, ...]
    smooth: float = 0.0
    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)
    resolution: int = 128

    def distance(self, p: np.ndarray) -> np.ndarray:
        """The scene's field (n,) float64 at points (n, 3)."""
        p = np.asarray(p, np.float64)
        d = self.primitives[0].distance(p)
        for prim in self.primitives[1:]:
            d = smooth_min(d, prim.distance(p), self.smooth)
        return d

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """An axis-aligned box (lo, hi) around the surface (the primitives' boxes, grown
        by the smooth-union radius)."""
        boxes = [prim.extent() for prim in self.primitives]
        lo = np.min([b[0] for b in boxes], axis=0) - self.smooth
        hi = np.max([b[1] for b in boxes], axis=0) + self.smooth
        return lo, hi

    @property
    def radius(self) -> float:
        lo, hi = self.bounds()
        return float(np.linalg.norm(hi - lo) / 2)

    def gradient(self, p: np.ndarray) -> np.ndarray:
        """∇f (n, 3) float64 by central differences of step GRADIENT_STEP · radius."""
        p = np.asarray(p, np.float64)
        h = GRADIENT_STEP * self.radius
        g = np.empty_like(p)
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            g[:, k] = (self.distance(p + e) - self.distance(p - e)) / (2 * h)
        return g

    def normal(self, p: np.ndarray) -> np.ndarray:
        """Unit outward normals (n, 3): the normalised gradient."""
        g = self.gradient(p)
        return g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-300)

    def project(self, p: np.ndarray, iterations: int = 4) -> np.ndarray:
        """Points (n, 3) moved onto the zero level set by Newton steps
        p ← p − f(p) ∇f / |∇f|²."""
        p = np.array(p, np.float64)
        for _ in range(iterations):
            g = self.gradient(p)
            p -= (self.distance(p) / np.maximum(np.einsum("ij,ij->i", g, g), 1e-300))[:, None] * g
        return p


def smooth_min(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Quilez's polynomial smooth minimum of radius ``k`` (k = 0: min)."""
    if k <= 0:
        return np.minimum(a, b)
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.minimum(a, b) - h * h * k * 0.25


def sphere_trace(scene: SdfScene, origins: np.ndarray, directions: np.ndarray,
                 t_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Rays (n, 3) with unit directions marched by the field until it is below
    HIT_EPSILON · radius (at most MAX_STEPS steps, distance ``t_max``). Returns hit (n,)
    bool and distance t (n,) float64 — the GLSL pass's loop, step for step."""
    eps = HIT_EPSILON * scene.radius
    t = np.zeros(len(origins))
    hit = np.zeros(len(origins), bool)
    live = np.ones(len(origins), bool)
    for _ in range(MAX_STEPS):
        idx = np.flatnonzero(live)
        if not len(idx):
            break
        d = scene.distance(origins[idx] + t[idx, None] * directions[idx])
        done = d < eps
        hit[idx[done]] = True
        t[idx[~done]] += d[~done]
        live[idx[done]] = False
        live[idx[~done][t[idx[~done]] > t_max]] = False
    return hit, t


def sdf_t_max(scene: SdfScene, eye: np.ndarray) -> float:
    """How far a ray from ``eye`` is marched: past the far side of the scene's bounding
    sphere."""
    lo, hi = scene.bounds()
    return float(np.linalg.norm(np.asarray(eye, np.float64) - (lo + hi) / 2)) + scene.radius


def marching_cubes(scene: SdfScene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The zero level set as a triangle mesh (scikit-image's marching cubes on a grid of
    ``resolution`` cells along the longest side, one cell of margin): positions (v, 3)
    float64, faces (f, 3) int64 counter-clockwise seen from outside, normals (v, 3) the
    field's unit gradient."""
    from skimage.measure import marching_cubes as skimage_marching_cubes

    lo, hi = scene.bounds()
    cell = float((hi - lo).max()) / scene.resolution
    lo, hi = lo - cell, hi + cell
    counts = np.ceil((hi - lo) / cell).astype(int) + 1
    axes = [lo[k] + cell * np.arange(counts[k]) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    values = scene.distance(grid).reshape(counts)
    verts, faces, _, _ = skimage_marching_cubes(values, 0.0, spacing=(cell,) * 3)
    positions = verts.astype(np.float64) + lo
    faces = faces.astype(np.int64)
    normals = scene.normal(positions)
    # wind the faces counter-clockwise about the outward normal
    v = positions[faces]
    cross = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    if np.einsum("ij,ij->", cross, normals[faces].mean(axis=1)) < 0:
        faces = faces[:, ::-1].copy()
    return positions, faces, normals


def packed(scene: SdfScene) -> np.ndarray:
    """The primitives as the GLSL fold reads them: (n, 3, 4) float32, per primitive
    a = (centre | a, radius | rounding | major), b = (radii | half_size | b | (minor,
    axis, 0, 0)), c = (kind code, 0, 0, 0)."""
    out = np.zeros((len(scene.primitives), 3, 4), np.float32)
    for i, p in enumerate(scene.primitives):
        if p.kind == "capsule":
            out[i, 0] = (*p.a, p.radius)
            out[i, 1, :3] = p.b
        else:
            w = {"sphere": p.radius, "box": p.rounding, "torus": p.major}.get(p.kind, 0.0)
            out[i, 0] = (*p.centre, w)
            if p.kind == "ellipsoid":
                out[i, 1, :3] = p.radii
            elif p.kind == "box":
                out[i, 1, :3] = p.half_size
            elif p.kind == "torus":
                out[i, 1, :2] = (p.minor, AXES[p.axis])
        out[i, 2, 0] = KINDS[p.kind]
    return out
