"""`prtcore bake` on hair (prtcore/hairbake.py): a strand-texture bundle that relight reads."""

from __future__ import annotations

import json

import numpy as np
import pytest
from render_passes import render_passes

from prtcore.cli import main as cli_main
from prtcore.core.errors import LimitExceeded, SpecError
from prtcore.core.spec import parse_spec
from prtcore.intake.hair import hair_scene
from prtcore.intake.points import place_measurement_points
from prtcore.io.bundle import load_runtime, read_manifest, sha256_file, verify_bundle
from prtcore.io.hair import read_hair, write_hair
from prtcore.io.imageio import read_image
from prtcore.pipeline import bake
from prtcore.receivers.strands import build_strand_space
from prtcore.scenes.hair import tangle, tangle_lights
from prtcore.transport.fibre import hair_tracer
from prtcore.transport.hair import bake_hair_dataset
from prtcore.validate import validate_bundle

# 64 training lights for 32 points: with 24 the transfer is underdetermined (the verdict
# says so), which passed only while the texels' noise swelled the projection bound as much
# as the error (1.03×; denoised, the error fell from 29.7 % to 10.4 % and the ratio rose to
# 1.28×)
SPEC = {"hair": {"texels_per_strand": 4, "albedo": [0.8, 0.6, 0.4]},
        "measurement_points": {"count": 32, "supersample": 2},
        "lights": {"count": 64, "holdout": 4,
                   "families": [{"type": "point", "position": {"shell": [1.5, 3.0]},
                                 "intensity": {"uniform": [0.02, 0.1]}}]},
        "transport": {"gather_rays": 16}, "fit": {"basis": 8}}


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    d = tmp_path_factory.mktemp("hairbake")
    asset = write_hair(d / "tangle.hair", tangle(200))
    return asset, bake(asset, parse_spec(SPEC), d / "out", quiet=True)


def test_hair_bundle_states_its_strand_layout(bundle):
    asset, out = bundle
    verify_bundle(out)
    assert read_manifest(out)["asset"]["sha256"] == sha256_file(asset)
    m = read_manifest(out)
    s = m["strands"]
    assert (s["strand_count"], s["texels_per_strand"]) == (200, 4)
    assert (m["atlas"]["width"], m["atlas"]["height"]) == (s["width"], s["height"])
    assert s["width"] == 4 * s["strands_per_row"] and "clamp(a * texels_per_strand" in \
        s["sample"]
    cov = read_image(out / "coverage.exr")[:, :, 0]
    assert cov.shape == (s["height"], s["width"]) and int(cov.sum()) == 800
    hair = read_hair(out / "asset.hair")  # the hair as baked: the spec's colour
    np.testing.assert_allclose(hair.color, np.tile([0.8, 0.6, 0.4], (hair.point_count, 1)),
                               rtol=1e-6)
    assert m["spec"]["measurement_points"]["placement"] == "hull"
    # held-out error within 1.25× of the projection bound (the verdict's gate)
    assert m["verdict"]["status"] == "pass" and m["verdict"]["ratio"] <= 1.25
    # the diffuse fibre's strand texels are denoised by default (hair.denoise_neighbours)
    report = json.loads((out / "report.json").read_text())
    assert report["transport"]["denoise"]["neighbours"] == 64
    assert m["spec"]["hair"]["denoise_neighbours"] == 64
    # and their direct light is the facing estimator's, with its samples stated
    assert (m["spec"]["hair"]["direct"], m["spec"]["hair"]["direct_samples"]) == ("facing", 2)


@pytest.fixture
def light(tmp_path):
    """A point light beside the tangle, as a light file."""
    path = tmp_path / "light.json"
    path.write_text(json.dumps({"type": "point", "position": [0.06, 0.04, 0.02],
                                "intensity": 0.05, "color": [1, 1, 1]}))
    return path


def test_relight_writes_the_strand_texture(bundle, light, tmp_path):
    _, out = bundle
    exr = tmp_path / "relit.exr"
    assert cli_main(["relight", str(out), "--light", str(light), "--out", str(exr)]) == 0
    img = read_image(exr)
    m = read_manifest(out)
    assert img.shape[:2] == (m["atlas"]["height"], m["atlas"]["width"])
    covered = img[:, :, 3] > 0.5
    assert covered.sum() == 800 and img[covered, :3].mean() > 0
    assert load_runtime(out).coverage.sum() == 800


@pytest.mark.parametrize("key, value", [
    ("keyframes", {"animation": 0}), ("measurement_points", {"placement": "qdeim"})])
def test_hair_bake_refuses_what_it_cannot_do_by_key(tmp_path, key, value):
    asset = write_hair(tmp_path / "t.hair", tangle(20))
    with pytest.raises(SpecError, match=key):
        bake(asset, parse_spec({**SPEC, key: value}), tmp_path / "out", quiet=True)


def test_render_draws_the_strands(bundle, light, tmp_path):
    _, out = bundle
    images = render_passes(out, light, {"position": [0, 0.02, 0.12], "target": [0, 0, 0],
                                        "fov_y_deg": 40, "width": 48, "height": 48},
                           tmp_path)
    seen = images["full"][:, :, 3] > 0.5
    assert 0.05 < seen.mean() < 0.9  # fibres of the ball, not the whole frame
    assert images["indirect"][seen, :3].mean() > 0 and images["direct"][seen, :3].mean() > 0
    np.testing.assert_allclose(images["full"][:, :, :3],
                               images["direct"][:, :, :3] + images["indirect"][:, :, :3],
                               rtol=1e-5, atol=1e-7)
    # --cpu: the fibre tubes ray traced on the CPU, the same fibres seen
    exr = tmp_path / "cpu.exr"
    assert cli_main(["render", str(out), "--light", str(light), "--camera",
                     str(tmp_path / "camera.json"), "--out", str(exr), "--cpu"]) == 0
    assert ((read_image(exr)[:, :, 3] > 0.5) != seen).mean() < 0.02


