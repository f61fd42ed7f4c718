"""Bake spec: strict validation with JSON paths, defaults, canonical hash."""

import json

import pytest

from prtcore.core.errors import SpecError
from prtcore.core.spec import BakeSpec, load_spec, parse_spec, spec_hash, spec_to_dict

DESIGN_EXAMPLE = {
    "atlas": {"resolution": 512, "padding": 4},
    "measurement_points": {"count": 256, "placement": "surface", "supersample": 8, "seed": 1},
    "lights": {
        "count": 128, "holdout": 16, "seed": 2,
        "families": [
            {"type": "spot", "weight": 1.0, "position": {"shell": [1.5, 3.0]},
             "aim": {"jitter": 0.3}, "intensity": {"log_uniform": [1, 100]},
             "color": "white", "outer_cone_angle": {"uniform": [0.3, 0.8]}},
            {"type": "point", "position": {"box": [[-1, 0, -1], [1, 2, 1]]},
             "intensity": {"uniform": [1, 5]}},
        ],
    },
    "transport": {"gather_rays": 64, "max_bounces": 16, "tolerance": 0.001},
    "fit": {"basis": 16, "ridge": "auto", "channels": "mono", "gamma": None},
    "keyframes": {"animation": 0, "count": 16, "transfer": "shared"},
    "output": {"dtype": "half"},
}


def test_design_example_parses():
    s = parse_spec(DESIGN_EXAMPLE)
    assert s.atlas.resolution == 512
    assert [f.type for f in s.lights.families] == ["spot", "point"]
    assert s.lights.families[1].position == {"box": [[-1, 0, -1], [1, 2, 1]]}
    assert s.lights.families[0].intensity == {"log_uniform": [1.0, 100.0]}
    assert s.fit.ridge == "auto"
    assert s.keyframes.animation == 0


def test_empty_spec_is_defaults():
    assert parse_spec({}) == BakeSpec()
    assert parse_spec(None) == BakeSpec()


@pytest.mark.parametrize(("data", "key"), [
    ({"atlass": {}}, "atlass"),
    ({"atlas": {"resolutoin": 5}}, "atlas.resolutoin"),
    ({"lights": {"families": [{"type": "spot", "colour": "white"}]}},
     "lights.families[0].colour"),
    ({"lights": {"families": [{"type": "area"}]}}, "lights.families[0].type"),
    ({"atlas": {"resolution": "big"}}, "atlas.resolution"),
    ({"atlas": {"resolution": 4}}, "atlas.resolution"),
    ({"fit": {"basis": 0}}, "fit.basis"),
    ({"fit": {"ridge": -1}}, "fit.ridge"),
    ({"lights": {"families": [{"intensity": {"log_uniform": [0, 1]}}]}},
     "lights.families[0].intensity.log_uniform[0]"),
    ({"lights": {"families": [{"position": {"shell": [3, 1]}}]}},
     "lights.families[0].position.shell"),
    ({"lights": {"families": [{"type": "point", "outer_cone_angle": 0.5}]}},
     "lights.families[0].outer_cone_angle"),
    ({"lights": {"families": [{"type": "spot", "outer_cone_angle": 2.0}]}},
     "lights.families[0].outer_cone_angle"),
    ({"lights": {"families": []}}, "lights.families"),
    ({"transport": {"tolerance": float("nan")}}, "transport.tolerance"),
    ({"measurement_points": {"placement": "volume"}}, "measurement_points.placement"),
    ({"hair": {"direct": "exact"}}, "hair.direct"),
    ({"hair": {"direct_samples": 0}}, "hair.direct_samples"),
    ({"hair": {"fibre": "chiang", "direct": "sampled"}}, "hair.direct"),
    ({"hair": {"fibre": "chiang", "direct_samples": 0}}, "hair.direct_samples"),
    ([1, 2], "<root>"),
])
def test_invalid_specs_name_their_key(data, key):
    with pytest.raises(SpecError) as e:
        parse_spec(data)
    assert e.value.key == key
    assert key in str(e.value)
    assert "\n" not in str(e.value)


def test_round_trip_and_hash(tmp_path):
    s = parse_spec(DESIGN_EXAMPLE)
    d = spec_to_dict(s)
    assert parse_spec(d) == s
    assert spec_hash(parse_spec(d)) == spec_hash(s)
    assert spec_hash(s) != spec_hash(BakeSpec())
    p = tmp_path / "spec.json"
    p.write_text(json.dumps(DESIGN_EXAMPLE))
    assert load_spec(p) == s


def test_load_spec_errors_name_the_file(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text("{ not json")
    with pytest.raises(SpecError, match=r"bad\.json.*line 1"):
        load_spec(p)
    p.write_text('{"fit": {"channels": "cmyk"}}')
    with pytest.raises(SpecError, match=r"bad\.json: spec fit\.channels"):
        load_spec(p)
    with pytest.raises(SpecError, match="cannot read"):
        load_spec(tmp_path / "missing.json")


def test_spec_reference_documents_every_key_and_is_up_to_date():
    """docs/spec.md is generated from the spec's definitions (issue 12)."""
    from pathlib import Path

    from prtcore.core.spec import BakeSpec
    from prtcore.core.spec_reference import DOCS, keys, reference

    assert set(keys()) == set(DOCS), set(keys()) ^ set(DOCS)
    assert parse_spec({}) == BakeSpec()  # the parser's defaults are the dataclasses'
    doc = Path(__file__).resolve().parents[1] / "docs" / "spec.md"
    assert doc.read_text(encoding="utf-8") == reference(), (
        "docs/spec.md is stale: .venv/bin/python -m prtcore.core.spec_reference > docs/spec.md")
