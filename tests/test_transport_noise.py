"""The fast transport's own error and the lightmap filter chosen from it
(prtcore.transport.noise, issue 13). The estimate is checked against the known truth of
synthetic lightmaps, and on the Cornell box against an independent transport with 16× the
gather rays; the validation's projection bound against a noisy reference against its
closed form."""

from __future__ import annotations

import dataclasses
import json
from types import SimpleNamespace

import numpy as np
import pytest
from scenes import tiny_spec

from prtcore.core.errors import SpecError
from prtcore.core.spec import parse_spec
from prtcore.emitters.families import sample_configurations
from prtcore.pipeline import bake, run_intake
from prtcore.receivers.smoothing import smooth_texels, smoothing_operator, smoothing_operators
from prtcore.scenes.cornell import write_cornell_box
from prtcore.transport.dataset import light_configurations, open_transport
from prtcore.transport.noise import (
    DENOISE_RADII,
    choose_radius,
    measure_noise,
    second_seed,
    with_denoise,
)
from prtcore.validate import BasisAtTexels

SPEC = tiny_spec(atlas={"resolution": 48, "padding": 2},
                 measurement_points={"count": 16, "supersample": 2},
                 lights={"count": 16, "holdout": 6, "families": [
                     {"type": "point", "position": {"box": [[-0.6, 1.3, -0.6],
                                                             [0.6, 1.7, 0.6]]},
                      "intensity": {"uniform": [0.5, 3.0]}}]},
                 transport={"gather_rays": 16, "max_bounces": 8}, fit={"basis": 8})


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    asset = write_cornell_box(tmp_path_factory.mktemp("box") / "box.glb")
    return asset, run_intake(asset, parse_spec(SPEC), quiet=True)


def _truth(texels, kind: str) -> np.ndarray:
    """(T, 2, 3) noiseless lightmaps: smooth (linear in position) or texel-sized detail."""
    p = np.asarray(texels.position, dtype=np.float64)
    rho = np.clip(texels.albedo, 0.05, 0.95)
    if kind == "smooth":
        e = np.stack([1.0 + 0.3 * p[:, 0], 1.0 + 0.3 * p[:, 2]], axis=1)
    else:  # a checkerboard of texel size: any filter blurs it
        cell = np.floor(p / 0.02).astype(int).sum(axis=1) % 2
        e = np.stack([0.2 + cell, 1.2 - cell], axis=1)
    return rho[:, None, :] * e[:, :, None]


@pytest.mark.parametrize(("kind", "noise", "best"), [("smooth", 0.2, "filter"),
                                                       ("detail", 0.01, "none")])
def test_the_estimate_tracks_the_true_error_and_picks_the_best_radius(box, kind, noise, best):
    tx = box[1].texels
    t = _truth(tx, kind)
    rng = np.random.default_rng(7)
    f, g = (t + noise * t.std() * rng.standard_normal(t.shape) for _ in range(2))
    radius, est = choose_radius(tx, f, g)
    ops = [None, *smoothing_operators(tx, DENOISE_RADII[1:])]
    true = [np.linalg.norm((f if W is None else smooth_texels(tx, f, operator=W)) - t)
            / np.linalg.norm(t) for W in ops]
    # the unbiased estimate against the truth itself: within 15 % of it at every radius
    np.testing.assert_allclose(est, true, rtol=0.15)
    assert radius == DENOISE_RADII[int(np.argmin(true))]
    assert (radius > 0) == (best == "filter")
    if best == "none":  # detail: the filter would cost more than 3× the noise
        assert min(true[1:]) > 3 * true[0]


def test_no_indirect_light_keeps_the_smallest_radius(box):
    tx = box[1].texels
    zero = np.zeros((tx.count, 2, 3))
    radius, est = choose_radius(tx, zero, zero)
    assert radius == 0.0 and all(e != e for e in est)