@pytest.fixture(scope="module")
def strand_frames(bundle):
    """The test bundle drawn by the GL renderer (prtcore/runtime/strands_gl.py) and by the
    CPU (prtcore/runtime/strands.py), 64×64, one point light, each mode."""
    from prtcore.core.scene import Light
    from prtcore.reference.camera import camera_from_dict
    from prtcore.runtime.strands import render_strands
    from prtcore.runtime.strands_gl import StrandRenderer

    _, out = bundle
    lights = [Light(type="point", color=np.ones(3), intensity=0.05,
                    position=np.array([0.06, 0.04, 0.02]))]
    cam = camera_from_dict({"position": [0, 0.02, 0.12], "target": [0, 0, 0],
                            "fov_y_deg": 40, "width": 64, "height": 64})
    with StrandRenderer(out) as r:
        gl = {m: r.render(lights, cam, mode=m).image for m in ("full", "direct", "indirect")}
    cpu = {m: render_strands(out, lights, cam, mode=m) for m in ("indirect", "direct")}
    return gl, cpu


def test_gl_hair_render_is_the_cpu_drawing(strand_frames):
    """The GL drawing covers the pixels the CPU's ray-traced tubes cover; its indirect term
    is the CPU's sample of the relit strand texture (the same sampling rule: 0.1 %, the
    GPU's bilinear weights); its direct term differs per pixel by the shadow maps (a
    shadow texel is wider than a fibre) but not on average (measured 22 % per pixel,
    −0.1 % in the mean; the bound here is 3 %); full = direct + indirect."""
    gl, cpu = strand_frames
    seen_gl, seen_cpu = gl["full"][:, :, 3] > 0.5, cpu["direct"][:, :, 3] > 0.5
    assert 0.05 < seen_cpu.mean() < 0.9
    assert (seen_gl != seen_cpu).mean() < 0.01
    both = seen_gl & seen_cpu
    g, c = gl["indirect"][both, :3], cpu["indirect"][both, :3]
    assert c.mean() > 0 and np.abs(g - c).mean() < 0.005 * c.mean()
    g, c = gl["direct"][both, :3], cpu["direct"][both, :3]
    assert c.mean() > 0 and abs(g.mean() / c.mean() - 1) < 0.03
    np.testing.assert_allclose(gl["full"][:, :, :3],
                               gl["direct"][:, :, :3] + gl["indirect"][:, :, :3],
                               rtol=1e-5, atol=1e-6)


def test_golden_hair_full(strand_frames):
    """The GL drawing of the test bundle against tests/goldens/hair_full.png (the golden
    tolerance of tests/golden_images.py; a failing comparison writes output, golden and
    difference under tests/_failures/)."""
    from golden_images import check_golden

    from prtcore.runtime.gl import tone_map

    check_golden("hair_full", tone_map(strand_frames[0]["full"], exposure=4.0))


def test_report_validates_a_hair_bundle_against_the_fibre_path_tracer(bundle):
    _, out = bundle
    v = validate_bundle(out, spp=16, count=1)
    assert v["reference"] == "path tracer, 16 spp" and v["lights"] == 1
    row = next(r for r in v["rows"] if r["n"] == 8)
    assert 0 < row["rmse_mean"] < 1 and row["rmse_noise_corrected_mean"] <= row["rmse_mean"]


def test_a_hair_bake_validates_itself_against_the_fibre_path_tracer(tmp_path):
    """validate.reference_spp > 0: the bake path-traces its held-out lights through the
    fibres and judges the verdict on that, noise removed, against the basis's projection
    bound on the same references (report.json "validation", the verdict's "against")."""
    asset = write_hair(tmp_path / "t.hair", tangle(200))
    spec = {**SPEC, "validate": {"reference_spp": 32, "reference_lights": 2}}
    out = bake(asset, parse_spec(spec), tmp_path / "out", quiet=True)
    report = json.loads((out / "report.json").read_text())
    v = report["validation"]
    assert v["spp"] == 32 and v["lights"] == 2
    row = next(r for r in v["rows"] if r["n"] == report["verdict"]["n"])
    assert 0 < row["projection_bound_noise_corrected_mean"] <= \
        row["rmse_noise_corrected_mean"] * 1.05
    assert "noise removed" in report["verdict"]["against"]
    assert report["verdict"]["error"] == pytest.approx(row["rmse_noise_corrected_mean"])
    assert "validate" in report["stage_seconds"]


def test_all_bounce_harmonics_bake_and_agree_with_the_first_bounce_variant(tmp_path):
    """hair.harmonics = all_bounces: the (3T, 3T) harmonic operator is solved and its mean
    block is the indirect light; it differs from the first-bounce variant by the
    radially-constant error of the later bounces (a few per cent), not more."""
    s = build_strand_space(tangle(300), 4)
    tracer, _ = hair_tracer(s)
    points = place_measurement_points(hair_scene(s.hair), parse_spec(
        {"measurement_points": {"count": 8, "placement": "hull"}}).measurement_points)
    spec = parse_spec({"transport": {"gather_rays": 32}}).transport
    first = bake_hair_dataset(s, points, tracer, tangle_lights(), spec=spec)
    every = bake_hair_dataset(s, points, tracer, tangle_lights(), spec=spec,
                              harmonics="all_bounces")
    assert every.stats["harmonics"] == "all_bounces" and every.indirect.shape == \
        first.indirect.shape
    ratio = every.indirect.sum() / first.indirect.sum()
    assert 0.85 < ratio < 1.15 and ratio != 1.0
    assert np.isfinite(every.indirect).all() and (every.indirect >= 0).all()
    # clamping is for the odd noisy texel, not a regime (measured 1.0 % of the values with
    # the mitred tubes, whose interior is darker, at this test's M = 32)
    assert every.stats["solve"]["negative_clamped"] < 0.02 * every.indirect.size


