"""The atlas's near field on the fibres (prtcore/transport/fibre_near.py): an atlas gather
ray that meets a fibre within reach is shaded at the point it meets, not read as its
strand texel's mean."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from prtcore.core.fibres import facing, fibre_at_hits, outside_offset
from prtcore.core.geometry import orthonormal_frame
from prtcore.core.progress import StageTimer
from prtcore.core.scene import Light
from prtcore.core.spec import ChiangSpec, TransportSpec, parse_spec
from prtcore.emitters.base import emitter_for
from prtcore.emitters.punctual import irradiance, unshadowed_irradiance
from prtcore.intake.hair import hair_scene
from prtcore.intake.points import place_measurement_points
from prtcore.pipeline import run_intake
from prtcore.receivers.strands import arc_of_hit, build_strand_space
from prtcore.scenes.hair import head_hair, head_lights, write_head
from prtcore.transport import fibre_near
from prtcore.transport.fibre import SHARE_MARGIN, MeshHits, hair_density, hair_tracer
from prtcore.transport.fibre_chiang import (
    EXITANCE_TERMS,
    chiang_direct,
    chiang_fibre,
    exitance_reads,
    exitance_weights,
    needs_frames,
    shaded_reads,
    texel_frames,
)
from prtcore.transport.fibre_near import (
    NEAR_SHADOW_PIECES,
    near_fibre_direct,
    near_fibre_rays,
    near_fibre_shaded,
    piece_visibility,
    shaded_fibre_correction,
    shadow_pieces,
)
from prtcore.transport.gather import HitMapper, gather_operator, near_field_reach
from prtcore.transport.hair_mesh_chiang import (
    StrandRays,
    bake_chiang_hair_mesh_dataset,
    chiang_mesh_product,
)

CLEAR_HAIR = ChiangSpec(eumelanin=0.0, pheomelanin=0.0)  # no absorption
REACH = 3.0  # footprints


@pytest.fixture(scope="module")
def scalp(tmp_path_factory):
    """The test head (10 cm icosphere, 32² atlas) with 500 curly strands, 8 texels each,
    and its atlas gather (32 rays, seed 1) twice: every fibre hit read as its texel, and
    the hits within REACH footprints kept apart."""
    d = tmp_path_factory.mktemp("near")
    intake = run_intake(write_head(d / "head.glb"), parse_spec(
        {"atlas": {"resolution": 32}, "measurement_points": {"count": 16}}), quiet=True)
    scene, texels = intake.scene, intake.texels
    space = build_strand_space(head_hair(500, "curly", seed=0), 8)
    tracer, fibres = hair_tracer(space, scene)
    f = scene.triangle_count
    plain = StrandRays(space, fibres, f, seed=1)
    g = gather_operator(scene, texels, tracer, 32, 1, foreign=plain)
    split = StrandRays(space, fibres, f, seed=1, reach=near_field_reach(texels, REACH))
    g2 = gather_operator(scene, texels, tracer, 32, 1, foreign=split)
    assert np.array_equal(g.valid_rays, g2.valid_rays)
    return scene, texels, space, tracer, fibres, plain, split, g


def test_the_near_hits_are_the_reads_they_leave_out(scalp):
    """With a reach, every atlas ray to a fibre is either read as its texel
    (StrandRays.rays) or kept as a near hit, never both, and the near hits are the ones
    closer than the reach: on this head a share of them, not none and not all."""
    _, texels, space, _, fibres, plain, split, _ = scalp
    rows, texel, d, _ = plain.rays()
    far_rows, far_texel, far_d, _ = split.rays()
    near = split.near()
    assert 0 < near.count < len(rows) and len(far_rows) + near.count == len(rows)
    # the point met (on the axis) lies within the reach of the ray's origin, which is on
    # the texel's square: within the reach and a footprint of its centre
    _, centre, _, _ = fibre_at_hits(space.hair, fibres, outside_offset(space.hair, fibres.sides),
                                    np.zeros((space.hair.point_count, 3)), near.triangle,
                                    near.barycentric.astype(np.float64))
    far = np.linalg.norm(centre - texels.position[near.row], axis=1)
    reach = near_field_reach(texels, REACH)[near.row]
    assert (far < reach * (1 + 1 / REACH) + 1e-3).all()

    def keys(r, t, dd):
        return sorted(zip(r.tolist(), t.tolist(), np.round(dd, 5).tolist(), strict=True))
    both = keys(np.concatenate([far_rows, near.row]), np.concatenate([far_texel, near.texel]),
                np.concatenate([far_d, near.direction.astype(np.float64)]))
    assert both == keys(rows, texel, d)
    assert plain.near().count == 0


@pytest.mark.parametrize("exitance", ["quadratic", "second_order"])
def test_the_near_direct_light_is_the_read_it_replaces(scalp, exitance):
    """near_fibre_direct, with quadratic exitance (six coefficients, in the texels'
    frames) and the second order (ten, a world form), is what the near hits read of the
    stacked direct light when they were texel reads: the product made of those reads
    alone, applied to it, at the atlas rows (the product's layout)."""
    _, texels, space, _, _, _, split, g = scalp
    t_m, t_h = texels.count, space.count
    near = split.near()
    frames = texel_frames(space) if needs_frames(exitance) else None
    fibre = chiang_fibre(CLEAR_HAIR, space)
    empty = MeshHits(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64),
                     np.zeros((0, 3)), np.zeros(0), np.zeros((0, 6), np.float32))
    reads = chiang_mesh_product(
        sp.csr_matrix((t_m, t_m + t_h), dtype=np.float32),
        (near.row, near.texel, near.direction.astype(np.float64), np.ones(near.count)),
        g.valid_rays, (np.zeros(0, np.int32), np.zeros(0, np.int32),
                       np.zeros((0, 6), np.float32)),
        empty, fibre, t_m, t_h, 32, 2, exitance, frames)
    k = 3
    direct = np.random.default_rng(0).random((reads.shape[0], k, 3)).astype(np.float32)
    direct[:t_m] = 0
    want = reads(direct.reshape(len(direct), -1)).reshape(-1, k, 3)[:t_m]
    rows, values = near_fibre_direct(near, g.valid_rays, direct, reads.coefficient_rows,
                                     t_m, t_h, EXITANCE_TERMS[exitance], frames)
    assert np.array_equal(rows, np.unique(near.row))
    np.testing.assert_allclose(values, want[rows], rtol=2e-5, atol=1e-6)
    assert not np.any(np.delete(want, rows, axis=0))  # no other atlas row read anything
    # some lights' columns alone (a bake reads the environment lights' only)
    _, some = near_fibre_direct(near, g.valid_rays, direct, reads.coefficient_rows, t_m,
                                t_h, EXITANCE_TERMS[exitance], frames, [2])
    assert np.array_equal(some[:, 2], values[:, 2]) and not some[:, :2].any()


