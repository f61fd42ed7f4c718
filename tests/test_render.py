"""Headless OpenGL runtime (prtcore.runtime.gl) against the CPU runtime, the light formulas,
the camera-space path tracer, and stored golden images.

One EGL context for the whole session (``gl_ctx``); every test here leaves it without a
pending GL error (``gl_state``, autouse). Works on Mesa's llvmpipe and on GPU drivers.

Goldens: ``tests/goldens/*.png``, tone-mapped 8-bit renders ≤ 256×256. A golden test passes
when at most GOLDEN_OUTLIERS of the pixels differ from the golden by more than
GOLDEN_TOLERANCE (8-bit levels, any channel) — room for driver differences in float
rounding, bilinear weights and shadow-map edges, far below what a broken pass changes.
A failure writes ``tests/_failures/<name>_{output,golden,diff}.png``. The tests always
compare; no environment variable turns that off. Regeneration is a separate command,
``.venv/bin/python scripts/regen_goldens.py``: it renders every golden view (the renders
reach it through ``PRT_GOLDEN_RENDERS=DIR``, which only adds a copy of each output), writes
the new goldens and a before/after/difference report under ``tests/_golden_report/`` —
look at it, and commit the report's images' verdict with the goldens.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from golden_images import (
    GOLDEN_TOLERANCE,
    compare_to_golden,
)
from golden_images import check_golden as _golden
from scenes import TINY_SPEC

from prtcore import pipeline
from prtcore.cli import main
from prtcore.core.raytrace import RayTracer
from prtcore.core.spec import parse_spec
from prtcore.emitters.lightfile import light_from_dict, load_light_file
from prtcore.emitters.punctual import irradiance, unshadowed_irradiance
from prtcore.io.bundle import read_manifest
from prtcore.io.imageio import read_image, write_png
from prtcore.reference.camera import Camera, CameraFileError, camera_from_dict, load_camera
from prtcore.report import format_table, merge_gpu_columns
from prtcore.runtime.cpu import blend, plane_weights, relight, shade_points
from prtcore.runtime.gl import (
    BundleRenderer,
    create_context,
    gpu_runtime_table,
    make_current,
    tone_map,
)
from prtcore.scenes.cornell import EXAMPLE_SPEC

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "examples" / "cornell_box.glb"
CAMERA = ROOT / "examples" / "cameras" / "cornell.json"
LIGHTS = ROOT / "examples" / "lights"

#: A shared asset with textures, several materials and self-shadowing.
TRUCK = "CesiumMilkTruck.glb"
TRUCK_SPEC = {
    "atlas": {"resolution": 128, "padding": 1},
    "measurement_points": {"count": 32, "supersample": 2},
    "lights": {"count": 24, "holdout": 4, "families": [
        {"type": "point", "position": {"shell": [1.2, 2.0]},
         "intensity": {"uniform": [2.0, 8.0]}}]},
    "transport": {"gather_rays": 16, "max_bounces": 8},
    "fit": {"basis": 8},
    "output": {"dtype": "float"},
}


# ---------------------------------------------------------------------------------------
# Fixtures


@pytest.fixture(scope="session")
def gl_ctx():
    """One headless EGL context for the session."""
    ctx = create_context()
    yield ctx
    ctx.release()


@pytest.fixture(autouse=True)
def gl_state(gl_ctx):
    """No GL error pending before or after any test of this module (checked with the
    session context current: the CLI tests create and release contexts of their own)."""
    make_current(gl_ctx)
    assert gl_ctx.error == "GL_NO_ERROR", "a GL error was pending before the test"
    yield
    make_current(gl_ctx)
    assert gl_ctx.error == "GL_NO_ERROR", "the test left a GL error behind"


def test_gl_errors_are_seen(gl_ctx):
    """The error check is live: releasing the bound framebuffer and creating another makes
    moderngl re-bind the deleted one (GL_INVALID_OPERATION) — what BundleRenderer._unbind
    prevents; reading the error clears it."""
    tex = [gl_ctx.texture((4, 4), 4) for _ in range(2)]
    fbo = gl_ctx.framebuffer([tex[0]])
    fbo.use()
    fbo.release()
    other = gl_ctx.framebuffer([tex[1]])
    assert gl_ctx.error == "GL_INVALID_OPERATION"
    assert gl_ctx.error == "GL_NO_ERROR"
    gl_ctx.detect_framebuffer(0).use()
    for o in (other, *tex):
        o.release()


def _bake(tmp_path_factory, asset, spec: dict, name: str) -> Path:
    out = tmp_path_factory.mktemp(name) / "bundle"
    return pipeline.bake(asset, parse_spec(spec), out, quiet=True)


@pytest.fixture(scope="module")
def cornell_bundle(tmp_path_factory):
    return _bake(tmp_path_factory, CORNELL, TINY_SPEC, "cornell")


@pytest.fixture(scope="module")
def cornell(gl_ctx, cornell_bundle):
    with BundleRenderer(cornell_bundle, ctx=gl_ctx) as r:
        yield r


@pytest.fixture(scope="module")
def cornell_tracer(cornell):
    return RayTracer(cornell.scene.positions, cornell.scene.faces, cornell.scene.radius)


@pytest.fixture(scope="module", params=[("rgb", None), ("mono", 2.2)], ids=["rgb", "gamma"])
def variant(request, gl_ctx, tmp_path_factory):
    """Renderers of bundles with an rgb basis and with gamma."""
    channels, gamma = request.param
    spec = json.loads(json.dumps(TINY_SPEC))
    spec["fit"].update({"channels": channels, "gamma": gamma})
    bundle = _bake(tmp_path_factory, CORNELL, spec, f"cornell_{channels}_{gamma}")
    with BundleRenderer(bundle, ctx=gl_ctx) as r:
        yield r


def _light(name: str):
    return load_light_file(LIGHTS / f"{name}.json")


def _camera(size: tuple[int, int] = (64, 64)) -> Camera:
    return dataclasses.replace(load_camera(CAMERA), width=size[0], height=size[1])


# ---------------------------------------------------------------------------------------
# Camera files


def test_camera_file(tmp_path):
    cam = load_camera(CAMERA)
    assert (cam.width, cam.height, cam.fov_y_deg) == (256, 256, 40.0)
    r, u, f = cam.frame()
    np.testing.assert_allclose([r @ u, r @ f, u @ f], 0.0, atol=1e-12)
    _, d = dataclasses.replace(cam, width=3, height=3).primary_rays()
    np.testing.assert_allclose(d[4], f, atol=1e-12)  # the centre pixel looks at the target
    assert d[0, 1] > f[1] and d[8, 1] < f[1]  # row 0 is the top of the image
    good = {"position": [0, 1, 3], "target": [0, 1, 0], "fov_y_deg": 40, "width": 8,
            "height": 4}
    camera_from_dict(good)
    for bad, msg in [({**good, "fov_y_deg": 180}, "fov_y_deg"),
                     ({**good, "width": 0}, "width"),
                     ({**good, "target": [0, 1, 3]}, "target"),
                     ({**good, "up": [0, 0, 1]}, "up"),
                     ({**good, "zoom": 2}, "zoom"),
                     ({k: v for k, v in good.items() if k != "height"}, "height")]:
        with pytest.raises(CameraFileError, match=msg):
            camera_from_dict(bad, "cam.json")
    p = tmp_path / "c.json"
    p.write_text("{")
    with pytest.raises(CameraFileError, match="not valid JSON"):
        load_camera(p)


# ---------------------------------------------------------------------------------------
# The GPU runtime against the CPU runtime


@pytest.mark.parametrize("name", ["point_center", "spot_front", "directional_window"])
def test_points_unshadowed_match_the_light_formulas(cornell, name):
    """Without shadows the compute shader's irradiance at every supersample equals
    prtcore.emitters.punctual.unshadowed_irradiance (float32 against float64)."""
    lights = _light(name)
    d = cornell.data
    pos, nrm = d.cluster_position.astype(np.float64), d.cluster_normal.astype(np.float64)
    _, e = cornell.shade_points(lights, use_shadows=False)
    ref = sum(unshadowed_irradiance(lt, pos, nrm)[0] for lt in lights)
    np.testing.assert_allclose(e, ref, rtol=1e-4, atol=1e-5 * np.abs(ref).max())


@pytest.mark.parametrize(("name", "x_tol"), [("point_center", 0.01), ("spot_front", 0.01),
                                             ("directional_window", 0.05)])
def test_points_shadowed_match_ray_traced_irradiance(cornell, cornell_tracer, name, x_tol):
    """GPU shading of the measurement points (shadows from the shadow maps) against
    lights.irradiance (shadow rays). Method: shadow map, normal offset 1.5 texels, depth
    bias 1 texel. Tolerance: supersamples agree to 1e-4 except at most 1% of them (those
    within a shadow texel or two of a shadow boundary or of a contact); x agrees to 1%
    (point, spot) or 5% (directional: one 1024² map over the bounding sphere, ~3.4 mm
    texels in the box, so a few more boundary samples flip)."""
    lights = _light(name)
    d = cornell.data
    pos, nrm = d.cluster_position.astype(np.float64), d.cluster_normal.astype(np.float64)
    x, e = cornell.shade_points(lights)
    ref = sum(irradiance(lt, pos, nrm, cornell_tracer) for lt in lights)
    assert (ref.max(axis=1) == 0).any() and (ref.max(axis=1) > 0).any()  # shadows present
    close = (np.abs(e - ref) <= 1e-4 * np.abs(ref) + 1e-6 * np.abs(ref).max()).all(axis=1)
    assert close.mean() >= 0.99, f"{(~close).sum()} of {len(close)} supersamples differ"
    xc = shade_points(d, lights, cornell_tracer)
    assert np.linalg.norm(x - xc) <= x_tol * np.linalg.norm(xc)


def _coefficient_check(r: BundleRenderer, lights) -> None:
    for n in (1, 3, r.n_basis):
        w = r.plane_weights(lights, n)
        x, _ = r.shade_points(lights)
        # x from the GPU is x' (gamma applied); undo for the CPU formula
        g = r.data.gamma
        x_lin = x if g is None else np.sign(x) * np.abs(x) ** g
        ref = plane_weights(r.data, x_lin, n)
        np.testing.assert_allclose(w, ref, rtol=2e-4, atol=2e-5 * np.abs(ref).max())
        assert not w[r.data.plane_element >= n].any()  # unused planes get weight 0


def test_gpu_coefficients_match_cpu_runtime(cornell):
    """u = M·x' and plane weights from the compute shader = runtime.plane_weights for
    the same x (mono basis), for 1, 3 and all elements."""
    _coefficient_check(cornell, _light("point_center"))


def test_gpu_coefficients_rgb_and_gamma(variant):
    _coefficient_check(variant, _light("spot_front"))


@pytest.fixture(scope="module")
def learnt(gl_ctx, tmp_path_factory):
    """The renderer of a bundle with a learnt transfer (fit.transfer "mlp", issue 18)."""
    spec = json.loads(json.dumps(TINY_SPEC))
    spec["fit"].update({"transfer": "mlp", "mlp_steps": 60, "mlp_width": 24,
                        "mlp_layers": 2})
    spec["lights"].update(count=7)  # too few for a validation split: the network ships
    bundle = _bake(tmp_path_factory, CORNELL, spec, "cornell_mlp")
    # the equality must hold for any network, not only the trained one: seeded random
    # weights of the same shapes
    rng = np.random.default_rng(18)
    for layer in read_manifest(bundle)["transfer"]["learnt"]["layers"]:
        for part in ("weight", "bias"):
            desc = layer[part]
            values = rng.standard_normal(desc["shape"]) / np.sqrt(desc["shape"][-1])
            (bundle / desc["file"]).write_bytes(values.astype("<f4").tobytes())
    with BundleRenderer(bundle, ctx=gl_ctx) as r:
        yield r


def test_gpu_learnt_transfer_is_the_cpu_one(learnt):
    """The GLSL network (learnt.glsl in the coefficients pass) against the numpy one
    (runtime.plane_weights) for the GPU's own x: equal to 1e-4 of the largest weight, for
    1, 3 and all elements and two lights; the learnt part is a large part of it."""
    for name in ("point_center", "spot_front"):
        lights = _light(name)
        x, _ = learnt.shade_points(lights)
        plain = plane_weights(dataclasses.replace(learnt.data, learnt=None), x)
        for n in (1, 3, learnt.n_basis):
            w = learnt.plane_weights(lights, n)
            ref = plane_weights(learnt.data, x, n)
            assert np.abs(w - ref).max() <= 1e-4 * np.abs(ref).max(), (name, n)
        assert np.abs(ref - plain).max() > 0.1 * np.abs(ref).max()


def _cpu_lightmap(r: BundleRenderer, lights, n=None) -> np.ndarray:
    """The CPU blend for the GPU's own x (isolates blending from shading)."""
    x, _ = r.shade_points(lights)
    g = r.data.gamma
    x_lin = x if g is None else np.sign(x) * np.abs(x) ** g
    return blend(r.data, plane_weights(r.data, x_lin, n))


