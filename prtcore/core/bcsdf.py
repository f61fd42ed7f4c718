"""The Chiang et al. 2016 hair scattering model ("A Practical and Controllable Hair and Fur
Model for Production Path Tracing"), as described in the paper and in pbrt-v3's hair
chapter, vectorised over rays: the second fibre model of issue 16.

Frame: for a fibre with unit tangent t, a direction w has longitudinal angle θ
(``sin θ = w·t``) and azimuth φ about t. ``h ∈ [−1, 1]`` is the offset across the fibre
where the ray meets it. The scattering function is the sum of lobes p = 0 (R), 1 (TT),
2 (TRT) and the rest (p ≥ 3, azimuthally uniform):

    S(wo, wi) = Σ_{p<3} M_p(θi, θo') A_p N_p(φi − φo) + M_3(θi, θo) A_3 / (2π)

* ``M_p``: the longitudinal lobe of d'Eon et al. 2011 (a modified Bessel function I₀),
  variance v_p from the longitudinal roughness β_m (v₁ = v₀/4, v₂ = v₃ = 4 v₀), the
  cuticle tilt α shifting θo by −2α, α, 4α for R, TT, TRT;
* ``A_p``: Fresnel (dielectric, IOR η) and absorption through the fibre
  (σ_a along the refracted path ``2 cos γt / cos θt``): A₀ = F, A₁ = (1 − F)² T,
  A_p = A_{p−1} T F, and the rest A₃ = A₂ T F / (1 − T F);
* ``N_p``: a trimmed logistic of scale s (from the azimuthal roughness β_n) about the
  exit azimuth Φ(p, h) = 2p γt − 2γo + pπ.

``S`` is per unit solid angle of wi: for a non-absorbing fibre, ∫ S dωi = 1 averaged over
h (energy conservation; the white-furnace test of tests/test_bcsdf.py). pbrt-v3 divides
this sum by the cosine of its ribbon frame, which its integrator multiplies back; here it
is left out. Absorption from melanin (:func:`sigma_a_from_melanin`) uses the eumelanin and
pheomelanin absorption coefficients of d'Eon et al. 2011 (per unit fibre radius).

What a strand texel stores for this fibre (``hair.fibre = "chiang"``, docs/hair.md): the
paper's radially constant value, taken as the fibre's outgoing radiance averaged over all
directions with the weight of its projected width, ``L̄ = (1/π²) ∫ L_o(ω) cos θ dω``. It
needs only the directional albedo :class:`FibreAlbedo`, ``Ā(θi) = (1/cos θi) ∫ S(ωo, ωi)
cos θo dωo`` averaged over h: ``L̄ = (1/π²) ∫ L_i(ωi) Ā(θi) cos θi dωi``, the diffuse
fibre's formula with its albedo ρ replaced by Ā of the direction the light comes from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import i0e

from prtcore.core.geometry import orthonormal_frame

#: eumelanin and pheomelanin absorption per unit concentration (RGB, per fibre radius)
EUMELANIN_SIGMA_A = np.array([0.419, 0.697, 1.37])
PHEOMELANIN_SIGMA_A = np.array([0.187, 0.4, 1.05])
P_MAX = 3


@dataclass(frozen=True)
class ChiangParams:
    """sigma_a : (3,) absorption per unit radius; beta_m, beta_n : longitudinal and
    azimuthal roughness in (0, 1]; alpha : cuticle tilt (radians); eta : IOR."""

    sigma_a: tuple[float, float, float] = (0.0, 0.0, 0.0)
    beta_m: float = 0.3
    beta_n: float = 0.3
    alpha: float = np.radians(2.0)
    eta: float = 1.55

    @property
    def variances(self) -> np.ndarray:
        """(4,) longitudinal variances v_p."""
        b = self.beta_m
        v0 = (0.726 * b + 0.812 * b * b + 3.7 * b ** 20) ** 2
        return np.array([v0, 0.25 * v0, 4 * v0, 4 * v0])

    @property
    def logistic_scale(self) -> float:
        """s, the azimuthal logistic's scale."""
        b = self.beta_n
        return float(np.sqrt(np.pi / 8) * (0.265 * b + 1.194 * b * b + 5.372 * b ** 22))


