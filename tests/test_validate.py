"""Bundle validation against the path tracer (prtcore.validate, `prtcore report
--reference-spp`), and the acceptance figures of the example bake (issue 4)."""

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest

from prtcore import pipeline
from prtcore.cli import main
from prtcore.core.spec import parse_spec
from prtcore.scenes.cornell import EXAMPLE_SPEC
from prtcore.validate import format_validation, validate_bundle

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "examples" / "cornell_box.glb"
LIGHTS = ROOT / "examples" / "lights"

SMALL_SPEC = copy.deepcopy(EXAMPLE_SPEC)
SMALL_SPEC["atlas"] = {"resolution": 48, "padding": 2}
SMALL_SPEC["lights"].update(count=32, holdout=4)
SMALL_SPEC["measurement_points"] = {"count": 48, "supersample": 2}
SMALL_SPEC["transport"]["gather_rays"] = 32
SMALL_SPEC["fit"]["basis"] = 8


@pytest.fixture(scope="module")
def small_bundle(tmp_path_factory):
    out = tmp_path_factory.mktemp("validate") / "bundle"
    return pipeline.bake(CORNELL, parse_spec(SMALL_SPEC), out, quiet=True)


#: Noise-corrected relative RMSE of SMALL_SPEC's bundle against the path tracer (held-out
#: lights 0 and 1, 32 spp, seed 1): measured 0.125 (n = 4) and 0.118 (n = 8); seeds 2 and 3
#: give 0.118–0.131, and 4 lights at 256 spp 0.135 / 0.128 (the 48² atlas and 32 gather
#: rays, not the fit, set this floor). Bound: the measurement + 30 % margin.
VALIDATE_RMSE = {4: 0.16, 8: 0.16}
#: The reference's own relative noise at 32 spp: measured 0.171 (seeds 1–3: 0.163–0.173).
VALIDATE_NOISE = 0.22


def test_validation_of_held_out_lights(small_bundle):
    v = validate_bundle(small_bundle, spp=32, count=2, seed=1)
    assert v["lights"] == 2 and v["light_source"] == "held-out"
    assert [r["n"] for r in v["rows"]] == [4, 8]
    for r in v["rows"]:
        # the reference noise removed (rmse² − noise²), not allowed for: what the method
        # achieves plus the stated margin; the correction can only lower the error
        assert 0.0 < r["rmse_noise_corrected_mean"] <= r["rmse_mean"], r
        assert r["rmse_noise_corrected_mean"] <= VALIDATE_RMSE[r["n"]], r
        # the raw error cannot be below the noise it contains
        assert r["rmse_mean"] >= 0.9 * v["reference_noise_mean"], (r, v["reference_noise_mean"])
    assert 0.0 < v["reference_noise_mean"] < VALIDATE_NOISE, v["reference_noise_mean"]
    # more elements fit better (on the mean over lights: the reference noise is shared)
    assert v["rows"][1]["rmse_mean"] <= v["rows"][0]["rmse_mean"] * 1.05
    text = format_validation(v)
    assert "2 held-out lights" in text and "noise-corrected" in text


def test_validation_is_seeded(small_bundle):
    a = validate_bundle(small_bundle, spp=8, count=1, seed=3)
    b = validate_bundle(small_bundle, spp=8, count=1, seed=3)
    c = validate_bundle(small_bundle, spp=8, count=1, seed=4)
    assert a["rows"] == b["rows"] and a["rows"] != c["rows"]


def test_report_cli_other_light_family(small_bundle, capsys):
    light = LIGHTS / "directional_family.json"
    assert main(["report", str(small_bundle), "--light", str(light)]) == 2
    assert "--reference-spp" in capsys.readouterr().err
    assert main(["report", str(small_bundle), "--reference-spp", "8", "--reference-lights",
                 "1", "--light", str(light), "-q"]) == 0
    out = capsys.readouterr().out
    assert "directional_family.json lights" in out
    report = json.loads((small_bundle / "report.json").read_text())
    v = report["validation_lights"]["directional_family.json"]
    assert v["lights"] == 1 and all(math.isfinite(r["rmse_mean"]) for r in v["rows"])
    assert "validation" not in report  # the held-out validation is a separate entry


@pytest.mark.slow
def test_example_bake_meets_the_accuracy_targets(tmp_path):
    """Issue 4 acceptance on the README example (Cornell box, 256², point lights).

    Against the fast transport of the held-out lights (the table of the report): with 16
    basis elements ≤ 6 % and ≤ 1.2 × the projection bound, with 64 ≤ 3 % (measured
    3.3 %, 1.04 ×, 1.4 %). Against the path tracer (2 held-out lights, 256 spp, its noise
    removed): ≤ 8 % at n = 16 (measured ~5 %: the rest is the fast transport's own error
    with 128 gather rays). Lights of another family (directional, through the open front):
    worse, but finite and plausible (< 100 %). ~3 min.
    """
    out = pipeline.bake(CORNELL, parse_spec(EXAMPLE_SPEC), tmp_path / "b", quiet=True)
    report = json.loads((out / "report.json").read_text())
    rows = {r["n"]: r for r in report["table"]["rows"]}
    r16, r64 = rows[16], rows[64]
    assert r16["heldout_rmse_mean"] <= 0.06, r16
    assert r16["heldout_rmse_mean"] <= 1.2 * r16["projection_bound_mean"], r16
    assert r64["heldout_rmse_mean"] <= 0.03, r64

    v = validate_bundle(out, spp=256, count=2, seed=0)
    held = {r["n"]: r for r in v["rows"]}
    assert held[16]["rmse_noise_corrected_mean"] <= 0.08, v["rows"]

    d = validate_bundle(out, spp=64, count=2, seed=0,
                        light_file=LIGHTS / "directional_family.json")
    other = {r["n"]: r for r in d["rows"]}
    assert np.isfinite(other[16]["rmse_mean"]) and other[16]["rmse_mean"] < 1.0, d["rows"]
    assert other[16]["rmse_noise_corrected_mean"] > held[16]["rmse_noise_corrected_mean"]
