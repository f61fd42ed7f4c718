"""Every numerical tolerance and ray offset of prtcore, in one place, scaled to the scene.

Never use a fixed absolute epsilon in world units: assets range from millimetres to
kilometres. Distances derive from the scene's bounding-sphere radius ``scale``.
"""

from __future__ import annotations

import numpy as np

#: Relative ray-origin offset, times the scene radius. float32 positions carry ~6e-8
#: relative precision; 1e-5 of the radius keeps origins off the surface with a wide margin
#: while staying far below any feature that matters for lighting.
RAY_OFFSET_REL = 1e-5
#: Ray t_far for "infinite" rays, times the scene radius.
RAY_TFAR_REL = 1e3
#: Triangles whose area is below this fraction of scale² count as degenerate.
DEGENERATE_AREA_REL = 1e-14
#: Vertices closer than this fraction of the radius are the same vertex (repair/welding).
WELD_DISTANCE_REL = 1e-7
#: UV overlap / containment tolerance, in texels.
UV_TEXEL_EPS = 1e-3
#: Barycentric slack when testing a point against a triangle in UV space.
BARY_EPS = 1e-9
#: Length below which a normal is considered zero.
NORMAL_EPS = 1e-12
#: Albedo clamp for transport (docs/bundle.md): per channel ≤ this.
ALBEDO_MAX = 0.99


# -- fitting (prtcore/fit.py) --------------------------------------------------------
#: Eigenvalues of the snapshot Gram matrix at or below this fraction of the largest are
#: dropped. An eigenvector error from eigh of ε·e_max turns into a relative basis error of
#: about ε·σ_max/σ_i after U = A V Σ⁻¹, so 1e-12 (σ_i/σ_max = 1e-6) keeps U accurate to
#: ~1e-10, while float64 round-off of an exactly low-rank A sits near 1e-16.
EIG_REL_TOL = 1e-12
#: Singular values of the (centred, normalised) direct matrix at or below this fraction of
#: the largest are treated as zero in the transfer solve: the λ → 0 limit is then the
#: minimum-norm solution of the well-determined part. Not a float64 rank tolerance: the
#: transfer M is stored and applied in float32 (relative rounding 6e-8), and a component
#: kept at σ_i/σ_max = r amplifies that rounding by up to 1/r. With 1e-12, nearly
#: collinear measurement points (σ_min/σ_max ≈ 4e-11) and λ = 0 gave |M| ≈ 8e8 and a
#: float32 reconstruction 2 % away from the float64 one (tests/stability); at 1e-6 the
#: float32 and float64 models agree to ~1e-6 relative.
DIRECT_SVD_REL_TOL = 1e-6
#: A configuration whose leverage h_kk leaves 1 − h_kk at or below this is interpolated by
#: the fit: its leave-one-out residual is undefined and that λ scores +inf.
LOO_LEVERAGE_TOL = 1e-10
#: The span of the training lights' direct vectors (out-of-family warnings) keeps singular
#: directions above this fraction of the largest singular value.
FAMILY_SPAN_REL_TOL = 1e-3
#: A light warns as out of family when the part of its direct vector outside that span
#: exceeds max(2 × the held-out lights' largest, this floor) of the vector's norm.
FAMILY_RESIDUAL_FLOOR = 0.05


def ray_offset(scale: float) -> float:
    """Ray-origin offset in world units for a scene of bounding-sphere radius ``scale``."""
    return float(RAY_OFFSET_REL * max(scale, np.finfo(np.float32).tiny))


def offset_origins(points: np.ndarray, normals: np.ndarray, scale: float) -> np.ndarray:
    """Move ray origins off their surface along ``normals``.

    points, normals : (n, 3) float
    Returns (n, 3) float32, the single ray-offset rule of the project.
    """
    return (points + normals * ray_offset(scale)).astype(np.float32)
