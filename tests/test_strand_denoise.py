"""The strand texels' denoising (prtcore.transport.strand_denoise): the kernel's rows, what
it must leave alone, and that it removes noise. Its accuracy against the fibre path tracer
is in tests/test_reference_fibres.py; the figures in docs/hair.md."""

from __future__ import annotations

import numpy as np
import pytest

from prtcore.core.spec import SpecError, parse_spec
from prtcore.receivers.strands import build_strand_space
from prtcore.scenes.hair import tangle
from prtcore.transport.dataset import Dataset
from prtcore.transport.strand_denoise import (
    denoise_dataset,
    denoise_irradiance,
    neighbour_kernel,
)


def _points(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).random((n, 3))


def test_kernel_rows_are_normalised_local_and_hold_the_texel_itself():
    p = _points(500)
    ker = neighbour_kernel(p, 16, local_linear=False)
    m = ker.matrix.tocsr()
    assert m.shape == (500, 500) and m.dtype == np.float32
    np.testing.assert_allclose(np.asarray(m.sum(axis=1)).ravel(), 1.0, rtol=1e-6)
    assert np.all(np.diff(m.indptr) == 16)
    assert np.all(m.diagonal() > 0)
    # every neighbour lies within the texel's radius, the 17th nearest point's distance
    rows = np.repeat(np.arange(500), 16)
    d = np.linalg.norm(p[m.indices] - p[rows], axis=1)
    assert np.all(d <= ker.radius[rows] + 1e-12)
    # the nearest other point weighs more than a farther one (Epanechnikov)
    w = m.toarray()
    i = 7
    order = np.argsort(np.linalg.norm(p - p[i], axis=1))
    assert w[i, order[1]] > w[i, order[10]] > 0


def test_fewer_texels_than_neighbours_and_the_identity():
    p = _points(5)
    ker = neighbour_kernel(p, 32, local_linear=False)  # every texel is every one's neighbour
    assert ker.neighbours == 5
    np.testing.assert_allclose(np.asarray(ker.matrix.sum(axis=1)).ravel(), 1, rtol=1e-6)
    assert np.all(ker.matrix.toarray() > 0)
    for k in (0, 1):
        np.testing.assert_array_equal(neighbour_kernel(p, k).matrix.toarray(), np.eye(5))


def test_uniform_irradiance_and_colour_edges_are_kept_exactly():
    """A field of constant irradiance over strands of two colours side by side is left as
    it is: the filter averages irradiance, not radiance, so colours do not mix. A channel
    in which a fibre is black stays black and lends nothing."""
    n = 400
    p = _points(n, 1)
    albedo = np.where((np.arange(n) % 2 == 0)[:, None], [0.9, 0.1, 0.0], [0.1, 0.2, 0.8])
    e = np.array([[1.0, 2.0, 3.0], [0.5, 0.5, 0.5]])  # (K, 3) irradiance per light
    radiance = (albedo[:, None, :] / np.pi * e[None]).astype(np.float32)
    out = denoise_irradiance(neighbour_kernel(p, 24), radiance.copy(), albedo, position=p)
    np.testing.assert_allclose(out, radiance, rtol=1e-5, atol=1e-7)
    assert np.all(out[0::2, :, 2] == 0)
    # the blue channel's kernel was rebuilt over the odd texels alone: without the
    # positions that cannot be done
    with pytest.raises(ValueError, match="positions"):
        denoise_irradiance(neighbour_kernel(p, 24), radiance.copy(), albedo)


def test_texels_that_lend_nothing_are_nobodys_neighbours():
    p = _points(300, 2)
    lend = np.arange(300) % 3 != 0
    m = neighbour_kernel(p, 12, lend=lend).matrix
    assert np.all(lend[m.indices]) and np.all(np.diff(m.indptr) == 12)
    np.testing.assert_allclose(np.asarray(m.sum(axis=1)).ravel(), 1, rtol=1e-5)


