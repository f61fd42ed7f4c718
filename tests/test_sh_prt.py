"""SH-PRT storage (per vertex, transfer textures): bake, files, the two runtime variants on
the CPU, the memory table."""

from __future__ import annotations

import numpy as np
import pytest

from prtcore.core.spec import parse_spec
from prtcore.emitters.environment import light_sh
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
    names = sh_prt.write_transfer_textures(tmp_path, tex, dtype="float")
    assert names == [f"sh_transfer_{c}_{k:02d}.exr" for c in "RGB" for k in range(3)]
    back = sh_prt.read_transfer_textures(tmp_path, 3)
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
