"""measurement_points.placement = "qdeim" (issue 13): P points chosen for the transfer from
blue-noise candidates by pivoted QR on their training direct light, after transport."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from prtcore.core.errors import SpecError
from prtcore.core.spec import parse_spec
from prtcore.io.bundle import read_manifest
from prtcore.pipeline import bake, run_intake

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "examples" / "cornell_box.glb"
SPEC = {"atlas": {"resolution": 32, "padding": 2},
        "measurement_points": {"count": 16, "supersample": 2, "placement": "qdeim",
                               "candidates": 96},
        "lights": {"count": 32, "holdout": 6, "families": [
            {"type": "point", "position": {"box": [[-0.6, 1.3, -0.6], [0.6, 1.7, 0.6]]},
             "intensity": {"uniform": [0.5, 3.0]}}]},
        "transport": {"gather_rays": 16, "max_bounces": 8}, "fit": {"basis": 8}}


def test_qdeim_points_are_p_of_the_candidates(tmp_path):
    spec = parse_spec(SPEC)
    candidates = run_intake(CORNELL, spec, quiet=True).points
    assert candidates.count == 96
    out = bake(CORNELL, spec, tmp_path / "b", quiet=True)
    m = read_manifest(out)
    pts = np.fromfile(out / m["points"]["points"]["file"], "<f4").reshape(
        m["points"]["points"]["shape"])
    assert pts.shape[0] == 16
    cand = np.asarray(candidates.position, np.float32)
    chosen = [int(np.argmin(np.linalg.norm(cand - p[:3], axis=1))) for p in pts]
    assert len(set(chosen)) == 16  # distinct candidates
    assert np.allclose(cand[chosen], pts[:, :3], atol=1e-6)
    assert "select points" in m["timings"]
    report = json.loads((out / "report.json").read_text())
    assert report["verdict"]["status"] in ("pass", "fail")


def test_qdeim_with_keyframes_is_refused(tmp_path):
    from keyframe_assets import bending_column_asset

    spec = parse_spec({**SPEC, "keyframes": {"animation": 0, "count": 2}})
    with pytest.raises(SpecError, match=r"measurement_points\.placement"):
        bake(bending_column_asset(tmp_path / "col.glb"), spec, tmp_path / "b", quiet=True)
