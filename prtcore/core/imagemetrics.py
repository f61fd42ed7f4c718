"""Image comparison figures (thesis Tables 4.1–4.4): MAE, PSNR and SSIM of display images
in [0, 1] — the one definition the learnt-transfer method's bake metrics and
``benchmarks/learnt_sh.py`` share."""

from __future__ import annotations

import math

import numpy as np

#: Rec. 709 luminance weights (SSIM is computed on luminance)
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def ssim(a: np.ndarray, b: np.ndarray, sigma: float = 1.5) -> float:
    """Mean SSIM (Wang et al. 2004, Gaussian window ``sigma``) of two (h, w) images in
    [0, 1]."""
    from scipy.ndimage import gaussian_filter

    c1, c2 = 0.01**2, 0.03**2
    mu_a, mu_b = gaussian_filter(a, sigma), gaussian_filter(b, sigma)
    va = gaussian_filter(a * a, sigma) - mu_a**2
    vb = gaussian_filter(b * b, sigma) - mu_b**2
    cov = gaussian_filter(a * b, sigma) - mu_a * mu_b
    s = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (va + vb + c2))
    return float(s.mean())


def compare_images(image: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    """MAE, PSNR (peak 1, dB; inf for equal images) and SSIM (of luminance) of two
    (h, w, 3) display images in [0, 1]."""
    a, b = np.asarray(image, np.float64), np.asarray(reference, np.float64)
    mse = float(np.mean((a - b) ** 2))
    return {"mae": float(np.mean(np.abs(a - b))),
            "psnr": 10.0 * math.log10(1.0 / mse) if mse > 0 else float("inf"),
            "ssim": ssim(a @ LUMINANCE, b @ LUMINANCE)}
