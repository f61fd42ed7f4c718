"""The punctual lights' evaluation compiled (numba): shadow rays and shaded direct light in
one pass over the points each, for the bake's direct-light stages
(:func:`prtcore.transport.direct.direct_radiance`).

Why: with numpy, one light over a chunk of points is dozens of array passes (the formula,
the ray set-up of :meth:`prtcore.core.raytrace.RayTracer.visible`, the mask, the mean over
a texel's points); on the 512² Cornell box they cost about three times the Embree
occlusion queries themselves. Here :func:`shadow_rays` computes the unshadowed
irradiance and the float32 shadow rays of the lit points in one pass, the caller traces
them (:meth:`~prtcore.core.raytrace.RayTracer.occluded`), and :func:`shade` masks, averages
and scales in a second pass.

The formula is the emitters' (:mod:`prtcore.emitters.point`, :mod:`~prtcore.emitters.spot`,
:mod:`~prtcore.emitters.directional`, :mod:`prtcore.emitters.punctual`), with the light's
constants computed by its emitter (:meth:`prtcore.emitters.base.Emitter.kernel_row`), and
rounds as numpy does: every product and sum in numpy's order (a 3-vector dot product as
``einsum`` sums it, ``(x₀y₀ + x₂y₂) + x₁y₁``), no fused multiply-add (``fastmath`` off).
Point and directional lights give bit-equal results (tests/test_direct_kernels.py). Two
operations differ in the last bit: a spot's axis cosine (numpy's ``@`` is an OpenBLAS
kernel with fused multiply-adds) and the range window's fourth power (numpy's SIMD
``power``); there the kernel agrees to a few ulp.

A light whose emitter has no row (an environment) is evaluated by
:func:`prtcore.emitters.punctual.irradiance` instead.
"""

from __future__ import annotations

import numba
import numpy as np

#: The row of a light (float64, ROW_SIZE): kind (KIND_*), position (3), axis (3: the
#: spot's axis, or the unit direction toward a directional light), colour × intensity (3),
#: range (0: none), the spot's cone scale and offset (:func:`prtcore.emitters.spot.
#: cone_coefficients`; scale 0: no cone).
ROW_SIZE = 14
KIND_POSITIONED = 0.0
KIND_DIRECTIONAL = 1.0
_KIND, _POS, _AXIS, _COLOR, _RANGE, _CONE = 0, 1, 4, 7, 10, 11


def light_row(kind: float, position=(0.0, 0.0, 0.0), axis=(0.0, 0.0, 0.0),
              color=(0.0, 0.0, 0.0), light_range: float | None = None,
              cone: tuple[float, float] | None = None) -> np.ndarray:
    """A light's row for the kernels (ROW_SIZE,) float64; the emitters build it
    (:meth:`prtcore.emitters.base.Emitter.kernel_row`)."""
    row = np.zeros(ROW_SIZE)
    row[_KIND] = kind
    row[_POS:_POS + 3] = position
    row[_AXIS:_AXIS + 3] = axis
    row[_COLOR:_COLOR + 3] = color
    row[_RANGE] = 0.0 if light_range is None else float(light_range)
    if cone is not None:
        row[_CONE:_CONE + 2] = cone
    return row


@numba.njit(inline="always", cache=True)
def _dot(a0, a1, a2, b0, b1, b2):  # pragma: no cover - compiled
    """A 3-vector dot product in numpy einsum's order."""
    return (a0 * b0 + a2 * b2) + a1 * b1


@numba.njit(inline="always", cache=True)
def _sign(x):  # pragma: no cover - compiled
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


@numba.njit(inline="always", cache=True)
def light_at(row, x0, x1, x2, n0, n1, n2):  # pragma: no cover - compiled
    """The unshadowed light of ``row`` (:func:`light_row`) at the point (x0, x1, x2) of
    unit normal (n0, n1, n2): the unit direction toward it (w0, w1, w2), the vector
    toward its position (d0, d1, d2; zeros for a directional light) and the irradiance
    (e0, e1, e2), as the emitters' ``unshadowed``."""
    kind = row[0]
    px, py, pz = row[1], row[2], row[3]
    a0, a1, a2 = row[4], row[5], row[6]
    cr, cg, cb = row[7], row[8], row[9]
    rng, cone_scale, cone_offset = row[10], row[11], row[12]
    d0, d1, d2 = 0.0, 0.0, 0.0
    if kind == 1.0:  # directional: w is the axis
        w0, w1, w2 = a0, a1, a2
        cos = _dot(n0, n1, n2, w0, w1, w2)
        att = cos if cos > 0.0 else 0.0
        return w0, w1, w2, d0, d1, d2, att * cr, att * cg, att * cb
    d0, d1, d2 = px - x0, py - x1, pz - x2
    r2 = _dot(d0, d1, d2, d0, d1, d2)
    dist = np.sqrt(r2)
    if dist > 0.0:
        w0, w1, w2 = d0 / dist, d1 / dist, d2 / dist
    else:
        w0, w1, w2 = 0.0, 0.0, 0.0
    cos = _dot(n0, n1, n2, w0, w1, w2)
    att = cos if cos > 0.0 else 0.0
    if rng > 0.0:
        q = 1.0 - (dist / rng) ** 4.0
        q = min(max(q, 0.0), 1.0)
        att = att * (q * q)
    else:
        att = att * 1.0
    if cone_scale != 0.0:
        c = -_dot(w0, w1, w2, a0, a1, a2) * cone_scale + cone_offset
        c = min(max(c, 0.0), 1.0)
        att = att * (c * c)
    att = att / r2 if r2 > 0.0 else 0.0
    return w0, w1, w2, d0, d1, d2, att * cr, att * cg, att * cb


