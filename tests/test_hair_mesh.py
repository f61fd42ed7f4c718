"""Hair and a glTF mesh in one bake (prtcore/transport/hair_mesh.py, prtcore/hairbake.py):
light going both ways between a head and its hair, checked against the hair + mesh path
tracer (prtcore/reference/hair_mesh.py), and the bundle with both textures."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from prtcore.cli import main as cli_main
from prtcore.core.errors import PrtError, SpecError
from prtcore.core.raytrace import RayTracer
from prtcore.core.spec import TransportSpec, parse_spec
from prtcore.hairbake import hair_spec
from prtcore.intake.hair import hair_scene
from prtcore.intake.points import place_measurement_points
from prtcore.io.bundle import is_hair_mesh, read_manifest, verify_bundle
from prtcore.io.hair import write_hair
from prtcore.io.imageio import read_image
from prtcore.pipeline import bake, run_intake
from prtcore.receivers.strands import build_strand_space, texel_turn
from prtcore.reference.fibres import noise_corrected_error
from prtcore.reference.hair_mesh import hair_mesh_reference
from prtcore.scenes.hair import head_hair, head_lights, write_head
from prtcore.transport.dataset import bake_dataset
from prtcore.transport.fibre import (
    SPARSE_FIBRE_SHARE,
    STRAIGHT_TURN_DEG,
    fibre_gather,
    hair_tracer,
    harmonic_blocks_bound,
    harmonic_receivers,
)
from prtcore.transport.gather import HitMapper, gather_operator
from prtcore.transport.hair import bake_hair_dataset
from prtcore.transport.hair_mesh import (
    StrandHits,
    bake_hair_mesh_dataset,
    combined_operator,
    harmonic_operator,
)

LIGHTS = head_lights()


@pytest.fixture(scope="module")
def head(tmp_path_factory):
    """The test head (10 cm icosphere, unwrapped, 32² atlas) with 500 curly strands."""
    d = tmp_path_factory.mktemp("head")
    intake = run_intake(write_head(d / "head.glb"), parse_spec(
        {"atlas": {"resolution": 32}, "measurement_points": {"count": 16}}), quiet=True)
    hair = head_hair(500, "curly", seed=0)
    space = build_strand_space(hair, 8)
    tracer, fibres = hair_tracer(space, intake.scene)
    points = place_measurement_points(hair_scene(hair), parse_spec(
        {"measurement_points": {"count": 16, "placement": "hull"}}).measurement_points)
    return intake.scene, intake.texels, space, tracer, fibres, points


def test_the_operator_carries_light_both_ways_and_creates_none(head):
    scene, texels, space, tracer, fibres, _ = head
    f, t_m, t_h = scene.triangle_count, texels.count, space.count
    strands = StrandHits(space, fibres, f, seed=1)
    g = gather_operator(scene, texels, tracer, 64, 1, foreign=strands)
    term = fibre_gather(space, tracer, fibres, f, 64, 1, all_bounces=True,
                        mesh_texels=HitMapper(scene, texels, tracer), mesh_columns=t_m)
    m = combined_operator(g.matrix, term)
    assert m.shape == (t_m + t_h,) * 2 and m.dtype == np.float32
    # every row is a fraction of its rays: no row brings in more light than it sees
    assert np.asarray(m.sum(axis=1)).max() <= 1 + 1e-5
    # the scalp sees the hair, the hair sees the scalp (a convex head never sees itself)
    assert m[:t_m, t_m:].nnz > 0 and m[t_m:, :t_m].nnz > 0 and m[:t_m, :t_m].nnz == 0
    # the strand rows' mesh block of all_bounces: its mean rows are the matrix's
    assert abs(term.mesh_block[:t_h] - term.mesh).max() < 1e-7
    h = harmonic_operator(g.matrix, strands.harmonics(g.valid_rays), term)
    assert h.shape == (t_m + 3 * t_h,) * 2
    np.testing.assert_allclose(h[:t_m, :t_m + t_h].toarray(), g.matrix.toarray(), atol=0)


def test_mesh_rows_read_a_fibre_between_its_texel_centres(head):
    """StrandHits.interpolated: each hit's 1/M (times its harmonic) is split between the
    two texel centres about it on its own strand, so every row keeps its sum and no
    column leaves the strand hit; it moves weight toward the root (the scalp's rays hit
    near it) and, unlike the texel mean, puts negative weight on the root's neighbour."""
    scene, texels, space, tracer, fibres, _ = head
    f, t_m = scene.triangle_count, texels.count
    strands = StrandHits(space, fibres, f, seed=1)
    g = gather_operator(scene, texels, tracer, 64, 1, foreign=strands)
    mean_block = g.matrix[:, t_m:].tocsr()
    plain = strands.harmonics(g.valid_rays)
    read = strands.interpolated(g.valid_rays, 1, "extrapolate")
    assert len(read) == 3 and all(b.shape == mean_block.shape for b in read)
    for before, after in zip((mean_block, *plain), read, strict=True):
        np.testing.assert_allclose(np.asarray(after.sum(axis=1)).ravel(),
                                   np.asarray(before.sum(axis=1)).ravel(), atol=1e-6)
    n = space.texels_per_strand
    rows, cols = mean_block.nonzero()
    strand_of = dict()  # each receiving row's strands before and after
    for r, c in zip(rows, cols, strict=True):
        strand_of.setdefault(r, set()).add(c // n)
    r2, c2 = read[0].nonzero()
    assert all(c // n in strand_of[r] for r, c in zip(r2, c2, strict=True))
    assert read[0].data.min() < 0 and mean_block.data.min() > 0
    assert abs(read[0] - mean_block).max() > 1e-3
    held = strands.interpolated(g.valid_rays, 1, "clamp")[0]
    assert held.data.min() >= 0


def test_white_head_under_white_hair_converges(head):
    """Albedo 1 everywhere (clamped to 0.99 for transport): the solve converges to a
    finite, non-negative solution; no energy is created."""
    scene, texels, space, tracer, fibres, points = head
    import dataclasses

    white_t = dataclasses.replace(texels, albedo=np.ones_like(texels.albedo))
    white_s = dataclasses.replace(space, albedo=np.ones_like(space.albedo))
    d = bake_hair_mesh_dataset(scene, white_t, white_s, fibres, points, tracer, LIGHTS,
                               spec=TransportSpec(gather_rays=32, max_bounces=200,
                                                  tolerance=1e-4),
                               harmonics="all_bounces")
    assert np.isfinite(d.indirect).all() and d.indirect.min() >= 0
    assert d.stats["solve"]["converged"] and d.residual < 1e-3


def test_fast_path_agrees_with_the_hair_mesh_path_tracer(head):
    """The hair + mesh transport against the path tracer through the same head and hair,
    its noise removed: 150 atlas and 150 strand texels × 1024 paths, for turn_bounces,
    mesh_bounces, all_bounces, and adaptive with every texel transported as two pieces
    (what the bake uses with a mesh: half the fibre gather's rays per piece, the pieces'
    light averaged back into the texel). Measured (this scene,
    2026-12-05, before the mesh rows read fibres between texel centres): mesh_bounces
    atlas −1.8 ± 2.8 %, strand texels −1.8 ± 1.6 %; all_bounces −0.7 ± 2.8 %,
    −1.5 ± 1.6 %. first_bounce, which loses the side of the fibre that faced the head,
    reads the atlas 12–13 % dark on sparse hair (docs/hair.md)."""
    scene, texels, space, tracer, fibres, points = head
    t_m = texels.count
    rng = np.random.default_rng(11)
    rows = np.concatenate([np.sort(rng.choice(t_m, 150, replace=False)),
                           np.sort(t_m + rng.choice(space.count, 150, replace=False))])
    a, b = hair_mesh_reference(scene, texels, space, tracer, fibres, LIGHTS, rows, 1024,
                               101)
    for harmonics, pieces in (("turn_bounces", 1), ("mesh_bounces", 1),
                              ("all_bounces", 1), ("adaptive", 2)):
        d = bake_hair_mesh_dataset(scene, texels, space, fibres, points, tracer, LIGHTS,
                                   spec=TransportSpec(gather_rays=256, direct_samples=8,
                                                      seed=0),
                                   harmonics=harmonics, arc_subdivision=pieces)
        assert d.stats["harmonics"] == harmonics
        assert d.indirect.shape[0] == t_m + space.count
        assert d.stats["arc_subdivision"] == {"pieces": pieces,
                                              "rays_per_piece": 256 // pieces,
                                              "direct_samples_per_piece": 2 // pieces}
        fast = d.indirect[rows].astype(np.float64)
        mesh = noise_corrected_error(fast[:150], a[:150], b[:150])
        hair = noise_corrected_error(fast[150:], a[150:], b[150:])
        assert abs(hair["bias"]) < 0.02 + 3 * hair["bias_se"], (harmonics, hair)
        assert hair["rrmse"] < 0.15, (harmonics, hair)
        assert abs(mesh["bias"]) < 0.02 + 3 * mesh["bias_se"], (harmonics, mesh)
        assert mesh["rrmse"] < 0.40, (harmonics, mesh)  # the atlas's gather noise, M = 256


def test_mesh_bounces_harmonics_take_the_mesh_s_light_not_the_fibres(head):
    """mesh_bounces: the strand texels' harmonic rows receive nothing from other fibres
    (their block rows are empty) and the mesh's light still; the mean rows are
    all_bounces' exactly."""
    scene, texels, space, tracer, fibres, _ = head
    f, t = scene.triangle_count, space.count
    terms = {rows: fibre_gather(space, tracer, fibres, f, 16, 3, all_bounces=True,
                                mesh_texels=HitMapper(scene, texels, tracer),
                                mesh_columns=texels.count, harmonic_rows=rows)
             for rows in (True, False)}
    every, mesh_only = terms[True], terms[False]
    assert every.block[t:].nnz > 0 and mesh_only.block[t:].nnz == 0
    assert (abs(every.block[:t] - mesh_only.block[:t]) > 0).nnz == 0
    assert mesh_only.mesh_block[t:].nnz > 0  # head → hair still has a side
    assert (abs(every.mesh_block - mesh_only.mesh_block) > 0).nnz == 0


def test_turn_bounces_harmonics_take_the_fibres_light_on_straight_texels_only(head):
    """turn_bounces: the harmonic rows of the texels whose fibre turns less than the
    threshold are all_bounces' exactly, the others' mesh_bounces' (no light from other
    fibres); the mean rows and the mesh block are the same in all three."""
    scene, texels, space, tracer, fibres, _ = head
    f, t = scene.triangle_count, space.count
    straight = texel_turn(space) < STRAIGHT_TURN_DEG
    assert 0 < straight.sum() < t  # the curly test hair has both
    terms = {name: fibre_gather(space, tracer, fibres, f, 16, 3, all_bounces=True,
                                mesh_texels=HitMapper(scene, texels, tracer),
                                mesh_columns=texels.count, harmonic_rows=rows)
             for name, rows in (("all", True), ("mesh", False), ("turn", straight))}
    rows = np.concatenate([np.arange(t), t + np.arange(t), 2 * t + np.arange(t)])
    for b in (1, 2):
        own = b * t + np.flatnonzero(straight)
        other = b * t + np.flatnonzero(~straight)
        assert terms["turn"].block[own].nnz > 0
        assert (abs(terms["turn"].block[own] - terms["all"].block[own]) > 0).nnz == 0
        assert terms["turn"].block[other].nnz == 0 == terms["mesh"].block[other].nnz
    assert (abs(terms["turn"].block[:t] - terms["all"].block[:t]) > 0).nnz == 0
    assert (abs(terms["turn"].mesh_block - terms["all"].mesh_block) > 0).nnz == 0
    assert len(rows) == 3 * t


def test_the_state_is_solved_in_an_order_that_keeps_its_blocks(head):
    """state_order: a permutation of the T_m + n·T_h state rows in which the atlas and
    the strands' first block mix (Morton order of their positions: head texels beside
    the hair above them) and each harmonic block is the strands' own Morton order."""
    from prtcore.transport.hair_mesh import state_order

    _, texels, space, *_ = head
    t_m, t_h = texels.count, space.count
    for n in (1, 3):
        order = state_order(texels, space, n)
        assert np.array_equal(np.sort(order), np.arange(t_m + n * t_h))
        head_block = order[:t_m + t_h]
        assert head_block.max() < t_m + t_h
        # atlas and strand rows interleave rather than follow each other
        atlas = np.flatnonzero(head_block < t_m)
        strands = np.flatnonzero(head_block >= t_m)
        assert strands[0] < atlas[-1] and atlas[0] < strands[-1]
        for b in range(1, n):
            block = order[t_m + b * t_h:t_m + (b + 1) * t_h]
            assert np.array_equal(block, t_m + b * t_h + space.morton)


def test_each_receiver_gets_light_from_the_other(head):
    """A convex head alone has no indirect light; with hair all of it comes off the hair.
    The hair gets more indirect light with the head under it than alone."""
    scene, texels, space, tracer, fibres, points = head
    spec = TransportSpec(gather_rays=64, seed=0)
    both = bake_hair_mesh_dataset(scene, texels, space, fibres, points, tracer, LIGHTS,
                                  spec=spec)
    head_alone = bake_dataset(scene, texels, points, LIGHTS, (), spec,
                              tracer=RayTracer(scene.positions, scene.faces, scene.radius),
                              operators=("surface",))
    hair_alone = bake_hair_dataset(space, points, hair_tracer(space)[0], LIGHTS, (), spec)
    t_m = texels.count
    assert head_alone.indirect.max() == 0 and both.indirect[:t_m].mean() > 0
    assert both.indirect[t_m:].mean() > 1.2 * hair_alone.indirect.mean()


def test_adaptive_harmonics_are_all_bounces_on_sparse_hair_and_turn_bounces_on_dense(
        head, monkeypatch):
    """adaptive: every texel's harmonic rows take other fibres' light when fewer than
    SPARSE_FIBRE_SHARE of the fibre gather's rays meet a fibre (the block is all_bounces'
    bit for bit), only the straight texels' otherwise (turn_bounces'); the report says
    which share of texels did. The memory estimate's bound holds in both cases."""
    import functools

    from prtcore.transport import fibre as fibre_module

    scene, texels, space, tracer, fibres, _ = head
    f, t = scene.triangle_count, space.count

    def gather(rows):
        return fibre_gather(space, tracer, fibres, f, 16, 3, all_bounces=True,
                            mesh_texels=HitMapper(scene, texels, tracer),
                            mesh_columns=texels.count, harmonic_rows=rows)

    adaptive = functools.partial(harmonic_receivers, "adaptive", space, STRAIGHT_TURN_DEG)
    sparse = gather(adaptive)
    share = sparse.stats["fibre_hits"] / sparse.stats["rays"]
    assert 0.05 < share < SPARSE_FIBRE_SHARE  # 500 strands on the test head: sparse
    every = gather(True)
    assert sparse.stats["harmonic_receivers"] == 1.0
    assert (abs(sparse.block - every.block) > 0).nnz == 0
    monkeypatch.setattr(fibre_module, "SPARSE_FIBRE_SHARE", share / 2)  # now dense
    dense = gather(adaptive)
    straight = texel_turn(space) < STRAIGHT_TURN_DEG
    turn = gather(straight)
    assert dense.stats["harmonic_receivers"] == pytest.approx(straight.mean())
    assert (abs(dense.block - turn.block) > 0).nnz == 0
    assert (abs(dense.block - every.block) > 0).nnz > 0
    for term, threshold in ((sparse, SPARSE_FIBRE_SHARE), (dense, share / 2)):
        monkeypatch.setattr(fibre_module, "SPARSE_FIBRE_SHARE", threshold)
        bound = harmonic_blocks_bound("adaptive", space)
        assert bound >= harmonic_blocks_bound("turn_bounces", space)
        assert term.block.nnz <= bound * 16 * t
    with pytest.raises(ValueError, match="fibre_share"):
        harmonic_receivers("adaptive", space)


def test_pieces_of_texels_trace_the_same_rays_and_average_back(head):
    """arc_subdivision = 2 transports the strand texels cut in two with ⌈M/2⌉ fibre
    rays and ⌈J/2⌉ arc samples per piece: exactly the fibre gather's and the direct
    light's rays of the whole-texel bake, the atlas gather's own. Each texel is the mean
    of its two pieces, so the hair's light is the whole-texel bake's within noise (a sum
    of the pieces would be twice it), but not bit for bit."""
    scene, texels, space, tracer, fibres, points = head
    t_m = texels.count
    spec = TransportSpec(gather_rays=32, seed=3)
    fine = space.subdivided(2)
    assert fine.count == 2 * space.count and space.subdivided(1) is space
    np.testing.assert_allclose(fine.arc[0::2, 0], space.arc[:, 0], atol=1e-12)
    np.testing.assert_allclose(fine.arc[1::2, 1], space.arc[:, 1], atol=1e-12)
    bakes = {s: bake_hair_mesh_dataset(scene, texels, space, fibres, points, tracer, LIGHTS,
                                       spec=spec, harmonics="adaptive", arc_subdivision=s)
             for s in (1, 2)}
    whole, two = bakes[1], bakes[2]
    assert two.indirect.shape == whole.indirect.shape
    for stage in ("gather", "fibre_gather", "direct_fibres"):
        assert two.stats["rays"][stage] == whole.stats["rays"][stage], stage
    assert two.stats["texels"]["strands"] == space.count
    hair_two = two.indirect[t_m:].astype(np.float64).mean()
    hair_whole = whole.indirect[t_m:].astype(np.float64).mean()
    assert abs(hair_two / hair_whole - 1) < 0.05, (hair_two, hair_whole)
    assert not np.array_equal(two.indirect, whole.indirect)


def test_arc_subdivision_auto_is_two_pieces_for_curly_hair_on_a_mesh(head):
    """"auto": two pieces per texel for the diffuse fibre with a mesh when the median
    texel's fibre turns at least 30° (the test head's curls: about 70°), whole texels for
    straight hair (about 11°), without a mesh and with the Chiang fibre; an explicit S
    is kept with a mesh and refused where it is not baked."""
    from prtcore.hairbake import MESH_ARC_SUBDIVISION, arc_pieces

    space = head[2]
    straight = build_strand_space(head_hair(500, "straight", seed=0), 8)
    on_mesh = hair_spec(parse_spec({}), with_mesh=True)
    assert on_mesh.hair.arc_subdivision == "auto"
    assert arc_pieces(on_mesh, space).hair.arc_subdivision == MESH_ARC_SUBDIVISION == 2
    assert arc_pieces(on_mesh, straight).hair.arc_subdivision == 1
    assert hair_spec(parse_spec({})).hair.arc_subdivision == 1
    chiang = parse_spec({"hair": {"fibre": "chiang"}})
    assert hair_spec(chiang, with_mesh=True).hair.arc_subdivision == 1
    three = parse_spec({"hair": {"arc_subdivision": 3}})
    assert arc_pieces(hair_spec(three, with_mesh=True), straight).hair.arc_subdivision == 3
    with pytest.raises(SpecError, match=r"hair\.arc_subdivision.*hair with a mesh only"):
        hair_spec(three)
    with pytest.raises(SpecError, match=r"hair\.arc_subdivision.*diffuse fibre only"):
        parse_spec({"hair": {"fibre": "chiang", "arc_subdivision": 2}})
    with pytest.raises(SpecError, match=r"hair\.arc_subdivision"):
        parse_spec({"hair": {"arc_subdivision": 9}})


def test_harmonics_auto_means_adaptive_with_a_mesh():
    assert hair_spec(parse_spec({})).hair.harmonics == "first_bounce"
    assert hair_spec(parse_spec({}), with_mesh=True).hair.harmonics == "adaptive"
    alone = parse_spec({"hair": {"harmonics": "turn_bounces"}})
    assert hair_spec(alone).hair.harmonics == "turn_bounces"  # hair alone has it too
    for h in ("first_bounce", "all_bounces", "mesh_bounces", "turn_bounces"):
        explicit = parse_spec({"hair": {"harmonics": h}})
        assert hair_spec(explicit, with_mesh=True).hair.harmonics == h
    # without a mesh there is no mesh light for the harmonics to carry
    alone = parse_spec({"hair": {"harmonics": "mesh_bounces"}})
    assert hair_spec(alone).hair.harmonics == "first_bounce"


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    d = tmp_path_factory.mktemp("hairmesh")
    hair = write_hair(d / "hair.hair", head_hair(300, "curly", seed=1))
    mesh = write_head(d / "head.glb")
    spec = d / "spec.json"
    spec.write_text(json.dumps({
        "atlas": {"resolution": 32}, "hair": {"texels_per_strand": 6},
        # 128 training lights for 32 points (with 24 the transfer is underdetermined and
        # the verdict's ratio swings 1.06–1.45× with the lights' seed on this small
        # asset; docs/hair.md, "Denoising the strand texels")
        "lights": {"count": 128, "holdout": 16, "seed": 2},
        "measurement_points": {"count": 32, "supersample": 2},
        "transport": {"gather_rays": 32}, "fit": {"basis": 8}}))
    out = d / "out"
    assert cli_main(["bake", str(hair), "--mesh", str(mesh), "--spec", str(spec),
                     "--out", str(out), "-q", "--allow-poor"]) == 0
    return out


def test_bundle_holds_the_lightmap_and_the_strand_texture(bundle):
    verify_bundle(bundle)
    m = read_manifest(bundle)
    assert is_hair_mesh(m)
    assert m["asset"]["file"] == "asset.glb" and m["asset"]["hair"]["file"] == "asset.hair"
    assert m["atlas"]["uv"] == "TEXCOORD_1" and m["fibre"]["harmonics"] == "adaptive"
    s = m["strands"]
    assert (s["strand_count"], s["texels_per_strand"]) == (300, 6)
    assert len(s["basis_files"]) == len(m["basis"]["files"])
    cov = read_image(bundle / s["coverage"])[:, :, 0]
    assert cov.shape == (s["height"], s["width"]) and int(cov.sum()) == 1800
    atlas_cov = read_image(bundle / "coverage.exr")[:, :, 0]
    assert int(atlas_cov.sum()) == m["atlas"]["covered_texels"]
    assert m["verdict"]["ratio"] <= 1.25, m["verdict"]
    # the atlas rows went through the surfaces' lightmap filter at the "auto" radius
    assert m["validation"]["reference"].endswith("denoised (radius 1.5 texels)")
    report = json.loads((bundle / "report.json").read_text())
    assert report["transport"]["atlas_denoise"]["radius_texels"] == 1.5


def test_the_atlas_rows_alone_are_filtered_at_the_spec_s_radius(head):
    """denoise_atlas: the first T_m rows of the dataset become the seam-aware filter of the
    mesh's texels (the surface pipeline's denoise_lightmaps), the strand rows stay bit for
    bit; hair_spec resolves fit.denoise "auto" to DENOISE_FALLBACK with a mesh and to 0
    without one, keeps a radius given, and gives "auto" lights MESH_FIXED_LIGHTS with a
    mesh."""
    import dataclasses

    from prtcore.core.progress import StageTimer
    from prtcore.hairbake import CHIANG_FIXED_LIGHTS, MESH_FIXED_LIGHTS, denoise_atlas
    from prtcore.receivers.smoothing import denoise_lightmaps
    from prtcore.transport.dataset import Dataset
    from prtcore.transport.noise import DENOISE_FALLBACK

    auto = hair_spec(parse_spec({}), with_mesh=True)
    assert auto.fit.denoise == DENOISE_FALLBACK
    # with the filter the head needs more lights than hair alone (docs/hair.md)
    assert auto.lights.count == MESH_FIXED_LIGHTS > hair_spec(parse_spec({})).lights.count
    assert hair_spec(parse_spec({"hair": {"fibre": "chiang"}}), with_mesh=True
                     ).lights.count == CHIANG_FIXED_LIGHTS
    assert hair_spec(parse_spec({}), with_mesh=False).fit.denoise == 0.0
    assert hair_spec(parse_spec({"fit": {"denoise": 0.75}}), with_mesh=True
                     ).fit.denoise == 0.75
    texels = head[1]
    t_m, t_h = texels.count, 500
    rng = np.random.default_rng(3)
    values = rng.uniform(0.5, 1.5, (t_m + t_h, 4, 3)).astype(np.float32)
    data = Dataset(lights=(), direct_points=np.zeros((1, 4, 3), np.float32),
                   direct_texels=None, indirect=values.copy(), iterations=0, residual=0.0,
                   stats={})
    out = denoise_atlas(data, texels, 1.5, StageTimer(quiet=True))
    assert out.stats["atlas_denoise"]["radius_texels"] == 1.5
    np.testing.assert_array_equal(out.indirect[t_m:], values[t_m:])
    np.testing.assert_allclose(out.indirect[:t_m], denoise_lightmaps(
        texels, values[:t_m], 1.5), rtol=1e-6)
    # a filter: the noise's spread falls, its mean does not move
    assert out.indirect[:t_m].std() < 0.6 * values[:t_m].std()
    assert abs(out.indirect[:t_m].mean() / values[:t_m].mean() - 1) < 0.02
    same = denoise_atlas(dataclasses.replace(data, indirect=values.copy()), texels, 0.0,
                         StageTimer(quiet=True))
    np.testing.assert_array_equal(same.indirect, values)


def test_relight_writes_both_textures(bundle, tmp_path):
    light = tmp_path / "light.json"
    light.write_text(json.dumps({"type": "point", "position": [0.25, 0.2, 0.2],
                                 "intensity": 1.0, "color": [1, 1, 1]}))
    exr = tmp_path / "relit.exr"
    assert cli_main(["relight", str(bundle), "--light", str(light), "--out", str(exr)]) == 0
    atlas, strands = read_image(exr), read_image(tmp_path / "relit.strands.exr")
    m = read_manifest(bundle)
    assert atlas.shape[:2] == (m["atlas"]["height"], m["atlas"]["width"])
    assert strands.shape[:2] == (m["strands"]["height"], m["strands"]["width"])
    for img in (atlas, strands):
        covered = img[:, :, 3] > 0.5
        assert np.isfinite(img).all() and img[covered, :3].mean() > 0
    assert int((strands[:, :, 3] > 0.5).sum()) == 1800


@pytest.fixture(scope="module")
def frames(bundle, tmp_path_factory):
    """The bundle drawn by ``render --cpu`` (ray traced) and by the GL renderer (one
    shadow atlas of head and hair), each in its three modes, through one camera."""
    from prtcore.emitters.lightfile import load_light_file
    from prtcore.reference.camera import load_camera
    from prtcore.runtime.hair_mesh_gl import HairMeshRenderer
    from prtcore.runtime.strands import render_strands

    d = tmp_path_factory.mktemp("frames")
    light = d / "light.json"
    light.write_text(json.dumps({"type": "point", "position": [0.25, 0.2, 0.2],
                                 "intensity": 1.0}))
    cam = d / "cam.json"
    cam.write_text(json.dumps({"position": [0.0, 0.05, 0.45], "target": [0, 0, 0],
                               "fov_y_deg": 45, "width": 64, "height": 64}))
    lights, camera = load_light_file(light), load_camera(cam)
    modes = ("full", "direct", "indirect")
    cpu = {m: render_strands(bundle, lights, camera, mode=m) for m in modes}
    with HairMeshRenderer(bundle) as r:
        gl = {m: r.render(lights, camera, mode=m).image for m in modes}
    return cpu, gl, light, cam


def test_report_validates_a_hair_mesh_bundle_against_the_hair_mesh_path_tracer(bundle):
    """`report --reference-spp`: the held-out lights relit from the bundle alone, both
    textures read back at their texels (atlas, then strands: the bake's receiver order),
    against prtcore.reference.hair_mesh's path tracer through the same head and hair.
    Measured 47 % noise-corrected at n = 8: the bundle's own gather noise at M = 32 on
    158 atlas texels; with the strand texels read back in reverse order, 98 %."""
    from prtcore.validate import validate_bundle

    v = validate_bundle(bundle, spp=32, count=2)
    assert v["reference"] == "path tracer, 32 spp" and v["lights"] == 2
    row = next(r for r in v["rows"] if r["n"] == 8)
    assert 0 < row["rmse_noise_corrected_mean"] <= row["rmse_mean"] < 1
    assert row["rmse_noise_corrected_mean"] < 0.7


def test_cpu_render_draws_head_and_hair(bundle, frames, tmp_path):
    """``render --cpu``: the head's pixels take the relit lightmap and the hair's the strand
    texture; full = direct + indirect; the head gets indirect light (all of it off the
    hair)."""
    cpu, _, light, cam = frames
    np.testing.assert_allclose(cpu["full"][..., :3], cpu["direct"][..., :3]
                               + cpu["indirect"][..., :3], rtol=1e-5, atol=1e-7)
    seen = cpu["full"][..., 3] > 0
    centre = seen[24:40, 24:40]  # the head fills the middle of the frame
    assert centre.all() and cpu["indirect"][24:40, 24:40, :3].mean() > 0
    out = tmp_path / "r.png"
    assert cli_main(["render", str(bundle), "--light", str(light), "--camera", str(cam),
                     "--cpu", "--out", str(out)]) == 0 and out.stat().st_size > 0


def test_gl_render_is_the_cpu_drawing(bundle, frames, tmp_path):
    """The GL drawing against the ray-traced one, over the pixels both cover: the
    indirect term (lightmap and strand texture blended per fragment) per pixel to the
    GPU's precision; the direct term on average (shadow maps resolve a fibre's shadow
    only on average: 25 % per pixel here, as for hair alone, docs/hair.md). Measured at
    256²: 0.09 % of the pixels covered by one drawing only, indirect 0.24 % per pixel,
    direct mean +1.3 %."""
    cpu, gl, light, cam = frames
    both = (cpu["full"][..., 3] > 0) & (gl["full"][..., 3] > 0)
    assert both.mean() > 0.2  # the head and the hair: a quarter of the frame
    assert ((cpu["full"][..., 3] > 0) != (gl["full"][..., 3] > 0)).mean() < 0.01
    ind_c, ind_g = cpu["indirect"][both, :3], gl["indirect"][both, :3]
    assert np.abs(ind_g - ind_c).mean() < 0.01 * ind_c.mean()
    dir_c, dir_g = cpu["direct"][both, :3], gl["direct"][both, :3]
    assert abs(dir_g.mean() / dir_c.mean() - 1) < 0.03
    np.testing.assert_allclose(gl["full"][..., :3], gl["direct"][..., :3]
                               + gl["indirect"][..., :3], rtol=1e-4, atol=1e-6)
    out = tmp_path / "g.png"
    assert cli_main(["render", str(bundle), "--light", str(light), "--camera", str(cam),
                     "--out", str(out)]) == 0 and out.stat().st_size > 0


def test_golden_hair_mesh_full(frames):
    """The GL drawing of the test bundle (head and hair) against
    tests/goldens/hair_mesh_full.png (the golden tolerance of tests/golden_images.py; a
    failing comparison writes output, golden and difference under tests/_failures/)."""
    from golden_images import check_golden

    from prtcore.runtime.gl import tone_map

    check_golden("hair_mesh_full", tone_map(frames[1]["full"], exposure=2.0))


def _with_point_light(glb: Path, out: Path) -> Path:
    """``glb`` with a KHR_lights_punctual point light on a new node (the JSON chunk
    rewritten, the binary chunk kept)."""
    import struct

    raw = glb.read_bytes()
    n = struct.unpack_from("<I", raw, 12)[0]
    doc = json.loads(raw[20:20 + n])
    rest = raw[20 + n:]
    doc.setdefault("extensionsUsed", []).append("KHR_lights_punctual")
    doc.setdefault("extensions", {})["KHR_lights_punctual"] = {
        "lights": [{"type": "point", "intensity": 2.0, "color": [1, 1, 1]}]}
    doc["nodes"].append({"translation": [0.3, 0.3, 0.3],
                         "extensions": {"KHR_lights_punctual": {"light": 0}}})
    doc["scenes"][doc.get("scene", 0)]["nodes"].append(len(doc["nodes"]) - 1)
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<I4s", len(text), b"JSON") + text + rest
    out.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)
    return out


def test_a_mesh_brings_its_lights_to_from_asset_families(tmp_path):
    """A light family with ``from_asset`` draws around the mesh's own lights (hair alone
    has none and is refused, naming the family)."""
    from prtcore.core.errors import LightFileError

    hair = write_hair(tmp_path / "h.hair", head_hair(30, seed=6))
    mesh = _with_point_light(write_head(tmp_path / "head.glb"), tmp_path / "lit.glb")
    spec = parse_spec({"atlas": {"resolution": 32}, "hair": {"texels_per_strand": 2},
                       "lights": {"count": 6, "holdout": 2, "families": [
                           {"type": "point", "from_asset": True}]},
                       "measurement_points": {"count": 8, "supersample": 1},
                       "transport": {"gather_rays": 8}, "fit": {"basis": 2}})
    out = bake(hair, spec, tmp_path / "out", quiet=True, mesh=mesh)
    lights = json.loads((out / "holdout_lights.json").read_text())["lights"]
    assert all(np.linalg.norm(np.asarray(li["position"]) - 0.3) < 0.3 for li in lights)
    with pytest.raises(LightFileError, match="from_asset"):
        bake(hair, spec, tmp_path / "alone", quiet=True)


def test_a_mesh_needs_a_hair_asset_and_a_file(tmp_path, capsys):
    mesh = write_head(tmp_path / "head.glb")
    with pytest.raises(PrtError, match="not a hair asset"):
        bake(mesh, parse_spec({}), tmp_path / "out", quiet=True, mesh=mesh)
    hair = write_hair(tmp_path / "h.hair", head_hair(20, seed=2))
    assert cli_main(["bake", str(hair), "--mesh", str(tmp_path / "none.glb"), "--out",
                     str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "none.glb: cannot read asset: no such file" in err
    assert "[prtcore] load" not in err  # refused before any work
    (tmp_path / "bad.glb").write_bytes(b"garbage")
    assert cli_main(["bake", str(hair), "--mesh", str(tmp_path / "bad.glb"), "--out",
                     str(tmp_path / "out")]) == 2
    assert "bad.glb: truncated GLB" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()  # nothing left behind
