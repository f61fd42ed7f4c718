"""The learnt transfer (issue 18): the numpy network of prtcore.core.mlp against explicit
loops, and the "mlp" regressor of prtcore.fit.mlp on synthetic transport — a nonlinear
one it must learn (held-out error well below the ridge's), determinism bit for bit, step
0 = the ridge exactly, homogeneity, and the bundle round trip through the CPU runtime.
The GLSL evaluation is compared with the CPU one in tests/test_render.py."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest
from scenes import tiny_spec

from prtcore import pipeline
from prtcore.core.errors import PrtError, SpecError
from prtcore.core.mlp import (
    Mlp,
    forward,
    positional_encoding,
    transfer_residual,
    transfer_rows,
)
from prtcore.core.spec import parse_spec
from prtcore.fit.mlp import split
from prtcore.fit.transfer import coefficients, fit_transfer, reconstruct64
from prtcore.io.bundle import load_runtime, read_manifest
from prtcore.report import truncate
from prtcore.runtime.cpu import plane_weights

ROOT_CORNELL = Path(__file__).resolve().parents[1] / "examples" / "cornell_box.glb"


def random_net(rng, sizes, output="linear") -> Mlp:
    return Mlp(tuple(rng.standard_normal((o, i)) for i, o in itertools.pairwise(sizes)),
               tuple(rng.standard_normal(o) for o in sizes[1:]), 0.01, output)


def loop_forward(net: Mlp, x: np.ndarray) -> np.ndarray:
    """The network written out neuron by neuron (independent of numpy broadcasting)."""
    h = list(x)
    for j, (w, c) in enumerate(zip(net.weights, net.biases, strict=True)):
        out = []
        for o in range(w.shape[0]):
            v = c[o] + sum(w[o, q] * h[q] for q in range(w.shape[1]))
            if j < len(net.weights) - 1:
                v = v if v >= 0 else net.slope * v
            elif net.output == "tanh":
                v = np.tanh(v)
            out.append(v)
        h = out
    return np.array(h)


# ---------------------------------------------------------------------------------------
# core/mlp.py


@pytest.mark.parametrize("output", ["linear", "tanh"])
def test_forward_is_the_layer_formula(output):
    rng = np.random.default_rng(1)
    net = random_net(rng, (5, 7, 6, 4), output)
    X = rng.standard_normal((3, 5))
    got = forward(net, X)
    assert got.shape == (3, 4)
    for k in range(3):
        np.testing.assert_allclose(got[k], loop_forward(net, X[k]), rtol=1e-12, atol=1e-12)
    assert (net.widths, net.inputs, net.outputs) == ((7, 6), 5, 4)


def test_network_shapes_are_checked():
    rng = np.random.default_rng(2)
    with pytest.raises(ValueError, match="layer 1 takes 4 inputs but layer 0 gives 3"):
        Mlp((rng.random((3, 2)), rng.random((1, 4))), (rng.random(3), rng.random(1)))
    with pytest.raises(ValueError, match="output 'relu'"):
        Mlp((rng.random((1, 2)),), (rng.random(1),), output="relu")
    with pytest.raises(ValueError, match="input of 3 values, the network takes 2"):
        forward(Mlp((rng.random((1, 2)),), (rng.random(1),)), np.ones(3))


def test_transfer_residual_layout_and_zero_light():
    """Input x'/s channel-major [c][p], output [c][i]: a one-layer network is the matrix
    it holds; select_outputs keeps rows [c][i < n] (transfer_rows)."""
    rng = np.random.default_rng(3)
    P, nb = 4, 5
    W = rng.standard_normal((3 * nb, 3 * P))
    net = Mlp((W,), (np.zeros(3 * nb),))
    x = rng.random((P, 3))
    s = np.linalg.norm(x)
    xhat = np.concatenate([x[:, c] for c in range(3)]) / s
    np.testing.assert_allclose(transfer_residual(net, x), (W @ xhat).reshape(3, nb))
    assert not transfer_residual(net, np.zeros((P, 3))).any()
    sub = net.select_outputs(transfer_rows(nb, 2))
    np.testing.assert_allclose(transfer_residual(sub, x), (W @ xhat).reshape(3, nb)[:, :2])


def test_positional_encoding_blocks():
    """v, then sin(2^k π v) for k < F, then cos(2^k π v), each block as wide as v."""
    v = np.array([[0.25, -0.5, 0.1]])
    got = positional_encoding(v, 2)
    want = [*v[0], *np.sin(np.pi * v[0]), *np.sin(2 * np.pi * v[0]),
            *np.cos(np.pi * v[0]), *np.cos(2 * np.pi * v[0])]
    np.testing.assert_allclose(got[0], want, rtol=1e-15)
    assert positional_encoding(v, 0).shape == (1, 3)


# ---------------------------------------------------------------------------------------
# fit/mlp.py


def nonlinear_scene(rng, K, T=150, P=6):
    """Lights along a parameter t; the direct light at P points is a smooth bump of t, the
    indirect light a nonlinear function of t that no linear map of the direct reaches."""
    t = rng.uniform(0.0, 1.0, K)
    d = np.exp(-((t[None, :] - np.linspace(0, 1, P)[:, None]) / 0.3) ** 2) + 0.05
    colour = np.array([1.0, 0.8, 0.6])
    D = d[:, :, None] * colour
    g = np.stack([np.sin(2 * np.pi * t), np.cos(3 * np.pi * t), (t - 0.5) ** 2,
                  np.ones_like(t)]) + 1.5
    A = np.random.default_rng(5).uniform(0.0, 1.0, (T, 4))
    I = (A @ g)[:, :, None] * colour * d.sum(axis=0)[None, :, None] / P
    return D, I


def pooled_error(model, Dh, Ih) -> float:
    num = sum(np.sum((reconstruct64(model, Dh[:, h]) - Ih[:, h]) ** 2)
              for h in range(Dh.shape[1]))
    return float(np.sqrt(num / np.sum(Ih**2)))


@pytest.fixture(scope="module")
def nonlinear():
    rng = np.random.default_rng(0)
    D, I = nonlinear_scene(rng, 120)
    Dh, Ih = nonlinear_scene(rng, 40)
    ridge = fit_transfer(D, I, basis=5)
    opts = {"steps": 300, "width": 32}
    mlp = fit_transfer(D, I, basis=5, transfer="mlp", transfer_options=opts)
    again = fit_transfer(D, I, basis=5, transfer="mlp", transfer_options=opts)
    return D, I, Dh, Ih, ridge, mlp, again


def test_mlp_learns_what_ridge_cannot(nonlinear):
    """Held-out (unseen lights) error of ridge + learnt residual ≤ half the ridge's; the
    ridge part is the ridge's own fit, and the validation choice saw the gain."""
    *_, Dh, Ih, ridge, mlp, _ = nonlinear
    e_ridge, e_mlp = pooled_error(ridge, Dh, Ih), pooled_error(mlp, Dh, Ih)
    assert e_mlp < 0.5 * e_ridge, (e_mlp, e_ridge)
    np.testing.assert_array_equal(mlp.transfer, ridge.transfer)
    learnt = mlp.diagnostics.learnt
    assert learnt["steps"] > 0 and learnt["validation_mse_mlp"] < learnt[
        "validation_mse_ridge"]
    assert mlp.diagnostics.transfer == "mlp" and ridge.diagnostics.learnt is None