def test_the_local_linear_fit_keeps_a_gradient_where_the_average_bends_it():
    """Irradiance falling linearly through a ball of texels (light entering from one
    side): the local linear fit reproduces it exactly, at the ball's surface too, where the
    kernel average's one-sided neighbours pull every texel towards the inside. Texels on
    one line (a lone strand) fit along the line and do not extrapolate across it."""
    rng = np.random.default_rng(4)
    p = rng.normal(size=(4000, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    p *= np.cbrt(rng.random((4000, 1)))
    e = 2.0 + p[:, 0]
    radiance = np.repeat((0.5 / np.pi * e)[:, None, None], 3, axis=2).astype(np.float32)
    albedo = np.full((4000, 3), 0.5)
    llr = denoise_irradiance(neighbour_kernel(p, 64), radiance.copy(), albedo)
    avg = denoise_irradiance(neighbour_kernel(p, 64, local_linear=False), radiance.copy(),
                             albedo)
    # within the slopes' ridge (SLOPE_RIDGE shrinks them by a fraction of a per cent)
    np.testing.assert_allclose(llr, radiance, rtol=5e-3)
    rim = np.linalg.norm(p, axis=1) > 0.9
    bent = np.abs(avg - radiance)[rim].max() / radiance[rim].mean()
    assert bent > 0.03, bent
    line = np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)]
    ker = neighbour_kernel(line, 16)
    assert ker.local_linear
    ramp = 1 + 3 * line[:, 0]
    np.testing.assert_allclose(ker.matrix @ ramp, ramp, rtol=1e-2)
    end = neighbour_kernel(line, 16, local_linear=False).matrix @ ramp
    assert end[0] > 1.2 and end[-1] < 3.8, end  # the average, pulled inwards at the ends
    assert np.abs(ker.matrix).sum(axis=1).max() <= 2.5


def test_the_directional_fit_keeps_a_response_that_turns_with_the_fibre():
    """Texels in a ball whose fibres point every way, receiving a field that depends on
    the fibre's direction as a radially averaged fibre's response does (second band in t,
    plus a gradient in space), with 30 % noise. The plane alone mixes fibres of other
    directions and keeps an error of the size of the direction term; the fit with the
    direction's second band (``direction="t2"``) recovers the field within a third of the
    noise, without bias. Where every neighbour points the same way (parallel strands) the
    direction terms cannot be told apart, and their ridge keeps the plane."""
    rng = np.random.default_rng(8)
    n = 20000
    p = rng.normal(size=(n, 3))
    p *= np.cbrt(rng.random((n, 1))) / np.linalg.norm(p, axis=1, keepdims=True)
    t = rng.normal(size=(n, 3))
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    axis = np.array([0.6, 0.0, 0.8])
    truth = (2.0 + 0.5 * p[:, 0] + 1.2 * (t @ axis) ** 2)[:, None, None] * np.ones((1, 2, 3))
    noisy = (truth * (1 + 0.3 * rng.standard_normal(truth.shape))).astype(np.float32)
    albedo = np.full((n, 3), 0.5)

    def err(kernel):
        out = denoise_irradiance(kernel, noisy.copy(), albedo)
        return np.sqrt(np.mean((out - truth) ** 2)) / np.sqrt(np.mean(truth ** 2)), \
            out.mean() / truth.mean() - 1

    plane = err(neighbour_kernel(p, 128))
    turned = neighbour_kernel(p, 128, tangent=t, direction="t2")
    assert turned.direction == "t2"
    turns = err(turned)
    noise = 0.3 * np.sqrt(np.mean(truth ** 2)) / np.sqrt(np.mean(truth ** 2))
    assert plane[0] > 0.1 and turns[0] < noise / 3, (plane, turns)
    assert abs(turns[1]) < 0.01, turns
    # parallel fibres: the same weights as the plane's, within the ridge
    same = np.tile([0.0, 0.0, 1.0], (n, 1))
    a = neighbour_kernel(p[:2000], 64, tangent=same[:2000], direction="t12").matrix
    b = neighbour_kernel(p[:2000], 64).matrix
    assert abs(a - b).max() < 1e-3
    with pytest.raises(ValueError, match="tangents"):
        neighbour_kernel(p, 16, direction="t2")


def test_denoising_removes_independent_noise_and_keeps_a_smooth_field():
    """A smooth field with 30 % independent noise per texel: the filter brings it within
    a third of the noise and does not shift its mean."""
    rng = np.random.default_rng(3)
    p = rng.random((20000, 3))
    truth = (1 + p[:, 0] + 0.5 * np.sin(3 * p[:, 1]))[:, None, None] * np.ones((1, 2, 3))
    noisy = (truth * (1 + 0.3 * rng.standard_normal(truth.shape))).astype(np.float32)
    albedo = np.full((len(p), 3), 0.5)
    out = denoise_irradiance(neighbour_kernel(p, 32), noisy.copy(), albedo)
    before = np.sqrt(np.mean((noisy - truth) ** 2))
    after = np.sqrt(np.mean((out - truth) ** 2))
    assert after < before / 3, (before, after)
    assert abs(out.mean() / truth.mean() - 1) < 0.01


