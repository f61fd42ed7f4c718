"""Light in hair with the Chiang et al. 2016 fibre (``hair.fibre = "chiang"``): the fast
path, checked against :mod:`prtcore.reference.chiang`.

**What a texel stores** (:mod:`prtcore.core.bcsdf`): the paper's radially constant value,
the fibre's outgoing radiance averaged over every direction with the weight of its
projected width, ``L̄ = (1/π²) ∫ L_o(ω) cos θ dω`` over the texel's arc. It equals
``(1/π²) ∫ L_i(ωi) Ā(θi) cos θi dωi``: the diffuse fibre's formula
(:mod:`prtcore.transport.fibre`) with the albedo ρ replaced by the fibre's directional
albedo Ā at the angle θi the light comes from (:class:`prtcore.core.bcsdf.FibreAlbedo`,
one table per bake; channels independent, so σ_a may differ per texel and channel). For a
non-absorbing fibre Ā ≈ 1 (the white furnace holds).

* **Direct light** (:func:`chiang_direct`): the diffuse fibre's J stratified surface
  samples and shadow rays, each sample's ``E/π · max(0, n·ωl) · V`` weighted by
  ``Ā(t·ωl, σ)`` at its own tangent t: ``L̄_d = Ā E⊥ cos θl V̄ / π²``, V̄ the cosine-weighted
  visibility over the fibre's surface.
* **Multiple scattering** (:func:`chiang_gather`, :func:`chiang_operator`): the diffuse
  fibre's gather rays (density cos θ / π² over the sphere), each weighted by
  ``Ā(t·d, σ_i)`` of its own direction and the receiving texel's σ per colour channel,
  applied matrix-free from the rays (:class:`prtcore.core.sparse.RayBlockProduct`) and
  solved on a basis of the light columns (:func:`prtcore.transport.low_rank.
  solve_low_rank`: the first bounce for every light, the later ones on the few columns
  that hold them).
* The samples' weights and their sums are one compiled loop (:func:`weighted_samples`),
  per light, from the same table.

**Isotropic exitance** (``hair.chiang.exitance = "isotropic"``, the paper's "radially
constant illumination at each point on the fiber"): a gather ray that hits fibre j
brings ``L̄_j``, not the BCSDF's outgoing radiance toward the ray. Hair scatters forward
(TT) and back (R, TRT), so this is where the fast path departs from the reference: 38 %
per texel on a light tangle (docs/hair.md).

**Linear exitance** (``"linear"``): transport carries each texel's outgoing radiance as
``L_o(ω) ≈ c0 + c · ω`` (world vector c), the projection with the weight cos θ / π² onto
{1, sin θ, cos θ cos φ, cos θ sin φ} (duals 1, 4 sin θ, 8/3 cos θ (cos φ, sin φ)). Light
arriving from ωi adds ``Ā`` to c0 and ``g = 4 Ā_t t + (8/3) Ā_⊥ ω̂i⊥`` to c (the
table's other two moments: forward scattering makes Ā_⊥ negative); a ray toward d
reads ``c0 − c · d`` of the fibre it hits. The direct light's coefficients come from the
same weights; every bounce goes through the (4T, 4T) operator (a rank-one 4 × 4 block
per ray and channel); the few texels whose truncated exitance dips below
zero are clamped and counted. The stored texel is still c0 (the runtime is unchanged).
Measured: 10.9 % per texel, bias +0.0 %, on the same tangle (M = 256; 8192 paths, the
reference's noise removed); what the default ("auto") takes
where the memory estimate allows (:func:`prtcore.hairbake.chiang_exitance`).

**Quadratic exitance** (``"quadratic"``): also ``cos² θ (cos 2φ, sin 2φ)`` in each
texel's frame at the middle of its arc (:func:`texel_frames`), dual weight
``(16/5) Ā_2``: a (6T, 6T) operator; 9.8 % on the same tangle.

**Second-order exitance** (``"second_order"``): also the rest of the second order,
``sin² θ − 1/4`` (how much of the light leaves near the fibre's normal plane, where the
longitudinal lobe puts it) and ``sin θ cos θ (cos φ, sin φ)``, duals ``16 Ā_z`` and
``16 Ā_s ω̂i⊥`` (the table's moments 4 and 5). These five and the quadratic's two are
quadratic forms of the direction, and they are kept as one symmetric 3 × 3 form in world
axes, ``Q = A_2 (2 p pᵀ + t tᵀ − I) + A_z (t tᵀ − I/4) + (A_s/2)(t pᵀ + p tᵀ)`` with p = ω̂i⊥,
t the tangent where the light arrives, ``A_2 = (16/5) Ā_2``, ``A_z = 16 Ā_z``,
``A_s = 16 Ā_s``; a ray toward d reads ``dᵀ Q d``. Its six entries make a (10T, 10T)
operator. In the fibre's own frame that is the same exitance, to rounding; summed over a
curly texel's arc it is the arc's mean exitance in every direction, where the quadratic's
mid-arc frame (until 2026-12-07 the second order's too) keeps the lobes' weights at each
point's tangent but their directions at the arc's middle: the dark head's path
light → scalp → fibre → scalp read −24 % with it, and +21 % with the world form, against
the second order's own model +16 ± 4 % (docs/hair.md). On the 1000-strand tangle the two
read alike (denoised at M = 64, light hair: 10.0 % before and after); measured there with
the frame: 8.5 % (its truncation 4.2 %, the rest its larger noise), 6.3 % with M = 512.

The gather rays are randomised quasi-Monte Carlo (:func:`prtcore.transport.fibre.
stratified_rays`): 15–20 % less noise per texel than independent rays.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np

from prtcore.core.bcsdf import (
    ChiangParams,
    FibreAlbedo,
    fibre_albedo,
    sigma_a_from_color,
    sigma_a_from_melanin,
)
from prtcore.core.errors import SpecError
from prtcore.core.fibres import FibreMesh
from prtcore.core.progress import bar
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.core.sparse import RayBlockProduct
from prtcore.core.spec import ChiangSpec
from prtcore.emitters.base import emitter_for
from prtcore.emitters.compiled import light_at
from prtcore.emitters.environment_light import environment_radiance
from prtcore.emitters.punctual import unshadowed_irradiance
from prtcore.receivers.strands import StrandSpace, axis_frame
from prtcore.transport.fibre import FibreTerm, direct_of_samples, direct_samples, fibre_gather

#: light types whose direct light the Chiang fibre evaluates: one direction per point, or
#: the environment estimator's cosine directions, each weighted (:func:`chiang_direct`)
CHIANG_LIGHT_TYPES = ("point", "spot", "directional", "environment")


@dataclass(frozen=True)
class ChiangFibre:
    """The fibre of a Chiang bake: ``params`` (its sigma_a unused), ``albedo`` the
    directional albedo table, ``sigma_texels`` (T, 3) float64 and ``sigma_points`` (p, 3)
    float64 the absorption per unit radius at every strand texel and hair point."""

    params: ChiangParams
    albedo: FibreAlbedo
    sigma_texels: np.ndarray
    sigma_points: np.ndarray


def chiang_fibre(spec: ChiangSpec, space: StrandSpace) -> ChiangFibre:
    """The fibre of ``spec`` on ``space``: σ_a from the melanin concentrations, or (with
    ``eumelanin`` null) from every texel's and point's colour as the hair volume's colour
    (:func:`prtcore.core.bcsdf.sigma_a_from_color`)."""
    params = ChiangParams(beta_m=spec.beta_m, beta_n=spec.beta_n,
                          alpha=float(np.radians(spec.alpha_deg)), eta=spec.eta)
    if spec.eumelanin is None:
        sig_t = sigma_a_from_color(space.albedo, spec.beta_n)
        sig_p = sigma_a_from_color(space.hair.color, spec.beta_n)
    else:
        one = sigma_a_from_melanin(spec.eumelanin, spec.pheomelanin)
        sig_t = np.tile(one, (space.count, 1))
        sig_p = np.tile(one, (space.hair.point_count, 1))
    return ChiangFibre(params=params, albedo=fibre_albedo(params), sigma_texels=sig_t,
                       sigma_points=sig_p)


def texel_albedo(fibre: ChiangFibre, nodes: int = 8) -> np.ndarray:
    """(T, 3) float64: every strand texel's directional albedo Ā averaged over incident
    directions uniform on the sphere (sin θi uniform in [−1, 1]: ``nodes`` Gauss–Legendre
    nodes in |sin θi|): the ρ whose ratio to it makes a Chiang texel's exitance an
    irradiance (:mod:`prtcore.transport.strand_denoise` averages that)."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    sig = fibre.sigma_texels
    out = np.zeros(sig.shape)
    for xi, wi in zip((x + 1) / 2, w / 2, strict=True):
        out += wi * fibre.albedo(np.full(len(sig), xi), sig)
    return out


