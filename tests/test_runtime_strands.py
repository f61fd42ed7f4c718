"""Hair bundles drawn on the CPU (prtcore/runtime/strands.py): the manifest's sampling rule."""

from __future__ import annotations

import numpy as np
import pytest

from prtcore.receivers.strands import build_strand_space
from prtcore.runtime.strands import sample_strands
from prtcore.scenes.hair import hairball


def test_sampling_rule_reads_texel_centres_and_stays_in_its_strand():
    s = build_strand_space(hairball(strands=23, segments=4, seed=2), 5)
    layout = s.layout()
    values = np.stack([s.strand * 100.0 + s.slot, np.ones(s.count)], axis=1)
    img = s.to_image(values)[:, :, :2]
    rng = np.random.default_rng(1)
    strand = np.repeat(s.strand[::5], 3)
    # at the centre of texel j (a = (j + 0.5)/n) the sample is that texel's value
    j = rng.integers(0, 5, len(strand))
    got = sample_strands(img, layout, strand, (j + 0.5) / 5)
    np.testing.assert_allclose(got[:, 0], strand * 100.0 + j, atol=1e-4)
    # anywhere along the strand, ends included: a blend of the strand's own texels only
    a = np.concatenate([rng.random(len(strand) - 2), [0.0, 1.0]])
    got = sample_strands(img, layout, strand, a)
    assert np.all(np.floor(got[:, 0] / 100.0 + 1e-6) == strand)
    np.testing.assert_allclose(got[:, 1], 1.0)  # weights sum to one, no empty texel read
    np.testing.assert_allclose(got[:, 0] - strand * 100.0, np.clip(a * 5 - 0.5, 0, 4),
                               atol=1e-4)


