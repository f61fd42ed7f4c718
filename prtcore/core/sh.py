"""Real spherical harmonics: the one home of the SH math (issue 17; used by issue 18).

Conventions (stated once, used by every caller):

* ``bands`` is the number of SH bands ``L``; a coefficient vector has ``L**2`` entries, band
  ``l`` in ``0 .. L-1``. The poster's "l = 5, 25 coefficients" is ``bands=5``.
* Coefficient ``i = l*(l+1) + m`` for ``m`` in ``-l .. l``.
* The basis is real and orthonormal over the unit sphere, **without** the Condon–Shortley
  phase: ``Y_1 ∝ (y, z, x)`` for ``m = -1, 0, 1`` (positive multiples of the coordinates).
  The polar axis of the basis is +z; it is only an axis of the basis, not of the world.
* Equirectangular maps follow Mitsuba 3's ``envmap`` (so a Mitsuba reference needs no
  transform): world +y is up; pixel column ``u`` in [0, 1) is ``φ = 2πu``, row ``v`` in [0, 1]
  (top row first) is ``θ = πv``; the direction is ``(sin θ sin φ, cos θ, −sin θ cos φ)``.
* A rotation ``R`` (3, 3) acts on a function as ``(R f)(ω) = f(Rᵀ ω)``: the lighting turns
  with the world. :func:`rotation_matrix` gives the (L², L²) matrix with
  ``coeffs(R f) = M @ coeffs(f)``.

Everything is float64. Integrals use product quadratures (Gauss–Legendre in ``cos θ``,
uniform in ``φ``) that are exact for band-limited integrands of the stated degree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache, lru_cache

import numpy as np

MAX_BANDS = 32
"""Largest band count accepted (the recurrences are float64-accurate well beyond this)."""


def n_coeffs(bands: int) -> int:
    """Number of coefficients of ``bands`` bands: ``bands**2``."""
    return _check_bands(bands) ** 2


def _check_bands(bands: int) -> int:
    if not isinstance(bands, (int, np.integer)) or not 1 <= int(bands) <= MAX_BANDS:
        raise ValueError(f"SH bands must be an integer in 1..{MAX_BANDS}, got {bands!r}")
    return int(bands)


def band_of(bands: int) -> np.ndarray:
    """(L²,) int64: the band ``l`` of each coefficient."""
    return np.repeat(np.arange(_check_bands(bands)), 2 * np.arange(bands) + 1)


def normalisation(bands: int) -> np.ndarray:
    """(L, L) float64 read-only table of K_l^m = sqrt((2l+1)/(4π) (l−m)!/(l+m)!) for
    0 ≤ m ≤ l < L (0 above): the basis' normalisation (a GPU evaluator reads it)."""
    return _normalisation(_check_bands(bands))


@cache
def _normalisation(bands: int) -> np.ndarray:
    """(L, L) float64: K_l^m = sqrt((2l+1)/(4π) (l−m)!/(l+m)!) for 0 ≤ m ≤ l (0 above)."""
    k = np.zeros((bands, bands))
    for l in range(bands):
        for m in range(l + 1):
            # (l−m)!/(l+m)! as a product, to stay finite for large l
            ratio = 1.0
            for j in range(l - m + 1, l + m + 1):
                ratio /= j
            k[l, m] = np.sqrt((2 * l + 1) / (4 * np.pi) * ratio)
    k.setflags(write=False)
    return k


def basis(directions: np.ndarray, bands: int) -> np.ndarray:
    """Real orthonormal SH basis at unit ``directions`` (..., 3) float → (..., L²) float64.

    The associated Legendre functions come from the standard three-term recurrence on the
    polynomial part ``P_l^m(z) / sin^m θ``; the azimuthal factors ``sin^m θ cos mφ`` and
    ``sin^m θ sin mφ`` are the real and imaginary parts of ``(x + iy)^m`` (no trigonometry,
    no pole singularity).
    """
    bands = _check_bands(bands)
    d = np.asarray(directions, dtype=np.float64)
    shape = d.shape[:-1]
    d = d.reshape(-1, 3)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    k = _normalisation(bands)
    out = np.empty((d.shape[0], bands * bands))
    c_m = np.ones_like(x)  # Re (x+iy)^m
    s_m = np.zeros_like(x)  # Im (x+iy)^m
    p_mm = np.ones_like(x)  # polynomial part of P_m^m: (2m−1)!!
    for m in range(bands):
        if m > 0:
            c_m, s_m = c_m * x - s_m * y, c_m * y + s_m * x
            p_mm = p_mm * (2 * m - 1)
        p_prev, p_cur = None, p_mm
        for l in range(m, bands):
            if l == m + 1:
                p_prev, p_cur = p_cur, z * (2 * m + 1) * p_mm
            elif l > m + 1:
                p_prev, p_cur = p_cur, ((2 * l - 1) * z * p_cur - (l + m - 1) * p_prev) / (l - m)
            centre = l * (l + 1)
            if m == 0:
                out[:, centre] = k[l, 0] * p_cur
            else:
                scale = np.sqrt(2.0) * k[l, m] * p_cur
                out[:, centre + m] = scale * c_m
                out[:, centre - m] = scale * s_m
    return out.reshape(*shape, bands * bands)


