"""float32 vs float64 paths, and determinism (issue 8).

Stated tolerances (relative RMSE over the lightmap, held-out lights of a real bake):
* float32 model (what a bundle stores) vs float64 model: F32_RTOL;
* the bundle's CPU runtime (float32 planes, float32 blend) vs the float64 model: RUNTIME_RTOL;
* output.dtype "half" planes vs "float" planes: HALF_RTOL.
Same asset + spec + seed → bit-identical checksummed files, also with another thread count.
"""

from __future__ import annotations

import numpy as np
import pytest
from stab_helpers import (
    CORNELL,
    ROOM_BOX,
    TINY,
    Transport,
    assert_bundle_finite,
    bake,
    spec_with,
)

from prtcore.fit.model import relative_rmse as rrmse
from prtcore.fit.transfer import fit_transfer, fit_transfer64, reconstruct, reconstruct64
from prtcore.io.bundle import load_runtime, read_manifest
from prtcore.runtime.cpu import blend, plane_weights

F32_RTOL = 1e-5
RUNTIME_RTOL = 1e-5
HALF_RTOL = 1e-3

WIDE_RGB_GAMMA = spec_with(
    lights={"families": [{"type": "point", "position": {"box": ROOM_BOX},
                          "intensity": {"log_uniform": [1e-6, 1e6]}, "color": "random"}]},
    fit={"basis": 8, "channels": "rgb", "gamma": 2.2})


@pytest.fixture(scope="module")
def transport():
    return Transport(CORNELL, TINY)


@pytest.mark.parametrize(("channels", "gamma", "ridge"),
                         [("mono", None, "auto"), ("rgb", None, 0.0), ("mono", 2.2, "auto"),
                          ("mono", None, 0.0)])
def test_float32_model_agrees_with_float64(transport, channels, gamma, ridge):
    train, hold = transport.configurations()
    D, I = transport.dataset(train)
    Dh, _ = transport.dataset(hold)
    kw = {"basis": 8, "ridge": ridge, "channels": channels, "gamma": gamma}
    m32, m64 = fit_transfer(D, I, **kw), fit_transfer64(D, I, **kw)
    for h in range(Dh.shape[1]):
        x = Dh[:, h].astype(np.float64)
        y64 = reconstruct64(m64, x)
        assert rrmse(reconstruct(m32, x), y64) <= F32_RTOL
        assert np.isfinite(y64).all()


def test_helper_transport_is_the_pipelines(transport, tmp_path):
    """The suite's Transport helper computes the same D as the bake (guards the helper)."""
    from prtcore.transport.dataset import bake_dataset

    train, hold = transport.configurations()
    ds = bake_dataset(transport.intake.scene, transport.intake.texels,
                      transport.intake.points, train, hold, transport.spec.transport)
    D, I = transport.dataset((*train, *hold))
    np.testing.assert_array_equal(D, ds.direct_points)
    np.testing.assert_array_equal(I, ds.indirect)


@pytest.fixture(scope="module")
def float_and_half(tmp_path_factory):
    root = tmp_path_factory.mktemp("prec")
    # without the basis filter (fit.denoise): the float64 model below is fitted on the
    # same unfiltered lightmaps as the bundle
    return (bake(CORNELL, spec_with(fit={"denoise": 0}), root / "float"),
            bake(CORNELL, spec_with(output={"dtype": "half"}, fit={"denoise": 0}),
                 root / "half"))


def test_runtime_and_half_planes_agree_with_float64(float_and_half, transport):
    fb, hb = float_and_half
    _, hold = transport.configurations()
    Dh, _ = transport.dataset(hold)
    train, _ = transport.configurations()
    D, I = transport.dataset(train)
    m = read_manifest(fb)
    m64 = fit_transfer64(D, I, basis=64, ridge=m["fit"]["ridge"])
    fdata, hdata = load_runtime(fb), load_runtime(hb)
    cov = fdata.coverage
    tx = transport.intake.texels
    for h in range(Dh.shape[1]):
        x = Dh[:, h].astype(np.float64)
        y64 = np.maximum(reconstruct64(m64, x, n=8), 0.0)  # the runtime clamps (formula)
        yf = blend(fdata, plane_weights(fdata, x))
        yh = blend(hdata, plane_weights(hdata, x))
        got = yf[tx.xy[:, 1], tx.xy[:, 0]]  # covered texels in the fit's order
        assert rrmse(got, y64) <= RUNTIME_RTOL
        assert rrmse(yh[cov], yf[cov]) <= HALF_RTOL


def test_same_seed_bit_identical_bundles_across_thread_counts(tmp_path, monkeypatch):
    monkeypatch.setenv("PRT_THREADS", "1")
    a = bake(CORNELL, WIDE_RGB_GAMMA, tmp_path / "a")
    monkeypatch.setenv("PRT_THREADS", "3")
    b = bake(CORNELL, WIDE_RGB_GAMMA, tmp_path / "b")
    ma, mb = assert_bundle_finite(a), read_manifest(b)
    assert ma["checksums"] == mb["checksums"]
    for f in ma["checksums"]:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f


def test_bundle_diagnostics_describe_the_bundles_basis(float_and_half):
    """The bake fits 64 elements for the report table and truncates to fit.basis = 8.
    Before the fix the manifest said n_method "capped" with a warning "basis count 64
    capped at …" and diagnostics.n_basis 61 for a bundle of 8 elements as requested."""
    m = read_manifest(float_and_half[0])
    d = m["diagnostics"]
    assert m["basis"]["count"] == m["fit"]["n_basis"] == d["n_basis"] == 8
    assert m["fit"]["n_method"] == d["n_basis_method"] == "given"
    assert d["n_basis_requested"] == 8
    assert m["fit"]["energy_kept"] == d["energy_curve"][7]
    assert not any(w.startswith("basis count") for w in m["fit"]["warnings"])
