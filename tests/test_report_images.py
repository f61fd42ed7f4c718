"""A report a person can read (issue 13): the shipped n and the gate on report.png, the
worst held-out light and the UV layout as images, and a warning for a poorly used atlas."""

from __future__ import annotations

import json
from pathlib import Path

from PIL import Image
from scenes import TINY_SPEC

from prtcore.core.spec import parse_spec
from prtcore.io.bundle import read_manifest
from prtcore.pipeline import bake, run_intake

CORNELL = Path(__file__).resolve().parents[1] / "examples" / "cornell_box.glb"


def test_report_images_are_written_and_left_out_of_the_checksums(tmp_path):
    out = bake(CORNELL, parse_spec(TINY_SPEC), tmp_path / "b", quiet=True)
    m = read_manifest(out)
    for name in ("report.png", "report_worst.png", "report_atlas.png"):
        with Image.open(out / name) as im:
            assert im.size[0] > 300 and im.size[1] > 200
        assert name not in m["checksums"] and name in m["run_files"]
    assert json.loads((out / "report.json").read_text())["verdict"]["n"] == m["basis"]["count"]


def test_a_poorly_used_atlas_warns(shared_assets):
    r = run_intake(shared_assets / "CesiumMilkTruck.glb",
                   parse_spec({"atlas": {"resolution": 192, "padding": 4},
                               "measurement_points": {"count": 16}}), quiet=True)
    assert r.prepare.utilisation < 0.1
    assert any(w.startswith("the lightmap atlas is 5.") and "atlas.resolution" in w
               for w in r.prepare.warnings), r.prepare.warnings