def test_training_is_deterministic(nonlinear):
    """Same data, options and seed: the same weights bit for bit; another seed differs."""
    D, I, *_, mlp, again = nonlinear
    for a, b in zip(mlp.learnt.weights + mlp.learnt.biases,
                    again.learnt.weights + again.learnt.biases, strict=True):
        assert a.tobytes() == b.tobytes()
    other = fit_transfer(D, I, basis=5, transfer="mlp",
                         transfer_options={"steps": 30, "width": 32, "seed": 1})
    assert other.learnt.weights[0].tobytes() != mlp.learnt.weights[0].tobytes()


def test_zero_steps_ship_the_ridge_alone_and_mlp_is_homogeneous(nonlinear):
    """When validation keeps 0 steps no network ships (the model is the ridge's, with a
    warning); a shipped one keeps u(a·x) = a·u(x)."""
    D, I, Dh, _, ridge, mlp, _ = nonlinear
    zero = fit_transfer(D, I, basis=5, transfer="mlp", transfer_options={"steps": 0})
    assert zero.learnt is None and not zero.diagnostics.learnt["shipped"]
    assert any("ridge ships alone" in w for w in zero.diagnostics.warnings)
    x = Dh[:, 0]
    np.testing.assert_array_equal(reconstruct64(zero, x), reconstruct64(ridge, x))
    y = reconstruct64(mlp, x)
    for a in (1e-6, 3.0, 1e6):
        np.testing.assert_allclose(reconstruct64(mlp, a * x), a * y, rtol=1e-9,
                                   atol=1e-12 * a * np.abs(y).max())