@pytest.mark.slow
@pytest.mark.parametrize("case", ["hair", "hair+mesh", "hair+mesh chiang"])
def test_hair_memory_estimate_is_an_upper_bound_of_the_measured_peak(tmp_path, case):
    """check_hair_memory against the peak RSS of a whole hair bake in a fresh process (the
    hairball at 4000 strands, K = 64 + 16: several light blocks of the first bounce; or
    4000 curly strands on the test head, baked together: mesh_bounces' stacked state; or
    the same with the Chiang fibre and linear exitance, its own transport).
    Measured: hair 739–774 MiB, estimate 882 MiB (1.2×); hair + mesh 2.27 GiB, estimate
    3.70 GiB (1.63×: mesh_bounces' stacked terms are counted on both phases; at 10k
    strands 1.61–1.74×, docs/hair.md), so its looseness is held to 1.8×. With the Chiang
    fibre the estimate is the bake's, after its density probe (hair_density: the shares
    of rays that hit and of texels with near-field rows): 1910–1926 MiB, estimate 2635 MiB
    (1.37×), held to 1.6× (2.16 GiB against 3.56 GiB until its product was assembled in
    place, 2026-12-06). Before the probe it counted an entry for every gather ray
    (on this convex head half the atlas's rays escape) and near-field rows for every
    strand texel: 4.97 GiB, 2.3× the peak once the atlas texels stopped carrying F
    coefficients (2.72 → 2.16 GiB). Until 2026-12-06 the Chiang fibre's estimate was
    the diffuse fibre's terms with its own added: 6.90 GiB here against 3.25 GiB."""
    with_mesh = case != "hair"
    import subprocess
    import sys

    from prtcore.core.limits import IntakeLimits
    from prtcore.core.progress import StageTimer
    from prtcore.hairbake import check_hair_memory, hair_spec, run_hair_intake
    from prtcore.pipeline import run_intake
    from prtcore.scenes.hair import hairball, head_hair, write_head

    if with_mesh:
        asset = write_hair(tmp_path / "hair.hair", head_hair(4000, "curly", seed=0))
        mesh = write_head(tmp_path / "head.glb")
    else:
        asset, mesh = write_hair(tmp_path / "ball.hair", hairball(4000)), None
    spec = {"lights": {"count": 64, "holdout": 16, "seed": 2}}
    if case.endswith("chiang"):
        spec["hair"] = {"fibre": "chiang", "chiang": {"exitance": "linear"}}
    # the child's own peak is VmHWM, not getrusage's ru_maxrss: Linux carries ru_maxrss
    # over execve, so a child started from this (large) pytest process would report the
    # parent's size (2.4 GiB in a full suite run against 0.8 GiB of its own)
    code = (f"import pathlib, re\n"
            f"from prtcore.core.spec import parse_spec\n"
            f"from prtcore.pipeline import bake\n"
            f"bake(pathlib.Path({str(asset)!r}), parse_spec({spec!r}), "
            f"pathlib.Path({str(tmp_path / 'b')!r}), quiet=True, "
            f"mesh={str(mesh) if mesh else None!r})\n"
            f"hwm = re.search(r'VmHWM:\\s+(\\d+) kB', open('/proc/self/status').read())\n"
            f"print(int(hwm.group(1)) * 1024)\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    peak = int(res.stdout.strip().splitlines()[-1])
    s = hair_spec(parse_spec(spec), with_mesh=with_mesh)
    intake = run_hair_intake(asset, s, StageTimer(quiet=True), IntakeLimits(), mesh,
                             run_intake)
    density = None
    if case.endswith("chiang"):  # as the bake estimates it once the probe is traced
        from prtcore.transport.fibre import hair_density, hair_tracer
        tracer, _ = hair_tracer(intake.strands, intake.scene)
        density = hair_density(intake.strands, tracer, intake.scene.triangle_count,
                               s.transport.gather_rays, s.transport.seed,
                               atlas=intake.texels.mesh, near_field=s.transport.near_field)
    est = check_hair_memory(asset, intake.strands, s, 1 << 62,
                            mesh_texels=intake.texels.mesh.count if with_mesh else 0,
                            density=density)
    print(f"peak {peak / 2**20:.0f} MiB, estimate {est / 2**20:.0f} MiB, {density}")
    loose = 1.8 if with_mesh and not case.endswith("chiang") else 1.6
    assert peak <= est <= loose * peak, (peak, est)


def test_the_140k_hairball_fits_the_default_memory_limit_and_k_scales_the_estimate():
    """The issue's 140k-strand hairball at K = 128 + 16 is baked with the default limits
    (its peak RSS measured 13.25 GiB, in the fibre gather; docs/hair.md): its estimate
    (14.8 GiB) fits the default ``max_bake_bytes``, and a bake with more lights, which
    does not fit, is refused by a one-line error naming the file and the limit. The
    phases are not summed: the gather's triples are gone before the solve's arrays exist
    (summed, the estimate was 17.1 GiB)."""
    from prtcore.core.limits import IntakeLimits
    from prtcore.hairbake import check_hair_memory, hair_spec
    from prtcore.scenes.hair import hairball

    space = build_strand_space(hairball(140000), 10)
    limit = IntakeLimits().max_bake_bytes
    spec = hair_spec(parse_spec({"lights": {"count": 128, "holdout": 16}}))
    est = check_hair_memory("ball.hair", space, spec, limit)
    assert 12 * 2**30 < est < limit
    more = hair_spec(parse_spec({"lights": {"count": 256, "holdout": 16}}))
    with pytest.raises(LimitExceeded, match=r"ball.hair: .*1400000 strand texels and 272 "
                       r"lights needs about .* GiB.*max_bake_bytes="):
        check_hair_memory("ball.hair", space, more, limit)


def test_the_10k_head_with_the_chiang_fibre_takes_the_second_order_under_the_default_limit():
    """The 10k curly head on the head mesh's 139 089 atlas texels, Chiang fibre, the
    default 512 + 16 lights. Before its density is traced ``auto`` takes linear (its
    estimate lies between the 9.81 GiB peak measured before the atlas texels carried one
    coefficient, and the default limit; with the diffuse fibre's model it was 18.84 GiB
    and the bake took isotropic), and the second order is over the limit. Once traced,
    the hair is dense, so denoised, and the second order fits (docs/hair.md)."""
    from prtcore.core.limits import IntakeLimits
    from prtcore.hairbake import check_hair_memory, chiang_exitance, hair_spec
    from prtcore.scenes.hair import head_hair

    space = build_strand_space(head_hair(10_000, "curly", seed=0), 10)
    limit, atlas = IntakeLimits().max_bake_bytes, 139_089
    spec = hair_spec(parse_spec({"hair": {"fibre": "chiang"}}), with_mesh=True)
    got, why = chiang_exitance("head.hair", space, spec, limit, mesh_texels=atlas)
    assert got.hair.chiang.exitance == "linear" and why is None
    est = check_hair_memory("head.hair", space, got, limit, mesh_texels=atlas)
    assert 9.81 * 2**30 < est < limit
    second = hair_spec(parse_spec({"hair": {"fibre": "chiang", "chiang": {
        "exitance": "second_order"}}}), with_mesh=True)
    with pytest.raises(LimitExceeded, match=r"head.hair: .*139089 atlas texels"):
        check_hair_memory("head.hair", space, second, limit, mesh_texels=atlas)
    # once its density is traced (the shares measured on this head, hair_density) it is
    # dense, denoised, and the second order's estimate with 128 fibre rays and the near
    # fibres at 20 footprints (13.53 GiB; 13.32 GiB with them at 5 and the shaded hits at
    # 20, as in 5c24296; 13.3 GiB without either: entries,
    # near-field rows and near fibre hits at their shares, not every ray's and every
    # texel's; 15.7 GiB until the atlas rows' entries kept three weights and the first
    # bounce's corrections one array) fits the
    # default limit, above the 12.81 GiB peak RSS the default bake measured with the near
    # fibres at 20 (12.27 GiB at 5, with the atlas's entries made smaller; docs/hair.md)
    from prtcore.hairbake import DENSE_MESH_RAYS, dense_hair
    from prtcore.transport.fibre import HairDensity
    density = HairDensity(0.679, 0.093, 0.806, 0.786, 0.388, 0.388)
    dense, lines = dense_hair("head.hair", space, got, density, limit, atlas, True)
    assert lines[1].endswith("the strand texels are denoised")
    assert lines[2].startswith(f"hair.gather_rays auto → {DENSE_MESH_RAYS}: dense hair")
    assert (dense.hair.chiang.exitance, dense.hair.denoise_neighbours,
            dense.hair.gather_rays, dense.transport.gather_rays) == ("second_order", 128,
                                                                      128, 64)
    est = check_hair_memory("head.hair", space, dense, limit, mesh_texels=atlas,
                            density=density)
    assert 12.81 * 2**30 < est < limit, est / 2**30
    # with less memory the fibre gather keeps the atlas's rays, and says why
    tight, lines = dense_hair("head.hair", space, got, density, int(est) - 1, atlas, True)
    assert (tight.hair.chiang.exitance, tight.hair.gather_rays) == ("second_order", 64)
    assert "with 128 rays" in lines[-1] and lines[-1].endswith("transport.gather_rays")


CHIANG = {**SPEC, "hair": {**SPEC["hair"], "fibre": "chiang"}}


def test_a_chiang_fibre_bake_states_its_fibre_and_validates_with_its_own_path_tracer(
        tmp_path):
    """hair.fibre = chiang: the bundle names the fibre and its parameters, its strand
    texels are denoised with the fibre's direction, the verdict passes on the default
    points (denoised, 32 points fail at 1.26×, 256 pass at 1.21×), and `report
    --reference-spp` traces the Chiang fibre (not the diffuse one: the two references
    differ by far more than this test's tolerance)."""
    asset = write_hair(tmp_path / "tangle.hair", tangle(200))
    spec = {**CHIANG, "measurement_points": {**SPEC["measurement_points"], "count": "auto"}}
    out = bake(asset, parse_spec(spec), tmp_path / "out", quiet=True)
    m = json.loads((out / "manifest.json").read_text())
    assert m["fibre"]["model"] == "chiang" and m["fibre"]["chiang"]["beta_m"] == 0.3
    assert "every direction" in m["units"]["radiance"]
    report = json.loads((out / "report.json").read_text())
    assert report["verdict"]["status"] == "pass"
    assert report["transport"]["denoise"]["direction"] == "t2"  # by default, hair alone
    assert m["spec"]["hair"]["denoise_neighbours"] == 64
    v = validate_bundle(out, spp=64, count=1)
    row = next(r for r in v["rows"] if r["n"] == 8)
    assert 0 < row["rmse_noise_corrected_mean"] < 0.6
    # hair alone, the diffuse fibre, with hair.gather_rays given: its one gather's rays
    diffuse = bake(asset, parse_spec({**SPEC, "hair": {**SPEC["hair"], "gather_rays": 24}}),
                   tmp_path / "diffuse", quiet=True)
    rays = json.loads((diffuse / "report.json").read_text())["transport"]["rays"]
    assert rays["fibre_gather"] == 200 * 4 * 24
    a = load_runtime(out)
    b = load_runtime(diffuse)
    cov = a.coverage
    # another fibre, other light: the mean planes differ
    assert not np.allclose(a.planes[cov][:, :3], b.planes[cov][:, :3], rtol=0.05)


def test_a_chiang_bake_takes_environment_lights_and_refuses_harmonics_by_key(tmp_path):
    asset = write_hair(tmp_path / "t.hair", tangle(60))
    sky = {**CHIANG, "lights": {"count": 16, "holdout": 4,
                                "families": [{"type": "environment"}]}}
    out = bake(asset, parse_spec(sky), tmp_path / "b", quiet=True)
    report = json.loads((out / "report.json").read_text())
    assert report["transport"]["model"] == "chiang"
    planes = load_runtime(out).planes
    assert np.isfinite(planes).all() and planes[load_runtime(out).coverage][:, :3].max() > 0
    with pytest.raises(SpecError, match=r"hair\.harmonics"):
        parse_spec({"hair": {"fibre": "chiang", "harmonics": "all_bounces"}})


def test_a_chiang_bake_carries_second_order_exitance_by_default_and_reports_what_it_clamped(
        tmp_path):
    """Hair alone is denoised by default, so the default exitance is the second order
    (docs/hair.md: the 10k hairball 6.8 % per texel against linear's 8.3 %, denoised),
    solved on a basis of the lights (transport/low_rank.py), from SECOND_ORDER_MIN_RAYS
    fibre rays (at 16 this tangle's second-order series diverges: it takes linear, and
    the second order asked for is refused by a one-line error naming the keys)."""
    from prtcore.core.errors import TransportDiverged
    from prtcore.hairbake import SECOND_ORDER_MIN_RAYS

    asset = write_hair(tmp_path / "tangle.hair", tangle(200))
    spec = {**CHIANG, "measurement_points": {**SPEC["measurement_points"], "count": "auto"},
            "hair": {**CHIANG["hair"], "gather_rays": SECOND_ORDER_MIN_RAYS}}
    out = bake(asset, parse_spec(spec), tmp_path / "out", quiet=True)
    report = json.loads((out / "report.json").read_text())
    assert report["transport"]["exitance"] == "second_order"
    solve = report["transport"]["solve"]
    assert solve["converged"] and solve["residual"] < 1e-3 and solve["bounces"] <= 64
    few = {**CHIANG, "measurement_points": {"count": 32},
           "hair": {**CHIANG["hair"], "gather_rays": 16}}
    few_out = bake(asset, parse_spec(few), tmp_path / "few", quiet=True)
    assert json.loads((few_out / "report.json").read_text())["transport"]["exitance"] \
        == "linear"
    asked = {**few, "hair": {**few["hair"], "chiang": {"exitance": "second_order"}}}
    with pytest.raises(TransportDiverged, match=r"hair\.gather_rays"):
        bake(asset, parse_spec(asked), tmp_path / "asked", quiet=True)
    m = json.loads((out / "manifest.json").read_text())
    assert m["fibre"]["chiang"]["exitance"] == "second_order"
    solve = report["transport"]["solve"]
    assert solve["method"] == "low_rank" and solve["negative_clamped"] >= 0
    assert report["verdict"]["status"] == "pass"
    assert load_runtime(out).planes[load_runtime(out).coverage][:, :3].min() >= 0


def test_auto_exitance_is_linear_where_memory_allows_and_isotropic_where_not():
    """Undenoised (the Chiang fibre's default with a mesh) and with few gather rays,
    hair.chiang.exitance "auto" (the default) takes linear exitance when the bake's
    estimate with it fits max_bake_bytes, else isotropic with a line naming the limit; an
    explicit exitance, and the diffuse fibre, are kept as they are."""
    from prtcore.hairbake import AUTO_EXITANCE, check_hair_memory, chiang_exitance, hair_spec
    space = build_strand_space(tangle(300), 4)
    undenoised = {**CHIANG, "hair": {**CHIANG["hair"], "denoise_neighbours": 0}}
    spec = hair_spec(parse_spec(undenoised))
    assert spec.hair.chiang.exitance == "auto" and AUTO_EXITANCE == "linear"
    linear = check_hair_memory("t.hair", space, spec, 1 << 50)  # "auto" counts as linear
    iso_spec = hair_spec(parse_spec({**undenoised, "hair": {
        **undenoised["hair"], "chiang": {"exitance": "isotropic"}}}))
    iso = check_hair_memory("t.hair", space, iso_spec, 1 << 50)
    assert iso < linear
    got, why = chiang_exitance("t.hair", space, spec, 1 << 50)
    assert got.hair.chiang.exitance == "linear" and why is None
    got, why = chiang_exitance("t.hair", space, spec, (iso + linear) // 2)
    assert got.hair.chiang.exitance == "isotropic"
    assert "auto → isotropic" in why and f"max_bake_bytes={(iso + linear) // 2}" in why
    assert chiang_exitance("t.hair", space, iso_spec, 1)[0] is iso_spec
    diffuse = hair_spec(parse_spec(SPEC))
    assert chiang_exitance("t.hair", space, diffuse, 1)[0] is diffuse


def test_auto_exitance_takes_the_second_order_when_denoised_or_with_many_gather_rays():
    """With hair gather rays ≥ SECOND_ORDER_RAYS, or with the strand texels denoised
    (``hair.denoise_neighbours`` > 1), "auto" takes second-order exitance (its truncation
    is the smallest error once the noise is taken), linear with a line naming the limit
    where the second order's estimate does not fit, and isotropic where neither does."""
    from prtcore.hairbake import (
        SECOND_ORDER_RAYS,
        check_hair_memory,
        chiang_exitance,
        hair_spec,
        strand_spec,
    )
    from prtcore.transport.strand_denoise import DEFAULT_NEIGHBOURS
    space = build_strand_space(tangle(300), 4)
    many = {**CHIANG, "hair": {**CHIANG["hair"], "gather_rays": SECOND_ORDER_RAYS,
                               "denoise_neighbours": 0}}  # the rays decide
    spec = hair_spec(parse_spec(many))
    est = {e: check_hair_memory("t.hair", space, hair_spec(parse_spec(
        {**many, "hair": {**many["hair"], "chiang": {"exitance": e}}})), 1 << 50)
        for e in ("isotropic", "linear", "second_order")}
    assert est["isotropic"] < est["linear"] < est["second_order"]
    got, why = chiang_exitance("t.hair", space, spec, 1 << 50)
    assert got.hair.chiang.exitance == "second_order" and why is None
    limit = (est["linear"] + est["second_order"]) // 2
    got, why = chiang_exitance("t.hair", space, spec, limit)
    assert got.hair.chiang.exitance == "linear"
    assert "auto → linear: with second_order exitance" in why
    assert f"max_bake_bytes={limit}" in why
    got, why = chiang_exitance("t.hair", space, spec, est["isotropic"])
    assert got.hair.chiang.exitance == "isotropic" and "with linear exitance" in why
    fewer = {**CHIANG, "hair": {**CHIANG["hair"], "gather_rays": SECOND_ORDER_RAYS - 1,
                                "denoise_neighbours": 0}}
    assert chiang_exitance("t.hair", space, hair_spec(parse_spec(fewer)), 1 << 50
                           )[0].hair.chiang.exitance == "linear"  # not denoised
    denoised = strand_spec(hair_spec(parse_spec({**fewer, "hair": {  # the default
        **fewer["hair"], "denoise_neighbours": "auto"}})), space, with_mesh=False)[0]
    assert denoised.hair.denoise_neighbours == DEFAULT_NEIGHBOURS
    assert chiang_exitance("t.hair", space, denoised, 1 << 50
                           )[0].hair.chiang.exitance == "second_order"


def test_small_chiang_hair_spends_the_hairballs_rays_and_denoises_less_with_many():
    """Chiang-fibre hair alone, "auto": hair.gather_rays is transport.gather_rays × s and
    hair.direct_samples the fibre's 4 × s, s the power of two (at most 8) that spends the
    10k hairball's budget (100 000 texels' worth); from 512 fibre rays the strand texels
    are denoised with 16 neighbours, not 64 (docs/hair.md, "Small hair spends the
    hairball's rays"). The hairball keeps the rays it was measured with; given values,
    the diffuse fibre and hair with a mesh are kept."""
    from prtcore.hairbake import (
        MANY_RAYS_NEIGHBOURS,
        RAY_BUDGET_TEXELS,
        hair_spec,
        small_hair,
        strand_spec,
    )
    from prtcore.transport.strand_denoise import DEFAULT_NEIGHBOURS

    class Texels:  # the count is all small_hair reads
        def __init__(self, count):
            self.count = count

    auto = hair_spec(parse_spec({"hair": {"fibre": "chiang"}}))
    got = {}
    for t in (1000 * 10, RAY_BUDGET_TEXELS, 3 * RAY_BUDGET_TEXELS, 30_000, 200 * 4):
        spec, lines = small_hair(auto, Texels(t))
        got[t] = (spec.hair.gather_rays, spec.hair.direct_samples,
                  spec.hair.denoise_neighbours)
        assert len(lines) == 3 and lines[0].startswith(
            f"hair.gather_rays auto → {spec.hair.gather_rays}: {t} strand texels")
    assert got == {10_000: (512, 32, MANY_RAYS_NEIGHBOURS),  # the tangle: 8×, capped
                   RAY_BUDGET_TEXELS: (64, 4, DEFAULT_NEIGHBOURS),  # the hairball as was
                   3 * RAY_BUDGET_TEXELS: (64, 4, DEFAULT_NEIGHBOURS),  # never fewer
                   30_000: (128, 8, DEFAULT_NEIGHBOURS),  # 3.3 → 2
                   800: (512, 32, MANY_RAYS_NEIGHBOURS)}
    assert MANY_RAYS_NEIGHBOURS == 16 < DEFAULT_NEIGHBOURS
    given = hair_spec(parse_spec({"hair": {"fibre": "chiang", "gather_rays": 600,
                                           "direct_samples": 5, "denoise_neighbours": 32}}))
    spec, lines = small_hair(given, Texels(800))
    assert (spec.hair.gather_rays, spec.hair.direct_samples,
            spec.hair.denoise_neighbours, lines) == (600, 5, 32, [])
    rays_only = hair_spec(parse_spec({"hair": {"fibre": "chiang", "gather_rays": 100}}))
    assert small_hair(rays_only, Texels(800))[0].hair.denoise_neighbours == 64  # < 512
    diffuse = hair_spec(parse_spec({}))
    assert small_hair(diffuse, Texels(800)) == (diffuse, [])
    mesh = hair_spec(parse_spec({"hair": {"fibre": "chiang"}}), with_mesh=True)
    space = build_strand_space(tangle(20), 4)
    assert strand_spec(mesh, space, with_mesh=True)[0].hair.gather_rays == "auto"
    assert mesh.hair.direct_samples == 4  # with a mesh: the fibre's default


def test_a_small_chiang_bake_reports_the_rays_it_spent(tmp_path, capsys):
    """A bake of a small tangle with the Chiang fibre spends the budget's rays and samples
    and says so in its stage lines; the manifest's spec carries what was resolved, and
    baking that spec again gives the same bundle."""
    asset = write_hair(tmp_path / "tangle.hair", tangle(60))
    spec = {**CHIANG, "lights": {**SPEC["lights"], "count": 16},
            "transport": {"gather_rays": 4, "direct_samples": 1}}  # 240 texels: 8×
    out = bake(asset, parse_spec(spec), tmp_path / "out")
    err = capsys.readouterr().err
    assert "hair.gather_rays auto → 32: 240 strand texels, 8× transport.gather_rays" in err
    assert "hair.direct_samples auto → 32: 240 strand texels, 8× the fibre's 4" in err
    m = read_manifest(out)
    assert (m["spec"]["hair"]["gather_rays"], m["spec"]["hair"]["direct_samples"],
            m["spec"]["hair"]["denoise_neighbours"]) == (32, 32, 64)
    report = json.loads((out / "report.json").read_text())
    assert report["transport"]["rays"]["fibre_gather"] == 60 * 4 * 32
    again = bake(asset, parse_spec(m["spec"]), tmp_path / "again", quiet=True)
    assert (load_runtime(again).planes == load_runtime(out).planes).all()


def test_a_chiang_bake_trains_on_more_lights_by_default():
    """The Chiang fibre's smoother indirect light needs more training lights for the
    verdict to pass (docs/hair.md: the 10k hairball fails at 1.52× with 128, passes at
    1.21× with 512); an explicit count is kept."""
    from prtcore.hairbake import CHIANG_FIXED_LIGHTS, hair_spec
    assert hair_spec(parse_spec({"hair": {"fibre": "chiang"}})).lights.count == \
        CHIANG_FIXED_LIGHTS == 512
    assert hair_spec(parse_spec({})).lights.count == 128
    assert hair_spec(parse_spec({"hair": {"fibre": "chiang"},
                                 "lights": {"count": 40}})).lights.count == 40


def _failing_fits(monkeypatch, fails):
    """Every fit of the data-driven method whose (lights, points) ``fails(K, P)`` says so
    reports a verdict failed at 9.9× the projection bound (as if the transfer were far
    from it); returns the (K, P) of every fit and the number of transports."""
    import dataclasses

    from prtcore import hairbake
    from prtcore.methods.data_driven import DataDriven

    fits, transports = [], []
    fit, transport = DataDriven.fit, hairbake._transport_and_fit

    def failing_fit(self, inputs, timer):
        result = fit(self, inputs, timer)
        k, p = len(inputs.train), inputs.intake.points.count
        fits.append((k, p))
        if fails(k, p):
            result = dataclasses.replace(result, verdict={**result.verdict,
                                                          "status": "fail", "ratio": 9.9})
        return result

    def counted(spec, *args):
        transports.append(spec.lights.count)
        return transport(spec, *args)

    monkeypatch.setattr(DataDriven, "fit", failing_fit)
    monkeypatch.setattr(hairbake, "_transport_and_fit", counted)
    return fits, transports


@pytest.mark.parametrize("with_mesh", [False, True])
def test_a_failed_verdict_is_fitted_again_on_more_points(tmp_path, monkeypatch, with_mesh):
    """``measurement_points.count: "auto"``: a fit whose verdict fails on the transfer's
    ratio is fitted again on twice the points, then four times, until it passes, with no
    second transport (the texels' light does not depend on the points). The bundle is the
    one a spec asking for those points gives, bit for bit; the report lists each fit. With
    a mesh the points' direct light is shadowed by the mesh as in the transport."""
    from prtcore import hairbake
    from prtcore.intake.plan import FIXED_POINTS
    from prtcore.scenes.hair import head_hair, write_head

    base = SPEC
    if with_mesh:
        asset = write_hair(tmp_path / "hair.hair", head_hair(60, "curly", seed=1))
        mesh = write_head(tmp_path / "head.glb")
        base = {**SPEC, "atlas": {"resolution": 32}}
    else:
        asset, mesh = write_hair(tmp_path / "tangle.hair", tangle(200)), None
    fits, transports = _failing_fits(monkeypatch, lambda k, p: p < 4 * FIXED_POINTS)
    spec = {**base, "measurement_points": {**SPEC["measurement_points"], "count": "auto"}}
    out = bake(asset, parse_spec(spec), tmp_path / "out", quiet=True, mesh=mesh)
    assert transports == [64]  # one transport, three fits
    assert fits == [(64, FIXED_POINTS), (64, 2 * FIXED_POINTS), (64, 4 * FIXED_POINTS)]
    assert 4 * FIXED_POINTS == hairbake.MAX_AUTO_POINTS
    report = json.loads((out / "report.json").read_text())
    tried = report["transport"]["points_tried"]
    assert [(t["points"], t["status"]) for t in tried] == [
        (FIXED_POINTS, "fail"), (2 * FIXED_POINTS, "fail"),
        (4 * FIXED_POINTS, report["verdict"]["status"])]
    assert report["verdict"]["ratio"] != 9.9 and "lights_tried" not in report["transport"]
    line = (out / "report.txt").read_text().splitlines()[0]
    assert line.startswith(f"fitted on: {FIXED_POINTS} points × 64 lights fail 9.90× → "
                           f"{2 * FIXED_POINTS} × 64 fail 9.90× → {4 * FIXED_POINTS} × 64 "
                           f"{report['verdict']['status']}"), line
    manifest = read_manifest(out)
    assert manifest["spec"]["measurement_points"]["count"] == 4 * FIXED_POINTS
    assert manifest["points"]["count"] == 4 * FIXED_POINTS
    asked = bake(asset, parse_spec({**base, "measurement_points": {
        **SPEC["measurement_points"], "count": 4 * FIXED_POINTS}}), tmp_path / "asked",
        quiet=True, mesh=mesh)
    for name in ("transfer.bin", "basis_00.exr", "points.bin",
                 *(("strand_basis_00.exr",) if with_mesh else ())):
        assert sha256_file(out / name) == sha256_file(asked / name)


def test_the_points_that_fit_best_ship_when_none_passes(tmp_path, monkeypatch):
    """When no point count passes, the fit with the lowest ratio ships (here the first:
    every fit reports 9.9×, and a tie keeps the fewer points)."""
    from prtcore.intake.plan import FIXED_POINTS

    asset = write_hair(tmp_path / "tangle.hair", tangle(200))
    fits, _ = _failing_fits(monkeypatch, lambda k, p: True)
    spec = {**SPEC, "measurement_points": {**SPEC["measurement_points"], "count": "auto"}}
    out = bake(asset, parse_spec(spec), tmp_path / "out", quiet=True)
    assert [p for _, p in fits] == [FIXED_POINTS, 2 * FIXED_POINTS, 4 * FIXED_POINTS]
    assert read_manifest(out)["points"]["count"] == FIXED_POINTS
    assert json.loads((out / "report.json").read_text())["verdict"]["ratio"] == 9.9


@pytest.mark.parametrize("case", ["auto", "auto lights", "explicit", "no memory"])
def test_a_failed_verdict_bakes_once_more_with_twice_the_lights(tmp_path, monkeypatch, case):
    """``lights.count: "auto"``: a bake whose verdict still fails on the transfer's ratio
    (after more points, when their count is "auto" too) is baked once more with twice the
    lights on the same points, and ships the bundle a spec asking for those asks for; the
    report lists both passes. An explicit count is kept whatever the verdict, and so is K
    when the memory estimate at 2K is over the limit."""
    from prtcore import hairbake
    from prtcore.intake.plan import FIXED_POINTS

    asset = write_hair(tmp_path / "tangle.hair", tangle(200))
    fits, transports = _failing_fits(monkeypatch, lambda k, p: k == 128)
    if case == "no memory":
        estimate = hairbake.check_hair_memory

        def over_at_2k(asset, space, spec, limit, **kw):
            if spec.lights.count > 128:
                raise LimitExceeded(str(asset), "", "over the limit (the test's)")
            return estimate(asset, space, spec, limit, **kw)

        monkeypatch.setattr(hairbake, "check_hair_memory", over_at_2k)
    spec = {**SPEC, "lights": {**SPEC["lights"],
                               "count": 128 if case == "explicit" else "auto"}}
    p = 32
    if case == "auto":
        spec["measurement_points"] = {**SPEC["measurement_points"], "count": "auto"}
        p = FIXED_POINTS  # 2P and 4P fail too, and the first of the tie is kept
    out = bake(asset, parse_spec(spec), tmp_path / "out", quiet=True)
    report = json.loads((out / "report.json").read_text())
    if case in ("explicit", "no memory"):
        assert transports == [128] and "lights_tried" not in report["transport"]
        assert report["verdict"]["ratio"] == 9.9  # the failed verdict ships, and says so
        return
    assert transports == [128, 256]
    assert [k for k, _ in fits] == [128] * (3 if case == "auto" else 1) + [256]
    tried = report["transport"]["lights_tried"]
    assert [(t["lights"], t["points"], t["status"]) for t in tried] == [
        (128, p, "fail"), (256, p, report["verdict"]["status"])]
    if case == "auto":
        assert [t["points"] for t in report["transport"]["points_tried"]] == [
            FIXED_POINTS, 2 * FIXED_POINTS, 4 * FIXED_POINTS]
    line = (out / "report.txt").read_text().splitlines()[0]
    assert line.startswith(f"fitted on: {p} points × 128 lights fail 9.90× → ") and \
        line.count("→") == (3 if case == "auto" else 1) and f"{p} × 256 " in line, line
    manifest = read_manifest(out)
    assert manifest["spec"]["lights"]["count"] == 256
    assert manifest["spec"]["measurement_points"]["count"] == p
    assert manifest["points"]["count"] == p
    monkeypatch.undo()
    asked = bake(asset, parse_spec({**SPEC, "lights": {**SPEC["lights"], "count": 256},
                                    "measurement_points": {**SPEC["measurement_points"],
                                                           "count": p}}),
                 tmp_path / "asked", quiet=True)
    for name in ("transfer.bin", "basis_00.exr"):
        assert sha256_file(out / name) == sha256_file(asked / name)


def test_the_chiang_fibre_with_a_mesh_denoises_dense_hair_with_the_second_order():
    """hair.denoise_neighbours "auto" with the Chiang fibre and a mesh is decided by the
    share of the fibre gather's rays that meet another fibre, traced before the transport
    (dense_hair): dense hair (the 10k curly head's 0.68) is denoised with k = 128 and, its
    exitance "auto", asked again for the second order (docs/hair.md: 8.5 % per texel
    against linear's 11.7 %), which it takes where its memory fits and says why not where
    it does not, and hair.gather_rays "auto" is twice the atlas's rays; sparse hair is not
    denoised and keeps linear (the filter bent 2–4 points of bias in on 500 strands) and
    the atlas's rays; a given value is kept, and hair_spec leaves "auto"."""
    from prtcore.hairbake import DENSE_MESH_NEIGHBOURS, chiang_exitance, dense_hair, hair_spec
    from prtcore.scenes.hair import head_hair
    from prtcore.transport.fibre import HairDensity
    from prtcore.transport.strand_denoise import DEFAULT_NEIGHBOURS

    space = build_strand_space(head_hair(500, "curly", seed=0), 8)
    spec = hair_spec(parse_spec({"hair": {"fibre": "chiang"}}), with_mesh=True)
    assert spec.hair.denoise_neighbours == "auto"
    assert hair_spec(parse_spec({"hair": {"fibre": "chiang"}})).hair.denoise_neighbours \
        == "auto"  # hair alone: small_hair's, by its rays
    assert hair_spec(parse_spec({})).hair.denoise_neighbours == DEFAULT_NEIGHBOURS
    limit, atlas = 16 * 2**30, 1000
    spec, why = chiang_exitance("h.hair", space, spec, limit, mesh_texels=atlas)
    assert spec.hair.chiang.exitance == "linear" and why is None  # not denoised yet

    dense, lines = dense_hair("h.hair", space, spec, HairDensity(0.678, 1.0), limit, atlas, True)
    assert dense.hair.denoise_neighbours == DENSE_MESH_NEIGHBOURS
    assert dense.hair.chiang.exitance == "second_order"
    assert "68% of the fibre gather" in lines[0] and "second_order" in lines[1]
    sparse, lines = dense_hair("h.hair", space, spec, HairDensity(0.3, 1.0), limit, atlas, True)
    assert sparse.hair.denoise_neighbours == 0 and sparse.hair.chiang.exitance == "linear"
    assert len(lines) == 2 and "sparse" in lines[0]
    assert sparse.hair.gather_rays == 64 and lines[1].startswith(
        "hair.gather_rays auto → 64: sparse hair")
    assert dense.hair.gather_rays == 128  # dense: twice the atlas's, within the limit
    # a given exitance is kept; the second order over the limit falls back to linear
    kept, _ = dense_hair("h.hair", space, spec, HairDensity(0.678, 1.0), limit, atlas, False)
    assert kept.hair.chiang.exitance == "linear"
    from prtcore.hairbake import check_hair_memory
    linear = check_hair_memory("h.hair", space, spec, limit, mesh_texels=atlas)
    dense_share = HairDensity(0.678, 1.0)
    small, lines = dense_hair("h.hair", space, spec, dense_share, int(linear * 1.01), atlas,
                              True)
    assert small.hair.chiang.exitance == "linear" and small.hair.denoise_neighbours == 128
    assert "with second_order exitance" in lines[1]
    given = hair_spec(parse_spec({"hair": {"fibre": "chiang", "denoise_neighbours": 8,
                                           "gather_rays": 96}}), with_mesh=True)
    assert dense_hair("h.hair", space, given, dense_share, limit, atlas, True) == (given, [])
    # each key alone: the given one kept, the other resolved
    rays = hair_spec(parse_spec({"hair": {"fibre": "chiang", "gather_rays": 96}}),
                     with_mesh=True)
    got, lines = dense_hair("h.hair", space, rays, dense_share, limit, atlas, False)
    assert (got.hair.gather_rays, got.hair.denoise_neighbours, len(lines)) == (96, 128, 1)
    k = hair_spec(parse_spec({"hair": {"fibre": "chiang", "denoise_neighbours": 8}}),
                  with_mesh=True)
    got, lines = dense_hair("h.hair", space, k, dense_share, limit, atlas, False)
    assert (got.hair.gather_rays, got.hair.denoise_neighbours, len(lines)) == (128, 8, 1)
    # hair.max_bounces: the Chiang fibre's solve runs to 64 (it converges slowly on light
    # hair, its late bounces cheap); the diffuse fibre's keeps transport's; a given value
    from prtcore.hairbake import CHIANG_MAX_BOUNCES
    assert spec.hair.max_bounces == CHIANG_MAX_BOUNCES == 64
    assert hair_spec(parse_spec({"transport": {"max_bounces": 9}})).hair.max_bounces == 9
    assert hair_spec(parse_spec({"hair": {"fibre": "chiang", "max_bounces": 12}}),
                     with_mesh=True).hair.max_bounces == 12
    # hair_spec resolves it for the diffuse fibre; the Chiang fibre alone waits for its
    # strands to be counted (small_hair)
    assert hair_spec(parse_spec({}), with_mesh=True).hair.gather_rays == 64
    assert hair_spec(parse_spec({"hair": {"fibre": "chiang"}, "transport": {
        "gather_rays": 32}})).hair.gather_rays == "auto"