def test_a_clear_fibre_s_near_rays_carry_all_it_scatters(scalp):
    """Without absorption the fibre scatters all it gets (Σ_p A_p = 1): each ray from a
    near hit weighs exactly 1 / (rays × the texel's valid rays), in every channel, and
    what the rays meet (the scalp, another fibre, or nothing) is counted."""
    scene, texels, space, tracer, fibres, _, split, g = scalp
    near = split.near()
    nr = near_fibre_rays(near, g.valid_rays, space, fibres, chiang_fibre(CLEAR_HAIR, space),
                         tracer, scene.triangle_count, HitMapper(scene, texels, tracer),
                         texels.count, 5, rays=2)
    np.testing.assert_allclose(nr.weight * (2 * g.valid_rays[nr.row])[:, None], 1.0,
                               rtol=1e-4)
    s = nr.stats
    assert s["rays"] == 2 * near.count == s["mesh"] + s["fibres"] + s["nothing"]
    assert s["mesh"] > 0 and s["fibres"] > 0 and len(nr.row) == s["mesh"] + s["fibres"]
    assert (nr.col >= texels.count).sum() == s["fibres"]  # the rays that met a fibre
    again = near_fibre_rays(near, g.valid_rays, space, fibres,
                            chiang_fibre(CLEAR_HAIR, space), tracer, scene.triangle_count,
                            HitMapper(scene, texels, tracer), texels.count, 5, rays=2)
    assert np.array_equal(again.col, nr.col) and np.array_equal(again.weight, nr.weight)


