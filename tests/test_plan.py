"""The planner: decisions and their reasons, consistent with what prepare_scene does."""

from __future__ import annotations

import re
import time

import numpy as np
import pytest
import trimesh

from prtcore.core.errors import AssetError, SpecError
from prtcore.core.scene import Animation, AnimationChannel, Material, PrimitiveInstance, Scene
from prtcore.core.spec import parse_spec
from prtcore.intake.plan import Plan, StagePlan, plan_asset
from prtcore.intake.prepare import prepare_scene


def make_scene(pos, faces, uv1=None, animations=()) -> Scene:
    pos = np.asarray(pos, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    nrm = np.array(trimesh.Trimesh(pos, faces, process=False).vertex_normals)
    inst = PrimitiveInstance(node=0, mesh=0, primitive=0, vertex_start=0,
                             vertex_count=len(pos), face_start=0, face_count=len(faces),
                             object_positions=pos.copy(), object_normals=nrm.copy(),
                             joints=np.zeros((0, 4), np.int32), weights=np.zeros((0, 4)))
    return Scene(source="plan-test", positions=pos, normals=nrm, uv0=np.zeros((len(pos), 2)),
                 uv1=None if uv1 is None else np.asarray(uv1, dtype=np.float64), faces=faces,
                 face_material=np.zeros(len(faces), np.int32),
                 face_instance=np.zeros(len(faces), np.int32),
                 materials=(Material("default", np.array([0.8, 0.8, 0.8, 1.0])),),
                 instances=(inst,), animations=tuple(animations))


def box_scene(**kw) -> Scene:
    m = trimesh.creation.box()
    return make_scene(m.vertices, m.faces, **kw)


def two_quads_with_uv1() -> Scene:
    pos = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                    [2, 0, 0], [3, 0, 0], [3, 1, 0], [2, 1, 0]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    uv = np.array([[0.1, 0.1], [0.3, 0.1], [0.3, 0.3], [0.1, 0.3],
                   [0.6, 0.1], [0.8, 0.1], [0.8, 0.3], [0.6, 0.3]])
    return make_scene(pos, faces, uv1=uv)


def spin() -> Animation:
    ch = AnimationChannel(node=0, path="rotation", times=np.array([0.0, 2.5]),
                          values=np.array([[0, 0, 0, 1.0], [0, 0.7071068, 0, 0.7071068]]))
    return Animation(name="spin", channels=(ch,))


def test_box_without_uv1_plan_text():
    text = plan_asset(box_scene(), parse_spec({})).format()
    for line in ("repair    skip — mesh clean",
                 "remesh    skip — not requested",
                 "uv        generate — TEXCOORD_1 missing",
                 "keyframes skip — asset has no animation",
                 "texels    run — 512×512 atlas, padding 4",
                 "sizing    run — auto: P ∈ {256, 512, 1024}, K from 128 up to 512 "
                 "until the held-out error is within 1.25× the projection bound "
                 "(transport budget 300 s)",
                 "points    run — 512 blue-noise candidates (2P as P grows), P chosen "
                 "after transport (qdeim), supersample 8",
                 "lights    run — 128–512 lights + 16 held out, 1 family (spot)",
                 "validate  run — 16 held-out lights against the reference"):
        assert line in text.splitlines(), (line, text)
    names = [ln.split()[0] for ln in text.splitlines()]
    assert names == ["repair", "remesh", "uv", "keyframes", "sizing", "texels", "points",
                     "lights", "transport", "fit", "export", "validate"]
    for ln in text.splitlines():  # "name␣…␣action — reason", names padded to 9 columns
        assert re.match(r"^[a-z]+ *\S+ — \S", ln) and ln[9] == " "


def test_spec_values_appear_in_the_plan():
    sp = parse_spec({"atlas": {"resolution": 1024, "padding": 2},
                     "measurement_points": {"count": 64, "placement": "hull", "supersample": 4},
                     "lights": {"count": 32, "holdout": 0},
                     "fit": {"basis": 8, "ridge": 0.1, "channels": "rgb"}})
    plan = plan_asset(box_scene(), sp)
    assert plan.stage("texels") == StagePlan("texels", "run", "1024×1024 atlas, padding 2")
    assert plan.stage("points").reason == "64 measurement points, hull, supersample 4"
    assert plan.stage("lights").reason.startswith("32 lights + 0 held out")
    assert plan.stage("fit").reason == "basis 8, ridge 0.1, rgb"
    assert plan.stage("validate").action == "skip"
    with pytest.raises(KeyError):
        plan.stage("nonsense")


def test_valid_uv1_is_kept():
    plan = plan_asset(two_quads_with_uv1(), parse_spec({"atlas": {"resolution": 64,
                                                                  "padding": 2}}))
    uv = plan.stage("uv")
    assert uv.action == "keep" and uv.reason.startswith("TEXCOORD_1 valid")
    assert plan.uv_check is not None and plan.uv_check.charts == 2
    forced = plan_asset(two_quads_with_uv1(), parse_spec({"prepare": {"uv": "generate"}}))
    assert forced.stage("uv") == StagePlan("uv", "generate",
                                           "forced by spec prepare.uv = generate")


def test_invalid_uv1_is_regenerated_with_reason_or_refused():
    s = two_quads_with_uv1()
    uv = s.uv1.copy()
    uv[4:] -= [0.4, 0.0]  # second quad on top of the first
    s = s.replace(uv1=uv)
    plan = plan_asset(s, parse_spec({}))
    assert plan.stage("uv").action == "generate"
    assert plan.stage("uv").reason.startswith("TEXCOORD_1 invalid: overlap")
    with pytest.raises(AssetError, match="TEXCOORD_1") as e:
        plan_asset(s, parse_spec({"prepare": {"uv": "keep"}}))
    assert "overlap" in str(e.value) and "plan-test" in str(e.value)


def test_repair_decisions():
    m = trimesh.creation.box()
    dup = make_scene(m.vertices, np.vstack([m.faces, m.faces[:2]]))
    assert plan_asset(dup, parse_spec({})).stage("repair") == StagePlan(
        "repair", "run", "2 duplicate faces")
    never = plan_asset(dup, parse_spec({"prepare": {"repair": "never"}})).stage("repair")
    assert never.action == "skip" and "2 duplicate faces" in never.reason
    always = plan_asset(box_scene(), parse_spec({"prepare": {"repair": "always"}}))
    assert always.stage("repair").action == "run"
    assert always.stage("repair").reason == "forced by spec prepare.repair = always"


def test_uv_decision_is_made_after_repair():
    """A duplicated face makes TEXCOORD_1 overlap only until repair removes it."""
    s = two_quads_with_uv1()
    s = make_scene(s.positions, np.vstack([s.faces, s.faces[:1]]), uv1=s.uv1)
    sp = parse_spec({"atlas": {"resolution": 64, "padding": 2}})
    plan = plan_asset(s, sp)
    assert plan.stage("repair").action == "run" and plan.stage("uv").action == "keep"
    sp_never = parse_spec({"atlas": {"resolution": 64, "padding": 2},
                           "prepare": {"repair": "never"}})
    assert plan_asset(s, sp_never).stage("uv").action == "generate"


def test_remesh_plan():
    plan = plan_asset(two_quads_with_uv1(), parse_spec({"prepare": {"remesh": 0.05}}))
    assert plan.stage("remesh").action == "run" and "0.05" in plan.stage("remesh").reason
    assert plan.stage("uv") == StagePlan("uv", "generate", "remeshing drops TEXCOORD_1")
    with pytest.raises(SpecError, match=r"prepare\.uv"):
        plan_asset(box_scene(), parse_spec({"prepare": {"remesh": 0.05, "uv": "keep"}}))


def test_keyframes_decisions():
    s = box_scene(animations=(spin(),))
    kf = plan_asset(s, parse_spec({})).stage("keyframes")
    assert kf.action == "skip" and kf.reason.startswith("static bake")
    kf = plan_asset(s, parse_spec({"keyframes": {"animation": 0, "count": 8}})).stage(
        "keyframes")
    assert kf.action == "run" and "'spin'" in kf.reason and "8 keyframes" in kf.reason
    assert "2.5 s" in kf.reason
    kf = plan_asset(s, parse_spec({"keyframes": {"animation": "spin",
                                                 "times": [0.0, 1.0, 2.0]}})).stage("keyframes")
    assert kf.action == "run" and "3 keyframes" in kf.reason
    with pytest.raises(SpecError, match=r"keyframes\.animation"):
        plan_asset(s, parse_spec({"keyframes": {"animation": 3}}))
    with pytest.raises(SpecError, match="walk"):
        plan_asset(s, parse_spec({"keyframes": {"animation": "walk"}}))
    with pytest.raises(SpecError, match=r"keyframes\.animation"):
        plan_asset(box_scene(), parse_spec({"keyframes": {"animation": 0}}))


@pytest.mark.parametrize("make", [box_scene, two_quads_with_uv1])
def test_prepare_follows_the_plan(make):
    s = make()
    sp = parse_spec({"atlas": {"resolution": 64, "padding": 2}})
    plan = plan_asset(s, sp)
    _, rep = prepare_scene(s, sp)
    assert {"generate": "generated", "keep": "kept"}[plan.stage("uv").action] == rep.uv_action
    assert rep.uv_reason == plan.stage("uv").reason
    assert rep.repaired == (plan.stage("repair").action == "run")
    assert rep.remeshed == (plan.stage("remesh").action == "run")
    out2, rep2 = prepare_scene(s, sp, plan=plan)  # reuses the plan's inspection
    assert rep2.uv_action == rep.uv_action and rep2.uv_check == rep.uv_check
    assert "inspect" not in rep2.seconds and out2.uv1 is not None


def test_truck_plan_is_cheap(shared_assets):
    from prtcore.io.gltf.loader import load_asset
    s = load_asset(shared_assets / "CesiumMilkTruck.glb")
    t0 = time.perf_counter()
    plan = plan_asset(s, parse_spec({}))
    assert time.perf_counter() - t0 < 2.0
    assert isinstance(plan, Plan)
    assert plan.stage("uv").reason == "TEXCOORD_1 missing"
    assert plan.stage("repair").reason == "mesh clean"
    assert plan.stage("keyframes").reason.startswith("static bake")
    assert plan.health is not None and plan.health.faces == len(s.faces)
