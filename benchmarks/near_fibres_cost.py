"""What the atlas's near field on the fibres costs (``hair.chiang.near_fibres``,
prtcore/transport/fibre_near.py) on the head with curly hair, the bake's 512² atlas and
its 64 atlas gather rays.

Traces the atlas gather with the near hits kept apart at ``--near-fibres`` footprints,
then times the near hits' rays (:func:`near_fibre_rays`) and their direct light shaded
at the point met (:func:`near_fibre_shaded`) for ``--timed-lights`` lights (the head's
two punctual lights, cycled), once for each ``--pieces``: the arc pieces a strand texel
whose hits share a shadow ray a light (the default, and so many that every hit has its
own ray, as it had before), and scales them to ``--lights`` lights (a bake's training
+ held-out: 512 + 16 by default): it is one pass per light, so it grows with them. The
texel reads it starts from (:func:`near_fibre_direct`) are timed on the head's two
lights. Seconds are this machine's, in one run: compare them with each other, not
across machines.

Printed and written to benchmarks/results/near_fibres_cost.json.

Usage: python benchmarks/near_fibres_cost.py [--strands 10000] [--near-fibres 20]
       [--lights 528] [--timed-lights 16] [--pieces 32 1048576] [--shaded-fibres R]
       [--gathered-fibres R]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.hair_mesh_accuracy import LIGHTS, head_scene  # noqa: E402
from prtcore.core.spec import ChiangSpec  # noqa: E402
from prtcore.receivers.strands import build_strand_space  # noqa: E402
from prtcore.scenes.hair import head_hair  # noqa: E402
from prtcore.transport.fibre import hair_tracer  # noqa: E402
from prtcore.transport.fibre_chiang import (  # noqa: E402
    EXITANCE_TERMS,
    chiang_fibre,
    needs_frames,
    texel_frames,
)
from prtcore.transport.fibre_near import (  # noqa: E402
    NEAR_SHADOW_PIECES,
    near_fibre_direct,
    near_fibre_rays,
    near_fibre_shaded,
    near_hits_reach,
    shaded_fibre_correction,
    texel_reads,
)
from prtcore.transport.gather import HitMapper, gather_operator, near_field_reach  # noqa: E402
from prtcore.transport.hair_mesh_chiang import StrandRays  # noqa: E402


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strands", type=int, default=10000)
    ap.add_argument("--texels-per-strand", type=int, default=10)
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--atlas-rays", type=int, default=64)
    ap.add_argument("--near-fibres", type=float, default=ChiangSpec().near_fibres)
    ap.add_argument("--exitance", default="second_order")
    ap.add_argument("--lights", type=int, default=528)
    ap.add_argument("--timed-lights", type=int, default=16,
                    help="lights timed (the head's two, cycled): the pieces' set-up is "
                         "once for all of them")
    ap.add_argument("--pieces", type=int, nargs="+", default=[NEAR_SHADOW_PIECES, 1 << 20],
                    help="arc pieces a texel sharing a shadow ray (many: one a hit)")
    ap.add_argument("--shaded-fibres", type=float, default=0.0,
                    help="also time the shaded hits' correction (hair.chiang."
                         "shaded_fibres, footprints; above --near-fibres)")
    ap.add_argument("--gathered-fibres", type=float, default=ChiangSpec().gathered_fibres,
                    help="the near hits beyond --near-fibres to this reach gather at the "
                         "point and read their direct light from the texel (hair.chiang."
                         "gathered_fibres): their texel reads are timed")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/near_fibres_cost.json"))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        scene, texels = head_scene(Path(tmp), args.resolution)
    space = build_strand_space(head_hair(args.strands, "curly", seed=0),
                               args.texels_per_strand)
    tracer, fibres = hair_tracer(space, scene)
    f, t_m, t_h = scene.triangle_count, texels.count, space.count
    fibre = chiang_fibre(ChiangSpec(eumelanin=1.3), space)
    rays_to = near_hits_reach(args.near_fibres, args.gathered_fibres)
    strands = StrandRays(space, fibres, f, 0, near_field_reach(texels, rays_to),
                         near_field_reach(texels, args.shaded_fibres)
                         if args.shaded_fibres > rays_to else None,
                         near_field_reach(texels, args.near_fibres)
                         if args.gathered_fibres > args.near_fibres else None)
    t0 = time.perf_counter()
    g = gather_operator(scene, texels, tracer, args.atlas_rays, 0, foreign=strands)
    gather_s = time.perf_counter() - t0
    near, lit = strands.near(), strands.near_lit()
    hits = strands.shaded()
    fibre_hits = len(strands.rays()[0]) + near.count
    t0 = time.perf_counter()
    rays = near_fibre_rays(near, g.valid_rays, space, fibres, fibre, tracer, f,
                           HitMapper(scene, texels, tracer), t_m, 3)
    rays_s = time.perf_counter() - t0
    n_f = EXITANCE_TERMS[args.exitance]
    t = t_m + t_h
    k = len(LIGHTS)
    direct = np.random.default_rng(0).random((t + (n_f - 1) * t_h, k, 3)).astype(
        np.float32)

    def rows_of(a: int) -> slice:  # RayBlockProduct.coefficient_rows
        return slice(0, t) if a == 0 else slice(t + (a - 1) * t_h, t + a * t_h)
    t0 = time.perf_counter()
    reads = near_fibre_direct(near, g.valid_rays, direct, rows_of, t_m, t_h, n_f,
                              texel_frames(space) if needs_frames(args.exitance) else None)
    read_s = time.perf_counter() - t0
    lights = [LIGHTS[i % len(LIGHTS)] for i in range(args.timed_lights)]
    tiled = np.tile(direct, (1, len(lights) // k + 1, 1))[:, :len(lights)]  # a column a light
    gathered = {}
    if lit is not None:  # beyond near_fibres: rays at the point, the texel's direct light
        beyond = near.subset(~lit)
        rows = np.unique(beyond.row)
        into = (rows, np.zeros((len(rows), len(lights), 3), np.float32))
        t0 = time.perf_counter()
        texel_reads(beyond, g.valid_rays, tiled, rows_of, t_m, t_h, n_f,
                    texel_frames(space) if needs_frames(args.exitance) else None, None,
                    into, 1, "gathered fibres (texel reads)")
        s = time.perf_counter() - t0
        gathered = {"gathered_fibres": args.gathered_fibres, "hits": beyond.count,
                    "share_of_fibre_hits": beyond.count / max(fibre_hits, 1),
                    "s_per_light": s / len(lights),
                    "s_at_lights": s / len(lights) * args.lights}
        near = near.subset(lit)  # the rest shade their direct light at the point
    reads = near_fibre_direct(near, g.valid_rays, tiled, rows_of, t_m, t_h, n_f,
                              texel_frames(space) if needs_frames(args.exitance) else None)
    shaded = {}
    for pieces in args.pieces:  # one shadow ray a piece and light; many: one a hit
        t0 = time.perf_counter()
        stats: dict = {}
        near_fibre_shaded(near, g.valid_rays, space, fibres, fibre, tracer, lights,
                          args.exitance, (reads[0], reads[1].copy()), 4, pieces, stats)
        s = time.perf_counter() - t0
        shaded[str(pieces)] = {"s_per_light": s / len(lights),
                               "s_at_lights": s / len(lights) * args.lights,
                               "shadow_pieces": stats["shadow_pieces"]}
    far = {}
    if hits.count:  # the shaded hits' correction: texel reads out, the point's light in
        into = (np.arange(t_m), np.zeros((t_m, len(lights), 3), np.float32))
        stats = {}
        t0 = time.perf_counter()
        shaded_fibre_correction(hits, g.valid_rays, space, fibres, fibre, tracer, lights,
                                args.exitance, tiled, rows_of, t_m,
                                texel_frames(space) if needs_frames(args.exitance) else None,
                                5, into, stats)
        s = time.perf_counter() - t0
        far = {"shaded_fibres": args.shaded_fibres, "hits": hits.count,
               "share_of_fibre_hits": hits.count / max(fibre_hits, 1),
               "shadow_pieces": stats["shadow_pieces"], "s_per_light": s / len(lights),
               "s_at_lights": s / len(lights) * args.lights}
    per_light = shaded[str(args.pieces[0])]["s_per_light"]
    res = {"strands": args.strands, "atlas_texels": t_m, "strand_texels": t_h,
           "atlas_rays": args.atlas_rays, "near_fibres": args.near_fibres,
           "fibre_hits": fibre_hits, "near_hits": near.count,
           "near_share_of_atlas_rays": near.count / (t_m * args.atlas_rays),
           "near_share_of_fibre_hits": near.count / max(fibre_hits, 1),
           "gather_s": gather_s, "near_rays_s": rays_s, "near_rays": rays.stats,
           "texel_reads_s_per_light": read_s / k, "shaded_s_per_light": per_light,
           "shaded_s_at_lights": per_light * args.lights, "lights": args.lights,
           "timed_lights": len(lights), "shaded_by_pieces": shaded, "shaded_hits": far,
           "gathered_hits": gathered}
    print(f"{args.strands} strands, {t_m} atlas texels × {args.atlas_rays} rays: "
          f"{near.count} near hits at {args.near_fibres:g} footprints "
          f"({res['near_share_of_atlas_rays']:.3f} of the atlas's rays, "
          f"{res['near_share_of_fibre_hits']:.3f} of its fibre hits)")
    print(f"atlas gather {gather_s:.1f} s; near rays {rays_s:.1f} s ({rays.stats}); "
          f"texel reads {read_s / k:.2f} s a light")
    for pieces, v in shaded.items():
        print(f"shaded at the point, {pieces} pieces a texel ({v['shadow_pieces']} shadow "
              f"rays a light): {v['s_per_light']:.2f} s a light → "
              f"{v['s_at_lights'] / 60:.1f} min at {args.lights} lights")
    if far:
        print(f"shaded hits to {far['shaded_fibres']:g} footprints: {far['hits']} "
              f"({far['share_of_fibre_hits']:.3f} of the fibre hits), "
              f"{far['shadow_pieces']} shadow rays a light: {far['s_per_light']:.2f} s a "
              f"light → {far['s_at_lights'] / 60:.1f} min at {args.lights} lights")
    if gathered:
        print(f"gathered hits {args.near_fibres:g}–{args.gathered_fibres:g} footprints: "
              f"{gathered['hits']} ({gathered['share_of_fibre_hits']:.3f} of the fibre "
              f"hits), their texels' direct light {gathered['s_per_light']:.2f} s a light "
              f"→ {gathered['s_at_lights'] / 60:.1f} min at {args.lights} lights (their "
              f"rays are the near rays above)")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=2))
    print(f"wrote {args.out}")
    return res


if __name__ == "__main__":
    main()