def test_measured_noise_agrees_with_a_far_less_noisy_transport(box):
    """Radius 0's estimate is the bake transport's error: checked against a transport with
    256 gather rays instead of 16 (its own error ~4× smaller, counted in the tolerance)."""
    _, intake = box
    spec = parse_spec(SPEC)
    _, hold = sample_configurations(spec.lights, intake.scene.center, intake.scene.radius)
    tr = open_transport(intake.scene, intake.texels, intake.points, spec.transport)
    f = light_configurations(tr, hold, 0).indirect
    noise = measure_noise(tr, hold, f)
    fine = dataclasses.replace(spec.transport, gather_rays=256, seed=99)
    trf = open_transport(intake.scene, intake.texels, intake.points, fine)
    ref = light_configurations(trf, hold, 0).indirect.astype(np.float64)
    true = [np.linalg.norm(smooth_texels(intake.texels, f, operator=smoothing_operator(
        intake.texels, r)) - ref) / np.linalg.norm(ref) for r in noise.radii]
    print("estimated", noise.expected_error, "against 256 rays", true)
    assert noise.noise == noise.expected_error[0]
    # the reference's own error (16/256 of the variance: ~0.25× the bake's) adds in
    # quadrature to every true figure; 20 % covers it and the estimate's spread
    np.testing.assert_allclose(noise.expected_error, true, rtol=0.2)
    assert noise.radius == noise.radii[int(np.argmin(noise.expected_error))]
    assert noise.seed == second_seed(spec.transport.seed) != spec.transport.seed
    # the chosen filter travels to the denoise stage: it is smoothing_operator's, bit for bit
    if noise.radius > 0:
        w = smoothing_operator(intake.texels, noise.radius)
        for a in ("indptr", "indices", "data"):
            np.testing.assert_array_equal(getattr(noise.operator, a), getattr(w, a))
    else:
        assert noise.operator is None


def test_bake_records_the_choice_and_a_given_radius_skips_it(box, tmp_path):
    asset, _ = box
    out = bake(asset, parse_spec(SPEC), tmp_path / "auto", quiet=True)
    m = json.loads((out / "manifest.json").read_text())
    rec = m["transport_noise"]
    assert rec["radius"] in DENOISE_RADII and len(rec["expected_error"]) == len(DENOISE_RADII)
    assert rec["lights"] == 6 and 0 < rec["transport_noise"] < 1
    assert "transport noise" in m["timings"]
    assert json.loads((out / "report.json").read_text())["transport_noise"] == rec
    assert (out / "report.txt").read_text().startswith("transport noise: ")
    given = tiny_spec(**{**SPEC, "fit": {**SPEC["fit"], "denoise": 1.5}})
    out2 = bake(asset, parse_spec(given), tmp_path / "given", quiet=True)
    m2 = json.loads((out2 / "manifest.json").read_text())
    assert "transport_noise" not in m2 and "transport noise" not in m2["timings"]
    assert m2["spec"]["fit"]["denoise"] == 1.5 and m["spec"]["fit"]["denoise"] == "auto"


def test_with_denoise_resolves_only_auto():
    spec = parse_spec(SPEC)
    assert spec.fit.denoise == "auto"
    assert with_denoise(spec, 0.75).fit.denoise == 0.75
    given = parse_spec({**SPEC, "fit": {"denoise": 2.0}})
    assert with_denoise(given, 0.75) is given
    with pytest.raises(SpecError, match=r"fit\.denoise"):
        parse_spec({**SPEC, "fit": {"denoise": "sometimes"}})


def test_projection_bound_against_a_noisy_reference_removes_the_noise():
    """Mono bundle of 1 mean + 4 planes over T texels; the reference = a vector in the span
    + a part outside it + noise of known standard error. The corrected residual must equal
    the outside part's energy (closed form), the raw one exceeds it by ~Σσ²."""
    rng = np.random.default_rng(3)
    T = 4000
    planes = rng.standard_normal((T, 7))  # R, G, B means, then 4 shared planes
    data = SimpleNamespace(plane_element=np.array([0, 0, 0, 1, 2, 3, 4]),
                           plane_channel=np.array([0, 1, 2, -1, -1, -1, -1]),
                           gamma=None, transfer=np.zeros((3, 4, 2)))
    basis = BasisAtTexels(data, planes)
    x = np.array([[3.0, 0, 0], [0, 4.0, 0]])  # ‖x‖ = 5: the mean's weight
    inside = 5 * planes[:, :3] + planes[:, 3:5] @ rng.standard_normal((2, 3))
    q, _ = np.linalg.qr(planes[:, 3:5])
    out = rng.standard_normal((T, 3))
    out -= q @ (q.T @ out)  # outside the first two shared planes (n = 3)
    sigma = np.full((T, 3), 0.5)
    ref = inside + 0.3 * out + sigma * rng.standard_normal((T, 3))
    exact = float((0.09 * out * out).sum())
    got = basis.residual(x, ref, sigma, 3)
    raw = basis.residual(x, ref, np.zeros_like(sigma), 3)
    assert abs(got - exact) < 0.05 * exact + 4 * np.sqrt(2 * T * 3) * 0.25
    assert raw - exact > 0.8 * (0.25 * T * 3)
    # n = 1: only the mean; everything but the mean term is outside
    assert basis.residual(x, 5 * planes[:, :3], np.zeros_like(sigma), 1) == pytest.approx(
        0.0, abs=1e-8)