def test_how_many_near_hits_there_are_is_known_before_the_gather(scalp):
    """hair_density's atlas_near_share (the memory estimate's share of atlas rays that
    meet a fibre within reach) bounds the share the gather keeps as near hits from above,
    by at most its margin and the probe's noise."""
    scene, texels, space, tracer, *_, split, _ = scalp
    share = split.near().count / (texels.count * 32)
    density = hair_density(space, tracer, scene.triangle_count, 32, 0, atlas=texels,
                           near_fibres=REACH)
    assert 0.01 < share <= density.atlas_near_share <= share + SHARE_MARGIN + 0.03, (
        share, density)
    assert hair_density(space, tracer, scene.triangle_count, 32, 0,
                        atlas=texels).atlas_near_share == SHARE_MARGIN


def test_the_direct_light_at_the_point_met_is_the_texels_model_there(scalp):
    """near_fibre_shaded computes each near hit's direct exitance as the strand texels'
    direct light does (chiang_direct's weights, E⊥ cos θl V / π²), at the point met, and
    reads it toward the ray: summed over the atlas texels it is the texel reads' light
    within a few per cent (measured 0.90 for the sun, 0.93 for the point light; the
    points near the scalp are shadowed a little more than their texels' averages), and
    texel by texel they go together (correlation 0.93 and 0.95)."""
    _, texels, space, tracer, fibres, _, split, g = scalp
    near = split.near()
    t_m, t_h = texels.count, space.count
    t = t_m + t_h
    fibre = chiang_fibre(ChiangSpec(), space)
    lights = head_lights()
    coefficients = chiang_direct(space, tracer, lights, 8, 2, fibre, "second_order")
    f = EXITANCE_TERMS["second_order"]
    direct = np.zeros((t + (f - 1) * t_h, len(lights), 3), np.float32)

    def rows_of(a: int) -> slice:  # the product's layout (RayBlockProduct.coefficient_rows)
        return slice(0, t) if a == 0 else slice(t + (a - 1) * t_h, t + a * t_h)
    for a in range(f):
        base = rows_of(a).start + (t_m if a == 0 else 0)
        direct[base:base + t_h] = coefficients[a]
    rows, read = near_fibre_direct(near, g.valid_rays, direct, rows_of, t_m, t_h, f, None)
    same, shaded = near_fibre_shaded(near, g.valid_rays, space, fibres, fibre, tracer,
                                     lights, "second_order", (rows, read.copy()), 4)
    assert np.array_equal(same, rows)
    for k in range(len(lights)):
        a, b = read[:, k].sum(axis=1), shaded[:, k].sum(axis=1)
        assert 0.8 < b.sum() / a.sum() < 1.1 and np.corrcoef(a, b)[0, 1] > 0.8, (
            k, b.sum() / a.sum(), np.corrcoef(a, b)[0, 1])
        assert not np.allclose(a, b)  # shaded, not read


def _bake(scalp, bounces: int, exitance: str, lights=None, **fibres_near):
    """The scalp's hair + mesh dataset under ``lights`` (the head's two by default; 32
    rays, J = 4, seed 0, ``bounces`` bounces), with bake_chiang_hair_mesh_dataset's
    ``fibres_near`` (near_fibres, shaded_fibres, gathered_fibres)."""
    scene, texels, space, tracer, fibres, *_ = scalp
    points = place_measurement_points(hair_scene(space.hair), parse_spec(
        {"measurement_points": {"count": 16, "placement": "hull"}}).measurement_points)
    return bake_chiang_hair_mesh_dataset(
        scene, texels, space, fibres, points, tracer, lights or head_lights(), (),
        TransportSpec(gather_rays=32, direct_samples=4, seed=0, max_bounces=bounces),
        StageTimer(quiet=True), chiang_fibre(ChiangSpec(), space), exitance=exitance,
        **fibres_near)


