"""SH-PRT storage (per vertex, transfer textures): bake, files, the two runtime variants on
the CPU, the memory table."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scenes import bake_sh_prt_bundle

from prtcore.core.spec import parse_spec
from prtcore.emitters.environment import light_sh
from prtcore.io.transfer_textures import read_transfer_textures, write_transfer_textures
from prtcore.methods import sh_prt
from prtcore.pipeline import run_intake
from prtcore.reference.pathtracer import default_tracer
from prtcore.scenes import floor_object


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    path = floor_object.write_floor_object(tmp_path_factory.mktemp("fo") / "fo.glb")
    spec = dict(floor_object.SPEC, atlas={"resolution": 32, "padding": 2})
    intake = run_intake(path, parse_spec(spec), quiet=True)
    tracer = default_tracer(intake.scene)
    vert = sh_prt.bake_sh_prt(intake.scene, tracer, "vertex", 3, 4, seed=1)
    tex = sh_prt.bake_sh_prt(intake.scene, tracer, "texture", 3, 4, seed=1,
                             texels=intake.texels)
    return intake.scene, intake.texels, vert, tex


def test_texture_files_round_trip_and_are_dilated(baked, tmp_path):
    _, texels, _, tex = baked
    names = write_transfer_textures(tmp_path, tex.image, dtype="float")
    assert names == [f"sh_transfer_{c}_{k:02d}.exr" for c in "RGB" for k in range(3)]
    back = read_transfer_textures(tmp_path, 3)
    np.testing.assert_array_equal(back, tex.image.astype(np.float32))
    # padding texels carry their source texel's transfer
    d = texels.dilate_xy[0]
    np.testing.assert_allclose(back[d[1], d[0]],
                               tex.transfer.coeffs[texels.dilate_src[0]], rtol=1e-6)


def test_runtime_variants_reproduce_the_stored_values(baked):
    scene, texels, vert, tex = baked
    light = light_sh(floor_object.key_light(), 3)
    # fragment variant at texel centres = the texel's own T · l
    uv = (texels.xy + 0.5) / np.array([texels.width, texels.height])
    np.testing.assert_allclose(sh_prt.evaluate_texture(tex.image, uv, light),
                               tex.transfer.radiance(light), rtol=1e-5, atol=1e-6)
    # vertex variant at a triangle's corner = that vertex's T · l
    tri = np.arange(scene.triangle_count)
    bary = np.tile([1.0, 0.0, 0.0], (len(tri), 1))
    np.testing.assert_allclose(sh_prt.evaluate_vertex(scene, vert.transfer, tri, bary, light),
                               vert.transfer.radiance(light)[scene.faces[:, 0]])


def test_storage_and_memory_table(baked):
    scene, texels, vert, tex = baked
    assert vert.storage_bytes == len(scene.positions) * 3 * 9 * 4
    assert tex.storage_bytes == texels.width * texels.height * 3 * 9 * 2
    rows = sh_prt.memory_table(len(scene.positions), (256, 512), (3, 5))
    assert {(r["storage"], r["size"], r["bands"]) for r in rows} == {
        ("vertex", len(scene.positions), 3), ("texture", 256, 3), ("texture", 512, 3),
        ("vertex", len(scene.positions), 5), ("texture", 256, 5), ("texture", 512, 5)}
    big = next(r for r in rows if r["size"] == 512 and r["bands"] == 5)
    assert big["bytes"] == 512 * 512 * 3 * 25 * 2


def test_storage_is_checked(baked):
    scene, _, _, _ = baked
    with pytest.raises(ValueError, match="storage"):
        sh_prt.bake_sh_prt(scene, default_tracer(scene), "octree", 3, 2, seed=0)


# ---------------------------------------------------------------------------------------
# The method in the pipeline: bake → bundle → relight with an environment light file


@pytest.mark.parametrize("storage", ["texture", "vertex"])
def test_sh_prt_bake_relights_with_an_environment_file(tmp_path, storage, capsys):
    import json

    import jsonschema

    from prtcore.cli import main
    from prtcore.emitters.environment import load_distant_lighting, sky_environment
    from prtcore.io.bundle import read_manifest, verify_bundle
    from prtcore.io.imageio import read_image, write_exr

    out = bake_sh_prt_bundle(tmp_path, storage)
    m = read_manifest(out)
    verify_bundle(out, m)
    schema = json.loads((Path(sh_prt.__file__).parents[1] / "data" /
                         "manifest.schema.json").read_text())
    jsonschema.validate(m, schema)
    assert m["method"] == "sh_prt" and m["sh_prt"]["storage"] == storage
    assert (out / "report.png").is_file() and (out / "coverage.exr").is_file()
    assert m["sh_prt"]["kind"] == "interreflected" and "verdict: not judged" in \
        m["verdict"]["line"]
    sky = sky_environment(np.array([0.3, 0.8, 0.2]), 16)
    write_exr(tmp_path / "sky.exr", sky.image)
    (tmp_path / "env.json").write_text(json.dumps(
        {"environment": {"file": "sky.exr", "rotation_y_deg": 30},
         "lights": [{"type": "directional", "direction": [0, -1, 0.5], "intensity": 1.5}]}))
    assert main(["relight", str(out), "--light", str(tmp_path / "env.json"), "--out",
                 str(tmp_path / "lit.exr")]) == 0
    assert "sh_prt" in capsys.readouterr().out
    lit = read_image(tmp_path / "lit.exr")
    assert lit.shape == (32, 32, 4)
    # the relit atlas is T · l of the bundle's own transfer at the covered texels
    lighting = load_distant_lighting(tmp_path / "env.json")
    expect = sh_prt.relight_bundle(out, m, lighting)
    np.testing.assert_allclose(lit, expect, rtol=1e-6, atol=1e-7)
    covered = lit[..., 3] > 0
    assert (lit[covered, :3].mean(axis=0) > 0.05).all()
    # --basis is a data-driven option
    assert main(["relight", str(out), "--light", str(tmp_path / "env.json"), "--out",
                 str(tmp_path / "x.exr"), "--basis", "2"]) == 2


def test_distant_light_file_errors_name_the_key(tmp_path):
    import json

    from prtcore.core.errors import LightFileError
    from prtcore.emitters.environment import load_distant_lighting

    (tmp_path / "a.json").write_text(json.dumps({"environment": {"file": "x.exr",
                                                                 "spin": 1}}))
    with pytest.raises(LightFileError, match=r"a\.json: environment\.spin: unknown key"):
        load_distant_lighting(tmp_path / "a.json")
    (tmp_path / "b.json").write_text(json.dumps({"type": "point", "position": [0, 1, 0]}))
    with pytest.raises(LightFileError, match="directional lights only"):
        load_distant_lighting(tmp_path / "b.json")
