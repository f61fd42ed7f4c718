"""Albedo at and above 1, black albedo, emissive materials (issue 8).

Transport clamps albedo per channel to [0, ALBEDO_MAX] (0.99) so the bounce series
converges; the number of clamped values is reported. Emission is ignored (Lambertian
reflectors lit by punctual lights only): an emissive material bakes exactly like the same
material without emission.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from stab_helpers import TINY, assert_bundle_finite, bake, cornell_with, result_files

from prtcore.core.errors import PrtError
from prtcore.core.tolerances import ALBEDO_MAX
from prtcore.io.bundle import load_runtime


@pytest.fixture(scope="module")
def bakes(tmp_path_factory):
    root = tmp_path_factory.mktemp("albedo")
    cases = {
        "clamp": {"base_color": {"*": [ALBEDO_MAX] * 3}},
        "one": {"base_color": {"*": [1.0, 1.0, 1.0]}},
        "above": {"base_color": {"*": [1.0, 1.0, 1.0], "floor": [1.5, 1.2, 7.0],
                                 "left": [3.0, 1.0, 1.0]}},
        "black_floor": {"base_color": {"floor": [0.0, 0.0, 0.0]}},
        "plain": {},
        "emissive": {"emissive": {"back": [5.0, 5.0, 5.0], "floor": [1.0, 0.2, 0.0]}},
    }
    return {name: bake(cornell_with(root / f"{name}.glb", **kw), TINY, root / name)
            for name, kw in cases.items()}


def test_albedo_at_and_above_one_bakes_finite_and_is_clamped(bakes):
    for name in ("one", "above"):
        m = assert_bundle_finite(bakes[name])
        transport = json.loads((bakes[name] / "report.json").read_text())["transport"]
        assert transport["albedo_clamped_values"] > 0
        assert m["metrics"]["transport_residual"] < 1.0
        assert load_runtime(bakes[name]).cluster_albedo.max() <= np.float32(ALBEDO_MAX)


def test_albedo_one_and_above_bake_exactly_like_the_clamp(bakes):
    ref = result_files(bakes["clamp"])
    assert result_files(bakes["one"]) == ref
    assert result_files(bakes["above"]) == ref


def test_black_floor_points_are_reported_unlit(bakes):
    m = assert_bundle_finite(bakes["black_floor"])
    data = load_runtime(bakes["black_floor"])
    albedo = np.zeros((data.point_count, 3))
    np.add.at(albedo, data.cluster_owner, data.cluster_albedo)
    black = albedo.max(axis=1) == 0.0
    assert black.any()
    unlit = set(m["diagnostics"]["unlit_points"])
    assert set(np.flatnonzero(black).tolist()) <= unlit
    assert any(f"{len(unlit)} measurement points are lit by no configuration" in w
               for w in m["fit"]["warnings"])


def test_all_black_scene_is_refused(tmp_path):
    asset = cornell_with(tmp_path / "black.glb", base_color={"*": [0.0, 0.0, 0.0]})
    with pytest.raises(PrtError, match="only 0 usable lighting configurations"):
        bake(asset, TINY, tmp_path / "b")
    assert not (tmp_path / "b").exists()


def test_emission_is_ignored(bakes):
    assert result_files(bakes["emissive"]) == result_files(bakes["plain"])