def test_truncation_keeps_the_learnt_rows(nonlinear):
    """The n-element model of a larger mlp fit gives the larger fit's first coefficients."""
    *_, Dh, _, _, mlp, _ = nonlinear
    small = truncate(mlp, 3)
    assert small.learnt.outputs == 3 * 2
    _, u_all = coefficients(mlp, Dh[:, 1])
    _, u_small = coefficients(small, Dh[:, 1])
    np.testing.assert_allclose(u_small, u_all[:, :2], rtol=1e-12)


def test_validation_split_is_seeded_and_small_sets_train_without_one():
    a, b = split(100, 0)
    assert len(b) == 20 and not set(a) & set(b) and len(a) + len(b) == 100
    assert (split(100, 0)[1] == b).all() and not (split(100, 1)[1] == b).all()
    assert len(split(7, 0)[1]) == 0


def test_spec_keys_and_refusals():
    spec = parse_spec({"fit": {"transfer": "mlp", "mlp_width": 16, "mlp_layers": 3,
                               "mlp_steps": 10, "seed": 4}})
    assert (spec.fit.transfer, spec.fit.mlp_width, spec.fit.mlp_layers, spec.fit.mlp_steps,
            spec.fit.seed) == ("mlp", 16, 3, 10, 4)
    assert parse_spec({}).fit.transfer == "ridge"
    with pytest.raises(SpecError, match=r"fit\.transfer"):
        parse_spec({"fit": {"transfer": "gp"}})
    with pytest.raises(SpecError, match="per_keyframe"):
        parse_spec({"fit": {"transfer": "mlp"}, "keyframes": {"transfer": "per_keyframe"}})
    rng = np.random.default_rng(4)
    D, I = nonlinear_scene(rng, 20)
    with pytest.raises(PrtError, match="per-keyframe"):
        fit_transfer(D, I, basis=3, transfer="mlp", groups=np.arange(20) % 2,
                     per_group=True)
    with pytest.raises(ValueError, match="unknown options"):
        fit_transfer(D, I, basis=3, transfer="mlp", transfer_options={"depth": 2})


# ---------------------------------------------------------------------------------------
# the bundle and the CPU runtime


def test_bundle_round_trip_and_cpu_runtime(tmp_path):
    """A bake with fit.transfer "mlp": the manifest describes the layers, load_runtime
    reads the network the fit shipped, and the CPU runtime's coefficients are the fit's."""
    # 7 training lights: too few for a validation split, so the network trains its steps
    spec = tiny_spec(fit={"basis": 6, "transfer": "mlp", "mlp_steps": 40, "mlp_width": 16})
    spec["lights"].update(count=7)
    out = pipeline.bake(ROOT_CORNELL, parse_spec(spec), tmp_path / "b", quiet=True)
    m = read_manifest(out)
    layers = m["transfer"]["learnt"]["layers"]
    assert m["fit"]["transfer"] == "mlp" and len(layers) == 3
    assert layers[-1]["weight"]["shape"] == [3 * 5, 16]
    assert all(f"transfer_learnt_{j}_weight.bin" in m["checksums"] for j in range(3))
    d = load_runtime(out)
    assert d.learnt is not None and d.learnt.outputs == 15 and d.learnt.inputs == 3 * 32
    x = np.random.default_rng(6).random((d.point_count, 3))
    w = plane_weights(d, x)
    plain = plane_weights(dataclasses.replace(d, learnt=None), x)
    residual = np.linalg.norm(x) * transfer_residual(d.learnt, x)  # (3, 5)
    mono = d.plane_channel < 0
    np.testing.assert_allclose(w[mono] - plain[mono], residual.T, rtol=1e-9, atol=1e-12)
