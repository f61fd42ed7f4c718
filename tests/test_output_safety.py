"""``--out`` never loses data (issue 14): only a prtcore bundle is replaced, and only with
``--force``; a file, a foreign directory and the input itself are refused with exit 2."""

from __future__ import annotations

import json

import pytest

from prtcore.cli import main
from prtcore.scenes.cornell import write_cornell_box

SPEC = {"atlas": {"resolution": 16, "padding": 0},
        "measurement_points": {"count": 8, "supersample": 1},
        "lights": {"count": 6, "holdout": 2, "families": [
            {"type": "point", "position": {"box": [[-0.5, 1.3, -0.5], [0.5, 1.7, 0.5]]}}]},
        "transport": {"gather_rays": 4, "max_bounces": 2}, "fit": {"basis": 2},
        "output": {"dtype": "float"}}


@pytest.fixture()
def setup(tmp_path):
    asset = write_cornell_box(tmp_path / "box.glb")
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps(SPEC))
    return tmp_path, asset, spec


def _bake(asset, spec, out, *extra):
    return main(["bake", str(asset), "--spec", str(spec), "--out", str(out), "-q", *extra])


def test_the_input_is_never_replaced(setup, capsys):
    tmp, asset, spec = setup
    before = asset.read_bytes()
    assert _bake(asset, spec, asset, "--force") == 2
    assert asset.read_bytes() == before
    assert "is the input" in capsys.readouterr().err
    assert _bake(asset, spec, tmp, "--force") == 2  # a directory holding the input
    assert asset.read_bytes() == before


def test_a_file_or_foreign_directory_is_refused_even_with_force(setup, capsys):
    tmp, asset, spec = setup
    f = tmp / "notes.txt"
    f.write_text("keep me")
    assert _bake(asset, spec, f, "--force") == 2
    assert f.read_text() == "keep me"
    foreign = tmp / "myproject"
    (foreign / "src").mkdir(parents=True)
    (foreign / "src" / "main.c").write_text("int main;")
    (foreign / "manifest.json").write_text('{"name": "not a bundle"}')
    assert _bake(asset, spec, foreign, "--force") == 2
    assert (foreign / "src" / "main.c").read_text() == "int main;"
    err = capsys.readouterr().err.strip().splitlines()
    assert "not a prtcore bundle" in err[-1] and "Traceback" not in "".join(err)


def test_a_bundle_is_replaced_only_with_force(setup):
    tmp, asset, spec = setup
    out = tmp / "bundle"
    assert _bake(asset, spec, out) == 0
    stamp = (out / "manifest.json").stat().st_mtime_ns
    assert _bake(asset, spec, out) == 2  # exists, no --force
    assert (out / "manifest.json").stat().st_mtime_ns == stamp
    assert _bake(asset, spec, out, "--force") == 0
    assert not any(p.name.startswith(".bundle") for p in tmp.iterdir())  # no leftovers
