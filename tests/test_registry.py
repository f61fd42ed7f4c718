"""Families with members register them by name; the stages ask the registry, never a type
string (issue 12)."""

from __future__ import annotations

import pytest

from prtcore.core.registry import Registry
from prtcore.emitters.base import emitter_for, types
from prtcore.fit.regressor import regressor


def test_registry_refuses_a_second_member_of_the_same_name_and_names_known_ones():
    reg: Registry[object] = Registry("widget", "name")

    @reg.register
    class A:
        name = "a"

    assert isinstance(reg.get("a"), A) and reg.names() == ("a",)
    with pytest.raises(ValueError, match="widget 'a' registered twice"):
        reg.register(type("B", (), {"name": "a"}))
    with pytest.raises(KeyError, match=r"no widget 'z' \(known: a\)"):
        reg.get("z")


def test_the_shipped_members_are_registered():
    assert types() == ("directional", "environment", "point", "spot")
    assert [emitter_for(t).gl_code for t in ("point", "spot", "directional")] == [0, 1, 2]
    assert regressor("ridge").name == "ridge"


def test_the_texel_space_is_a_receiver(tmp_path):
    from prtcore.core.spec import parse_spec
    from prtcore.pipeline import run_intake
    from prtcore.receivers.base import Receiver
    from prtcore.receivers.texels import texels_to_image
    from prtcore.scenes.cornell import write_cornell_box

    ts = run_intake(write_cornell_box(tmp_path / "b.glb"),
                    parse_spec({"atlas": {"resolution": 16, "padding": 0},
                                "measurement_points": {"count": 4}}), quiet=True).texels
    assert isinstance(ts, Receiver) and ts.kind == "texels"
    v = ts.position[:, :2]
    assert (ts.to_image(v) == texels_to_image(ts, v)).all()