@numba.njit(cache=True, nogil=True)
def shadow_rays(row, positions, normals, per, offset, tfar, e, origin, direction,
                tmax, index):  # pragma: no cover - compiled
    """Unshadowed irradiance at every point, and a shadow ray from every lit one.

    row : (ROW_SIZE,) float64 (:func:`light_row`); positions (m, 3) float64; normals
    (m // per, 3) float64 unit shading normals, one per ``per`` consecutive points.
    Writes e (m, 3) float64 (the unshadowed irradiance), and for the lit points (any
    channel > 0), in order: origin, direction (c, 3) float32, tmax (c,) float32 — the
    rays of :meth:`prtcore.core.raytrace.RayTracer.visible` (positioned lights) or
    :meth:`~prtcore.core.raytrace.RayTracer.unoccluded_towards` (directional), offset and
    far distance ``offset``, ``tfar`` — and index (c,) int64, the points they leave from.
    Returns c.
    """
    kind = row[0]
    px, py, pz = row[1], row[2], row[3]
    count = 0
    for i in range(len(positions)):
        x0, x1, x2 = positions[i, 0], positions[i, 1], positions[i, 2]
        nrm = normals[i // per]
        n0, n1, n2 = nrm[0], nrm[1], nrm[2]
        w0, w1, w2, d0, d1, d2, e0, e1, e2 = light_at(row, x0, x1, x2, n0, n1, n2)
        e[i, 0], e[i, 1], e[i, 2] = e0, e1, e2
        if not ((e0 + e1) + e2 > 0.0):
            continue
        if kind == 1.0:
            s = _sign(_dot(w0, w1, w2, n0, n1, n2))
            o0, o1, o2 = x0 + n0 * s * offset, x1 + n1 * s * offset, x2 + n2 * s * offset
            u0, u1, u2 = w0, w1, w2
            t = tfar
        else:
            s = _sign(_dot(d0, d1, d2, n0, n1, n2))
            o0, o1, o2 = x0 + n0 * s * offset, x1 + n1 * s * offset, x2 + n2 * s * offset
            v0, v1, v2 = px - o0, py - o1, pz - o2
            dd = np.sqrt(_dot(v0, v1, v2, v0, v1, v2))
            if dd > 0.0:
                u0, u1, u2 = v0 / dd, v1 / dd, v2 / dd
            else:
                u0, u1, u2 = 0.0, 0.0, 0.0
            t = max(dd - offset, 0.0)
            t = min(t, tfar)
        origin[count, 0], origin[count, 1], origin[count, 2] = o0, o1, o2
        direction[count, 0], direction[count, 1], direction[count, 2] = u0, u1, u2
        tmax[count] = t
        index[count] = i
        count += 1
    return count


@numba.njit(cache=True, nogil=True)
def shade(e, index, occluded, per, scale, out):  # pragma: no cover - compiled
    """Shadowed, averaged, scaled direct light.

    e (m, 3) float64 from :func:`shadow_rays` (zeroed here where ``occluded``); index (c,)
    int64 and occluded (c,) bool: the traced points and their result; per : points per
    row; scale (m // per, 3) float64 (ρ/π); out (m // per, 3) float32 (any strides):
    ``out[r] = (Σ_j e[r·per + j]) / per · scale[r]``, the sum in j's order.
    """
    for c in range(len(index)):
        if occluded[c]:
            i = index[c]
            e[i, 0], e[i, 1], e[i, 2] = 0.0, 0.0, 0.0
    for r in range(len(out)):
        i = r * per
        s0, s1, s2 = e[i, 0], e[i, 1], e[i, 2]
        if per > 1:
            for j in range(1, per):
                s0 += e[i + j, 0]
                s1 += e[i + j, 1]
                s2 += e[i + j, 2]
            s0, s1, s2 = s0 / per, s1 / per, s2 / per
        out[r, 0] = s0 * scale[r, 0]
        out[r, 1] = s1 * scale[r, 1]
        out[r, 2] = s2 * scale[r, 2]