def test_the_gl_bcsdf_is_the_numpy_one(gl_ctx):
    """runtime/shaders/chiang.glsl evaluated by a compute shader on 4096 random fibre
    geometries against prtcore.core.bcsdf.scattering (float64): measured 6.4e-5 relative
    at worst (Mesa's asin was 1 % off near |h| = 1, pbrt's ten-term I0 series 2 % low near
    x = 12: both replaced)."""
    from prtcore.core.bcsdf import ChiangParams, scattering
    from prtcore.runtime.glcontext import make_current, set_uniform
    from prtcore.runtime.glsl import shader_file

    make_current(gl_ctx)
    cs = gl_ctx.compute_shader(
        "#version 430\nlayout(local_size_x = 64) in;\n"
        "const float PI = 3.14159265358979323846;\n" + shader_file("chiang.glsl") + """
layout(std430, binding = 0) readonly buffer In { float inp[]; };
layout(std430, binding = 1) writeonly buffer Out { float outp[]; };
uniform int n;
void main() {
    int i = int(gl_GlobalInvocationID.x);
    if (i >= n) return;
    int b = 13 * i;
    vec3 s = chiang_scattering(vec3(inp[b], inp[b + 1], inp[b + 2]),
                               vec3(inp[b + 3], inp[b + 4], inp[b + 5]),
                               vec3(inp[b + 6], inp[b + 7], inp[b + 8]), inp[b + 9],
                               vec3(inp[b + 10], inp[b + 11], inp[b + 12]));
    outp[3 * i] = s.x; outp[3 * i + 1] = s.y; outp[3 * i + 2] = s.z;
}""")
    rng = np.random.default_rng(0)
    n = 4096
    t, wo, wi = (v / np.linalg.norm(v, axis=1, keepdims=True)
                 for v in rng.normal(size=(3, n, 3)))
    h, sigma = rng.uniform(-1, 1, n), rng.uniform(0, 3, (n, 3))
    params = ChiangParams(beta_m=0.3, beta_n=0.3, alpha=np.radians(2.0), eta=1.55)
    expect = scattering(t, wo, wi, h, params, sigma)
    src = gl_ctx.buffer(np.concatenate([t, wo, wi, h[:, None], sigma], axis=1)
                        .astype("<f4").tobytes())
    dst = gl_ctx.buffer(reserve=n * 12)
    src.bind_to_storage_buffer(0)
    dst.bind_to_storage_buffer(1)
    for name, value in (("n", n), ("chiang_v", tuple(float(x) for x in params.variances)),
                        ("chiang_s", float(params.logistic_scale)),
                        ("chiang_alpha", float(params.alpha)), ("chiang_eta", params.eta)):
        set_uniform(cs, name, value)
    cs.run(group_x=n // 64)
    got = np.frombuffer(dst.read(), "<f4").reshape(n, 3)
    for obj in (src, dst, cs):
        obj.release()
    rel = np.abs(got - expect) / np.maximum(np.abs(expect), 1e-3 * np.abs(expect).max())
    assert rel.max() < 1e-3, rel.max()


@pytest.fixture(scope="module")
def chiang_bundle(tmp_path_factory):
    from prtcore.core.spec import parse_spec
    from prtcore.io.hair import write_hair
    from prtcore.pipeline import bake
    from prtcore.scenes.hair import tangle

    d = tmp_path_factory.mktemp("chiang_render")
    return bake(write_hair(d / "t.hair", tangle(200)), parse_spec({
        "hair": {"texels_per_strand": 4, "fibre": "chiang"},
        "lights": {"count": 24, "holdout": 4, "seed": 1}, "transport": {"gather_rays": 16},
        "measurement_points": {"count": 32}, "fit": {"basis": 8}}), d / "out", quiet=True)


def _chiang_frames(bundle, shadows: bool, monkeypatch):
    import prtcore.runtime.shadows as shadows_module
    import prtcore.runtime.strands as cpu_module
    from prtcore.core.scene import Light
    from prtcore.reference.camera import camera_from_dict
    from prtcore.runtime.strands_gl import StrandRenderer

    if not shadows:  # both drawings without visibility: the shading alone is compared
        nee = cpu_module.fibre_nee
        monkeypatch.setattr(cpu_module, "fibre_nee",
                            lambda lights, tracer, *a: nee(lights, None, *a))
        bind = shadows_module.ShadowMaps.bind
        monkeypatch.setattr(shadows_module.ShadowMaps, "bind",
                            lambda self, prog, use_shadows=True: bind(self, prog, False))
    lights = [Light(type="point", color=np.ones(3), intensity=0.05,
                    position=np.array([0.06, 0.04, 0.02]))]
    cam = camera_from_dict({"position": [0, 0.02, 0.12], "target": [0, 0, 0],
                            "fov_y_deg": 40, "width": 96, "height": 96})
    with StrandRenderer(bundle) as r:
        gl = r.render(lights, cam, mode="direct").image
    cpu = cpu_module.render_strands(bundle, lights, cam, mode="direct")
    both = (gl[..., 3] > 0.5) & (cpu[..., 3] > 0.5)
    assert both.mean() > 0.05
    return gl[both, :3], cpu[both, :3]


def test_a_chiang_bundle_is_shaded_with_its_bcsdf_on_the_cpu_and_the_gpu(chiang_bundle,
                                                                        monkeypatch):
    """The direct light of a Chiang fibre's bundle: the BCSDF toward the camera at the
    offset each pixel sees (core.bcsdf.impact_offset), times E⊥ V from the side facing the
    light. Without visibility the GL drawing is the CPU's (measured +0.07 % in the mean,
    0.17 % per pixel): the offset, the view direction, σ_a per vertex and the fibre's
    parameters reach the shader."""
    g, c = _chiang_frames(chiang_bundle, False, monkeypatch)
    assert c.mean() > 0 and abs(g.mean() / c.mean() - 1) < 0.005
    assert np.abs(g - c).mean() < 0.01 * c.mean()


def test_a_chiang_bundle_s_shadows_differ_by_the_shadow_maps_alone(chiang_bundle,
                                                                  monkeypatch):
    """With visibility the GL drawing's shadow maps (a texel wider than a fibre) make it
    darker in the mean than the CPU's ray-traced shadows: measured −3.6 % at the default
    1024² shadow views, −2.0 % at 2048², 0.07 % without shadows (above)."""
    g, c = _chiang_frames(chiang_bundle, True, monkeypatch)
    assert abs(g.mean() / c.mean() - 1) < 0.06
