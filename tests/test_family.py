"""Out-of-family lights (issue 13): relight and render warn, with the measure, when a
light's direct vector lies outside the span of the training lights' direct vectors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from prtcore.cli import main
from prtcore.runtime.family import direct_span, family_residual, warn_above

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "examples" / "cornell_box.glb"
LIGHTS = ROOT / "examples" / "lights"


def test_span_and_residual_on_vectors_with_a_known_answer():
    rng = np.random.default_rng(0)
    basis = rng.normal(size=(2, 5, 3))  # two direct "patterns" over 5 points
    coef = rng.uniform(0.1, 2.0, size=(2, 7))
    D = np.einsum("ipc,ik->pkc", basis, coef)  # 7 lights, all in a 2-D span
    span = direct_span(D)
    assert span.shape == (15, 2)
    np.testing.assert_allclose(span.T @ span, np.eye(2), atol=1e-12)
    inside = 0.3 * basis[0] - 1.1 * basis[1]
    assert family_residual(span, inside) < 1e-12
    outside = rng.normal(size=(5, 3))
    outside -= (span @ (span.T @ outside.ravel())).reshape(5, 3)  # orthogonal to the span
    assert abs(family_residual(span, outside) - 1.0) < 1e-12
    assert family_residual(span, np.zeros((5, 3))) == 0.0
    assert warn_above(np.array([0.01, 0.2])) == 0.4 and warn_above(np.array([])) == 0.05


def test_relight_warns_only_for_a_light_outside_the_family(tmp_path, capsys):
    spec = {"atlas": {"resolution": 32, "padding": 2},
            "measurement_points": {"count": 32, "supersample": 2},
            "lights": {"count": 48, "holdout": 8, "families": [
                {"type": "point", "position": {"box": [[-0.6, 1.3, -0.6], [0.6, 1.7, 0.6]]},
                 "intensity": {"uniform": [0.5, 3.0]}}]},
            "transport": {"gather_rays": 16, "max_bounces": 8}, "fit": {"basis": 8}}
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    out = tmp_path / "b"
    main(["bake", str(CORNELL), "--spec", str(tmp_path / "spec.json"), "--out", str(out),
          "-q", "--allow-poor"])
    family = json.loads((out / "manifest.json").read_text())["family"]
    assert family["warn_above"] >= 0.05
    capsys.readouterr()
    assert main(["relight", str(out), "--light", str(LIGHTS / "point_center.json"),
                 "--out", str(tmp_path / "a.exr")]) == 0
    assert "outside the trained family" not in capsys.readouterr().err
    assert main(["relight", str(out), "--light", str(LIGHTS / "directional_window.json"),
                 "--out", str(tmp_path / "b.exr")]) == 0
    err = capsys.readouterr().err
    assert "warning: light outside the trained family" in err and "%" in err