def bundle_fibre(manifest: dict, space: StrandSpace) -> ChiangFibre | None:
    """The Chiang fibre a bundle was baked with (its manifest's ``fibre.chiang``) on
    ``space``, or None for a diffuse fibre's bundle: what its drawing and its validation
    shade with."""
    chiang = (manifest.get("fibre") or {}).get("chiang")
    return None if chiang is None else chiang_fibre(ChiangSpec(**chiang), space)


def check_lights(lights: Sequence[Light]) -> None:
    """Refuse lights the Chiang fibre cannot shade (none of :data:`CHIANG_LIGHT_TYPES`): a
    :class:`~prtcore.core.errors.SpecError` naming ``lights.families``."""
    bad = sorted({li.type for li in lights if li.type not in CHIANG_LIGHT_TYPES})
    if bad:
        raise SpecError("lights.families", f"the 'chiang' fibre shades "
                        f"{', '.join(CHIANG_LIGHT_TYPES)} lights, not {', '.join(bad)} "
                        "(use hair.fibre 'diffuse')")


#: Memory per gather ray beyond the diffuse fibre's (bytes): each hit's direction and
#: tangent (24) and row/column (8) as gathered, the matrix-free operator's copy of those
#: (8) with F × 3 weights and F reads (16 F), the weights' float64 temporaries (48 F)
CHIANG_BYTES_PER_RAY = {"isotropic": 100, "linear": 300, "quadratic": 420,
                        "second_order": 680}