def test_denoise_dataset_filters_the_strand_rows_only():
    """With a mesh's atlas texels first, only the strand rows change; the stats say so."""
    space = build_strand_space(tangle(60), 4)
    t_m, t = 7, space.count
    rng = np.random.default_rng(0)
    indirect = rng.random((t_m + t, 3, 3)).astype(np.float32)
    data = Dataset(lights=(), direct_points=np.zeros((0, 3, 3), np.float32),
                   direct_texels=None, indirect=indirect.copy(), iterations=1, residual=0.0)
    out = denoise_dataset(data, space, 8, first_row=t_m)
    np.testing.assert_array_equal(out.indirect[:t_m], indirect[:t_m])
    assert not np.allclose(out.indirect[t_m:], indirect[t_m:])
    assert out.stats["denoise"]["neighbours"] == 8
    # the strand rows are exactly the kernel applied to the irradiance
    ker = neighbour_kernel(space.position, 8)
    expect = denoise_irradiance(ker, indirect[t_m:].copy(), space.albedo)
    np.testing.assert_array_equal(out.indirect[t_m:], expect)
    assert denoise_dataset(data, space, 0) is data


def test_the_spec_key_and_its_default_per_fibre():
    from prtcore.hairbake import hair_spec
    assert parse_spec({}).hair.denoise_neighbours == "auto"
    assert hair_spec(parse_spec({})).hair.denoise_neighbours == 64
    assert hair_spec(parse_spec({})).hair.denoise_direction == "none"
    # the Chiang fibre's texels differ with the fibre's direction (docs/hair.md): its fit
    # takes the direction's second band; whether it is denoised waits for the strands
    # to be counted: alone, by the rays its texels get (small_hair), with a mesh by how
    # dense the hair is, before the transport (tests/test_hairbake.py, dense_hair)
    chiang = hair_spec(parse_spec({"hair": {"fibre": "chiang"}})).hair
    assert (chiang.denoise_neighbours, chiang.denoise_direction) == ("auto", "t2")
    chiang = hair_spec(parse_spec({"hair": {"fibre": "chiang"}}), with_mesh=True).hair
    assert (chiang.denoise_neighbours, chiang.denoise_direction) == ("auto", "t2")
    assert hair_spec(parse_spec({}), with_mesh=True).hair.denoise_neighbours == 64
    assert hair_spec(parse_spec({"hair": {"fibre": "chiang", "denoise_direction": "none"}})
                     ).hair.denoise_direction == "none"
    with pytest.raises(SpecError, match=r"hair\.denoise_direction"):
        parse_spec({"hair": {"denoise_direction": "t3"}})
    assert hair_spec(parse_spec({"hair": {"fibre": "chiang", "denoise_neighbours": 8}})
                     ).hair.denoise_neighbours == 8
    assert parse_spec({"hair": {"denoise_neighbours": 0}}).hair.denoise_neighbours == 0
    with pytest.raises(SpecError, match=r"hair\.denoise_neighbours"):
        parse_spec({"hair": {"denoise_neighbours": -1}})


def test_a_chiang_bake_is_denoised_when_asked_against_its_fibres_albedo(tmp_path):
    """``hair.denoise_neighbours`` set for the Chiang fibre: the bake denoises, dividing by
    the fibre's sphere-averaged directional albedo, which is in (0, 1) and larger for
    lighter hair."""
    import json

    from prtcore.core.spec import ChiangSpec
    from prtcore.io.hair import write_hair
    from prtcore.pipeline import bake
    from prtcore.transport.fibre_chiang import chiang_fibre, texel_albedo

    space = build_strand_space(tangle(40), 2)
    light = texel_albedo(chiang_fibre(ChiangSpec(eumelanin=0.5), space))
    dark = texel_albedo(chiang_fibre(ChiangSpec(eumelanin=4.0), space))
    assert light.shape == (space.count, 3) and np.all((0 < dark) & (dark < light) & (light < 1))
    asset = write_hair(tmp_path / "t.hair", tangle(60))
    spec = {"hair": {"texels_per_strand": 4, "fibre": "chiang", "denoise_neighbours": 8},
            "lights": {"count": 12, "holdout": 4}, "measurement_points": {"count": 8},
            "transport": {"gather_rays": 8}, "fit": {"basis": 4}}
    out = bake(asset, parse_spec(spec), tmp_path / "out", quiet=True)
    report = json.loads((out / "report.json").read_text())
    assert report["transport"]["denoise"]["neighbours"] == 8
