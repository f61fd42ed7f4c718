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

Not yet used by the bake: ``hair.fibre`` accepts only ``"diffuse"``; this module is the
tested building block for the path tracer and the fast path.
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


def attenuation(cos_theta_o: np.ndarray, h: np.ndarray, params: ChiangParams
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A_p (P_MAX + 1, n, 3) for rays at longitudinal cosine cos θo and offsets h (n,), with
    γo and γt (n,) for the azimuthal lobes."""
    eta = params.eta
    sin_o = np.sqrt(np.clip(1 - cos_theta_o ** 2, 0.0, None))
    sin_t = sin_o / eta
    cos_t = np.sqrt(np.clip(1 - sin_t ** 2, 0.0, None))
    etap = np.sqrt(np.clip(eta * eta - sin_o ** 2, 0.0, None)) / np.maximum(cos_theta_o, 1e-12)
    sin_gt = np.clip(h / etap, -1.0, 1.0)
    cos_gt = np.sqrt(1 - sin_gt ** 2)
    gamma_o = np.arcsin(np.clip(h, -1.0, 1.0))
    gamma_t = np.arcsin(sin_gt)
    trans = np.exp(-np.asarray(params.sigma_a)[None, :] * (2 * cos_gt / np.maximum(
        cos_t, 1e-12))[:, None])
    f = _fresnel(cos_theta_o * np.cos(gamma_o), eta)[:, None]
    a = np.empty((P_MAX + 1, len(h), 3))
    a[0] = f
    a[1] = (1 - f) ** 2 * trans
    a[2] = a[1] * trans * f
    a[3] = a[2] * f * trans / np.maximum(1 - trans * f, 1e-12)
    return a, gamma_o, gamma_t


def scattering(tangent: np.ndarray, wo: np.ndarray, wi: np.ndarray, h: np.ndarray,
               params: ChiangParams) -> np.ndarray:
    """S(wo, wi) (n, 3) for fibres of unit tangents (n, 3), unit directions wo (toward the
    viewer) and wi (toward the light), each (n, 3), at offsets h (n,)."""
    sin_o, cos_o, phi_o = _frame(tangent, wo)
    sin_i, cos_i, phi_i = _frame(tangent, wi)
    a, gamma_o, gamma_t = attenuation(cos_o, h, params)
    v = params.variances
    s = params.logistic_scale
    phi = phi_i - phi_o
    s2a = [np.sin(2 ** k * params.alpha) for k in range(3)]
    c2a = [np.cos(2 ** k * params.alpha) for k in range(3)]
    # θo rotated by the tilt: −2α for R, +α for TT, +4α for TRT
    rot = [(sin_o * c2a[1] - cos_o * s2a[1], cos_o * c2a[1] + sin_o * s2a[1]),
           (sin_o * c2a[0] + cos_o * s2a[0], cos_o * c2a[0] - sin_o * s2a[0]),
           (sin_o * c2a[2] + cos_o * s2a[2], cos_o * c2a[2] - sin_o * s2a[2])]
    out = np.zeros((len(h), 3))
    for p in range(P_MAX):
        sin_op, cos_op = rot[p]
        dphi = phi - (2 * p * gamma_t - 2 * gamma_o + p * np.pi)
        dphi = np.mod(dphi + np.pi, 2 * np.pi) - np.pi
        lobe = _mp(cos_i, np.abs(cos_op), sin_i, sin_op, v[p]) * _trimmed_logistic(dphi, s)
        out += lobe[:, None] * a[p]
    out += (_mp(cos_i, cos_o, sin_i, sin_o, v[P_MAX]) / (2 * np.pi))[:, None] * a[P_MAX]
    return out