#: the fibre's outgoing radiance carried through transport (``hair.chiang.exitance``)
EXITANCE = ("isotropic", "linear", "quadratic", "second_order")
#: coefficients per texel of each
EXITANCE_TERMS = {"isotropic": 1, "linear": 4, "quadratic": 6, "second_order": 10}
#: the world quadratic form's six entries (xx, yy, zz, xy, xz, yz) as index pairs, and what
#: a ray toward d reads of each: d_i d_j, twice for i ≠ j (:func:`exitance_reads`)
FORM_ENTRIES = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def needs_frames(exitance: str) -> bool:
    """Whether ``exitance`` has terms in each texel's frame (:func:`texel_frames`): the
    quadratic exitance alone (the second order's form is in world axes)."""
    return EXITANCE_TERMS[exitance] == 6


def texel_frames(space: StrandSpace) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) (T, 3) float64: a unit frame across each texel's fibre at the middle of its
    arc (the transported frame; its tangent is u × v), for the quadratic exitance's terms
    (the second order's world form needs none)."""
    _, tangent, u = axis_frame(space.hair, space.strand, space.arc.mean(axis=1))
    return u, np.cross(tangent, u)


def _second_order(w: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray,
                                                                         np.ndarray]:
    """``((w·u)² − (w·v)², 2 (w·u)(w·v))`` (n,) each: cos² θ (cos 2φ, sin 2φ) of w (n, 3) in
    the frames (u, v) (n, 3)."""
    a, b = np.einsum("ij,ij->i", w, u), np.einsum("ij,ij->i", w, v)
    return a * a - b * b, 2 * a * b


def exitance_weights(albedo: FibreAlbedo, tangent: np.ndarray, w: np.ndarray,
                     sigma: np.ndarray, exitance: str, frame: tuple | None = None
                     ) -> np.ndarray:
    """Per incident direction w (n, 3) at fibres of tangents (n, 3) and absorption σ
    (n, 3): the weights that turn light arriving from w (with density cos θ / π²) into the
    exitance coefficients, (F, n, 3): F = 1, Ā (isotropic); F = 4, Ā then the world
    vector ``g = 4 Ā_t t + (8/3) Ā_⊥ ŵ_⊥`` (linear); F = 6, those then
    ``(16/5) Ā_2 (cos 2φ, sin 2φ)`` of w in the receiving texels' ``frame`` (u, v)
    (quadratic); F = 10, Ā, g, then the world form Q's six entries (second_order:
    :data:`FORM_ENTRIES`, the module docstring; no frame)."""
    sin = np.einsum("ij,ij->i", tangent, w)
    mean = albedo(sin, sigma)
    if exitance == "isotropic":
        return mean[None]
    perp = w - sin[:, None] * tangent
    perp /= np.maximum(np.linalg.norm(perp, axis=1, keepdims=True), 1e-12)
    at, ap = albedo(sin, sigma, 1), albedo(sin, sigma, 2)
    g = 4 * at[:, None, :] * tangent[:, :, None] + 8 / 3 * ap[:, None, :] * perp[:, :, None]
    out = [mean[None], np.moveaxis(g, 1, 0)]
    if needs_frames(exitance):
        c2, s2 = _second_order(w, *frame)
        norm = np.maximum(c2 * c2 + s2 * s2, 1e-24) ** 0.5  # cos² θ of w
        a2 = 16 / 5 * albedo(sin, sigma, 3)
        out += [(a2 * (c2 / norm)[:, None])[None], (a2 * (s2 / norm)[:, None])[None]]
    if EXITANCE_TERMS[exitance] == 10:
        a2 = 16 / 5 * albedo(sin, sigma, 3)
        a_z, a_s = 16 * albedo(sin, sigma, 4), 16 * albedo(sin, sigma, 5)
        for i, j in FORM_ENTRIES:
            delta = float(i == j)
            g2 = 2 * perp[:, i] * perp[:, j] + tangent[:, i] * tangent[:, j] - delta
            gz = tangent[:, i] * tangent[:, j] - delta / 4
            gs = (tangent[:, i] * perp[:, j] + perp[:, i] * tangent[:, j]) / 2
            out.append((a2 * g2[:, None] + a_z * gz[:, None] + a_s * gs[:, None])[None])
    return np.concatenate(out)


def exitance_reads(d: np.ndarray, frame: tuple | None, terms: int) -> list:
    """What a ray toward d (n, 3) reads of each coefficient of the fibre it hits: 1, −d,
    then (quadratic, with the texels' frames (u, v) (n, 3)) cos² θ (cos 2φ, sin 2φ) of −d,
    or (second order) the world form's entries d_i d_j (:data:`FORM_ENTRIES`, twice off
    the diagonal; all even in d)."""
    out = [np.ones(len(d))]
    if terms >= 4:
        out += [-d[:, 0], -d[:, 1], -d[:, 2]]
    if terms == 6:
        out += list(_second_order(d, *frame))  # even in d
    if terms == 10:
        out += [d[:, i] * d[:, j] * (1.0 if i == j else 2.0) for i, j in FORM_ENTRIES]
    return out


@numba.njit(inline="always", cache=True)
def _add_weighted(t0, t1, t2, w0, w1, w2, fu, fv, r, jq, fq, values, sin_nodes, m, acc
                  ):  # pragma: no cover - compiled
    """Adds :func:`exitance_weights`' weights of light from (w0, w1, w2) at a fibre of
    tangent (t0, t1, t2) (frame fu, fv (3,)), times the radiance r (3,) per channel, to
    acc (F, 3) (F = acc.shape[0]: 1, 4, 6 or 10); the table :class:`~prtcore.core.bcsdf.
    FibreAlbedo`'s values (6, S, Q) bilinear in sin θ and √σ (jq, fq (3,): each
    channel's √σ node and fraction); m (6,) scratch."""
    terms = acc.shape[0]
    ns = len(sin_nodes)
    s0, ds = sin_nodes[0], sin_nodes[1] - sin_nodes[0]
    moments = 1 if terms == 1 else (3 if terms == 4 else (4 if terms == 6 else 6))
    quadratic = terms == 6
    sn = t0 * w0 + t1 * w1 + t2 * w2
    x = (min(max(sn, s0), sin_nodes[ns - 1]) - s0) / ds
    ii = min(int(x), ns - 2)
    fx = x - ii
    p0, p1, p2 = w0 - sn * t0, w1 - sn * t1, w2 - sn * t2
    pn = max(np.sqrt(p0 * p0 + p1 * p1 + p2 * p2), 1e-12)
    p0, p1, p2 = p0 / pn, p1 / pn, p2 / pn
    c2 = s2 = 0.0
    if quadratic:
        a = w0 * fu[0] + w1 * fu[1] + w2 * fu[2]
        b = w0 * fv[0] + w1 * fv[1] + w2 * fv[2]
        c2, s2 = a * a - b * b, 2 * a * b
        norm = max(c2 * c2 + s2 * s2, 1e-24) ** 0.5
        c2, s2 = c2 / norm, s2 / norm
    for c in range(3):
        rc = r[c]
        if rc == 0:
            continue
        jj, fy = jq[c], fq[c]
        for mo in range(moments):
            v = values[mo]
            top = v[ii, jj] * (1 - fy) + v[ii, jj + 1] * fy
            bottom = v[ii + 1, jj] * (1 - fy) + v[ii + 1, jj + 1] * fy
            m[mo] = top * (1 - fx) + bottom * fx
        acc[0, c] += m[0] * rc
        if terms >= 4:
            at, ap = 4 * m[1] * rc, 8 / 3 * m[2] * rc
            acc[1, c] += at * t0 + ap * p0
            acc[2, c] += at * t1 + ap * p1
            acc[3, c] += at * t2 + ap * p2
        if quadratic:
            a2 = 16 / 5 * m[3] * rc
            acc[4, c] += a2 * c2
            acc[5, c] += a2 * s2
        if terms == 10:  # the world form (exitance_weights), entry by entry
            a2, az, a_s = 16 / 5 * m[3] * rc, 16 * m[4] * rc, 8 * m[5] * rc
            acc[4, c] += a2 * (2 * p0 * p0 + t0 * t0 - 1) + az * (t0 * t0 - 0.25) \
                + a_s * 2 * t0 * p0
            acc[5, c] += a2 * (2 * p1 * p1 + t1 * t1 - 1) + az * (t1 * t1 - 0.25) \
                + a_s * 2 * t1 * p1
            acc[6, c] += a2 * (2 * p2 * p2 + t2 * t2 - 1) + az * (t2 * t2 - 0.25) \
                + a_s * 2 * t2 * p2
            acc[7, c] += a2 * (2 * p0 * p1 + t0 * t1) + az * t0 * t1 \
                + a_s * (t0 * p1 + p0 * t1)
            acc[8, c] += a2 * (2 * p0 * p2 + t0 * t2) + az * t0 * t2 \
                + a_s * (t0 * p2 + p0 * t2)
            acc[9, c] += a2 * (2 * p1 * p2 + t1 * t2) + az * t1 * t2 \
                + a_s * (t1 * p2 + p1 * t2)


@numba.njit(inline="always", cache=True)
def _sigma_nodes(sigma, root_nodes, jq, fq):  # pragma: no cover - compiled
    """Each channel's √σ node and fraction (jq, fq (3,), written) of σ (3,) in the table's
    root_nodes (Q,)."""
    nq = len(root_nodes)
    r0, dr = root_nodes[0], root_nodes[1] - root_nodes[0]
    rmax2 = root_nodes[nq - 1] ** 2
    for c in range(3):
        y = (np.sqrt(min(max(sigma[c], 0.0), rmax2)) - r0) / dr
        jj = min(int(y), nq - 2)
        jq[c], fq[c] = jj, y - jj


@numba.njit(parallel=True, cache=True, nogil=True)
def weighted_samples(tangent, to_light, sigma, rad, values, sin_nodes, root_nodes, fu, fv,
                     out):  # pragma: no cover - compiled
    """Each texel's exitance coefficients from its J samples of one light: ``(1/J) Σ_j
    w_f(ωl) rad_j`` with :func:`exitance_weights`' weights w_f (F = out.shape[0]: 1, 4, 6 or
    10), the table :class:`~prtcore.core.bcsdf.FibreAlbedo`'s bilinear interpolation.

    tangent, to_light (n, J, 3) float64 at the samples; sigma (n, 3) float64 per texel;
    rad (n, J, 3) float32 the samples' radiance; values (6, S, Q) float64, sin_nodes (S,),
    root_nodes (Q,) the table; fu, fv (n, 3) the texels' frames (F = 6; else unread); out
    (F, n, 3) float32, written."""
    n, nj = rad.shape[0], rad.shape[1]
    terms = out.shape[0]
    for i in numba.prange(n):
        jq = np.empty(3, np.int64)
        fq = np.empty(3)
        _sigma_nodes(sigma[i], root_nodes, jq, fq)
        acc = np.zeros((terms, 3))
        m = np.empty(6)
        for j in range(nj):
            _add_weighted(tangent[i, j, 0], tangent[i, j, 1], tangent[i, j, 2],
                          to_light[i, j, 0], to_light[i, j, 1], to_light[i, j, 2],
                          fu[i], fv[i], rad[i, j], jq, fq, values, sin_nodes, m, acc)
        for f in range(terms):
            for c in range(3):
                out[f, i, c] = acc[f, c] / nj


@numba.njit(parallel=True, cache=True, nogil=True)
def shaded_reads(row, centre, tangent, radius, sigma, fu, fv, reads, weight, slot, values,
                 sin_nodes, root_nodes, out):  # pragma: no cover - compiled
    """One punctual light's direct light at fibre points, turned into their exitance
    coefficients as the strand texels' direct light does (:func:`chiang_direct`:
    :func:`exitance_weights`' ``w(ωl) · E⊥ · cos θl``, the weights as
    :func:`weighted_samples` makes them), read toward a ray and summed per receiver:
    ``out[slot_i] += weight_i Σ_f reads_if w_f(ωl_i) E⊥_i cos θl_i``. ωl is the light's
    direction from the axis point, E⊥ its unshadowed irradiance on the fibre's side
    facing it (the point ``centre + radius · facing``, normal ωl: as
    :func:`prtcore.emitters.punctual.irradiance` there).

    row (ROW_SIZE,) float64 the light (:func:`prtcore.emitters.compiled.light_row`);
    centre, tangent, fu, fv (n, 3) float64 the axis points, tangents and frames (F = 6);
    radius (n,) float64 the outside radius; sigma (n, 3) float64; reads (n, F) float64
    what each ray reads of each coefficient (:func:`exitance_reads`); weight (n,)
    float64 each point's share (its visibility, over its receiver's rays and π²); slot
    (n,) int64 its receiver; values, sin_nodes, root_nodes the table; out (r, 3) float64,
    added to."""
    n, terms = reads.shape
    value = np.zeros((n, 3))
    for i in numba.prange(n):
        if weight[i] == 0.0:
            continue
        t0, t1, t2 = tangent[i, 0], tangent[i, 1], tangent[i, 2]
        x0, x1, x2 = centre[i, 0], centre[i, 1], centre[i, 2]
        w0, w1, w2, _, _, _, _, _, _ = light_at(row, x0, x1, x2, t0, t1, t2)
        sn = t0 * w0 + t1 * w1 + t2 * w2
        f0, f1, f2 = w0 - sn * t0, w1 - sn * t1, w2 - sn * t2
        fn = np.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
        if fn <= 1e-9:  # the light along the fibre: cos θl = 0
            continue
        rr = radius[i] / fn
        _, _, _, _, _, _, e0, e1, e2 = light_at(row, x0 + rr * f0, x1 + rr * f1,
                                                x2 + rr * f2, w0, w1, w2)
        s = np.sqrt(max(1.0 - sn * sn, 0.0)) * weight[i]
        r = np.empty(3)
        r[0], r[1], r[2] = e0 * s, e1 * s, e2 * s
        jq = np.empty(3, np.int64)
        fq = np.empty(3)
        _sigma_nodes(sigma[i], root_nodes, jq, fq)
        acc = np.zeros((terms, 3))
        m = np.empty(6)
        _add_weighted(t0, t1, t2, w0, w1, w2, fu[i], fv[i], r, jq, fq, values, sin_nodes, m,
                      acc)
        for f in range(terms):
            for c in range(3):
                value[i, c] += reads[i, f] * acc[f, c]
    for i in range(n):  # serial: receivers repeat
        for c in range(3):
            out[slot[i], c] += value[i, c]


#: the fewest direct-light samples a Chiang-fibre strand texel takes by default
MIN_DIRECT_SAMPLES = 4


def chiang_samples(given: int | str, transport_samples: int) -> int:
    """J, the Chiang fibre's direct-light samples per strand texel: ``hair.direct_samples``
    when given (an int), else ("auto") the larger of :data:`MIN_DIRECT_SAMPLES` and
    ``transport_samples`` (``transport.direct_samples``)."""
    return int(given) if given != "auto" else max(MIN_DIRECT_SAMPLES, int(transport_samples))


def chiang_direct(space: StrandSpace, tracer: RayTracer, lights: Sequence[Light],
                  samples: int, seed: int, fibre: ChiangFibre, exitance: str = "isotropic",
                  out: Sequence[np.ndarray] | None = None
                  ) -> np.ndarray | Sequence[np.ndarray]:
    """Direct exitance coefficients of every strand texel for every light, (F, T, K, 3)
    float32 (F = 1 isotropic: L̄_d; F = 4 linear: L̄_d then the world vector c), from the
    same surface samples as :func:`prtcore.transport.fibre.fibre_direct`; or written
    into ``out``, F (T, K, 3) float32 arrays (a hair + mesh bake's stacked direct light:
    the 10k head's second order held 5.7 GB more when it was made and then copied), and
    ``out`` returned.

    Punctual lights: each sample's ``E/π · max(0, n·ωl) · V`` weighted by the coefficients'
    weights of ωl. Environment lights: the environment estimator's S cosine directions about
    each sample's normal and their visibility (shared by every environment light,
    :meth:`prtcore.emitters.environment_light.EnvironmentEmitter.directions`), each
    direction's ``L · V`` weighted by its own weights: ``(1/(J S)) Σ_j Σ_s L V w(ω_s)``, the
    same estimate with the cosine sampled instead of a single direction."""
    check_lights(lights)
    drawn = direct_samples(space, samples, seed)
    arc, _ = space.surface_sample_params(samples, seed)  # the samples' arcs, as drawn
    tangent = axis_frame(space.hair, np.repeat(space.strand, samples),
                         arc.reshape(-1))[1].reshape(space.count, samples, 3)
    frames = texel_frames(space) if needs_frames(exitance) else None

    terms = EXITANCE_TERMS[exitance]
    table = fibre.albedo

    def weight(idx: np.ndarray, origin: np.ndarray, lights_: Sequence[Light],
               rad: np.ndarray) -> np.ndarray:
        n, j = origin.shape[:2]
        pts = origin.reshape(-1, 3)
        tg = np.ascontiguousarray(tangent[idx])
        sig = np.ascontiguousarray(fibre.sigma_texels[idx], dtype=np.float64)
        fu, fv = (np.zeros((n, 3)),) * 2 if frames is None else \
            (np.ascontiguousarray(frames[0][idx]), np.ascontiguousarray(frames[1][idx]))
        out = np.empty((terms, n, len(lights_), 3), dtype=np.float32)
        one = np.empty((terms, n, 3), dtype=np.float32)
        for k, light in enumerate(lights_):
            _, to_light, _ = unshadowed_irradiance(light, pts, tg.reshape(-1, 3))
            weighted_samples(tg, np.ascontiguousarray(to_light.reshape(n, j, 3)), sig,
                             np.ascontiguousarray(rad[:, :, k]), table.values,
                             table.sin_theta, table.root_sigma, fu, fv, one)
            out[:, :, k] = one
        return out

    env = [k for k, light in enumerate(lights) if light.type == "environment"]
    punctual = [k for k in range(len(lights)) if k not in set(env)]
    if not env:
        return direct_of_samples(space, tracer, lights, drawn, 0, progress=True,
                                 weight=weight, terms=terms, out=out)
    given, out = out, np.empty((EXITANCE_TERMS[exitance], space.count, len(lights), 3),
                               np.float32)
    if punctual:
        out[:, :, punctual] = direct_of_samples(space, tracer, [lights[k] for k in punctual],
                                                drawn, 0, progress=True,
                                                weight=weight, terms=terms)
    out[:, :, env] = _environment_direct(space, tracer, [lights[k] for k in env], drawn,
                                         tangent, fibre, exitance, frames)
    if given is None:
        return out
    for a in range(len(out)):  # environment lights: made whole, then copied in
        given[a][...] = out[a]
    return given


def _environment_direct(space: StrandSpace, tracer: RayTracer, lights: Sequence[Light],
                        drawn, tangent: np.ndarray, fibre: ChiangFibre, exitance: str,
                        frames: tuple | None, block: int = 1 << 11) -> np.ndarray:
    """:func:`chiang_direct` for environment ``lights``: (F, T, K_env, 3) float32."""
    emitter = emitter_for(lights[0])
    origin, normal, _, order = drawn  # direct_samples: origin, normal, phi, order
    t, j = origin.shape[:2]
    out = np.empty((EXITANCE_TERMS[exitance], t, len(lights), 3), np.float32)
    for a in bar(range(0, t, block), "direct fibres (environment)",
                 total=-(-t // block)):
        idx = order[a:a + block]
        d, vis = emitter.directions(origin[idx].reshape(-1, 3), normal[idx].reshape(-1, 3),
                                    tracer)  # (n J, S, 3), (n J, S)
        s = d.shape[1]
        frame = None if frames is None else tuple(np.repeat(f[idx], j * s, axis=0)
                                                  for f in frames)
        w = exitance_weights(fibre.albedo,
                             np.repeat(tangent[idx].reshape(-1, 3), s, axis=0),
                             d.reshape(-1, 3),
                             np.repeat(fibre.sigma_texels[idx], j * s, axis=0), exitance,
                             frame)  # (F, n J S, 3)
        w = (w.reshape(len(w), len(idx), j * s, 3)
             * vis.reshape(len(idx), j * s)[None, :, :, None])
        for k, light in enumerate(lights):
            rad = environment_radiance(light, d.reshape(-1, 3)).reshape(len(idx), j * s, 3)
            out[:, idx, k] = np.einsum("fnsc,nsc->fnc", w, rad) / (j * s)
    return out


def chiang_gather(space: StrandSpace, tracer: RayTracer, mesh: FibreMesh, mesh_faces: int,
                  rays: int, seed: int, fibre: ChiangFibre, mesh_texels=None,
                  mesh_columns: int = 0) -> FibreTerm:
    """:func:`prtcore.transport.fibre.fibre_gather` (the same rays as the diffuse fibre's)
    keeping every fibre hit's direction and tangent at its origin
    (``FibreTerm.rays``, data (n, 6): d, t) for :func:`chiang_operator`; with
    ``mesh_texels`` (a hair + mesh bake) the rays to the mesh too
    (``FibreTerm.mesh_hits.data``)."""
    hair = space.hair

    def ray_data(texel: np.ndarray, arc: np.ndarray, d: np.ndarray) -> np.ndarray:
        return np.concatenate([d, axis_frame(hair, space.strand[texel], arc)[1]], axis=1)

    return fibre_gather(space, tracer, mesh, mesh_faces, rays, seed, harmonics=0,
                        stratified=True,
                        ray_data=ray_data, mesh_texels=mesh_texels,
                        mesh_columns=mesh_columns)


def ray_weights(fibre: ChiangFibre, rows: np.ndarray, data: np.ndarray,
                exitance: str = "isotropic", frames: tuple | None = None) -> np.ndarray:
    """The exitance weights (F, n, 3) float64 (:func:`exitance_weights`; F = 1: the
    directional albedo Ā(t·d, σ)) of gather rays from strand texels ``rows`` (n,) with
    :func:`chiang_gather`'s ``data`` (n, 6); ``frames``: :func:`texel_frames` of the
    texels, for quadratic and second-order exitance."""
    data = np.asarray(data, dtype=np.float64)
    frame = None if frames is None else (frames[0][rows], frames[1][rows])
    return exitance_weights(fibre.albedo, data[:, 3:6], data[:, :3],
                            fibre.sigma_texels[rows], exitance, frame)


def chiang_operator(space: StrandSpace, term: FibreTerm, fibre: ChiangFibre, rays: int,
                    exitance: str = "isotropic", threads: int = 2
                    ) -> tuple[RayBlockProduct, np.ndarray]:
    """``solve_indirect``'s (product, albedo) for the gather on the exitance coefficients,
    W_c (FT, FT) per channel c, matrix-free (:class:`prtcore.core.sparse.RayBlockProduct`):
    row block a of the receiving texel takes each ray's weight a (:func:`ray_weights`: of
    its direction, the receiving texel's σ) times column block b of the texel hit, read
    toward the ray (isotropic: L̄_j; linear: ``c_j0 − c_j · d``; quadratic and second
    order: plus their second-order terms at −d, :func:`exitance_reads`), over M. The solver computes
    ``L = ρ ∘ W'(L_d + L)``; with ``W' = 2 W`` and ρ = 1/2 (below its albedo clamp) that
    is ``L = W (L_d + L)``."""
    rows, cols, data = term.rays
    t = space.count
    frames = texel_frames(space) if needs_frames(exitance) else None
    w = ray_weights(fibre, rows, data, exitance, frames)  # (F, n, 3)
    f = len(w)
    read = exitance_reads(data[:, :3].astype(np.float64), None if frames is None
                          else (frames[0][cols], frames[1][cols]), f)
    weight = np.moveaxis(w, 0, 1) * (2.0 / rays)  # (n, F, 3)
    product = RayBlockProduct(rows, cols, weight, np.stack(read, axis=1), t, threads)
    return product, np.full((f * t, 3), 0.5)
