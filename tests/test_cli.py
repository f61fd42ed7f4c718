"""The prtcore command: exit status 2 and one line for bad input; commands that work."""

import json
import subprocess
import sys
from pathlib import Path

import hostile_assets as ha
import numpy as np
import pytest

from prtcore.cli import main

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "examples" / "cornell_box.glb"
PRTCORE = Path(sys.executable).parent / "prtcore"


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize(("make", "needle"), [
    (lambda d: ha.path_traversal_asset(d)[0], "buffers[0].uri"),
    (lambda d: ha.uri_buffer_asset(d, "http://example.com/x.bin"), "buffers[0].uri"),
    (lambda d: ha.truncated_glb_asset(d), "truncated.glb"),
    (lambda d: ha.wrong_magic_asset(d), "magic"),
    (lambda d: ha.positions_asset(d, float("nan")), "POSITION"),
    (lambda d: ha.accessor_overrun_asset(d), "accessors[0]"),
])
def test_hostile_assets_exit_2_with_one_line(tmp_path, capsys, make, needle):
    path = make(tmp_path)
    out = tmp_path / "bundle"
    code, _, err = _run(capsys, "bake", path, "--out", out, "-q")
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert needle in lines[0]
    assert str(path.name) in lines[0]
    assert not out.exists()


def test_bad_spec_and_light_files(tmp_path, capsys):
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"lights": {"families": [{"type": "spot", "colour": 1}]}}))
    code, _, err = _run(capsys, "bake", CORNELL, "--spec", spec, "--out", tmp_path / "o")
    assert code == 2
    assert "lights.families[0].colour" in err and "spec.json" in err
    assert len(err.strip().splitlines()) == 1
    light = tmp_path / "light.json"
    light.write_text(json.dumps({"type": "spot", "position": [0, 1, 0], "intensity": 1}))
    code, _, err = _run(capsys, "reference", CORNELL, "--light", light, "--out",
                        tmp_path / "r.exr", "--spp", "1")
    assert code == 2
    assert "direction" in err and "light.json" in err
    code, _, err = _run(capsys, "relight", tmp_path, "--light", light, "--out",
                        tmp_path / "r.exr")
    assert code == 2 and "not a bundle" in err


def test_plan_says_why(capsys):
    code, out, _ = _run(capsys, "plan", CORNELL)
    assert code == 0
    assert "TEXCOORD_1 missing" in out
    assert "clean" in out


def test_bake_relight_report_through_the_installed_command(tmp_path):
    """The real entry point, as a user runs it."""
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({
        "atlas": {"resolution": 32, "padding": 2},
        "measurement_points": {"count": 24, "supersample": 1},
        "lights": {"count": 16, "holdout": 2, "families": [
            {"type": "point", "position": {"box": [[-0.5, 0.5, -0.5], [0.5, 1.5, 0.5]]}}]},
        "transport": {"gather_rays": 8, "max_bounces": 4},
        "fit": {"basis": 4}}))
    out = tmp_path / "bundle"
    # a deliberately tiny bake: its verdict may fail (exit 3), --allow-poor accepts it
    r = subprocess.run([PRTCORE, "bake", CORNELL, "--spec", spec, "--out", out, "-q",
                        "--allow-poor"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert f"bundle: {out}" in r.stdout and "report.json" in r.stdout
    assert r.stdout.strip().splitlines()[-1].startswith("verdict: ")
    exr = tmp_path / "relit.exr"
    r = subprocess.run([PRTCORE, "relight", out, "--light",
                        ROOT / "examples" / "lights" / "point_center.json", "--out", exr,
                        "--basis", "3"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    from prtcore.io.imageio import read_image
    img = read_image(exr)
    assert img.shape == (32, 32, 4) and np.isfinite(img).all()
    assert img[:, :, :3].max() > 0
    r = subprocess.run([PRTCORE, "relight", out, "--light",
                        ROOT / "examples" / "lights" / "point_center.json", "--out", exr,
                        "--basis", "99"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 2 and "--basis 99" in r.stderr
    r = subprocess.run([PRTCORE, "report", out], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "error against run time" in r.stdout