def test_atlas_relight_matches_cpu_relight(cornell, cornell_tracer, variant):
    """The fragment-shader blend at texel centres = the CPU blend (same x), texel for
    texel, alpha = coverage; with the CPU's own shading (shadow rays) within 2%."""
    lights = _light("point_center")
    for r in (cornell, variant):
        for n in (2, None):
            gpu = r.relight_atlas(lights, n).image
            cpu = _cpu_lightmap(r, lights, n)
            np.testing.assert_allclose(gpu[:, :, :3], cpu, rtol=1e-4,
                                       atol=1e-5 * np.abs(cpu).max())
            np.testing.assert_array_equal(gpu[:, :, 3], r.data.coverage.astype(np.float32))
    full = relight(cornell.data, lights, cornell_tracer)
    gpu = cornell.relight_atlas(lights).image
    assert np.linalg.norm(gpu[:, :, :3] - full[:, :, :3]) <= 0.02 * np.linalg.norm(full[:, :, :3])


def test_glsl_blend_is_the_cpu_blend(cornell, variant):
    """blend.glsl (the atlas pass, ATLAS_FS) = prtcore.runtime.cpu.blend, the formula's
    source, for random plane weights (not only the coefficients a light gives): mono, rgb
    and gamma bundles, weights of either sign over four decades. Tolerance: both sum in
    float32, so per texel and channel |gpu − cpu| ≤ 1e-5 · Σ_j |plane_j|·|w_j| (the sum's
    rounding scale), times the derivative of c^gamma with gamma (pow on the GPU); llvmpipe
    stays within 3e-7 of that scale. Alpha = coverage exactly."""
    from prtcore.core.errors import PrtError

    rng = np.random.default_rng(12)
    for r in (cornell, variant):
        planes = np.abs(r.data.planes.astype(np.float64))
        g = r.data.gamma
        for _ in range(3):
            w = rng.normal(size=(len(r.data.plane_element), 3)) * 10.0 ** rng.uniform(-2, 2)
            gpu = r.blend_atlas(w).image
            cpu = blend(r.data, w)
            scale = np.einsum("hwq,qc->hwc", planes, np.abs(w))
            if g is not None:
                scale = g * np.maximum(cpu, scale) ** ((g - 1) / g) * scale
            err = np.abs(gpu[:, :, :3] - cpu)
            assert (err <= 1e-5 * scale + 1e-30).all(), float((err / scale).max())
            np.testing.assert_array_equal(gpu[:, :, 3], r.data.coverage.astype(np.float32))
    with pytest.raises(PrtError, match="plane weights"):
        cornell.blend_atlas(np.zeros((2, 3)))


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """GL_LINEAR / CLAMP_TO_EDGE lookup of (h, w, c) at uv (..., 2), texel centres at
    ((x + 0.5)/W, (y + 0.5)/H), row 0 at v = 0 (the atlas convention, DESIGN 3.1)."""
    h, w = image.shape[:2]
    x = uv[..., 0] * w - 0.5
    y = uv[..., 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    xa, xb = np.clip(x0, 0, w - 1).astype(int), np.clip(x0 + 1, 0, w - 1).astype(int)
    ya, yb = np.clip(y0, 0, h - 1).astype(int), np.clip(y0 + 1, 0, h - 1).astype(int)
    top = image[ya, xa] * (1 - fx) + image[ya, xb] * fx
    bot = image[yb, xa] * (1 - fx) + image[yb, xb] * fx
    return top * (1 - fy) + bot * fy


@pytest.mark.parametrize("name", ["point_center", "spot_front"])
def test_indirect_view_is_the_cpu_lightmap_through_the_uvs(cornell, cornell_tracer, name):
    """The camera pass's indirect-only image = the CPU lightmap sampled bilinearly at the
    TEXCOORD_1 the rasteriser interpolated at each pixel. Tolerance: 0.5% of the image's
    peak per pixel (GL filtering weights carry only ~8 fractional bits), and 0.2% RMS."""
    lights = _light(name)
    res = cornell.render(lights, _camera((96, 96)), mode="indirect")
    front = res.image[:, :, 3] > 0
    assert front.mean() > 0.5
    got = res.image[:, :, :3][front]

    def rel_rms(a, b):
        return np.sqrt(((a - b) ** 2).mean() / (b ** 2).mean())

    # the GPU filters the planes, then clamps the blend at 0 (runtime formula): compare
    # with the CPU's blend before its clamp, filtered alike, then clamped
    x, _ = cornell.shade_points(lights)
    assert cornell.data.gamma is None
    h, w, q = cornell.data.planes.shape
    unclamped = (cornell.data.planes.reshape(-1, q).astype(np.float64)
                 @ plane_weights(cornell.data, x, None)).reshape(h, w, 3)
    same_x = np.maximum(bilinear(unclamped, res.uv1), 0.0)[front]
    assert np.abs(got - same_x).max() <= 0.005 * np.abs(same_x).max()
    assert rel_rms(got, same_x) <= 0.002
    # with the CPU's own shading (shadow rays instead of shadow maps): within 2%
    cpu = bilinear(relight(cornell.data, lights, cornell_tracer)[:, :, :3], res.uv1)[front]
    assert rel_rms(got, cpu) <= 0.02


def test_modes_add_up_and_back_faces_are_black(cornell):
    lights = _light("point_center")
    cam = _camera((48, 48))
    full = cornell.render(lights, cam).image
    direct = cornell.render(lights, cam, mode="direct").image
    indirect = cornell.render(lights, cam, mode="indirect").image
    np.testing.assert_allclose(full[:, :, :3], direct[:, :, :3] + indirect[:, :, :3],
                               rtol=1e-5, atol=1e-6)
    assert (direct[:, :, :3] > 0).any() and (indirect[:, :, :3] > 0).any()
    # from behind the back wall (single-sided, facing +z) the camera sees its back face
    behind = Camera(position=np.array([0.0, 1.0, -3.0]), target=np.array([0.0, 1.0, 0.0]),
                    up=np.array([0.0, 1.0, 0.0]), fov_y_deg=20.0, width=16, height=16)
    img = cornell.render(lights, behind).image
    assert not img[6:10, 6:10].any()  # black, alpha 0


def test_render_timings_and_basis_bounds(cornell):
    from prtcore.core.errors import PrtError

    res = cornell.render(_light("point_center"), _camera((32, 32)), n=2)
    assert set(res.wall_milliseconds) == {"shadow_maps", "points", "coefficients", "camera"}
    assert set(res.milliseconds) == set(res.wall_milliseconds)
    assert all(v is None or (np.isfinite(v) and v >= 0) for v in res.milliseconds.values())
    with pytest.raises(PrtError, match="--basis 99"):
        cornell.render(_light("point_center"), _camera((8, 8)), n=99)


def test_gpu_columns_in_the_report(cornell):
    table = {"reference": "x", "heldout_configurations": 1, "rows": [
        {"n": n, "heldout_rmse_mean": 0.1, "heldout_rmse_max": 0.2,
         "projection_bound_mean": 0.05, "cpu_coefficients_us": 1.0, "cpu_blend_ms": 1.0,
         "textures": 1, "storage_bytes": 1024} for n in (4, 8)]}
    before = format_table(table)
    assert "GPU" not in before and "timer" not in before
    gpu = gpu_runtime_table(cornell, _light("point_center"), [4], repeat=1)
    merge_gpu_columns(table, gpu)
    text = format_table(table)
    assert text.startswith(before)  # existing output unchanged, a block added
    assert gpu["renderer"] in text
    assert table["rows"][0]["gpu_atlas_blend_wall_ms"] > 0
    assert "gpu_points_ms" not in table["rows"][1]


# ---------------------------------------------------------------------------------------
# CLI


def test_cli_render_and_camera_reference(cornell_bundle, tmp_path, capsys, gl_ctx):
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({**json.loads(CAMERA.read_text()), "width": 24,
                               "height": 16}))
    light = str(LIGHTS / "point_center.json")
    exr, png = tmp_path / "f.exr", tmp_path / "f.png"
    assert main(["render", str(cornell_bundle), "--light", light, "--camera", str(cam),
                 "--out", str(exr), "--basis", "4"]) == 0
    assert main(["render", str(cornell_bundle), "--light", light, "--camera", str(cam),
                 "--out", str(png), "--indirect-only"]) == 0
    img = read_image(exr)
    assert img.shape == (16, 24, 4) and img[:, :, :3].max() > 0
    assert read_image(png).shape == (16, 24, 3)
    assert capsys.readouterr().out.count("rendered:") == 2
    assert main(["render", str(cornell_bundle), "--light", light, "--camera", str(cam),
                 "--out", str(tmp_path / "f.jpg")]) == 2
    assert main(["render", str(cornell_bundle), "--light", light, "--camera", str(cam),
                 "--out", str(png), "--basis", "0"]) == 2
    assert "--basis 0" in capsys.readouterr().err
    ref = tmp_path / "ref.exr"
    assert main(["reference", str(cornell_bundle), "--light", light, "--camera", str(cam),
                 "--out", str(ref), "--spp", "2", "-q"]) == 0
    r = read_image(ref)
    assert r.shape == (16, 24, 4)
    np.testing.assert_array_equal(r[:, :, 3] > 0, img[:, :, 3] > 0)
    assert main(["reference", str(cornell_bundle), "--light", light, "--out", str(ref),
                 "--indirect-only"]) == 2
    capsys.readouterr()
    assert main(["report", str(cornell_bundle), "--gpu"]) == 0
    assert "GL timer query / wall clock" in capsys.readouterr().out
    rows = json.loads((cornell_bundle / "report.json").read_text())["table"]["rows"]
    assert {r["n"] for r in rows if "gpu_points_ms" in r} == {r["n"] for r in rows
                                                              if r["n"] <= 8}  # n the bundle has
    assert all(r["gpu_atlas_blend_wall_ms"] > 0 for r in rows if r["n"] <= 8)