def test_a_bake_with_the_near_field_on_the_fibres(scalp):
    """hair.chiang.near_fibres through the bake: its stats count the near hits and their
    rays, the atlas texels' light changes and keeps its scale, and off it is the bake
    it was (no near hits kept, no stats)."""
    texels = scalp[1]
    on, off = _bake(scalp, 3, "linear", near_fibres=REACH), _bake(scalp, 3, "linear")
    s = on.stats["near_fibres"]
    assert s["hits"] > 0 and s["rays"] == 2 * s["hits"] and "near_fibres" not in off.stats
    t_m = texels.count
    a, b = on.indirect[:t_m].astype(np.float64), off.indirect[:t_m].astype(np.float64)
    assert np.isfinite(a).all() and not np.array_equal(a, b)
    assert 0.7 < a.sum() / b.sum() < 1.3, a.sum() / b.sum()


def test_the_hits_of_a_shadow_piece_lie_within_its_arc_and_share_a_drawn_hit_s_ray(scalp):
    """shadow_pieces cuts each strand texel into equal arcs: every hit of a piece lies on
    one texel and within one piece's arc of the others, the drawn hit is one of them,
    and the same seed draws the same hits. piece_visibility is that hit's shadow ray,
    so with a piece a hit the shading is the ray-a-hit shading, and with the default
    pieces it keeps its sum and goes with it texel by texel."""
    _, _, space, tracer, fibres, _, split, g = scalp
    near = split.near()
    cut = shadow_pieces(near, space, fibres, seed=4)
    assert 0 < cut.count < near.count
    assert np.array_equal(cut.of_hit[cut.hit], np.arange(cut.count))
    assert np.array_equal(shadow_pieces(near, space, fibres, seed=4).hit, cut.hit)
    assert not np.array_equal(shadow_pieces(near, space, fibres, seed=5).hit, cut.hit)
    strand, arc = arc_of_hit(space.hair, fibres, near.triangle, near.barycentric)
    span = space.hair.strand_length[strand] / (space.texels_per_strand * NEAR_SHADOW_PIECES)
    order = np.argsort(cut.of_hit, kind="stable")
    bounds = np.searchsorted(cut.of_hit[order], np.arange(cut.count + 1))
    for u in range(0, cut.count, max(1, cut.count // 200)):
        mine = order[bounds[u]:bounds[u + 1]]
        assert len(set(near.texel[mine])) == 1 and len(set(strand[mine])) == 1
        assert np.ptp(arc[mine]) <= span[mine[0]] * (1 + 1e-9)
    # a piece a hit: each hit its own drawn hit
    fine = shadow_pieces(near, space, fibres, seed=4, pieces=1 << 20)
    assert fine.count == near.count and np.array_equal(fine.hit[fine.of_hit],
                                                       np.arange(near.count))
    fibre = chiang_fibre(ChiangSpec(), space)
    lights = head_lights()
    seen = np.unpackbits(piece_visibility(cut, near, space, fibres, fibre, tracer, lights),
                         axis=1, count=len(lights))
    assert seen.shape == (cut.count, len(lights)) and 0 < seen.mean() < 1
    # the drawn hits' own shadow rays, light by light
    tangent, centre, radius, _ = fibre_at_hits(
        space.hair, fibres, outside_offset(space.hair, fibres.sides), fibre.sigma_points,
        near.triangle[cut.hit], near.barycentric[cut.hit].astype(np.float64))
    for k, light in enumerate(lights):
        _, to_light, _ = unshadowed_irradiance(light, centre, tangent)
        e = irradiance(light, centre + radius[:, None] * facing(tangent, to_light),
                       to_light, tracer)
        assert np.array_equal(seen[:, k], e.sum(axis=1) > 0), k
    rows = np.unique(near.row)
    zero = np.zeros((len(rows), len(lights), 3), np.float32)
    args = (near, g.valid_rays, space, fibres, fibre, tracer, lights, "linear")
    _, shared = near_fibre_shaded(*args, (rows, zero.copy()), 4)
    _, own = near_fibre_shaded(*args, (rows, zero.copy()), 4, pieces=1 << 20)
    _, texel = near_fibre_shaded(*args, (rows, zero.copy()), 4, pieces=1)
    for k in range(len(lights)):
        a, b = own[:, k].sum(axis=1), shared[:, k].sum(axis=1)
        assert 0.9 < b.sum() / a.sum() < 1.1 and np.corrcoef(a, b)[0, 1] > 0.8, (
            k, b.sum() / a.sum(), np.corrcoef(a, b)[0, 1])
        assert not np.array_equal(a, texel[:, k].sum(axis=1))  # a ray a texel: shared


@pytest.mark.parametrize("exitance", ["isotropic", "linear", "quadratic", "second_order"])
def test_the_compiled_shading_is_the_texels_direct_model_read_toward_the_ray(exitance):
    """shaded_reads (the near hits' direct light, compiled) sums, per receiver, each
    point's exitance_weights of the light times E⊥ on its side facing the light and
    cos θl, read toward its ray with exitance_reads: the numpy rule's value to rounding,
    for every exitance, a point light and a directional one."""
    rng = np.random.default_rng(3)
    n, r = 500, 7
    fibre = chiang_fibre(ChiangSpec(eumelanin=0.8), build_strand_space(head_hair(20, "curly"),
                                                                        4))
    tangent, d = (v / np.linalg.norm(v, axis=1, keepdims=True)
                  for v in rng.normal(size=(2, n, 3)))
    centre = rng.uniform(-0.1, 0.1, (n, 3))
    radius = rng.uniform(1e-5, 1e-4, n)
    frame = orthonormal_frame(tangent)
    sigma = rng.uniform(0, 3, (n, 3))
    weight = rng.uniform(0, 1, n) * (np.arange(n) % 9 != 0)  # some points in shadow
    slot = rng.integers(0, r, n)
    terms = EXITANCE_TERMS[exitance]
    toward = exitance_reads(d, frame, terms)
    table = fibre.albedo
    for light in head_lights():
        _, to_light, _ = unshadowed_irradiance(light, centre, tangent)
        cos_l = np.sqrt(np.clip(1 - np.einsum("ij,ij->i", tangent, to_light) ** 2, 0, None))
        e = irradiance(light, centre + radius[:, None] * facing(tangent, to_light), to_light,
                       None)
        w = exitance_weights(table, tangent, to_light, sigma, exitance, frame)
        value = sum(t[:, None] * wa for t, wa in zip(toward, w, strict=True))
        value *= e * (cos_l * weight)[:, None]
        want = np.stack([np.bincount(slot, value[:, c], minlength=r) for c in range(3)],
                        axis=1)
        got = np.zeros((r, 3))
        shaded_reads(emitter_for(light).kernel_row(light), centre, tangent, radius, sigma,
                     *frame, np.stack(toward, axis=1), weight, slot, table.values,
                     table.sin_theta, table.root_sigma, got)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())
        assert np.abs(want).max() > 0


@pytest.fixture(scope="module")
def shaded_split(scalp):
    """The scalp's atlas gather once more, its fibre hits within one footprint near and
    those within REACH shaded (StrandRays' ``shade``)."""
    scene, texels, space, tracer, fibres, *_ = scalp
    both = StrandRays(space, fibres, scene.triangle_count, seed=1,
                      reach=near_field_reach(texels, 1.0),
                      shade=near_field_reach(texels, REACH))
    return both, gather_operator(scene, texels, tracer, 32, 1, foreign=both)


def test_shaded_hits_are_the_far_reads_within_the_second_reach(scalp, shaded_split):
    """With ``shade`` beyond ``reach``, StrandRays keeps the hits closer than ``reach``
    as near hits and leaves them out of its reads (StrandRays.rays), and marks apart the
    reads closer than ``shade``, which it keeps: the near and the shaded hits together
    are the near hits at ``shade``'s reach, hit for hit. Without ``shade`` none."""
    _, _, _, _, _, plain, split, g = scalp
    both, g3 = shaded_split
    assert np.array_equal(g3.valid_rays, g.valid_rays)
    near, shaded = both.near(), both.shaded()
    assert near.count > 0 and shaded.count > 0 and split.shaded().count == 0
    assert len(both.rays()[0]) + near.count == len(plain.rays()[0])

    def keys(*h):
        d = np.concatenate([x.direction for x in h]).astype(np.float64)
        return sorted(zip(np.concatenate([x.row for x in h]).tolist(),
                          np.concatenate([x.texel for x in h]).tolist(),
                          map(tuple, np.round(d, 5).tolist()), strict=True))
    assert keys(near, shaded) == keys(split.near())
    reads = sorted(zip(both.rays()[0].tolist(), both.rays()[1].tolist(),
                       map(tuple, np.round(both.rays()[2], 5).tolist()), strict=True))
    assert set(keys(shaded)) <= set(reads)  # they stay reads


def test_how_many_shaded_hits_there_are_is_known_before_the_gather(scalp, shaded_split):
    """hair_density's atlas_shaded_share (the memory estimate's bound on the shaded
    hits) bounds the share of atlas rays the gather keeps as near or shaded hits from
    above, by at most its margin and the probe's noise."""
    scene, texels, space, tracer, *_ = scalp
    both, _ = shaded_split
    share = (both.near().count + both.shaded().count) / (texels.count * 32)
    density = hair_density(space, tracer, scene.triangle_count, 32, 0, atlas=texels,
                           near_fibres=1.0, shaded_fibres=REACH)
    assert 0.01 < share <= density.atlas_shaded_share <= share + SHARE_MARGIN + 0.03, (
        share, density)
    assert density.atlas_near_share < density.atlas_shaded_share


def test_the_shaded_correction_swaps_the_texel_read_for_the_point_s_light(
        scalp, shaded_split, monkeypatch):
    """shaded_fibre_correction adds, into an accumulator with more rows than its hits',
    each shaded hit's direct light at the point met (near_fibre_shaded) less its texel's
    read (near_fibre_direct) for the punctual lights, whatever its chunks; an
    environment light's columns stay as they were."""
    both, g = shaded_split
    _, texels, space, tracer, fibres, *_ = scalp
    hits = both.shaded()
    t_m, t_h = texels.count, space.count
    fibre = chiang_fibre(ChiangSpec(), space)
    lights = [*head_lights(), Light(type="environment", color=np.ones(3), intensity=1.0,
                                    environment="ambient")]
    f = EXITANCE_TERMS["second_order"]
    direct = np.random.default_rng(3).random((t_m + t_h + (f - 1) * t_h, len(lights), 3))
    direct = direct.astype(np.float32)

    def rows_of(a: int) -> slice:
        return slice(0, t_m + t_h) if a == 0 else slice(t_m + t_h + (a - 1) * t_h,
                                                        t_m + t_h + a * t_h)
    rows = np.arange(t_m)
    start = np.random.default_rng(4).random((t_m, len(lights), 3)).astype(np.float32)
    punctual = [0, 1]
    _, read = near_fibre_direct(hits, g.valid_rays, direct, rows_of, t_m, t_h, f, None,
                                punctual)
    mine, point = near_fibre_shaded(hits, g.valid_rays, space, fibres, fibre, tracer,
                                    lights, "second_order",
                                    (np.unique(hits.row), np.zeros_like(read)), 6)
    want = start.copy()
    want[mine] += point - read
    monkeypatch.setattr(fibre_near, "SHADED_CHUNK", 1000)  # several chunks
    into = (rows, start.copy())
    stats: dict = {}
    shaded_fibre_correction(hits, g.valid_rays, space, fibres, fibre, tracer, lights,
                            "second_order", direct, rows_of, t_m, None, 6, into, stats)
    np.testing.assert_allclose(into[1], want, rtol=1e-5, atol=1e-6)
    assert np.array_equal(into[1][:, 2], start[:, 2])  # the environment's
    assert stats["shadow_pieces"] > 0 and not np.allclose(into[1], start)


@pytest.mark.parametrize("near", [REACH, 0.0])
def test_a_bake_with_shaded_fibres_moves_the_first_bounce_of_its_atlas_texels_alone(scalp,
                                                                                   near):
    """hair.chiang.shaded_fibres through the bake, first bounce alone, with the near
    fibres on or off: the strand texels' light is the bake without it bit for bit, some
    of the atlas texels change (those with shaded hits) and keep their scale (the point's
    light against its texel's mean), and the stats count the hits."""
    texels = scalp[1]
    on, off = (_bake(scalp, 1, "second_order", near_fibres=near, shaded_fibres=shaded)
               for shaded in (4 * REACH, 0.0))
    t_m = texels.count
    assert np.array_equal(on.indirect[t_m:], off.indirect[t_m:])
    assert on.stats["shaded_fibres"]["hits"] > 0 and "shaded_fibres" not in off.stats
    a, b = on.indirect[:t_m].astype(np.float64), off.indirect[:t_m].astype(np.float64)
    moved = np.any(a != b, axis=(1, 2))
    assert 0 < moved.sum() < t_m and np.isfinite(a).all()
    assert 0.8 < a.sum() / b.sum() < 1.2, a.sum() / b.sum()


def test_gathered_hits_are_near_hits_whose_direct_light_is_beyond_the_lit_reach(scalp):
    """StrandRays with ``lit`` inside its reach: the near hits are the reach's, in the
    same order, and near_lit marks exactly those the lit reach alone would keep near;
    without ``lit`` it says None (every near hit shaded at the point)."""
    scene, texels, space, tracer, fibres, _, split, _ = scalp
    f = scene.triangle_count
    both = StrandRays(space, fibres, f, seed=1, reach=near_field_reach(texels, REACH),
                      lit=near_field_reach(texels, 1.0))
    inner = StrandRays(space, fibres, f, seed=1, reach=near_field_reach(texels, 1.0))
    for rays in (both, inner):
        gather_operator(scene, texels, tracer, 32, 1, foreign=rays)
    near, lit, want = both.near(), both.near_lit(), split.near()
    assert np.array_equal(near.row, want.row) and np.array_equal(near.triangle, want.triangle)
    assert 0 < lit.sum() < near.count and split.near_lit() is None
    close = inner.near()
    assert np.array_equal(near.subset(lit).row, close.row)
    assert np.array_equal(near.subset(lit).triangle, close.triangle)


def test_a_bake_with_gathered_fibres_reads_their_direct_light_from_the_texels(scalp):
    """hair.chiang.gathered_fibres through the bake, first bounce alone: the near hits and
    their rays are those of near_fibres at that reach, so the strand texels are
    bit-identical; the atlas texels whose hits lie beyond near_fibres move (their direct
    light read from the texel, not shaded at the point) and keep their scale. Under an
    environment light alone (read from the texel either way) the two bakes agree."""
    t_m = scalp[1].count
    args = (scalp, 1, "second_order")
    split = _bake(*args, near_fibres=1.0, gathered_fibres=REACH)
    whole = _bake(*args, near_fibres=REACH)
    s, w = split.stats["near_fibres"], whole.stats["near_fibres"]
    assert (s["hits"], s["rays"]) == (w["hits"], w["rays"])
    assert 0 < s["read_direct"] < s["hits"] and "read_direct" not in w
    assert np.array_equal(split.indirect[t_m:], whole.indirect[t_m:])
    a, b = split.indirect[:t_m].astype(np.float64), whole.indirect[:t_m].astype(np.float64)
    assert not np.array_equal(a, b) and np.isfinite(a).all()
    assert 0.8 < a.sum() / b.sum() < 1.2, a.sum() / b.sum()
    sky = [Light(type="environment", color=np.ones(3), intensity=1.0, environment="ambient")]
    split, whole = (_bake(*args, lights=sky, near_fibres=1.0, gathered_fibres=REACH),
                    _bake(*args, lights=sky, near_fibres=REACH))
    np.testing.assert_allclose(split.indirect, whole.indirect, rtol=1e-5, atol=1e-7)
