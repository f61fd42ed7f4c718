"""The GL runtime of sh_prt bundles against the CPU variants, pixel by pixel: the
vertex-shader variant vs per-vertex T · l interpolated at the pixel's surface point, the
fragment-shader variant vs the bilinear transfer textures at its TEXCOORD_1."""

from __future__ import annotations

import numpy as np
import pytest
from scenes import bake_sh_prt_bundle, write_render_inputs

from prtcore.core.geometry import shading_normals
from prtcore.core.materials import CLAMP_TO_EDGE, sample_texture
from prtcore.core.scene import Texture
from prtcore.emitters.environment import light_sh, sky_environment
from prtcore.io.bundle import load_raw, read_manifest
from prtcore.io.gltf.loader import load_asset
from prtcore.io.transfer_textures import VISIBILITY, read_transfer_textures
from prtcore.methods import sh_prt
from prtcore.reference.pathtracer import default_tracer
from prtcore.runtime.sh_gl import ShPrtRenderer
from prtcore.scenes import floor_object
from prtcore.transport.sh_transfer import ShTransfer


def _gl_and_hits(out, gl_ctx):
    """Render the bundle under a sky + the key light (3 bands) through the comparison
    camera; return the scene, the light, the frame and the pixels' surface points
    (pixel indices, triangles, barycentrics) by ray casting through the pixel centres."""
    from prtcore.compare import default_camera

    scene = load_asset(out / "asset.glb")
    light = (sky_environment(np.array([0.2, 0.9, 0.3]), 16).sh_coefficients(3)
             + light_sh(floor_object.key_light(), 3))
    camera = default_camera(96, 64)
    with ShPrtRenderer(out, ctx=gl_ctx) as r:
        res = r.render(light, camera)
    tracer = default_tracer(scene)
    hits = tracer.intersect(*camera.primary_rays())
    sel = np.flatnonzero(hits.hit & hits.front)
    return scene, light, camera, res, tracer, sel, hits.triangle[sel], hits.barycentric[sel]


@pytest.mark.parametrize("storage", ["vertex", "texture"])
def test_gl_variants_match_the_cpu(tmp_path, gl_ctx, storage):
    out = bake_sh_prt_bundle(tmp_path, storage, bounce=False)
    m = read_manifest(out)
    scene, light, _, res, _, sel, tri, bary = _gl_and_hits(out, gl_ctx)
    assert res.wall_milliseconds[f"sh_{storage}"] > 0
    if storage == "vertex":
        t = ShTransfer(load_raw(out, m["sh_prt"]["vertex_transfer"]).astype(np.float64),
                       "shadowed", 3, 0)
        cpu = sh_prt.evaluate_vertex(scene, t, tri, bary, light)
    else:
        uv = np.einsum("mk,mkj->mj", bary, scene.uv1[scene.faces[tri]])
        cpu = sh_prt.evaluate_texture(read_transfer_textures(out, 3), uv, light)
    gl = res.image.reshape(-1, 4)[sel]
    inside = gl[:, 3] > 0  # pixels the rasteriser also covers (edges may differ)
    assert inside.mean() > 0.97
    err = np.abs(gl[inside, :3] - cpu[inside])
    # float32 on the GPU; bilinear weights at 8 bits of subtexel precision
    assert np.percentile(err, 99) < 0.01 * np.abs(cpu).max()


def test_gl_glossy_layer_matches_the_cpu_triple_product(tmp_path, gl_ctx):
    """The fragment shader's TP (visibility textures × the light by the triple product, the
    Phong kernel at the mirror direction) vs :func:`prtcore.methods.sh_prt.glossy_tp` on the
    CPU at each pixel's surface point, plus the diffuse transfer."""
    out = bake_sh_prt_bundle(tmp_path, "texture", bounce=False, specular=0.6)
    assert read_manifest(out)["sh_prt"]["glossy"]["specular"] == 0.6
    scene, light, camera, res, tracer, sel, tri, bary = _gl_and_hits(out, gl_ctx)
    uv = np.einsum("mk,mkj->mj", bary, scene.uv1[scene.faces[tri]])
    pos = tracer.surface_point(tri, bary)
    view = camera.position - pos
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    refl = sh_prt.reflect(view, shading_normals(scene, tri, bary))
    vis_img = read_transfer_textures(out, 3, VISIBILITY)[:, :, 0]
    vis = sample_texture(Texture(vis_img, CLAMP_TO_EDGE, CLAMP_TO_EDGE), uv)
    cpu = (sh_prt.evaluate_texture(read_transfer_textures(out, 3), uv, light)
           + sh_prt.glossy_tp(vis, light, refl, 8.0, np.full((len(sel), 3), 0.6)))
    gl = res.image.reshape(-1, 4)[sel]
    inside = gl[:, 3] > 0
    assert inside.mean() > 0.97
    err = np.abs(gl[inside, :3] - cpu[inside])
    glossy_part = sh_prt.glossy_tp(vis, light, refl, 8.0, np.full((len(sel), 3), 0.6))
    assert np.abs(glossy_part).max() > 0.05 * np.abs(cpu).max()  # the layer is visible
    assert np.percentile(err, 99) < 0.01 * np.abs(cpu).max()


def test_render_command_on_an_sh_prt_bundle(tmp_path, capsys):
    from prtcore.cli import main

    out = bake_sh_prt_bundle(tmp_path, "texture", bounce=False)
    cam, sun = write_render_inputs(tmp_path)
    render = ["render", str(out), "--light", str(sun), "--camera", str(cam), "--out"]
    assert main([*render, str(tmp_path / "f.png")]) == 0
    assert "sh_prt" in capsys.readouterr().out and (tmp_path / "f.png").is_file()
    assert main([*render, str(tmp_path / "g.png"), "--indirect-only"]) == 2
