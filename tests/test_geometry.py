"""The shading-normal rule (prtcore.core.geometry) with glTF normal maps (issue 17).

Expectations are computed here from the quad's known layout (∂P/∂u = +2x̂, ∂P/∂v = +2ẑ,
so the image's +X is +x̂ and its +Y, up the image, is −ẑ) and from the stored 8-bit
pixels decoded independently: never from prtcore's own tangent frames.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scenes import write_normal_mapped_quad

from prtcore.core.geometry import shading_normals
from prtcore.io.gltf.loader import load_asset


def _load(path):
    r = load_asset(path)
    return getattr(r, "scene", r)


def _expected(pixel: np.ndarray, scale: float) -> np.ndarray:
    """World normal of one stored pixel on the test quad (tangent x̂, image-up −ẑ, normal ŷ)."""
    t = pixel.astype(np.float64) / 255.0 * 2.0 - 1.0
    t[:2] *= scale
    w = t[0] * np.array([1.0, 0, 0]) + t[1] * np.array([0, 0, -1.0]) + t[2] * np.array(
        [0, 1.0, 0])
    return w / np.linalg.norm(w)


@pytest.mark.parametrize("tilt,scale", [((1, 0), 1.0), ((0, 1), 1.0), ((1, 1), 0.5)])
def test_constant_normal_map_tilts_the_shading_normal(tmp_path, tilt, scale):
    a = math.radians(30.0)
    n = np.array([tilt[0] * math.sin(a), tilt[1] * math.sin(a), math.cos(a)])
    n /= np.linalg.norm(n)
    path, pix = write_normal_mapped_quad(tmp_path / "q.glb", np.tile(n, (4, 4, 1)), scale)
    scene = _load(path)
    mat = scene.materials[0]
    assert mat.normal_texture >= 0 and mat.normal_scale == scale
    # linear data (float32 pixels: tolerance 1e-6 below): no sRGB decoding of the normal map
    np.testing.assert_allclose(scene.textures[mat.normal_texture].pixels[0, 0, :3],
                               pix[0, 0] / 255.0, atol=1e-6)
    rng = np.random.default_rng(0)
    b = rng.dirichlet(np.ones(3), 40)
    tri = rng.integers(0, 2, 40)
    got = shading_normals(scene, tri, b)
    np.testing.assert_allclose(got, np.tile(_expected(pix[0, 0], scale), (40, 1)), atol=1e-6)


def test_varying_map_follows_the_texture_and_flat_material_is_untouched(tmp_path):
    h = w = 8
    x = (np.arange(w) + 0.5) / w
    ang = 0.5 * np.sin(2 * math.pi * x)  # tilt about the image's Y axis, varying along u
    nm = np.zeros((h, w, 3))
    nm[..., 0], nm[..., 2] = np.sin(ang)[None, :], np.cos(ang)[None, :]
    path, pix = write_normal_mapped_quad(tmp_path / "q.glb", nm)
    scene = _load(path)
    # texel centres of column i, row j: u = (i + .5)/w, v = (j + .5)/h → x = 2u − 1, z = 2v − 1
    i, j = np.meshgrid(np.arange(w), np.arange(h))
    u, v = (i.ravel() + 0.5) / w, (j.ravel() + 0.5) / h
    # triangles: 0 = (v0, v1, v2) with uv (0,0), (0,1), (1,1); 1 = (v0, v2, v3)
    upper = v >= u
    tri = np.where(upper, 0, 1)
    bary = np.where(upper[:, None], np.stack([1 - v, v - u, u], 1),
                    np.stack([1 - u, v, u - v], 1))
    got = shading_normals(scene, tri, bary)
    want = np.array([_expected(pix[jj, ii], 1.0)
                     for ii, jj in zip(i.ravel(), j.ravel(), strict=True)])
    np.testing.assert_allclose(got, want, atol=1e-6)
    # the same quad without the map: the interpolated vertex normal, exactly
    flat = scene.replace(materials=tuple(m.__class__(m.name, m.base_color_factor)
                                         for m in scene.materials))
    np.testing.assert_array_equal(shading_normals(flat, tri, bary),
                                  np.tile([0.0, 1.0, 0.0], (len(tri), 1)))
