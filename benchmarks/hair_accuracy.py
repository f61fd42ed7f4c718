"""Benchmark: the fast diffuse-fibre transport against the project's fibre path tracer.

A dense procedural hairball (prtcore.scenes.hair.hairball) under a sun and a point light.
The fast path (prtcore.transport.fibre: direct with J samples per texel, the fibre gather
with M rays per texel, the solve) is compared on a random subset of strand texels with
prtcore.reference.fibres (each hit shaded with its own radial normal), noise removed with
two independent half estimates (noise² ≈ mean((a − b)²)/4). Printed and written to
benchmarks/results/hair_accuracy.json, per variant:

* ``constant``: radially constant outgoing radiance in every bounce (the paper's storage);
* ``harmonic``: the direct light's first azimuthal harmonic kept in the first bounce;
* ``all_bounces``: every texel's (mean, cos, sin) through every bounce (``hair.harmonics``);
* ``all_bounces_h2``: the same plus the direct light's second azimuthal harmonic in the
  first bounce (``harmonic_first_bounce(..., first=2)``);
* ``harmonic_denoised``, ``all_bounces_denoised``: those two after the bake's denoising
  of the strand texels (``prtcore.transport.strand_denoise``, ``--neighbours`` k: a local
  linear fit); ``harmonic_averaged``: the harmonic variant under the plain kernel average
  of the same k neighbours (the filter before the local fit);
* with ``--second-seed``: ``harmonic_denoised_seed2``, the denoised harmonic variant
  with independent seeds; ``harmonic_systematic``, the harmonic variant's error shared by
  two fast paths with independent seeds (both runs' noise removed as the reference's is),
  and ``harmonic_noise``, the fast path's own per-texel noise relative to the light's RMS;
* ``model``: the constant variant against a reference that makes the same radially constant
  assumption (``radially_averaged=True``) — what the gather and solve themselves cost;
* with ``--mitsuba-samples S``: ``harmonic_vs_mitsuba`` and ``pathtracer_vs_mitsuba``,
  against Mitsuba 3 (prtcore.reference.mitsuba_fibres: round curves, its own path
  tracer) on the first ``--mitsuba-texels`` of the subset, both references' noise removed.

The hair has one colour (0.8, 0.6, 0.4) so that Mitsuba needs one BSDF.

``--scene hairball`` measures the bake's own test asset instead of the tangle: the 10k
hairball of ``prtcore.scenes.hair.hairball`` (``--strands``, default 10000 then) under
``hairball_lights`` (the tangle's sun and side point light, moved outside the ball). With
``--rays 64 --samples 4 --texels-per-strand 10`` the fast path runs at the bake's defaults.

``--max-bounces N`` limits the fast path's solves and the references' paths to N bounces
(1: the first bounce alone — where its error comes from).

Usage: python benchmarks/hair_accuracy.py [--scene tangle|hairball] [--strands 1000]
       [--rays 256] [--paths 1024] [--texels 300] [--texels-per-strand 4] [--mitsuba-samples 0]
       [--mitsuba-texels 100] [--max-bounces 64]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from prtcore.receivers.strands import build_strand_space  # noqa: E402
from prtcore.reference.fibres import fibre_reference, noise_corrected_error  # noqa: E402
from prtcore.scenes.hair import hairball, hairball_lights, tangle, tangle_lights  # noqa: E402
from prtcore.transport.fibre import (  # noqa: E402
    fibre_direct,
    fibre_gather,
    hair_tracer,
    harmonic_first_bounce,
)
from prtcore.transport.solve import solve_indirect  # noqa: E402
from prtcore.transport.strand_denoise import (  # noqa: E402
    DEFAULT_NEIGHBOURS,
    denoise_irradiance,
    neighbour_kernel,
)


def _second_run(space, tracer, mesh, lights, args, harm, sel, ref, kernel) -> dict:
    """The harmonic variant again with independent seeds: the error the two runs share
    against the reference, the fast path's own noise (rows of the same form), and the
    second run denoised by ``kernel`` (the bake's error with another seed)."""
    direct = fibre_direct(space, tracer, lights, args.samples, seed=11, harmonics=2,
                          estimator=args.direct)
    if args.source_neighbours > 1:
        denoise_irradiance(neighbour_kernel(space.position, args.source_neighbours),
                           direct.mean, space.albedo)
    term = fibre_gather(space, tracer, mesh, 0, args.rays, seed=12, harmonics=1)
    again, *_ = solve_indirect(term.matrix, space.albedo, direct.mean, args.max_bounces,
                               1e-4, first_bounce=harmonic_first_bounce(term, direct))
    a, b = harm[sel].astype(float), again[sel].astype(float)
    shared = noise_corrected_error((a, b), *ref)
    rms = float(np.sqrt(np.mean(((ref[0] + ref[1]) / 2) ** 2)))
    own = float(np.sqrt(np.mean((a - b) ** 2) / 2)) / rms
    again_d = denoise_irradiance(kernel, again.copy(), space.albedo)
    return {"harmonic_denoised_seed2": noise_corrected_error(again_d[sel].astype(float),
                                                             *ref),
            "harmonic_systematic": shared,
            "harmonic_noise": {"rrmse": own, "raw_rrmse": own, "reference_noise": 0.0,
                               "bias": 0.0, "bias_se": 0.0}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", choices=("tangle", "hairball"), default="tangle")
    ap.add_argument("--strands", type=int, default=None,
                    help="1000 for the tangle, 10000 for the hairball")
    ap.add_argument("--rays", type=int, default=256)
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--direct", choices=("facing", "sampled"), default="facing",
                    help="the direct light's estimator (hair.direct); --samples: its arc "
                         "samples (facing) or surface points (sampled) per texel")
    ap.add_argument("--paths", type=int, default=1024)
    ap.add_argument("--texels", type=int, default=300)
    ap.add_argument("--texels-per-strand", type=int, default=4)
    ap.add_argument("--mitsuba-samples", type=int, default=0)
    ap.add_argument("--mitsuba-texels", type=int, default=100)
    ap.add_argument("--max-bounces", type=int, default=64)
    ap.add_argument("--neighbours", type=int, default=DEFAULT_NEIGHBOURS)
    ap.add_argument("--source-neighbours", type=int, default=0,
                    help="k > 1: the direct light's mean filtered over k neighbours "
                         "before the solves (experiment)")
    ap.add_argument("--second-seed", action="store_true",
                    help="run the harmonic fast path again with other seeds: its own noise")
    args = ap.parse_args()
    nb = args.max_bounces
    if args.scene == "hairball":
        hair, lights = hairball(args.strands or 10_000), hairball_lights()
    else:
        hair, lights = tangle(args.strands or 1000), tangle_lights()
    hair = dataclasses.replace(hair, color=np.tile([0.8, 0.6, 0.4], (hair.point_count, 1)))
    space = build_strand_space(hair, args.texels_per_strand)
    tracer, mesh = hair_tracer(space)
    t0 = time.perf_counter()
    direct = fibre_direct(space, tracer, lights, args.samples, seed=1, harmonics=2,
                          estimator=args.direct)
    if args.source_neighbours > 1:
        denoise_irradiance(neighbour_kernel(space.position, args.source_neighbours),
                           direct.mean, space.albedo)
    term = fibre_gather(space, tracer, mesh, 0, args.rays, seed=2, all_bounces=True,
                        harmonics=2)
    const, *_ = solve_indirect(term.matrix, space.albedo, direct.mean, nb, 1e-4)
    t1 = time.perf_counter()
    harm1 = dataclasses.replace(term, harmonics=term.harmonics[:2])
    harm, *_ = solve_indirect(term.matrix, space.albedo, direct.mean, nb, 1e-4,
                              first_bounce=harmonic_first_bounce(harm1, direct))
    t2 = time.perf_counter()
    every, *_ = solve_indirect(
        term.block, np.tile(space.albedo, (3, 1)),
        np.concatenate([direct.mean, direct.harmonics[0], direct.harmonics[1]]), nb, 1e-4,
        method="neumann")
    every = np.maximum(every[:space.count], 0)
    t = space.count
    rows2, val2 = harmonic_first_bounce(term, direct, first=2)
    every2, *_ = solve_indirect(
        term.block, np.tile(space.albedo, (3, 1)),
        np.concatenate([direct.mean, direct.harmonics[0], direct.harmonics[1]]), nb, 1e-4,
        method="neumann", first_bounce=(rows2, val2))
    every2 = np.maximum(every2[:t], 0)
    kernel = neighbour_kernel(space.position, args.neighbours)
    harm_d = denoise_irradiance(kernel, harm.copy(), space.albedo)
    harm_a = denoise_irradiance(neighbour_kernel(space.position, args.neighbours,
                                                 local_linear=False), harm.copy(),
                                space.albedo)
    every_d = denoise_irradiance(kernel, every.copy(), space.albedo)
    sel = np.random.default_rng(0).choice(space.count, args.texels, replace=False)
    ref = fibre_reference(space, tracer, mesh, 0, lights, sel, args.paths, seed=7,
                          max_depth=nb)
    t3 = time.perf_counter()
    avg = fibre_reference(space, tracer, mesh, 0, lights, sel, args.paths, seed=8,
                          max_depth=nb, radially_averaged=True)
    rows = {"constant": noise_corrected_error(const[sel].astype(float), *ref),
            "harmonic": noise_corrected_error(harm[sel].astype(float), *ref),
            "all_bounces": noise_corrected_error(every[sel].astype(float), *ref),
            "all_bounces_h2": noise_corrected_error(every2[sel].astype(float), *ref),
            "harmonic_denoised": noise_corrected_error(harm_d[sel].astype(float), *ref),
            "all_bounces_denoised": noise_corrected_error(every_d[sel].astype(float), *ref),
            "harmonic_averaged": noise_corrected_error(harm_a[sel].astype(float), *ref),
            **(_second_run(space, tracer, mesh, lights, args, harm, sel, ref, kernel)
               if args.second_seed else {}),
            "model": noise_corrected_error(const[sel].astype(float), *avg)}
    if args.mitsuba_samples:
        from prtcore.reference.mitsuba_fibres import mitsuba_fibre_indirect

        m = args.mitsuba_texels
        t4 = time.perf_counter()
        mit = mitsuba_fibre_indirect(space, lights, sel[:m], args.mitsuba_samples, seed=9)
        print(f"mitsuba {time.perf_counter() - t4:.1f} s for {m} texels × "
              f"{args.mitsuba_samples} rays")
        rows["harmonic_vs_mitsuba"] = noise_corrected_error(harm[sel[:m]].astype(float),
                                                            *mit)
        rows["pathtracer_vs_mitsuba"] = noise_corrected_error((ref[0][:m], ref[1][:m]), *mit)
    for name, e in rows.items():
        print(f"{name:20}: rRMSE {e['rrmse']:.3f} (raw {e['raw_rrmse']:.3f}, reference noise "
              f"{e['reference_noise']:.3f})  bias {e['bias']:+.3f} ± {e['bias_se']:.3f}")
    print(f"texels {space.count}, fast path {t1 - t0:.1f} s (+{t2 - t1:.1f} s harmonic "
          f"solve), reference {t3 - t2:.1f} s for {args.texels} texels × {args.paths} paths "
          f"(load {os.getloadavg()[0]:.1f})")
    out = ROOT / "benchmarks" / "results" / (
        "hair_accuracy.json" if args.scene == "tangle" else f"hair_accuracy_{args.scene}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"args": vars(args), "errors": rows,
                               "fast_seconds": t1 - t0, "reference_seconds": t3 - t2},
                              indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