def evaluate(coeffs: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Reconstruct a function from ``coeffs`` (L², ...) at ``directions`` (n, 3).

    Returns (n, ...) float64: ``basis(directions) @ coeffs``.
    """
    coeffs = np.asarray(coeffs, dtype=np.float64)
    bands = _bands_of(coeffs.shape[0])
    y = basis(directions, bands)
    return np.tensordot(y, coeffs, axes=([1], [0]))


def _bands_of(count: int) -> int:
    bands = math.isqrt(count)
    if bands * bands != count:
        raise ValueError(f"an SH coefficient vector has a square length, got {count}")
    return _check_bands(bands)


@dataclass(frozen=True)
class Quadrature:
    """Directions and weights of a spherical quadrature.

    directions : (n, 3) float64 unit vectors; weights : (n,) float64 solid angles, sum 4π.
    """

    directions: np.ndarray
    weights: np.ndarray


@lru_cache(maxsize=64)
def _product_quadrature(degree: int) -> Quadrature:
    n_theta = degree // 2 + 1
    n_phi = degree + 1
    z, wz = np.polynomial.legendre.leggauss(n_theta)
    phi = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    sin_t = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    dirs = np.stack([np.outer(sin_t, np.cos(phi)), np.outer(sin_t, np.sin(phi)),
                     np.repeat(z[:, None], n_phi, axis=1)], axis=-1).reshape(-1, 3)
    weights = np.repeat(wz * (2.0 * np.pi / n_phi), n_phi)
    dirs.setflags(write=False)
    weights.setflags(write=False)
    return Quadrature(dirs, weights)


def quadrature(degree: int) -> Quadrature:
    """A product quadrature exact for every spherical polynomial of degree ≤ ``degree``
    (any product of SH of total band ≤ ``degree``): ``degree//2 + 1`` Gauss–Legendre nodes in
    ``cos θ`` times ``degree + 1`` uniform azimuths."""
    if degree < 0:
        raise ValueError(f"quadrature degree must be ≥ 0, got {degree}")
    return _product_quadrature(int(degree))


def project_function(f, bands: int, degree: int | None = None) -> np.ndarray:
    """SH coefficients of ``f`` (callable: (n, 3) directions → (n, ...) values).

    Integrated with :func:`quadrature` of ``degree`` (default ``4 * bands``): exact when ``f``
    is band-limited to ``degree − bands + 1`` bands, a quadrature estimate otherwise (raise
    ``degree`` for functions with kinks). Returns (L², ...) float64.
    """
    bands = _check_bands(bands)
    q = quadrature(4 * bands if degree is None else degree)
    values = np.asarray(f(q.directions), dtype=np.float64)
    y = basis(q.directions, bands) * q.weights[:, None]
    return np.tensordot(y, values, axes=([0], [0]))


def equirect_directions(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre directions (H, W, 3) float64 and exact pixel solid angles (H, W) float64
    of an equirectangular map (the module's convention). Solid angles sum to 4π."""
    theta_edges = np.linspace(0.0, np.pi, height + 1)
    theta = 0.5 * (theta_edges[:-1] + theta_edges[1:])
    phi = (np.arange(width) + 0.5) * (2.0 * np.pi / width)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    dirs = np.stack([st * np.sin(phi)[None, :], np.broadcast_to(ct, (height, width)),
                     -st * np.cos(phi)[None, :]], axis=-1)
    band_area = (2.0 * np.pi / width) * (np.cos(theta_edges[:-1]) - np.cos(theta_edges[1:]))
    return dirs, np.broadcast_to(band_area[:, None], (height, width)).copy()


def equirect_uv(directions: np.ndarray) -> np.ndarray:
    """(..., 2) float64 equirect coordinates (u in [0, 1), v in [0, 1]) of unit
    ``directions`` (..., 3): the inverse of :func:`equirect_directions`' mapping."""
    d = np.asarray(directions, dtype=np.float64)
    u = np.mod(np.arctan2(d[..., 0], -d[..., 2]) / (2.0 * np.pi), 1.0)
    v = np.arccos(np.clip(d[..., 1], -1.0, 1.0)) / np.pi
    return np.stack([u, v], axis=-1)


def project_equirect(image: np.ndarray, bands: int, *, chunk_rows: int = 64) -> np.ndarray:
    """SH coefficients (L², C) float64 of an equirect ``image`` (H, W, C) (or (H, W)) of
    radiance: ``Σ_pixels L(ω_p) Y(ω_p) dΩ_p`` with exact pixel solid angles. Rows are
    processed ``chunk_rows`` at a time so memory stays O(chunk · W · L²)."""
    bands = _check_bands(bands)
    img = np.asarray(image, dtype=np.float64)
    flat = img.ndim == 2
    if flat:
        img = img[..., None]
    h, w, c = img.shape
    dirs, area = equirect_directions(h, w)
    out = np.zeros((bands * bands, c))
    for r0 in range(0, h, chunk_rows):
        r1 = min(h, r0 + chunk_rows)
        y = basis(dirs[r0:r1].reshape(-1, 3), bands)
        vals = img[r0:r1].reshape(-1, c) * area[r0:r1].reshape(-1, 1)
        out += y.T @ vals
    return out[:, 0] if flat else out


def reconstruct_equirect(coeffs: np.ndarray, height: int, width: int) -> np.ndarray:
    """The function of ``coeffs`` (L², ...) sampled at an equirect map's pixel centres:
    (H, W, ...) float64."""
    dirs, _ = equirect_directions(height, width)
    return evaluate(coeffs, dirs.reshape(-1, 3)).reshape(height, width, *np.shape(coeffs)[1:])


def band_energy(coeffs: np.ndarray) -> np.ndarray:
    """Per-band energy ``Σ_m c_lm²`` (L, ...) float64 of ``coeffs`` (L², ...): invariant under
    rotation; its sum is the squared L² norm of the reconstructed function."""
    coeffs = np.asarray(coeffs, dtype=np.float64)
    bands = _bands_of(coeffs.shape[0])
    sq = coeffs ** 2
    return np.stack([sq[l * l:(l + 1) * (l + 1)].sum(axis=0) for l in range(bands)])


def rotation_matrix(rotation: np.ndarray, bands: int) -> np.ndarray:
    """(L², L²) float64 block-diagonal matrix ``M`` with ``coeffs(R f) = M @ coeffs(f)`` for a
    3×3 rotation ``R`` (``(R f)(ω) = f(Rᵀ ω)``).

    Each band block is the projection of the rotated basis onto the basis with a quadrature
    exact for degree ``2l`` products (so the blocks are exact to rounding, orthogonal, and no
    matrix is inverted).
    """
    bands = _check_bands(bands)
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-9) \
            or np.linalg.det(r) < 0:
        raise ValueError("rotation must be a proper 3×3 rotation matrix")
    q = quadrature(2 * (bands - 1))
    y = basis(q.directions, bands)                    # Y(ω)
    y_rot = basis(q.directions @ r, bands)            # Y(Rᵀ ω), rows are ω
    m = np.zeros((bands * bands, bands * bands))
    for l in range(bands):
        s = slice(l * l, (l + 1) * (l + 1))
        # coeffs of the rotated basis function Y_j(Rᵀ ω) on Y_i: ∫ Y_i(ω) Y_j(Rᵀω) dω
        m[s, s] = (y[:, s] * q.weights[:, None]).T @ y_rot[:, s]
    return m