@pytest.mark.parametrize("name", ["point_center", "spot_front", "directional_window"])
def test_direct_view_matches_ray_traced_direct(cornell, name):
    """Camera pass, direct only, against the camera-space reference's direct term (ray
    cast per pixel centre, shadow rays): the same surface is seen in (almost) every pixel
    (silhouettes may differ by the rasteriser's tie rules) and the images agree pixel for
    pixel to 1e-3 of the peak except at ≤ 1% of the pixels (shadow-map edges); relative
    RMSE ≤ 2%. Checks camera matrices, pixel-centre conventions and shadow-map lookups."""
    from prtcore.reference.camera import reference_image

    lights = _light(name)
    cam = _camera((48, 48))
    img = cornell.render(lights, cam, mode="direct").image
    ref = reference_image(cornell.scene, lights, cam, spp=1)
    seen = ref.alpha > 0
    both = seen & (img[:, :, 3] > 0)
    assert both.sum() >= 0.995 * max(seen.sum(), (img[:, :, 3] > 0).sum())
    got, want = img[:, :, :3][both], ref.direct[both]
    off = (np.abs(got - want) > 1e-3 * want.max()).any(axis=1)
    assert off.mean() <= 0.01
    assert np.sqrt(((got - want) ** 2).mean() / (want ** 2).mean()) <= 0.02


