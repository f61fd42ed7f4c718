"""The pipeline's stage list is the one a bake actually times (workers report progress by it)."""

from __future__ import annotations

import json

from prtcore import STAGES
from prtcore.core.progress import StageTimer
from prtcore.core.spec import parse_spec
from prtcore.pipeline import run_intake
from prtcore.scenes.cornell import write_cornell_box


def test_intake_times_its_stages_in_the_listed_order(tmp_path):
    asset = write_cornell_box(tmp_path / "box.glb")
    timer = StageTimer(quiet=True)
    run_intake(asset, parse_spec({"atlas": {"resolution": 32, "padding": 2},
                                  "measurement_points": {"count": 16}}), timer=timer)
    seen = [s for s in timer.seconds if s in STAGES]
    assert seen == sorted(seen, key=STAGES.index)
    assert set(timer.seconds) <= set(STAGES), set(timer.seconds) - set(STAGES)


def test_bake_times_its_stages_in_the_listed_order(tmp_path):
    from prtcore import bake, read_manifest

    asset = write_cornell_box(tmp_path / "box.glb")
    spec = parse_spec({"atlas": {"resolution": 32, "padding": 2},
                       "measurement_points": {"count": 16, "supersample": 2},
                       "lights": {"count": 12, "holdout": 4, "families": [
                           {"type": "point", "position": {"box": [[-0.5, 1.3, -0.5],
                                                                  [0.5, 1.7, 0.5]]}}]},
                       "transport": {"gather_rays": 8}, "fit": {"basis": 4}})
    out = bake(asset, spec, tmp_path / "b", quiet=True)
    manifest = read_manifest(out)
    timings = manifest["timings"]
    assert list(timings) == sorted(timings, key=STAGES.index)
    assert {"gather operator", "indirect solve", "fit", "report", "export"} <= set(timings)
    assert manifest["method"] == "data_driven"
    # the run files carry the export stage too (it ends after they are first written)
    report = json.loads((out / "report.json").read_text())
    assert report["stage_seconds"] == timings
    assert "export" in (out / "report.txt").read_text().split("bake stages:")[1]


def test_the_source_name_is_the_manifests(tmp_path):
    from prtcore import bake, read_manifest

    asset = write_cornell_box(tmp_path / "stored.glb")
    spec = parse_spec({"atlas": {"resolution": 16, "padding": 0},
                       "measurement_points": {"count": 4, "supersample": 1},
                       "lights": {"count": 6, "holdout": 0, "families": [
                           {"type": "point", "position": {"box": [[-0.5, 1.3, -0.5],
                                                                  [0.5, 1.7, 0.5]]}}]},
                       "transport": {"gather_rays": 4}, "fit": {"basis": 2}})
    out = bake(asset, spec, tmp_path / "b", quiet=True, source_name="My Model.glb")
    assert read_manifest(out)["asset"]["source"] == "My Model.glb"
    out = bake(asset, spec, tmp_path / "c", quiet=True)
    assert read_manifest(out)["asset"]["source"] == "stored.glb"