def sigma_a_from_melanin(eumelanin: float, pheomelanin: float = 0.0) -> np.ndarray:
    """(3,) absorption per unit radius for melanin concentrations."""
    return eumelanin * EUMELANIN_SIGMA_A + pheomelanin * PHEOMELANIN_SIGMA_A


def sigma_a_from_color(color: np.ndarray, beta_n: float) -> np.ndarray:
    """(..., 3) absorption per unit radius that gives a hair volume of multiple-scattering
    colour ``color`` (..., 3) in (0, 1] at azimuthal roughness β_n (Chiang et al. 2016,
    eq. 9; pbrt's SigmaAFromReflectance): ``σ_a = (ln c / (5.969 − 0.215 β_n + 2.532 β_n²
    − 10.73 β_n³ + 5.574 β_n⁴ + 0.245 β_n⁵))²``."""
    b = beta_n
    d = 5.969 - 0.215 * b + 2.532 * b ** 2 - 10.73 * b ** 3 + 5.574 * b ** 4 + 0.245 * b ** 5
    c = np.clip(np.asarray(color, dtype=np.float64), 1e-4, 1.0)
    return (np.log(c) / d) ** 2


def _fresnel(cos_i: np.ndarray, eta: float) -> np.ndarray:
    """Unpolarised Fresnel reflectance of a dielectric (outside → inside, IOR eta)."""
    cos_i = np.clip(cos_i, -1.0, 1.0)
    sin_t2 = (1 - cos_i ** 2) / eta ** 2
    cos_t = np.sqrt(np.clip(1 - sin_t2, 0.0, None))
    ci = np.abs(cos_i)
    r_par = (eta * ci - cos_t) / (eta * ci + cos_t)
    r_perp = (ci - eta * cos_t) / (ci + eta * cos_t)
    return np.where(sin_t2 >= 1, 1.0, 0.5 * (r_par ** 2 + r_perp ** 2))


def _mp(cos_i, cos_o, sin_i, sin_o, v):
    """The longitudinal lobe; I₀ through its scaled form for stability at small v."""
    a = cos_i * cos_o / v
    b = sin_i * sin_o / v
    # exp(−b) I₀(a) / (2 v sinh(1/v)), with I₀(a) = i0e(a) e^|a| and
    # sinh(1/v) = e^(1/v) (1 − e^(−2/v)) / 2
    log = np.log(i0e(a)) + np.abs(a) - b - 1 / v - np.log(v) - np.log1p(-np.exp(-2 / v))
    return np.exp(log)


def _trimmed_logistic(x, s):
    def cdf(y):
        return 1 / (1 + np.exp(-y / s))
    e = np.exp(-np.abs(x) / s)
    return e / (s * (1 + e) ** 2) / (cdf(np.pi) - cdf(-np.pi))