# ---------------------------------------------------------------------------------------
# Golden images


@pytest.mark.parametrize("env", [{}, {"PRT_REGEN_GOLDENS": "1"}, {"PRT_UPDATE_GOLDENS": "1"},
                                 {"PRT_GOLDEN_RENDERS": "renders"}])
def test_golden_check_always_compares(tmp_path, monkeypatch, env):
    """No environment turns the golden comparison into a pass or overwrites a golden: a
    render unlike the golden fails, and the golden file is left as it was."""
    for k, v in env.items():
        monkeypatch.setenv(k, str(tmp_path / v) if k == "PRT_GOLDEN_RENDERS" else v)
    rng = np.random.default_rng(1)
    golden = rng.integers(0, 256, (16, 16, 3)).astype(np.uint8)
    write_png(tmp_path / "g.png", golden)
    before = (tmp_path / "g.png").read_bytes()
    with pytest.raises(pytest.fail.Exception, match="pixels differ"):
        _golden("g", 255 - golden, goldens=tmp_path)
    assert (tmp_path / "g.png").read_bytes() == before
    _golden("g", golden, goldens=tmp_path)  # and an equal render passes
    with pytest.raises(AssertionError, match="missing"):
        _golden("absent", golden, goldens=tmp_path)


def test_golden_comparison_can_fail():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (40, 40, 3)).astype(np.uint8)
    assert compare_to_golden(img, img)[0]
    near = np.clip(img.astype(int) + rng.integers(-GOLDEN_TOLERANCE, GOLDEN_TOLERANCE + 1,
                                                  img.shape), 0, 255).astype(np.uint8)
    assert compare_to_golden(near, img)[0]
    moved = img.copy()
    moved[:6, :6] = 255 - moved[:6, :6]  # a 6×6 patch: 2.25% of the pixels
    ok, msg, diff = compare_to_golden(moved, img)
    assert not ok and "2.25%" in msg and diff.shape == img.shape
    assert not compare_to_golden(img[:-1], img)[0]