def rotate(coeffs: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Coefficients (L², ...) of the function of ``coeffs`` turned by ``rotation`` (3, 3)."""
    coeffs = np.asarray(coeffs, dtype=np.float64)
    return np.tensordot(rotation_matrix(rotation, _bands_of(coeffs.shape[0])), coeffs,
                        axes=([1], [0]))


@lru_cache(maxsize=16)
def _triple_product_tensor(bands: int) -> np.ndarray:
    q = quadrature(3 * (bands - 1))
    y = basis(q.directions, bands)
    t = np.einsum("ni,nj,nk,n->ijk", y, y, y, q.weights, optimize=True)
    t[np.abs(t) < 1e-13] = 0.0
    t.setflags(write=False)
    return t


def triple_product_tensor(bands: int) -> np.ndarray:
    """Γ (L², L², L²) float64, ``Γ_ijk = ∫ Y_i Y_j Y_k dω`` (exact quadrature of degree
    3(L−1); entries below 1e−13 are exactly zero). Symmetric in all three indices; read-only
    and cached."""
    return _triple_product_tensor(_check_bands(bands))


def product_matrix(coeffs: np.ndarray) -> np.ndarray:
    """(L², L²) float64 matrix ``P`` with ``P @ b`` = the SH projection (same bands) of the
    product of the functions of ``coeffs`` (L²,) and ``b``: ``P_kj = Σ_i Γ_ijk a_i``."""
    coeffs = np.asarray(coeffs, dtype=np.float64)
    return np.tensordot(coeffs, triple_product_tensor(_bands_of(coeffs.shape[0])),
                        axes=([0], [0]))


def product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """SH projection (L²,) of the product of the functions of ``a`` and ``b`` (L²,) each."""
    return product_matrix(a) @ np.asarray(b, dtype=np.float64)


def clamped_cosine_zonal(bands: int) -> np.ndarray:
    """(L,) float64 zonal coefficients ``z_l`` of ``max(0, cos θ)`` about the polar axis (its
    SH coefficients are ``z_l`` at ``m = 0``): ``z_0 = √π/2``, ``z_1 = √(π/3)``, 0 for odd
    ``l > 1``, and for even ``l`` the closed form of Ramamoorthi & Hanrahan (2001)."""
    bands = _check_bands(bands)
    a = np.zeros(bands)  # convolution weights Â_l; z_l = Â_l √((2l+1)/(4π))
    a[0] = np.pi
    if bands > 1:
        a[1] = 2.0 * np.pi / 3.0
    for l in range(2, bands, 2):
        half = l // 2
        # l! / (2^l (l/2)!²) by a running product (finite for large l)
        ratio = 1.0
        for j in range(1, half + 1):
            ratio *= (half + j) / (4.0 * j)
        a[l] = 2.0 * np.pi * (-1) ** (half - 1) / ((l + 2) * (l - 1)) * ratio
    return a * np.sqrt((2 * np.arange(bands) + 1) / (4.0 * np.pi))


def phong_zonal(exponent: float, bands: int) -> np.ndarray:
    """(L,) float64 zonal coefficients of the normalised Phong lobe about the polar axis,
    ``(n+1)/(2π) · max(0, cos θ)^n`` (integral 1 over the sphere), n = ``exponent`` ≥ 0.

    Integrated by Gauss–Legendre in cos θ over [0, 1] with enough nodes to be exact for
    integer n (the integrand is a polynomial there); accurate to rounding for fractional n
    ≥ 1 with the same nodes doubled.
    """
    bands = _check_bands(bands)
    if not exponent >= 0:
        raise ValueError(f"Phong exponent must be ≥ 0, got {exponent!r}")
    nodes = math.ceil(exponent) // 2 + bands + 8
    if exponent != int(exponent):
        nodes *= 2
    z, w = np.polynomial.legendre.leggauss(nodes)
    z, w = 0.5 * (z + 1.0), 0.5 * w  # onto [0, 1]
    lobe = (exponent + 1.0) / (2.0 * np.pi) * z ** exponent
    polar = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)
    y0 = basis(polar, bands)[:, [l * (l + 1) for l in range(bands)]]
    return 2.0 * np.pi * (w * lobe) @ y0


def zonal_kernel(zonal: np.ndarray) -> np.ndarray:
    """(L²,) float64 Funk–Hecke scale of each coefficient for a kernel with zonal
    coefficients ``zonal`` (L,): ``√(4π/(2l+1)) z_l`` at every m of band l. Convolving a
    function with the kernel multiplies its coefficients by this; the kernel turned to a
    direction a is ``zonal_kernel(z) * basis(a)``."""
    z = np.asarray(zonal, dtype=np.float64)
    bands = z.shape[0]
    return (np.sqrt(4.0 * np.pi / (2 * np.arange(bands) + 1)) * z)[band_of(bands)]


def convolve_zonal(coeffs: np.ndarray, zonal: np.ndarray) -> np.ndarray:
    """Convolution of a function (coeffs (L², ...)) with a kernel symmetric about the polar
    axis (its zonal coefficients (L,)): ``c'_lm = √(4π/(2l+1)) z_l c_lm`` (Funk–Hecke).
    With :func:`clamped_cosine_zonal` this turns radiance into irradiance."""
    coeffs = np.asarray(coeffs, dtype=np.float64)
    scale = zonal_kernel(np.asarray(zonal)[:_bands_of(coeffs.shape[0])])
    return coeffs * scale.reshape(-1, *([1] * (coeffs.ndim - 1)))


def zonal_to_direction(zonal: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Coefficients (L²,) of a kernel with zonal coefficients ``zonal`` (L,) turned so its
    symmetry axis is the unit ``axis`` (3,): ``c_lm = √(4π/(2l+1)) z_l Y_lm(axis)``."""
    k = zonal_kernel(zonal)
    return basis(np.asarray(axis, dtype=np.float64)[None, :], _bands_of(len(k)))[0] * k
