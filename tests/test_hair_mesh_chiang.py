"""The Chiang fibre with a mesh in one bake (prtcore/transport/hair_mesh_chiang.py): the
operator over atlas and strand texels, checked against the hair + mesh path tracer with
Chiang fibres (prtcore/reference/hair_mesh.py's chiang_hair_mesh_reference), and the bake
through the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from prtcore.cli import main as cli_main
from prtcore.core.progress import StageTimer
from prtcore.core.spec import ChiangSpec, TransportSpec, parse_spec
from prtcore.intake.hair import hair_scene
from prtcore.intake.points import place_measurement_points
from prtcore.io.bundle import load_runtime, read_manifest, verify_bundle
from prtcore.io.hair import write_hair
from prtcore.pipeline import bake, run_intake
from prtcore.receivers.strands import build_strand_space
from prtcore.reference.fibres import noise_corrected_error
from prtcore.reference.hair_mesh import chiang_hair_mesh_reference
from prtcore.scenes.hair import head_hair, head_lights, write_head
from prtcore.transport.dataset import add_first_bounce, first_bounce_rows
from prtcore.transport.direct import direct_radiance, near_field_correction, near_field_rows
from prtcore.transport.fibre import SHARE_MARGIN, hair_density, hair_tracer
from prtcore.transport.fibre_chiang import EXITANCE_TERMS, chiang_fibre, chiang_gather
from prtcore.transport.gather import HitMapper, NearField, gather_operator
from prtcore.transport.hair import bake_hair_dataset
from prtcore.transport.hair_mesh_chiang import (
    StrandRays,
    bake_chiang_hair_mesh_dataset,
    chiang_hair_near_field,
    chiang_mesh_product,
)

LIGHTS = head_lights()
LIGHT_HAIR = ChiangSpec()  # the file's colour read as the hair volume's
CLEAR_HAIR = ChiangSpec(eumelanin=0.0, pheomelanin=0.0)  # no absorption


@pytest.fixture(scope="module")
def scalp(tmp_path_factory):
    """The test head (10 cm icosphere, 32² atlas) with 500 curly strands, 8 texels each."""
    d = tmp_path_factory.mktemp("scalp")
    intake = run_intake(write_head(d / "head.glb"), parse_spec(
        {"atlas": {"resolution": 32}, "measurement_points": {"count": 16}}), quiet=True)
    space = build_strand_space(head_hair(500, "curly", seed=0), 8)
    tracer, fibres = hair_tracer(space, intake.scene)
    points = place_measurement_points(hair_scene(space.hair), parse_spec(
        {"measurement_points": {"count": 16, "placement": "hull"}}).measurement_points)
    return intake.scene, intake.texels, space, tracer, fibres, points


def _bake(scalp, chiang: ChiangSpec, bounces: int = 64, rays: int = 256):
    scene, texels, space, tracer, fibres, points = scalp
    fibre = chiang_fibre(chiang, space)
    data = bake_chiang_hair_mesh_dataset(
        scene, texels, space, fibres, points, tracer, LIGHTS, (),
        TransportSpec(gather_rays=rays, direct_samples=8, seed=0, max_bounces=bounces),
        StageTimer(quiet=True), fibre)
    return data, fibre


def _receivers(texels, space, seed: int) -> tuple[int, np.ndarray]:
    """Up to 200 random atlas texels, then 300 strand texels, in the combined numbering:
    (how many atlas texels, rows (n,) int64)."""
    t_m = texels.count
    rng = np.random.default_rng(seed)
    n_m = min(200, t_m)
    return n_m, np.concatenate([np.sort(rng.choice(t_m, n_m, replace=False)),
                                np.sort(t_m + rng.choice(space.count, 300, replace=False))])


@pytest.fixture(scope="module")
def gathers(scalp):
    """Both gathers on the scalp (64 rays, seed 1) with a clear fibre: (fibre, the
    surface gather's StrandRays, the surface gather, the fibre gather)."""
    scene, texels, space, tracer, fibres, _ = scalp
    f, t_m = scene.triangle_count, texels.count
    fibre = chiang_fibre(CLEAR_HAIR, space)
    strands = StrandRays(space, fibres, f, seed=1)
    g = gather_operator(scene, texels, tracer, 64, 1, foreign=strands)
    term = chiang_gather(space, tracer, fibres, f, 64, 1, fibre,
                         mesh_texels=HitMapper(scene, texels, tracer), mesh_columns=t_m)
    return fibre, strands, g, term


def test_the_operator_is_the_surface_gather_above_and_albedo_weighted_rays_below(scalp,
                                                                                gathers):
    _, texels, space, *_ = scalp
    t_m, t_h = texels.count, space.count
    fibre, strands, g, term = gathers
    assert term.mesh_hits.data.shape == (len(term.mesh_hits.row), 6)
    w = chiang_mesh_product(g.matrix, strands.rays(), g.valid_rays, term.rays,
                            term.mesh_hits, fibre, t_m, t_h, 64, 2)
    x = np.random.default_rng(0).random((t_m + t_h, 3)).astype(np.float32)
    y = w(x)
    np.testing.assert_allclose(y[:t_m], g.matrix @ x, rtol=1e-5, atol=1e-7)
    # a clear fibre scatters what it receives (Ā ≈ 1): with the solver's albedo 1/2 a
    # strand row is the fraction of its rays that hit something, never more than all
    rows = 0.5 * w(np.ones((t_m + t_h, 3), np.float32))[t_m:]
    assert rows.max() <= 1.03 and rows.mean() > 0.05
    # the hair sees the head: light on the mesh alone reaches strand rows
    on_mesh = np.zeros((t_m + t_h, 3), np.float32)
    on_mesh[:t_m] = 1
    assert (w(on_mesh)[t_m:] > 0).mean() > 0.05


def test_atlas_rays_can_read_a_fibre_between_its_texel_centres(scalp, gathers):
    """StrandRays.rays(root): each atlas ray to a fibre read between the two texel centres
    about the hit (arc_weights), as the diffuse fibre's mesh rows read. A profile linear
    along the strand (the exitance's average, texel j's centre holding j + 1/2) is read
    exactly at the hit's arc position, continued below the root's centre and held beyond
    the last; a constant reads as the texel mean does (the weights sum to 1); None reads
    the texel mean (weights 1)."""
    _, texels, space, *_ = scalp
    t_m, t_h = texels.count, space.count
    fibre, strands, g, term = gathers

    def product(root):
        return chiang_mesh_product(g.matrix, strands.rays(root), g.valid_rays, term.rays,
                                   term.mesh_hits, fibre, t_m, t_h, 64, 2, "linear")

    mean, arc = product(None), product("extrapolate")
    n = space.texels_per_strand
    x = np.zeros((mean.shape[0], 3), np.float32)  # one light's three channels
    x[t_m:t_m + t_h] = (np.arange(t_h) % n + 0.5)[:, None]  # coefficient 0: linear
    rows, _, _, w = strands.rays()
    assert np.array_equal(w, np.ones(len(rows)))
    frac = np.concatenate([strands._parts[k][3] for k in sorted(strands._parts)])
    want = np.zeros(t_m)
    np.add.at(want, rows, np.minimum(frac.astype(np.float64) * n, n - 0.5)
              / np.maximum(g.valid_rays[rows], 1))
    on_strands = x.copy()
    on_strands[:t_m] = 0
    for c in range(3):
        np.testing.assert_allclose(arc(on_strands)[:t_m, c], want, rtol=1e-5, atol=1e-7)
    assert np.abs(mean(on_strands)[:t_m, 0] - want).max() > 0.02  # the mean does not
    ones = on_strands.copy()
    ones[t_m:t_m + t_h] = 1
    np.testing.assert_allclose(arc(ones)[:t_m], mean(ones)[:t_m], rtol=1e-5, atol=1e-7)


def test_the_near_field_is_shaded_once_for_every_exitance_coefficient(scalp):
    """The fibre gather's near mesh hits with second-order exitance: one correction whose
    hits are shaded once and weighted F = 10 times equals the F corrections each
    coefficient's weights give alone, at the product's rows for that coefficient."""
    scene, texels, space, tracer, fibres, _ = scalp
    f, t_m, t_h = scene.triangle_count, texels.count, space.count
    fibre = chiang_fibre(LIGHT_HAIR, space)
    term = chiang_gather(space, tracer, fibres, f, 16, 1, fibre,
                         mesh_texels=HitMapper(scene, texels, tracer), mesh_columns=t_m)
    g = gather_operator(scene, texels, tracer, 16, 1)
    direct = direct_radiance(scene, tracer, LIGHTS, g.direct_position, texels.normal,
                             texels.albedo)
    nf = chiang_hair_near_field(term.mesh_hits, texels, fibre, t_m, t_h, 2.0, 16,
                                "second_order")
    n_f = EXITANCE_TERMS["second_order"]
    assert nf.count > 0 and nf.weight.shape == (nf.count, n_f, 3)
    rows, values = near_field_correction(scene, tracer, nf, LIGHTS, direct)
    assert len(rows) == n_f * len(np.unique(nf.row)) and (np.diff(rows) > 0).all()
    for a in range(n_f):
        alone = NearField(row=nf.row + nf.offsets[a], col=nf.col, triangle=nf.triangle,
                          barycentric=nf.barycentric,
                          weight=np.ascontiguousarray(nf.weight[:, a]))
        r, v = near_field_correction(scene, tracer, alone, LIGHTS, direct)
        at = np.searchsorted(rows, r)
        assert np.array_equal(rows[at], r) and np.array_equal(values[at], v)
    # coefficient a ≥ 1 of strand texel i is row T + (a − 1) T_h + i (the product's)
    assert rows.max() < t_m + t_h + (n_f - 1) * t_h and rows.min() >= t_m
    # corrections of other rows added into one array (the bake's, no union beside
    # them): each correction's rows read what it gives alone, bit for bit, and a third
    # whose rows are all its own is added in place (add_first_bounce)
    assert np.array_equal(near_field_rows(nf), rows)
    # an atlas near field (the convex head has none of its own): the same mesh points
    # received by random atlas texels, with coefficient 0's weights
    g_near = NearField(row=np.sort(np.random.default_rng(5).integers(0, t_m, nf.count)),
                       col=nf.col, triangle=nf.triangle, barycentric=nf.barycentric,
                       weight=np.ascontiguousarray(nf.weight[:, 0]))
    g_rows = near_field_rows(g_near)
    one = first_bounce_rows(g_rows, rows, configurations=len(LIGHTS))
    assert np.array_equal(one[0], np.union1d(g_rows, rows))
    for x in (g_near, nf):
        assert near_field_correction(scene, tracer, x, LIGHTS, direct, into=one) is one
    atlas = near_field_correction(scene, tracer, g_near, LIGHTS, direct)
    assert len(g_rows) and np.array_equal(one[1][np.searchsorted(one[0], g_rows)], atlas[1])
    assert np.array_equal(one[1][np.searchsorted(one[0], rows)], values)
    want = add_first_bounce(add_first_bounce(atlas, (rows, values)), atlas)
    assert add_first_bounce(one, atlas) is one and np.array_equal(one[1], want[1])
    with pytest.raises(ValueError, match="into's rows must hold every row"):
        near_field_correction(scene, tracer, nf, LIGHTS, direct,
                              into=first_bounce_rows(g_rows, configurations=len(LIGHTS)))


def test_how_dense_the_hair_is_is_known_before_the_gather(scalp):
    """hair_density, traced on 4096 texels before the transport (hairbake.dense_hair),
    reads the share of rays meeting a fibre that the fibre gather's stats give once it
    is traced, and bounds the share of strand texels with near-field rows (the memory
    estimate's) from above."""
    scene, texels, space, tracer, fibres, _ = scalp
    f, t_m, t_h = scene.triangle_count, texels.count, space.count
    fibre = chiang_fibre(LIGHT_HAIR, space)
    term = chiang_gather(space, tracer, fibres, f, 32, 1, fibre,
                         mesh_texels=HitMapper(scene, texels, tracer), mesh_columns=t_m)
    gathered = term.stats["fibre_hits"] / term.stats["rays"]
    nf = chiang_hair_near_field(term.mesh_hits, texels, fibre, t_m, t_h, 1.0, 32)
    near = len(np.unique(nf.row)) / t_h
    density = hair_density(space, tracer, f, 32, 0, atlas=texels, near_field=1.0)
    assert 0.05 < gathered < 0.6 and abs(density.fibre_share - gathered) < 0.02
    # entries: the fibre gather's rays that hit, and the atlas's (its CSR and its rays to
    # fibres), bounded by the shares of rays that hit
    hit = (term.stats["fibre_hits"] + term.stats["mesh_hits"]) / term.stats["rays"]
    assert hit <= density.hit_share <= hit + SHARE_MARGIN + 0.02
    g = gather_operator(scene, texels, tracer, 32, 1,
                        foreign=(strands := StrandRays(space, fibres, f, seed=1)))
    atlas_entries = g.matrix.tocsc()[:, :t_m].nnz + len(strands.rays()[0])
    assert atlas_entries <= density.atlas_hit_share * t_m * 32
    # above it by the margin and by the largest texel's reach standing for every texel's
    # (measured: 0.571 gathered, 0.618 + 0.05 traced before, on this 32² atlas)
    assert 0.05 < near and near <= density.near_share <= near + SHARE_MARGIN + 0.1
    assert hair_density(space, tracer, f, 32, 0, atlas=texels, near_field=1.0) == density
    assert hair_density(space, tracer, f, 32, 0).near_share == SHARE_MARGIN


def test_first_bounce_agrees_with_the_path_tracer_of_the_same_model(scalp):
    """One bounce against the reference that shades every fibre hit with the isotropic
    exitance, as the fast path does: what is left is the transport's own error. Measured:
    strand texels −0.9 ± 1.4 % (300 texels × 2048 paths; docs/hair.md)."""
    scene, texels, space, tracer, fibres, _ = scalp
    data, fibre = _bake(scalp, LIGHT_HAIR, bounces=1)
    n_m, rows = _receivers(texels, space, 11)
    a, b = chiang_hair_mesh_reference(scene, texels, space, tracer, fibres, LIGHTS, rows,
                                      2048, 101, fibre.params, fibre.sigma_points,
                                      max_depth=1, exitance="isotropic")
    fast = data.indirect[rows].astype(np.float64)
    mesh = noise_corrected_error(fast[:n_m], a[:n_m], b[:n_m])
    hair = noise_corrected_error(fast[n_m:], a[n_m:], b[n_m:])
    assert abs(hair["bias"]) < 0.02 + 3 * hair["bias_se"], hair
    assert hair["rrmse"] < 0.2, hair
    assert abs(mesh["bias"]) < 0.02 + 3 * mesh["bias_se"], mesh
    assert mesh["rrmse"] < 0.5, mesh  # the atlas texels' gather noise at M = 256


def test_the_scalp_reads_model_truncates_the_atlas_texels_own_reads_alone(scalp):
    """``where="scalp"`` projects only the fibre hits of an atlas texel's own rays: the
    strand texels' paths stay the exact reference's, draw for draw, while the atlas texels'
    first bounce is the isotropic model's (the fibres' average, not their light toward
    the scalp), which differs from the exact one there."""
    scene, texels, space, tracer, fibres, _ = scalp
    fibre = chiang_fibre(LIGHT_HAIR, space)
    n_m, rows = _receivers(texels, space, 13)
    args = (scene, texels, space, tracer, fibres, LIGHTS)
    hair = rows[n_m:]
    exact = chiang_hair_mesh_reference(*args, hair, 256, 5, fibre.params,
                                       fibre.sigma_points, max_depth=3)
    scalp_only = chiang_hair_mesh_reference(*args, hair, 256, 5, fibre.params,
                                            fibre.sigma_points, max_depth=3,
                                            exitance="isotropic", where="scalp")
    every = chiang_hair_mesh_reference(*args, hair, 256, 5, fibre.params,
                                       fibre.sigma_points, max_depth=3,
                                       exitance="isotropic")
    assert all(np.array_equal(x, y) for x, y in zip(exact, scalp_only, strict=True))
    assert not np.array_equal(exact[0], every[0])
    mesh = rows[:n_m]
    ref = chiang_hair_mesh_reference(*args, mesh, 2048, 6, fibre.params,
                                     fibre.sigma_points, max_depth=1)
    iso = chiang_hair_mesh_reference(*args, mesh, 2048, 7, fibre.params,
                                     fibre.sigma_points, max_depth=1,
                                     exitance="isotropic", where="scalp")
    e = noise_corrected_error(iso, *ref)
    assert e["rrmse"] > 0.15, e  # measured 0.48 (bias −12 %)


def _variant_pairs(scalp, rows_seed: int, paths: int, seed: int, depth: int, order: str,
                   key: str, values: tuple) -> list:
    """The light hair's reference on the scalp's receivers (``_receivers(rows_seed)``),
    one part then the other (``order`` "atlas first" or "strands first"), each with
    ``key`` = each of ``values``: four (a, b) pairs, the same seed throughout."""
    scene, texels, space, tracer, fibres, _ = scalp
    fibre = chiang_fibre(LIGHT_HAIR, space)
    n_m, rows = _receivers(texels, space, rows_seed)
    parts = (rows[:n_m], rows[n_m:])
    return [chiang_hair_mesh_reference(scene, texels, space, tracer, fibres, LIGHTS, part,
                                       paths, seed, fibre.params, fibre.sigma_points,
                                       max_depth=depth, **{key: value})
            for part in (parts if order == "atlas first" else parts[::-1])
            for value in values]


def test_the_scalp_arc_model_moves_only_the_atlas_texels_own_fibre_hits(scalp):
    """``where="scalp_arc"`` shades an atlas texel's own fibre hits at a point uniform over
    the hit texel's arc (the texel's mean, as the fast path reads it): the strand texels'
    paths stay the exact reference's draw for draw, the atlas texels' values move but
    keep their scale (measured on the 10k head: the point light's 12.8 % systematic,
    docs/hair.md)."""
    run = _variant_pairs(scalp, 15, 256, 9, 2, "strands first", "where",
                         ("every", "scalp_arc"))
    assert all(np.array_equal(x, y) for x, y in zip(run[0], run[1], strict=True))
    exact, moved = np.mean(run[2]), np.mean(run[3])
    assert not np.array_equal(run[2][0], run[3][0]) and 0.5 < moved / exact < 2, (
        moved, exact)
    # within ``scalp_reach`` the hits stay where they are: a reach beyond every hit is
    # the exact reference again, draw for draw
    scene, texels, space, tracer, fibres, _ = scalp
    fibre = chiang_fibre(LIGHT_HAIR, space)
    n_m, rows = _receivers(texels, space, 15)
    near = chiang_hair_mesh_reference(scene, texels, space, tracer, fibres, LIGHTS,
                                      rows[:n_m], 256, 9, fibre.params, fibre.sigma_points,
                                      max_depth=2, where="scalp_arc", scalp_reach=1e3)
    assert all(np.array_equal(x, y) for x, y in zip(run[2], near, strict=True))
    with pytest.raises(ValueError, match=r"where must be .* not 'scalp-arc'"):
        chiang_hair_mesh_reference(scene, texels, space, tracer, fibres, LIGHTS, rows[:n_m],
                                   256, 9, fibre.params, fibre.sigma_points,
                                   where="scalp-arc")


def test_the_reference_can_leave_out_the_light_the_hair_sends_to_the_head(scalp):
    """``fibre_to_mesh=False`` ends the paths that go from a fibre to the mesh: an atlas
    texel's first bounce (its rays' own hits) is the exact reference's draw for draw, and
    the strand texels lose the light of the scalp under them."""
    run = _variant_pairs(scalp, 14, 512, 8, 1, "atlas first", "fibre_to_mesh",
                         (True, False))
    assert all(np.array_equal(x, y) for x, y in zip(run[0], run[1], strict=True))
    whole, cut = np.mean(run[2]), np.mean(run[3])
    assert cut < 0.8 * whole, (cut, whole)  # measured 0.49 of it


def test_the_reference_tallies_its_paths_by_depth_and_vertex_kind(scalp):
    """``tally`` keeps the next-event estimates of the chosen (depth, kind) vertices and
    draws the same paths: the four parts of two bounces sum to the whole, draw for draw,
    an atlas texel's depth-2 mesh vertices (the scalp's light sent back to it through a
    fibre) carry light on the head, and its depth-1 mesh vertices none (the head is
    convex). An unknown kind is refused."""
    scene, texels, space, tracer, fibres, _ = scalp
    fibre = chiang_fibre(LIGHT_HAIR, space)
    n_m, rows = _receivers(texels, space, 16)

    def run(tally):
        return chiang_hair_mesh_reference(scene, texels, space, tracer, fibres, LIGHTS,
                                          rows, 256, 10, fibre.params, fibre.sigma_points,
                                          max_depth=2, tally=tally)
    whole = run(None)
    parts = {key: run(frozenset({key})) for key in
             ((1, "fibre"), (1, "mesh"), (2, "fibre"), (2, "mesh"))}
    for h in range(2):
        np.testing.assert_allclose(sum(p[h] for p in parts.values()), whole[h],
                                   rtol=1e-12, atol=1e-15)
    assert not np.any(parts[(1, "mesh")][0][:n_m])
    loop = np.mean(parts[(2, "mesh")][0][:n_m])
    assert 0 < loop < np.mean(whole[0][:n_m]), loop
    with pytest.raises(ValueError, match=r"tally's kinds must be 'fibre' or 'mesh'"):
        run(frozenset({(2, "scalp")}))


@pytest.mark.parametrize("exitance", ["linear", "quadratic"])
def test_projected_exitance_s_first_bounce_is_its_model_path_traced(scalp, exitance):
    """Linear and quadratic exitance with a mesh: the first bounce against the hair + mesh
    path tracer that projects every fibre hit's outgoing radiance the same way (a fresh
    view weighted by the projection's kernel): the atlas rows now read a fibre's exitance
    toward their rays, the strand rows weight their rays to the scalp by every
    coefficient's weight. Measured in docs/hair.md."""
    scene, texels, space, tracer, fibres, points = scalp
    fibre = chiang_fibre(LIGHT_HAIR, space)
    data = bake_chiang_hair_mesh_dataset(
        scene, texels, space, fibres, points, tracer, LIGHTS, (),
        TransportSpec(gather_rays=256, direct_samples=8, seed=0, max_bounces=1),
        StageTimer(quiet=True), fibre, exitance=exitance)
    n_m, rows = _receivers(texels, space, 12)
    a, b = chiang_hair_mesh_reference(scene, texels, space, tracer, fibres, LIGHTS, rows,
                                      4096, 102, fibre.params, fibre.sigma_points,
                                      max_depth=1, exitance=exitance)
    fast = data.indirect[rows].astype(np.float64)
    for part in (slice(0, n_m), slice(n_m, None)):
        e = noise_corrected_error(fast[part], a[part], b[part])
        assert abs(e["bias"]) < 0.03 + 3 * e["bias_se"], (exitance, part, e)


def test_each_receiver_gets_light_from_the_other(scalp):
    """A convex head alone has no indirect light: with Chiang hair all of it comes off the
    hair; the hair gets more with the head under it than alone."""
    _, texels, space, _, _, points = scalp
    both, fibre = _bake(scalp, LIGHT_HAIR, rays=64)
    alone = bake_hair_dataset(space, points, hair_tracer(space)[0], LIGHTS, (),
                              TransportSpec(gather_rays=64, direct_samples=8, seed=0),
                              fibre=fibre)
    t_m = texels.count
    assert both.indirect[:t_m].mean() > 0 and np.isfinite(both.indirect).all()
    assert both.indirect[t_m:].mean() > 1.2 * alone.indirect.mean()
    assert both.stats["model"] == "chiang" and both.stats["solve"]["converged"]


def test_a_chiang_bake_with_a_head_through_the_cli(tmp_path):
    hair = write_hair(tmp_path / "hair.hair", head_hair(200, "curly", seed=1))
    mesh = write_head(tmp_path / "head.glb")
    spec = {"atlas": {"resolution": 32}, "hair": {"texels_per_strand": 6,
                                                   "fibre": "chiang"},
            "lights": {"count": 24, "holdout": 6, "seed": 2},
            "measurement_points": {"count": 32}, "transport": {"gather_rays": 32},
            "fit": {"basis": 8}}
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    out = tmp_path / "out"
    assert cli_main(["bake", str(hair), "--mesh", str(mesh), "--spec",
                     str(tmp_path / "spec.json"), "--out", str(out), "-q",
                     "--allow-poor"]) == 0
    verify_bundle(out)
    m = read_manifest(out)
    assert m["fibre"]["model"] == "chiang" and "harmonics" not in m["fibre"]
    assert m["fibre"]["chiang"]["exitance"] == "linear"  # the default
    assert "every direction" in m["units"]["radiance"]
    report = json.loads((out / "report.json").read_text())
    assert report["transport"]["model"] == "chiang"
    from prtcore.validate import validate_bundle  # the Chiang hair + mesh path tracer
    row = next(r for r in validate_bundle(out, spp=16, count=1)["rows"] if r["n"] == 8)
    assert 0 < row["rmse_noise_corrected_mean"] <= row["rmse_mean"] < 1
    assert report["transport"]["exitance"] == "linear"
    assert report["transport"]["solve"]["negative_clamped"] >= 0
    # sparse hair: the fibre gather keeps the atlas's rays, and the manifest says so
    assert m["spec"]["hair"]["gather_rays"] == 32
    assert report["transport"]["rays"]["fibre_gather"] == 200 * 6 * 32
    # a given hair.gather_rays is the fibre gather's alone
    iso = {**spec, "hair": {**spec["hair"], "chiang": {"exitance": "isotropic"},
                            "gather_rays": 48}}
    out = bake(hair, parse_spec(iso), tmp_path / "isotropic", quiet=True, mesh=mesh)
    report = json.loads((out / "report.json").read_text())
    assert report["transport"]["rays"]["fibre_gather"] == 200 * 6 * 48
    assert report["transport"]["gather"]["gather_rays"] == 32
    assert report["transport"]["exitance"] == "isotropic"
    assert "negative_clamped" not in report["transport"]["solve"]  # nothing truncated
    planes = load_runtime(out).planes
    assert np.isfinite(planes).all()