GOLDEN_VIEWS = [("cornell_full", "full"), ("cornell_direct", "direct"),
                ("cornell_indirect", "indirect")]


@pytest.mark.parametrize(("name", "mode"), GOLDEN_VIEWS, ids=[g[0] for g in GOLDEN_VIEWS])
def test_golden_cornell(cornell, name, mode):
    lights = _light("point_center") + _light("spot_front")
    res = cornell.render(lights, _camera((128, 128)), mode=mode)
    _golden(name, tone_map(res.image, exposure=2.5 if mode == "indirect" else 0.6))


@pytest.fixture(scope="module")
def truck(gl_ctx, shared_assets, tmp_path_factory):
    bundle = _bake(tmp_path_factory, shared_assets / TRUCK, TRUCK_SPEC, "truck")
    with BundleRenderer(bundle, ctx=gl_ctx) as r:
        yield r


def test_golden_shared_asset(truck):
    """CesiumMilkTruck: base-colour textures and factor-only materials, self-shadowing
    under a point and a directional light."""
    c, R = truck.center, truck.radius
    cam = Camera(position=c + R * np.array([1.3, 0.9, 1.9]), target=c,
                 up=np.array([0.0, 1.0, 0.0]), fov_y_deg=40.0, width=128, height=96)
    lights = [light_from_dict({"type": "point", "position": list(c + R * np.array(
                  [0.8, 1.5, 0.9])), "intensity": 6.0 * R * R}),
              light_from_dict({"type": "directional", "direction": [0.4, -1.0, -0.3],
                               "intensity": 1.0, "color": [1.0, 0.9, 0.8]})]
    res = truck.render(lights, cam)
    assert (res.image[:, :, 3] > 0).mean() > 0.2
    _golden("truck_full", tone_map(res.image))


