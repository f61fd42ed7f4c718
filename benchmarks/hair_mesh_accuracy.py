"""Benchmark: the hair + mesh transport against the project's hair + mesh path tracer.

A head (prtcore.scenes.hair.write_head: an icosphere of 10 cm, through the glTF intake and
its lightmap unwrap) with curly or straight hair (head_hair, ``--style``), under a sun and
a point light. The fast
path (prtcore.transport.hair_mesh: the surface gather whose rays reach the strand texels,
the fibre gather whose rays reach the atlas texels, one solve) is compared on random
subsets of the atlas texels and of the strand texels with
prtcore.reference.hair_mesh (every fibre hit shaded with its own round-fibre normal, mesh
hits with their own normal and albedo), the reference's noise removed with two independent
halves; for the ``hair.harmonics`` variants (first_bounce: the hair's direct first
harmonic in the first bounce only; all_bounces: every strand texel's mean, cos and sin in
every bounce; mesh_bounces, what a hair + mesh bake uses by default: the same state, the
harmonics fed by the direct light and the mesh only), each with and without the near
field of the hair's rays that hit the scalp close by (``--no-hair-near`` drops it), and
with the near field after the bake's denoising of the strand texels
(``prtcore.transport.strand_denoise``, ``--neighbours`` k: rows "…, denoised"). Also
printed: how much of each receiver's indirect light the other brings (the
hair-alone and head-alone bakes on the same receivers), which says the two-way interaction
is there and how large it is.

The atlas is 64² by default, as the figures in docs/hair.md were measured. A bake's is
512² on this head (``--resolution 512``), and the coarse atlas reads the scalp brighter:
the 10k curly head's filtered scalp is +2.1 ± 0.7 % on 64² and +0.1 / −0.1 % on 512²
(docs/hair.md, 2026-12-06).

Printed and written to benchmarks/results/hair_mesh_accuracy.json.

Usage: python benchmarks/hair_mesh_accuracy.py [--strands 2000] [--rays 256]
       [--paths 1024] [--texels 300] [--resolution 64] [--texels-per-strand 8]
       [--seed 0] [--bake-seeds 0,1,2,3] [--variants mesh_bounces] [--near-only]
       [--no-alone] [--atlas-radii 0.75,1.5,2.5] [--style straight]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from prtcore.core.spec import TransportSpec, parse_spec  # noqa: E402
from prtcore.intake.hair import hair_scene  # noqa: E402
from prtcore.intake.points import place_measurement_points  # noqa: E402
from prtcore.pipeline import run_intake  # noqa: E402
from prtcore.receivers.smoothing import smooth_texels, smoothing_operators  # noqa: E402
from prtcore.receivers.strands import build_strand_space  # noqa: E402
from prtcore.reference.fibres import noise_corrected_error  # noqa: E402
from prtcore.reference.hair_mesh import hair_mesh_reference  # noqa: E402
from prtcore.scenes.hair import head_hair, head_lights, write_head  # noqa: E402
from prtcore.transport.fibre import hair_tracer  # noqa: E402
from prtcore.transport.hair_mesh import bake_hair_mesh_dataset  # noqa: E402
from prtcore.transport.strand_denoise import (  # noqa: E402
    DEFAULT_NEIGHBOURS,
    denoise_dataset,
)

LIGHTS = head_lights()
#: the coverage above which atlas texels are counted in the "mesh_covered" error
COVERED = 0.1


def head_scene(tmp: Path, resolution: int):
    """(scene, texels) of the test head through the glTF intake (unwrapped, TEXCOORD_1)."""
    spec = parse_spec({"atlas": {"resolution": resolution},
                       "measurement_points": {"count": 32}})
    intake = run_intake(write_head(tmp / "head.glb"), spec, quiet=True)
    return intake.scene, intake.texels


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strands", type=int, default=2000)
    ap.add_argument("--rays", type=int, default=256)
    ap.add_argument("--paths", type=int, default=1024)
    ap.add_argument("--texels", type=int, default=300, help="of each kind")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--texels-per-strand", type=int, default=8)
    ap.add_argument("--style", choices=("curly", "straight"), default="curly",
                    help="the head's hair (scenes.hair.head_hair)")
    ap.add_argument("--samples", type=int, default=8,
                    help="the mesh's direct samples J (transport.direct_samples), and the "
                         "hair's with --direct sampled")
    ap.add_argument("--direct", choices=("facing", "sampled"), default="facing",
                    help="the hair's direct-light estimator (hair.direct; facing takes "
                         "its default arc samples)")
    ap.add_argument("--seed", type=int, default=0,
                    help="draws the head of hair, the compared texels and (without "
                         "--bake-seeds) the bake's transport.seed")
    ap.add_argument("--bake-seeds", default=None,
                    help="comma-separated transport seeds: each variant is baked once per "
                         "seed against one reference, and a row '…, mean of N bake seeds' "
                         "compares their mean (the bias that does not average out over "
                         "bakes, from the bias of one bake, whose noise the solve and the "
                         "denoiser correlate over neighbouring texels)")
    ap.add_argument("--variants", default="first_bounce,mesh_bounces,all_bounces",
                    help="comma-separated hair.harmonics variants to bake, each with "
                    "optional tags: +turnDEG (turn_bounces' threshold, degrees), "
                    "+texel_mean (the mesh rows read a fibre hit as its texel's mean, as "
                    "before 2026-12-05), +clamp (between texel centres, held at the root's)")
    ap.add_argument("--atlas-radii", default="",
                    help="comma-separated radii (texels) of the surface pipeline's "
                         "seam-aware lightmap filter applied to the atlas rows after the "
                         "strand texels' denoising (variants '…, atlas smoothed r')")
    ap.add_argument("--near-only", action="store_true",
                    help="skip the variants without the hair's near field")
    ap.add_argument("--no-alone", action="store_true",
                    help="skip the hair-alone and head-alone bakes (what each receiver "
                         "brings the other)")
    ap.add_argument("--neighbours", type=int, default=DEFAULT_NEIGHBOURS,
                    help="k of the strand texels' denoising (variants '…, denoised')")
    ap.add_argument("--max-bounces", type=int, default=64,
                    help="the fast path's solve and the reference's paths stop after N")
    ap.add_argument("--arc-subdivision", type=int, default=1,
                    help="hair.arc_subdivision S: each strand texel transported as S "
                         "pieces (the bake's default with a mesh is 2)")
    ap.add_argument("--orders", type=int, default=1,
                    help="azimuthal harmonics H carried by all_bounces")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/hair_mesh_accuracy.json"))
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        scene, texels = head_scene(Path(tmp), a.resolution)
    hair = head_hair(a.strands, a.style, seed=a.seed)
    space = build_strand_space(hair, a.texels_per_strand)
    tracer, fibres = hair_tracer(space, scene)
    points = place_measurement_points(hair_scene(hair), parse_spec(
        {"measurement_points": {"count": 16, "placement": "hull"}}).measurement_points)
    seeds = [a.seed] if a.bake_seeds is None else [int(x) for x in a.bake_seeds.split(",")]
    specs = {s: TransportSpec(gather_rays=a.rays, direct_samples=a.samples, seed=s,
                              max_bounces=a.max_bounces) for s in seeds}
    spec = specs[seeds[0]]
    t_m, t_h = texels.count, space.count
    rng = np.random.default_rng(a.seed + 11)
    mesh_rows = np.sort(rng.choice(t_m, min(a.texels, t_m), replace=False))
    hair_rows = np.sort(t_m + rng.choice(t_h, min(a.texels, t_h), replace=False))
    rows = np.concatenate([mesh_rows, hair_rows])
    t1 = time.perf_counter()
    ra, rb = hair_mesh_reference(scene, texels, space, tracer, fibres, LIGHTS, rows,
                                 a.paths, a.seed + 101, max_depth=a.max_bounces)
    ref_s = time.perf_counter() - t1
    nm = len(mesh_rows)
    # texels that cover at least COVERED of their square: a sliver at a chart's edge (2 %
    # covered) is sampled over a different part of its triangle by the gather's origins
    # than by the path tracer's regions, where the light under hair changes within a mm
    big = texels.coverage[mesh_rows] >= COVERED
    result = {"strands": a.strands, "mesh_texels": t_m, "strand_texels": t_h,
              "rays": a.rays, "direct_samples": a.samples, "direct": a.direct,
              "paths": a.paths, "seed": a.seed, "bake_seeds": seeds,
              "arc_subdivision": a.arc_subdivision,
              "reference_seconds": ref_s, "variants": {}}
    def errors(values: np.ndarray, seconds: float) -> dict:
        """A variant's rows: its (T, K, 3) indirect light at the sampled texels against
        the reference, per receiver."""
        fast = values[rows].astype(np.float64)
        return {"seconds": seconds,
                "mesh": noise_corrected_error(fast[:nm], ra[:nm], rb[:nm]),
                "mesh_covered": noise_corrected_error(fast[:nm][big], ra[:nm][big],
                                                      rb[:nm][big]),
                "hair": noise_corrected_error(fast[nm:], ra[nm:], rb[nm:]),
                "all": noise_corrected_error(fast, ra, rb)}

    radii = [float(r) for r in a.atlas_radii.split(",") if r]
    smoothers = smoothing_operators(texels, tuple(radii)) if radii else []
    kept = None
    for variant in a.variants.split(","):
        harmonics, *tags = variant.split("+")  # +texel_mean, +clamp, +turnDEG
        turn = dict(("straight_turn", float(x[4:])) for x in tags if x.startswith("turn"))
        arc_reads = ("clamp" if "clamp" in tags else None if "texel_mean" in tags
                     else "extrapolate")
        sums: dict[str, np.ndarray] = {}
        for seed in seeds:
            tag = f" (bake seed {seed})" if len(seeds) > 1 else ""
            for near in (1.0,) if a.near_only else (1.0, 0.0):
                t0 = time.perf_counter()
                data = bake_hair_mesh_dataset(scene, texels, space, fibres, points, tracer,
                                              LIGHTS, spec=specs[seed], harmonics=harmonics,
                                              hair_near=near, orders=a.orders,
                                              direct_estimator=a.direct,
                                              arc_reads=arc_reads,
                                              arc_subdivision=a.arc_subdivision, **turn)
                name = f"{variant}{'' if near else ', no hair near field'}"
                result["variants"][name + tag] = errors(data.indirect,
                                                        time.perf_counter() - t0)
                fs = data.stats["fibre"]  # how dense the hair is (adaptive's rule)
                result["fibre_share"] = fs["fibre_hits"] / max(fs["rays"], 1)
                sums[name] = sums.get(name, 0) + data.indirect[rows].astype(np.float64)
                if near:  # and after the bake's denoising of the strand texels
                    den = denoise_dataset(dataclasses.replace(
                        data, indirect=data.indirect.copy()), space, a.neighbours,
                        first_row=t_m)
                    result["variants"][f"{variant}, denoised{tag}"] = errors(
                        den.indirect, time.perf_counter() - t0)
                    sums[f"{variant}, denoised"] = sums.get(
                        f"{variant}, denoised", 0) + den.indirect[rows].astype(np.float64)
                    for r, w in zip(radii, smoothers, strict=True):
                        sm = den.indirect.copy()
                        sm[:t_m] = smooth_texels(texels, den.indirect[:t_m], operator=w)
                        name_r = f"{variant}, denoised, atlas smoothed {r:g}"
                        result["variants"][name_r + tag] = errors(sm, time.perf_counter() - t0)
                        sums[name_r] = sums.get(name_r, 0) + sm[rows].astype(np.float64)
                if harmonics == "mesh_bounces" and near and kept is None:  # the default
                    kept = data
        if len(seeds) > 1:
            for name, total in sums.items():
                mean = np.zeros((rows.max() + 1, *total.shape[1:]))
                mean[rows] = total / len(seeds)
                result["variants"][f"{name}, mean of {len(seeds)} bake seeds"] = errors(
                    mean, 0.0)
    if not a.no_alone and kept is not None:  # what the other receiver brings: the
        # same receivers without it
        alone_h = _hair_alone(space, points, spec)
        alone_m = _head_alone(scene, texels, points, spec)
        both = kept.indirect.astype(np.float64)
        result["hair_indirect_from_head"] = float(1 - alone_h.mean() / both[t_m:].mean())
        # a convex head alone has no indirect light: all of it then comes off the hair
        result["head_indirect_from_hair"] = float(1 - alone_m.mean() / both[:t_m].mean())
    print(f"{a.strands} strands × {a.texels_per_strand} texels, {t_m} atlas texels, "
          f"M = {a.rays}, J = {a.samples}; {len(mesh_rows)} + {len(hair_rows)} texels × "
          f"{a.paths} reference paths ({ref_s:.1f} s)")
    print(f"rRMSE / bias ± its standard error; atlas texels all ({nm}) and covering ≥ "
          f"{100 * COVERED:.0f} % of their square ({int(big.sum())})")
    print(f"{'variant':34s} {'atlas, all':>22s} {'atlas, covered':>22s} "
          f"{'strand texels':>22s}")
    for name, v in result["variants"].items():
        cells = [f"{100 * v[k]['rrmse']:4.1f} % / {100 * v[k]['bias']:+5.1f} ± "
                 f"{100 * v[k]['bias_se']:.1f} %" for k in ("mesh", "mesh_covered", "hair")]
        print(f"{name:34s} {cells[0]:>22s} {cells[1]:>22s} {cells[2]:>22s}  "
              f"({v['seconds']:.1f} s)")
    if "fibre_share" in result:
        print(f"share of the fibre gather's rays that meet a fibre: "
              f"{result['fibre_share']:.3f}")
    if "hair_indirect_from_head" in result:
        print(f"hair indirect from the head: {100 * result['hair_indirect_from_head']:.1f} "
              f"%, head indirect from the hair: {100 * result['head_indirect_from_hair']:.1f} %")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(result, indent=1))
    return result


def _hair_alone(space, points, spec):
    from prtcore.transport.hair import bake_hair_dataset

    tracer, _ = hair_tracer(space)
    return bake_hair_dataset(space, points, tracer, LIGHTS, (), spec).indirect.astype(
        np.float64)


def _head_alone(scene, texels, points, spec):
    from prtcore.core.raytrace import RayTracer
    from prtcore.transport.dataset import bake_dataset

    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    return bake_dataset(scene, texels, points, LIGHTS, (), spec, tracer=tracer,
                        operators=("surface",)).indirect.astype(np.float64)


if __name__ == "__main__":
    main()
