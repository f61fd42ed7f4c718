"""A verdict on every bake (issue 13): pass/fail by the spec's validate thresholds, the
cause and what to change, the last terminal line, exit status 3 unless --allow-poor."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from prtcore.cli import main
from prtcore.core.spec import ValidateSpec
from prtcore.io.bundle import read_manifest
from prtcore.verdict import EXIT_POOR, judge

CORNELL = Path(__file__).resolve().parents[1] / "examples" / "cornell_box.glb"
ROW = {"n": 16, "heldout_rmse_mean": 0.10, "projection_bound_mean": 0.09,
       "heldout_rmse_global_mean": 0.08}
DIAG = {"direct_effective_rank": [60, 60, 60], "excluded": []}


def _judge(row, diag=DIAG, **kw):
    table = {"reference": "fast transport", "heldout_configurations": 16, "rows": [row]}
    args = {"points": 64, "configurations": 128, **kw}
    return judge(table, diag, 16, ValidateSpec(), **args)


def test_near_the_bound_passes():
    v = _judge(ROW)
    assert v["status"] == "pass" and v["causes"] == []
    assert v["ratio"] == pytest.approx(0.10 / 0.09)
    assert v["line"].startswith("verdict: pass — held-out error 10.0 % at n = 16")


def test_far_from_the_bound_fails_and_says_what_to_change():
    v = _judge({**ROW, "heldout_rmse_mean": 0.30})
    assert v["status"] == "fail"
    assert "more measurement points" in v["causes"][-1]["advice"]
    # underdetermined transfer: more points than lights
    v = _judge({**ROW, "heldout_rmse_mean": 0.30}, points=256, configurations=128)
    assert any("lights.count" in c["advice"] for c in v["causes"])
    # the points see the lights in few independent ways
    v = _judge({**ROW, "heldout_rmse_mean": 0.30}, {**DIAG, "direct_effective_rank": [3]})
    assert any("independent ways" in c["cause"] for c in v["causes"])


def test_a_basis_too_small_fails_on_the_absolute_error():
    v = _judge({**ROW, "heldout_rmse_mean": 0.9, "projection_bound_mean": 0.85,
                "heldout_rmse_global_mean": 0.7})
    assert v["status"] == "fail" and "fit.basis" in v["causes"][0]["advice"]


def test_a_black_channel_is_named():
    v = _judge(ROW, black_channels=("B",))
    assert v["causes"][0]["cause"].startswith("black channel: albedo B is zero")


def test_no_usable_heldout_lights_is_unknown():
    table = {"reference": "x", "heldout_configurations": 8,
             "rows": [{"n": 16, "heldout_rmse_mean": None}]}
    v = judge(table, DIAG, 16, ValidateSpec(), points=8, configurations=64)
    assert v["status"] == "unknown" and "none of the 8 held-out lights" in v["line"]


#: a spot family whose narrow cones mostly miss 8 measurement points: the transfer cannot
#: predict the indirect light (measured: 2.3× the projection bound, 99 of 128 training
#: lights give no direct light at the points)
UNSEEN = {"atlas": {"resolution": 32, "padding": 2},
          "measurement_points": {"count": 8, "supersample": 1},
          "lights": {"count": 128, "holdout": 8, "families": [
              {"type": "spot", "position": {"box": [[-0.6, 1.6, -0.6], [0.6, 1.7, 0.6]]},
               "aim": {"target": [0, 0, 0], "jitter": 2.0},
               "outer_cone_angle": {"uniform": [0.2, 0.3]},
               "intensity": {"uniform": [1, 3]}}]},
          "transport": {"gather_rays": 16, "max_bounces": 8}, "fit": {"basis": 32},
          "output": {"dtype": "float"}}


def test_a_family_the_points_cannot_see_fails_its_gate(tmp_path, capsys):
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps(UNSEEN))
    out = tmp_path / "b"
    assert main(["bake", str(CORNELL), "--spec", str(spec), "--out", str(out)]) == EXIT_POOR
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1].startswith("verdict: fail") and "light family does not fit" in lines[-1]
    m = read_manifest(out)  # the bundle is written all the same
    assert m["verdict"]["status"] == "fail" and m["verdict"]["ratio"] > 1.25
    report = json.loads((out / "report.json").read_text())
    assert report["verdict"] == m["verdict"]
    assert (out / "report.txt").read_text().strip().splitlines()[-1] == lines[-1]
    assert main(["bake", str(CORNELL), "--spec", str(spec), "--out", str(out), "--force",
                 "--allow-poor", "-q"]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].startswith("verdict: fail")


def test_reference_spp_judges_against_the_path_tracer(tmp_path):
    from prtcore.core.spec import parse_spec
    from prtcore.pipeline import bake

    spec = {"atlas": {"resolution": 32, "padding": 2},
            "measurement_points": {"count": 16, "supersample": 2},
            "lights": {"count": 32, "holdout": 4, "families": [
                {"type": "point", "position": {"box": [[-0.6, 1.3, -0.6], [0.6, 1.7, 0.6]]},
                 "intensity": {"uniform": [0.5, 3.0]}}]},
            "transport": {"gather_rays": 16, "max_bounces": 8}, "fit": {"basis": 8},
            "validate": {"reference_spp": 32, "reference_lights": 2}}
    out = bake(CORNELL, parse_spec(spec), tmp_path / "b", quiet=True)
    m = read_manifest(out)
    report = json.loads((out / "report.json").read_text())
    v = m["verdict"]
    assert v["against"] == "path tracer, 32 spp, noise removed"
    assert report["validation"]["lights"] == 2 and report["verdict"] == v
    row = next(r for r in report["validation"]["rows"] if r["n"] == 8)
    assert v["error"] == row["rmse_noise_corrected_mean"]
    # the bound: the basis projected on the same path-traced references, noise removed
    assert v["bound"] == row["projection_bound_noise_corrected_mean"] > 0
    assert v["ratio"] == pytest.approx(v["error"] / v["bound"])
    assert "validate" in m["timings"]
    assert (out / "report.txt").read_text().strip().splitlines()[-1] == v["line"]
