"""Automatic sizing (prtcore/sizing.py, intake/plan.py decide_sizing): what is tried, what
ships, why the search stops, and that growing K transports the same lights one pass
would."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from scenes import tiny_spec

from prtcore import pipeline
from prtcore.core.errors import SpecError
from prtcore.core.progress import StageTimer
from prtcore.core.spec import parse_spec
from prtcore.emitters.families import sample_configurations
from prtcore.intake.plan import decide_sizing
from prtcore.sizing import Trial, choose, fallback, size_bake
from prtcore.transport.dataset import (
    add_training,
    direct_at_points,
    light_configurations,
    open_transport,
)
from prtcore.transport.noise import DENOISE_FALLBACK, with_denoise

CORNELL = Path(__file__).resolve().parents[1] / "examples" / "cornell_box.glb"


def trial(p, error, bound=0.1, k=64):
    return Trial(points=p, lights=k, n=8, error=error, bound=bound,
                 ratio=None if error is None else error / bound, seconds=0.0)


def test_choose_ships_the_smallest_p_that_meets_the_target():
    scan = [trial(128, 0.20), trial(256, 0.120), trial(512, 0.116)]
    assert choose(scan, 1.25).points == 256
    assert choose([trial(128, 0.5), trial(256, 0.4)], 1.25) is None
    # nothing meets the target: the smallest P close (5 %) to the lowest error
    assert fallback([trial(128, 0.5), trial(256, 0.31), trial(512, 0.30)]).points == 256
    assert fallback([trial(128, 0.5), trial(256, 0.4), trial(512, 0.30)]).points == 512
    assert fallback([trial(128, None), trial(256, None)]).points == 128


def test_decide_sizing_resolves_auto_and_keeps_given_counts():
    auto = decide_sizing(parse_spec({}), keyframed=False)
    assert auto.points == (256, 512, 1024) and auto.placement == "qdeim"
    assert auto.select and auto.candidates == 512 and auto.grow_candidates
    assert (auto.lights_start, auto.lights_max) == (128, 512) and auto.automatic
    given = decide_sizing(parse_spec({"measurement_points": {"count": 200},
                                      "lights": {"count": 100}}), keyframed=False)
    assert given.points == (200,) and given.placement == "surface" and not given.select
    assert not given.grow_candidates
    assert (given.lights_start, given.lights_max) == (100, 100) and not given.automatic
    small = decide_sizing(parse_spec({"sizing": {"max_points": 600}}), keyframed=False)
    assert small.points == (256, 512, 600)
    kf = decide_sizing(parse_spec({}), keyframed=True)
    assert kf.points == (256,) and kf.placement == "surface" and not kf.automatic
    assert "keyframe bake" in kf.reason
    with pytest.raises(SpecError, match="qdeim"):
        decide_sizing(parse_spec({"measurement_points": {"placement": "qdeim"}}), True)
    with pytest.raises(SpecError, match=r"sizing\.max_lights"):
        parse_spec({"sizing": {"lights_start": 64, "max_lights": 32}})
    with pytest.raises(SpecError, match=r"measurement_points\.count"):
        parse_spec({"measurement_points": {"count": "many"}})


def _sized(spec_dict, limit=1 << 40):
    spec = with_denoise(parse_spec(spec_dict), DENOISE_FALLBACK)
    timer = StageTimer(quiet=True)
    intake = pipeline.run_intake(CORNELL, spec, timer=timer, quiet=True)
    sz = intake.plan.sizing
    pool, hold = sample_configurations(dataclasses.replace(spec.lights, count=sz.lights_max),
                                       intake.scene.center, intake.scene.radius, ())
    tr = open_transport(intake.scene, intake.texels, intake.points, spec.transport, timer)
    data = light_configurations(tr, (*pool[:sz.lights_start], *hold), sz.lights_start, timer)
    return spec, sz, tr, pool, hold, size_bake(spec, sz, tr, data, pool, len(hold), limit,
                                               timer)


SMALL_AUTO = {"measurement_points": {"supersample": 2},
              "sizing": {"max_points": 32, "lights_start": 8, "max_lights": 32},
              "validate": {"target_ratio": 1.0}}  # never met: K grows to the most allowed


def test_growing_k_transports_only_new_lights_and_matches_one_pass():
    spec, _, tr, pool, hold, sized = _sized(tiny_spec(
        measurement_points=SMALL_AUTO["measurement_points"], sizing=SMALL_AUTO["sizing"],
        validate=SMALL_AUTO["validate"],
        lights={**tiny_spec()["lights"], "count": "auto"}))
    sized_k = [t.lights for t in sized.trials]
    assert sorted(set(sized_k)) == [8, 16, 32]
    assert "K = 32 is the most allowed (sizing.max_lights)" in sized.stop
    assert len(sized.train) == 32 and sized.data.stats["train"] == 32
    assert sized.data.stats["passes"] == 3
    assert sized.data.direct_points.shape == (sized.chosen.points, 32 + len(hold), 3)
    # the grown dataset is what one pass over the same lights gives: held-out columns
    # untouched, training columns within the solver's tolerance
    one = light_configurations(tr, (*pool[:32], *hold), 32, StageTimer(quiet=True))
    ref = one.indirect
    got = sized.data.indirect
    np.testing.assert_array_equal(got[:, 32:], ref[:, 32:])
    assert np.linalg.norm(got - ref) <= 5 * spec.transport.tolerance * np.linalg.norm(ref)
    np.testing.assert_array_equal(sized.data.direct_texels, one.direct_texels)


def test_the_memory_limit_and_the_time_budget_stop_growth():
    base = tiny_spec(measurement_points=SMALL_AUTO["measurement_points"],
                     sizing=SMALL_AUTO["sizing"], validate=SMALL_AUTO["validate"],
                     lights={**tiny_spec()["lights"], "count": "auto"})
    *_, sized = _sized(base, limit=1)
    assert {t.lights for t in sized.trials} == {8}
    assert "would exceed the memory limit" in sized.stop
    timed = {**base, "sizing": {**base["sizing"], "max_seconds": 1e-3}}
    *_, sized = _sized(timed)
    assert {t.lights for t in sized.trials} == {8} and "sizing.max_seconds" in sized.stop


def test_add_training_inserts_before_the_held_out_columns():
    spec = parse_spec(tiny_spec())
    intake = pipeline.run_intake(CORNELL, spec, quiet=True)
    train, hold = sample_configurations(spec.lights, intake.scene.center,
                                        intake.scene.radius, ())
    tr = open_transport(intake.scene, intake.texels, intake.points, spec.transport)
    a = light_configurations(tr, (*train[:4], *hold), 4)
    b = light_configurations(tr, train[4:6], 2)
    ab = add_training(a, b)
    assert ab.lights == (*train[:6], *hold) and ab.stats["train"] == 6
    np.testing.assert_array_equal(ab.direct_points[:, 4:6], b.direct_points)
    np.testing.assert_array_equal(ab.direct_points[:, 6:], a.direct_points[:, 4:])
    assert ab.stats["rays"]["total"] == a.stats["rays"]["total"] + sum(
        b.stats["rays"][n] for n in ("direct_points", "direct_texels", "near_field"))


def test_an_auto_bake_reports_what_it_chose(tmp_path):
    spec = tiny_spec(measurement_points={"supersample": 2},
                     lights={**tiny_spec()["lights"], "count": "auto"},
                     sizing={"max_points": 32, "lights_start": 16, "max_lights": 32})
    out = pipeline.bake(CORNELL, parse_spec(spec), tmp_path / "b", quiet=True)
    manifest = json.loads((out / "manifest.json").read_text())
    sizing = manifest["sizing"]
    assert sizing["points"] == manifest["points"]["count"]
    assert manifest["points"]["placement"] == sizing["placement"] == "qdeim"
    assert sizing["lights"] == manifest["fit"]["configurations"]
    assert sizing["trials"] and sizing["reason"]
    assert manifest["spec"]["lights"]["count"] == "auto"
    assert json.loads((out / "report.json").read_text())["sizing"] == sizing
    head = (out / "report.txt").read_text().splitlines()[:2]  # after the transport noise
    assert head[0].startswith("transport noise: ") and head[1] == f"sizing: {sizing['reason']}"
    chosen = [t for t in sizing["trials"] if t["points"] == sizing["points"]
              and t["lights"] == sizing["lights"]]
    # the verdict is judged on the same fit sizing measured
    assert chosen and manifest["verdict"]["error"] == pytest.approx(chosen[0]["error"],
                                                                     rel=1e-6)


def test_candidates_grow_with_p_and_the_shipped_points_are_the_ones_lit():
    """P = 512 outgrows the first 512 candidates: 1024 new ones are placed and lit; the
    shipped points' direct light is theirs (pool and rows kept together)."""
    _, sz, tr, _, _, sized = _sized(tiny_spec(
        measurement_points={"supersample": 2}, validate={"target_ratio": 1.0},
        lights={**tiny_spec()["lights"], "count": 16},
        sizing={"max_points": 512}))
    assert sz.grow_candidates and sz.candidates == 512
    assert [t.points for t in sized.trials] == [256, 512]
    assert "K = 16 is the most allowed (lights.count)" in sized.stop
    chosen = sized.chosen.points
    assert sized.points.count == chosen == sized.data.direct_points.shape[0]
    lit = direct_at_points(tr.scene, tr.tracer, sized.data.lights, sized.points,
                           StageTimer(quiet=True))
    np.testing.assert_array_equal(lit, sized.data.direct_points)


def test_nothing_to_judge_stops_at_once(tmp_path):
    """A convex box lit from outside has no indirect light: sizing must not grow P and K
    to their limits for nothing (BoxTextured took 35x the fixed sizes' time)."""
    from prtcore.scenes.parts import block, material_scene, write_glb

    box = write_glb(material_scene({"box": block((0, 0, 0), (1, 1, 1))},
                                   {"box": (0.8, 0.8, 0.8)}), tmp_path / "box.glb")
    spec = parse_spec({"atlas": {"resolution": 32, "padding": 2},
                       "measurement_points": {"supersample": 2},
                       "lights": {"holdout": 4, "families": [
                           {"type": "point", "position": {"shell": [1.5, 3.0]}}]},
                       "transport": {"gather_rays": 8},
                       "sizing": {"lights_start": 16, "max_lights": 64}})
    out = pipeline.bake(box, spec, tmp_path / "b", quiet=True)
    sizing = json.loads((out / "manifest.json").read_text())["sizing"]
    assert [(t["points"], t["lights"]) for t in sizing["trials"]] == [(256, 16)]
    assert "nothing to size on" in sizing["reason"]