# ---------------------------------------------------------------------------------------
# Against the camera-space path tracer


@pytest.mark.slow
def test_render_matches_the_camera_space_reference(gl_ctx, tmp_path_factory):
    """The example bake (EXAMPLE_SPEC, n = 16) rendered through the example camera
    (64×64) for its first four held-out lights vs the path-traced view (direct with
    ray-traced shadows + indirect, 256 paths per pixel): relative RMSE over the pixels that
    see geometry ≤ 8% for each. Measured on llvmpipe over all 16 held-out lights: 2.5–3.8%
    (mean 3.0%), of which ~2.2% is the reference's own noise."""
    from prtcore.reference.camera import reference_image

    bundle = _bake(tmp_path_factory, CORNELL, EXAMPLE_SPEC, "example")
    cam = _camera((64, 64))
    with BundleRenderer(bundle, ctx=gl_ctx) as r:
        holdout = load_light_file(bundle / "holdout_lights.json")[:4]
        assert r.n_basis >= 16
        for light in holdout:
            img = r.render([light], cam, n=16).image
            ref = reference_image(r.scene, [light], cam, spp=256, seed=1)
            seen = ref.alpha > 0
            np.testing.assert_array_equal(img[:, :, 3] > 0, seen)
            err = img[:, :, :3][seen] - ref.full[seen]
            rel = np.sqrt((err ** 2).mean() / (ref.full[seen] ** 2).mean())
            assert rel <= 0.08, f"held-out light {light.position}: relative RMSE {rel:.2%}"


def test_environment_lights_are_refused_by_the_gl_renderer(gl_ctx):
    """The GL light table has no environment lights (emitters/environment_light.py): one
    line, before any GL work, pointing at the CPU relight."""
    from prtcore.core.errors import PrtError
    from prtcore.core.scene import Light
    from prtcore.runtime.shadows import ShadowMaps

    vbo = gl_ctx.buffer(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], "f4").tobytes())
    maps = ShadowMaps(gl_ctx, vbo, "3f", np.array([[0, 1, 2]]), np.zeros(3), 1.0, 16)
    sky = Light(type="environment", color=np.ones(3), intensity=1.0,
                direction=np.array([0.0, -1.0, 0.0]), environment="sky")
    try:
        with pytest.raises(PrtError, match=r"environment lights are not drawn.*relight"):
            maps.upload([sky])
    finally:
        maps.release()
        vbo.release()