def _frame(t: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """sin θ, cos θ and φ of directions w (n, 3) about tangents t (n, 3)."""
    u, v = orthonormal_frame(t)
    sin_t = np.clip(np.einsum("ij,ij->i", w, t), -1.0, 1.0)
    phi = np.arctan2(np.einsum("ij,ij->i", w, v), np.einsum("ij,ij->i", w, u))
    return sin_t, np.sqrt(1 - sin_t ** 2), phi


def attenuation(cos_theta_o: np.ndarray, h: np.ndarray, params: ChiangParams,
                sigma: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A_p (P_MAX + 1, n, 3) for rays at longitudinal cosine cos θo and offsets h (n,), with
    γo and γt (n,) for the azimuthal lobes. ``sigma`` (n, 3): a σ_a per ray instead of
    ``params.sigma_a``."""
    eta = params.eta
    sin_o = np.sqrt(np.clip(1 - cos_theta_o ** 2, 0.0, None))
    sin_t = sin_o / eta
    cos_t = np.sqrt(np.clip(1 - sin_t ** 2, 0.0, None))
    etap = np.sqrt(np.clip(eta * eta - sin_o ** 2, 0.0, None)) / np.maximum(cos_theta_o, 1e-12)
    sin_gt = np.clip(h / etap, -1.0, 1.0)
    cos_gt = np.sqrt(1 - sin_gt ** 2)
    gamma_o = np.arcsin(np.clip(h, -1.0, 1.0))
    gamma_t = np.arcsin(sin_gt)
    sa = np.asarray(params.sigma_a)[None, :] if sigma is None else np.asarray(sigma)
    trans = np.exp(-sa * (2 * cos_gt / np.maximum(cos_t, 1e-12))[:, None])
    f = _fresnel(cos_theta_o * np.cos(gamma_o), eta)[:, None]
    a = np.empty((P_MAX + 1, len(h), 3))
    a[0] = f
    a[1] = (1 - f) ** 2 * trans
    a[2] = a[1] * trans * f
    a[3] = a[2] * f * trans / np.maximum(1 - trans * f, 1e-12)
    return a, gamma_o, gamma_t


def _tilted(sin_o: np.ndarray, cos_o: np.ndarray, alpha: float) -> list:
    """(sin, cos) of θo rotated by the cuticle tilt: −2α for R, +α for TT, +4α for TRT."""
    s2a = [np.sin(2 ** k * alpha) for k in range(3)]
    c2a = [np.cos(2 ** k * alpha) for k in range(3)]
    return [(sin_o * c2a[1] - cos_o * s2a[1], cos_o * c2a[1] + sin_o * s2a[1]),
            (sin_o * c2a[0] + cos_o * s2a[0], cos_o * c2a[0] - sin_o * s2a[0]),
            (sin_o * c2a[2] + cos_o * s2a[2], cos_o * c2a[2] - sin_o * s2a[2])]


def impact_offset(tangent: np.ndarray, normal: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """The offset h (n,) in [−1, 1] at which a ray toward −``wo`` meets a round fibre at
    the point of radial ``normal`` (tangents, normals, wo (n, 3) unit): ``h = sin γo``, γo
    the azimuth from ωo's projection across the fibre to the normal, with the sign of
    :func:`scattering`'s exit azimuths (the R lobe leaves at φi − φo = −2γo, the mirror of
    ωo about the normal; checked in tests/test_bcsdf.py). A camera drawing the fibre
    shades each pixel with it."""
    w = wo - np.einsum("ij,ij->i", wo, tangent)[:, None] * tangent
    n = np.linalg.norm(w, axis=1)
    h = np.einsum("ij,ij->i", np.cross(normal, w), tangent) / np.maximum(n, 1e-300)
    return np.clip(np.where(n > 1e-12, h, 0.0), -1.0, 1.0)


def scattering(tangent: np.ndarray, wo: np.ndarray, wi: np.ndarray, h: np.ndarray,
               params: ChiangParams, sigma: np.ndarray | None = None) -> np.ndarray:
    """S(wo, wi) (n, 3) for fibres of unit tangents (n, 3), unit directions wo (toward the
    viewer) and wi (toward the light), each (n, 3), at offsets h (n,); ``sigma`` (n, 3): a
    σ_a per fibre instead of ``params.sigma_a``."""
    sin_o, cos_o, phi_o = _frame(tangent, wo)
    sin_i, cos_i, phi_i = _frame(tangent, wi)
    a, gamma_o, gamma_t = attenuation(cos_o, h, params, sigma)
    v = params.variances
    s = params.logistic_scale
    phi = phi_i - phi_o
    rot = _tilted(sin_o, cos_o, params.alpha)
    out = np.zeros((len(h), 3))
    for p in range(P_MAX):
        sin_op, cos_op = rot[p]
        dphi = phi - (2 * p * gamma_t - 2 * gamma_o + p * np.pi)
        dphi = np.mod(dphi + np.pi, 2 * np.pi) - np.pi
        lobe = _mp(cos_i, np.abs(cos_op), sin_i, sin_op, v[p]) * _trimmed_logistic(dphi, s)
        out += lobe[:, None] * a[p]
    out += (_mp(cos_i, cos_o, sin_i, sin_o, v[P_MAX]) / (2 * np.pi))[:, None] * a[P_MAX]
    return out


#: the directional albedo table: sin θi nodes, √σ nodes up to SIGMA_MAX (per unit radius),
#: and the Gauss–Legendre nodes over θo and h of its quadrature. Ā is concave in √σ near
#: σ = 0 (A_p ≈ 1 − σ ℓ_p), so linear interpolation there reads low by about
#: (dĀ/dσ) √σ (Δ − √σ) for a node spacing Δ in √σ: with 49 nodes the light hair's fibre
#: stored 0.57 % less energy than it scatters (the quadrature of S itself), which the
#: ~6 bounces of light hair compounded into a −3 % bias (docs/hair.md, "The directional
#: albedo table's σ nodes"); 193 nodes leave 0.01 %.
ALBEDO_SIN_NODES = 129
ALBEDO_SIGMA_NODES = 193
SIGMA_MAX = 32.0
ALBEDO_THETA_QUAD = 512
ALBEDO_H_QUAD = 64


@dataclass(frozen=True)
class FibreAlbedo:
    """The directional albedo of a fibre and its first moments over the outgoing
    direction, averaged over the offset h, tabulated per absorption σ of one channel
    (channels are independent): ``sin_theta`` (S,) and ``root_sigma`` (Q,) float64 nodes,
    ``values`` (6, S, Q) float64, moment m of

    * 0: ``Ā(θi) = (1/cos θi) ∫ S(ωo, ωi) cos θo dωo``;
    * 1: ``Ā_t(θi) = (1/cos θi) ∫ S(ωo, ωi) sin θo cos θo dωo``;
    * 2: ``Ā_⊥(θi) = (1/cos θi) ∫ S(ωo, ωi) cos² θo cos(φo − φi) dωo``;
    * 3: ``Ā_2(θi) = (1/cos θi) ∫ S(ωo, ωi) cos³ θo cos 2(φo − φi) dωo``;
    * 4: ``Ā_z(θi) = (1/cos θi) ∫ S(ωo, ωi) (sin² θo − 1/4) cos θo dωo``;
    * 5: ``Ā_s(θi) = (1/cos θi) ∫ S(ωo, ωi) sin θo cos² θo cos(φo − φi) dωo``.

    Call it with sin θi (n,), σ (n, 3) and the moment for (n, 3) by bilinear
    interpolation (sin θi clamped to the nodes' range, σ to [0, SIGMA_MAX])."""

    sin_theta: np.ndarray
    root_sigma: np.ndarray
    values: np.ndarray

    def __call__(self, sin_theta: np.ndarray, sigma: np.ndarray, moment: int = 0
                 ) -> np.ndarray:
        s = self.sin_theta
        x = (np.clip(sin_theta, s[0], s[-1]) - s[0]) / (s[1] - s[0])
        i = np.minimum(x.astype(np.int64), len(s) - 2)
        fx = (x - i)[:, None]
        r = self.root_sigma
        y = (np.sqrt(np.clip(sigma, 0.0, r[-1] ** 2)) - r[0]) / (r[1] - r[0])
        j = np.minimum(y.astype(np.int64), len(r) - 2)
        fy = y - j
        v = self.values[moment]
        i2 = i[:, None]
        top = v[i2, j] * (1 - fy) + v[i2, j + 1] * fy
        bottom = v[i2 + 1, j] * (1 - fy) + v[i2 + 1, j + 1] * fy
        return top * (1 - fx) + bottom * fx


def fibre_albedo(params: ChiangParams) -> FibreAlbedo:
    """:class:`FibreAlbedo` of the fibre ``params`` (its ``sigma_a`` is ignored: the table
    spans σ). ∫ S dφo is Σ_p M_p A_p (each N_p integrates to one over the azimuth) and
    ∫ S cos(φo − φi) dφo is Σ_p M_p A_p cos Φ_p · E[cos x] (x the lobe's trimmed logistic;
    the sin Φ_p part cancels over ±h), so the tables are quadratures over θo and h only:
    Gauss–Legendre, ALBEDO_THETA_QUAD × ALBEDO_H_QUAD nodes (tests/test_bcsdf.py checks
    them against Monte Carlo over ωo and h with :func:`scattering` itself)."""
    x, w = np.polynomial.legendre.leggauss(ALBEDO_THETA_QUAD)
    theta_o, w_o = x * np.pi / 2, w * np.pi / 2
    sin_o, cos_o = np.sin(theta_o), np.cos(theta_o)
    xh, wh = np.polynomial.legendre.leggauss(ALBEDO_H_QUAD)
    wh = wh / 2  # the mean over h ∈ [−1, 1]
    root = np.linspace(0.0, np.sqrt(SIGMA_MAX), ALBEDO_SIGMA_NODES)
    sigma = root ** 2
    # means over h of A_p(θo, h; σ) and A_p cos Φ_p: (P_MAX + 1, O, Q), three σ per call
    a_mean = np.empty((P_MAX + 1, len(theta_o), len(sigma)))
    a_cos = np.zeros_like(a_mean)
    a_cos2 = np.zeros_like(a_mean)
    cos_rep, h_rep = np.repeat(cos_o, len(xh)), np.tile(xh, len(theta_o))
    # E[cos x] of the azimuthal lobe (the trimmed logistic is even)
    xl, wl = np.polynomial.legendre.leggauss(512)
    lobe = wl * np.pi * _trimmed_logistic(xl * np.pi, params.logistic_scale)
    lobe_cos = float(np.sum(lobe * np.cos(xl * np.pi)))
    lobe_cos2 = float(np.sum(lobe * np.cos(2 * xl * np.pi)))
    for q0 in range(0, len(sigma), 3):
        trip = np.resize(sigma[q0:q0 + 3], 3)
        a, gamma_o, gamma_t = attenuation(cos_rep, h_rep, ChiangParams(
            sigma_a=tuple(trip), beta_m=params.beta_m, beta_n=params.beta_n,
            alpha=params.alpha, eta=params.eta))
        n = min(3, len(sigma) - q0)
        shape = (len(theta_o), len(xh), 3)
        for p in range(P_MAX + 1):
            a_mean[p, :, q0:q0 + n] = np.einsum("ohc,h->oc", a[p].reshape(shape), wh)[:, :n]
            if p < P_MAX:
                phi_p = 2 * p * gamma_t - 2 * gamma_o + p * np.pi
                for arr, c in ((a_cos, np.cos(phi_p) * lobe_cos),
                               (a_cos2, np.cos(2 * phi_p) * lobe_cos2)):
                    arr[p, :, q0:q0 + n] = np.einsum("ohc,h->oc", (a[p] * c[:, None]).reshape(
                        shape), wh)[:, :n]
    sin_i = np.linspace(-1.0, 1.0, ALBEDO_SIN_NODES) * 0.995
    cos_i = np.sqrt(1 - sin_i ** 2)
    v = params.variances
    rot = [*_tilted(sin_o, cos_o, params.alpha), (sin_o, cos_o)]
    table = np.zeros((6, len(sin_i), len(sigma)))
    for p in range(P_MAX + 1):
        sin_op, cos_op = rot[p]
        m = _mp(cos_i[:, None], np.abs(cos_op)[None, :], sin_i[:, None], sin_op[None, :],
                v[p])  # (S, O)
        table[0] += (m * (w_o * cos_o ** 2)[None, :]) @ a_mean[p]
        table[1] += (m * (w_o * sin_o * cos_o ** 2)[None, :]) @ a_mean[p]
        table[2] += (m * (w_o * cos_o ** 3)[None, :]) @ a_cos[p]
        table[3] += (m * (w_o * cos_o ** 4)[None, :]) @ a_cos2[p]
        table[4] += (m * (w_o * (sin_o ** 2 - 0.25) * cos_o ** 2)[None, :]) @ a_mean[p]
        table[5] += (m * (w_o * sin_o * cos_o ** 3)[None, :]) @ a_cos[p]
    return FibreAlbedo(sin_theta=sin_i, root_sigma=root, values=table / cos_i[None, :, None])


def sample_scattering(tangent: np.ndarray, wo: np.ndarray, h: np.ndarray,
                      params: ChiangParams, rng: np.random.Generator,
                      sigma: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Importance-sample wi of :func:`scattering` as pbrt-v3's HairBSDF::Sample_f does: a
    lobe p with probability A_p / Σ A (at wo and h), θi from the longitudinal lobe about
    the tilted −θo (d'Eon's lobe is the marginal of a von Mises–Fisher distribution, sampled
    exactly), φi = φo + Φ(p, h) + a trimmed logistic sample (uniform for the rest). The
    density is then ``Σ_p (A_p/ΣA) M_p N_p`` and the weight ``S / pdf = Σ_p A_p`` exactly.

    tangent, wo : (n, 3) unit; h : (n,); sigma : (n, 3) σ_a per fibre, or None for
    ``params.sigma_a``. Returns wi (n, 3) unit and the weight (n, 3)."""
    n = len(h)
    sin_o, cos_o, phi_o = _frame(tangent, wo)
    a, gamma_o, gamma_t = attenuation(cos_o, h, params, sigma)
    lum = a.mean(axis=2)  # (P + 1, n): the lobe picked by its mean over channels
    cdf = np.cumsum(lum, axis=0) / np.maximum(lum.sum(axis=0), 1e-300)
    p = (rng.random(n)[None, :] > cdf).sum(axis=0).clip(0, P_MAX)
    rot = [*_tilted(sin_o, cos_o, params.alpha), (sin_o, cos_o)]
    sin_op = np.choose(p, [r[0] for r in rot])
    cos_op = np.abs(np.choose(p, [r[1] for r in rot]))
    v = params.variances[p]
    u = np.maximum(rng.random(n), 1e-5)
    cos_t = 1 + v * np.log(u + (1 - u) * np.exp(-2 / v))
    sin_t = np.sqrt(np.clip(1 - cos_t ** 2, 0.0, None))
    sin_i = np.clip(-cos_t * sin_op + sin_t * np.cos(2 * np.pi * rng.random(n)) * cos_op,
                    -1.0, 1.0)
    cos_i = np.sqrt(1 - sin_i ** 2)
    s = params.logistic_scale

    def cdf_l(x):
        return 1 / (1 + np.exp(-x / s))
    k = cdf_l(np.pi) - cdf_l(-np.pi)
    x = np.clip(-s * np.log(1 / (rng.random(n) * k + cdf_l(-np.pi)) - 1), -np.pi, np.pi)
    dphi = np.where(p < P_MAX, 2 * p * gamma_t - 2 * gamma_o + p * np.pi + x,
                    2 * np.pi * rng.random(n))
    phi_i = phi_o + dphi
    uu, vv = orthonormal_frame(tangent)
    wi = sin_i[:, None] * tangent + (cos_i * np.cos(phi_i))[:, None] * uu \
        + (cos_i * np.sin(phi_i))[:, None] * vv
    # S/pdf = Σ A_p only when the lobe is picked with A_p/ΣA per channel; with one pick
    # for all channels by their mean, it is S_c / Σ_p (mean A_p / mean ΣA) M_p N_p
    return wi, _sampled_weight(tangent, wo, wi, h, params, lum, sigma)


def _sampled_weight(tangent, wo, wi, h, params, lum, sigma) -> np.ndarray:
    """S(wo, wi) / pdf(wi) (n, 3) for :func:`sample_scattering`'s density with the lobe
    probabilities ``lum`` (P + 1, n)."""
    s = scattering(tangent, wo, wi, h, params, sigma)
    sin_o, cos_o, phi_o = _frame(tangent, wo)
    sin_i, cos_i, phi_i = _frame(tangent, wi)
    _, gamma_o, gamma_t = attenuation(cos_o, h, params)
    rot = _tilted(sin_o, cos_o, params.alpha)
    v = params.variances
    sc = params.logistic_scale
    prob = lum / np.maximum(lum.sum(axis=0), 1e-300)
    pdf = np.zeros(len(h))
    for p in range(P_MAX):
        sin_op, cos_op = rot[p]
        dphi = (phi_i - phi_o) - (2 * p * gamma_t - 2 * gamma_o + p * np.pi)
        dphi = np.mod(dphi + np.pi, 2 * np.pi) - np.pi
        pdf += prob[p] * _mp(cos_i, np.abs(cos_op), sin_i, sin_op, v[p]) \
            * _trimmed_logistic(dphi, sc)
    pdf += prob[P_MAX] * _mp(cos_i, cos_o, sin_i, sin_o, v[P_MAX]) / (2 * np.pi)
    return s / np.maximum(pdf, 1e-300)[:, None]
