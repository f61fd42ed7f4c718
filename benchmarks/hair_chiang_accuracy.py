"""Benchmark: the Chiang-fibre fast path against the project's Chiang path tracer.

The dense procedural tangle (prtcore.scenes.hair.tangle, 1000 strands × 12 texels) under
a sun and a point light, one hair colour read as the hair volume's colour (σ_a from it,
Chiang et al. 2016 eq. 9), the default roughness, tilt and IOR. The fast path
(prtcore.transport.fibre_chiang: J direct samples, M gather rays per texel, the solve) is
compared on random strand texels with prtcore.reference.chiang, noise removed with two
independent halves. Printed and written to benchmarks/results/hair_chiang_accuracy.json,
per colour:

* ``isotropic``: transport carries each texel's direction-averaged outgoing radiance (the
  paper's storage, ``hair.chiang.exitance = "isotropic"``);
* ``linear``: plus a linear function of direction through every bounce (``"linear"``,
  the default); ``quadratic``: plus cos² θ (cos 2φ, sin 2φ) (``"quadratic"``); both
  solved as the bake solves them (prtcore.transport.low_rank);
* with ``--projected P``: ``linear_firstP`` and ``quadratic_firstP``, a diagnostic: the
  projected exitance through the first P bounces only, the direction average after
  (docs/hair.md: +19 % on light hair at P = 1, so a bake carries it through every bounce);
* ``isotropic_model``: the isotropic fast path against the path tracer that shades each
  hit toward a fresh direction (``exitance="isotropic"``): the gather, table and solve
  alone, without the approximation;
* ``isotropic_denoised`` (and for every exitance): after the plane fit of the strand
  texels' denoiser (``prtcore.transport.strand_denoise``, ``--neighbours`` k, irradiance
  taken against the fibre's sphere-averaged albedo); ``{exitance}_denoised_t2`` (what a
  bake takes for this fibre when asked to denoise) and ``_t12`` with the fibre-direction terms of
  ``--directions`` in the fit too;
* with ``--second-seed``: ``{exitance}_systematic``, the fast path's error with its own
  noise removed too (two bakes of other seeds), and ``{exitance}_noise``, that noise per
  texel (relative to the reference's RMS);
* with ``--mitsuba-rays R``: ``pathtracer_vs_mitsuba``, prtcore's Chiang path tracer
  against Mitsuba 3's own ``hair`` BSDF and path tracer (prtcore.reference.mitsuba_fibres:
  the polylines as B-spline curves), both sides' noise removed; and ``{exitance}_vs_mitsuba``,
  the fast path against Mitsuba directly.

``--scene hairball``: the bake's 10k hairball (``--strands`` 10000 then) under
``hairball_lights`` instead of the tangle. ``--scene head``: the curly hair of the hair +
mesh checks (``head_hair``, 500 strands, benchmarks/hair_mesh_chiang_accuracy.py) under
``head_lights``, without its head: which part of that benchmark's strand texels' error is
the hair's own.

Usage: python benchmarks/hair_chiang_accuracy.py [--scene tangle|hairball|head] [--strands 1000]
       [--texels-per-strand 12]
       [--rays 256] [--samples 16] [--paths 2048] [--texels 150]
       [--colors 0.8,0.6,0.4 0.3,0.2,0.1] [--mitsuba-rays 0] [--projected 1 2]
       [--second-seed] [--exitances isotropic linear quadratic second_order]
       [--directions t2 t12] [--neighbours 64]
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

from prtcore.core.sparse import RayBlockProduct  # noqa: E402
from prtcore.core.spec import ChiangSpec  # noqa: E402
from prtcore.receivers.strands import build_strand_space  # noqa: E402
from prtcore.reference.chiang import chiang_reference  # noqa: E402
from prtcore.reference.fibres import noise_corrected_error  # noqa: E402
from prtcore.scenes.hair import (  # noqa: E402
    hairball,
    hairball_lights,
    head_hair,
    head_lights,
    tangle,
    tangle_lights,
)
from prtcore.transport.fibre import hair_tracer  # noqa: E402
from prtcore.transport.fibre_chiang import (  # noqa: E402
    EXITANCE,
    chiang_direct,
    chiang_fibre,
    chiang_gather,
    chiang_operator,
    texel_albedo,
)
from prtcore.transport.low_rank import solve_low_rank  # noqa: E402
from prtcore.transport.solve import solve_indirect  # noqa: E402
from prtcore.transport.strand_denoise import (  # noqa: E402
    DEFAULT_NEIGHBOURS,
    DIRECTIONS,
    denoise_irradiance,
    neighbour_kernel,
)


def projected_first(product, rho, stacked, p: int, t: int) -> np.ndarray:
    """The diagnostic ``{exitance}_first{p}``: the first p bounces carry every exitance
    coefficient, the later ones the direction average alone (the same rays, weight and
    read 0 only). (T, K, 3) float32, not clamped."""
    leading = RayBlockProduct(product.row, product.col, product.weight[:, :1],
                              product.read[:, :1], product.t, product.threads)
    term, acc = stacked, None
    for _ in range(p):
        term = solve_indirect(None, rho, term, 1, 1.0, method="neumann", product=product,
                              out=term)[0]
        acc = term[:t].copy() if acc is None else acc + term[:t]
    tail = solve_indirect(None, rho[:t], np.ascontiguousarray(term[:t]), 64 - p, 1e-4,
                          method="neumann", product=leading)[0]
    return tail + acc


def fast_path(space, tracer, mesh, fibre, args, lights, seed: int = 0
              ) -> tuple[dict, dict]:
    """{exitance: indirect (T, K, 3)} and {exitance: seconds} (the gather shared); ``seed``
    offsets the gather's and the direct light's seeds (another bake of the same scene)."""
    t0 = time.perf_counter()
    term = chiang_gather(space, tracer, mesh, 0, args.rays, 2 + 10 * seed, fibre)
    gather = time.perf_counter() - t0
    out, seconds = {}, {}
    for exitance in args.exitances:
        t1 = time.perf_counter()
        direct = chiang_direct(space, tracer, lights, args.samples, 1 + 10 * seed, fibre,
                               exitance)
        product, rho = chiang_operator(space, term, fibre, args.rays, exitance)
        t_direct = time.perf_counter() - t1
        stacked = direct.reshape(-1, *direct.shape[2:])
        for p in [0] + ([] if exitance == "isotropic" else args.projected):
            t2 = time.perf_counter()
            name = exitance if p == 0 else f"{exitance}_first{p}"
            if p == 0:  # as the bake solves
                x = solve_low_rank(product, rho, stacked.copy(), 64, 1e-4,
                                   rows=space.count)[0]
            else:
                x = projected_first(product, rho, stacked.copy(), p, space.count)
            out[name] = np.maximum(x[:space.count], 0).astype(np.float64)
            seconds[name] = gather + t_direct + time.perf_counter() - t2
    return out, seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", choices=("tangle", "hairball", "head"), default="tangle")
    ap.add_argument("--strands", type=int, default=None,
                    help="1000 for the tangle, 10000 for the hairball")
    ap.add_argument("--neighbours", type=int, default=DEFAULT_NEIGHBOURS)
    ap.add_argument("--texels-per-strand", type=int, default=12)
    ap.add_argument("--rays", type=int, default=256)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--paths", type=int, default=2048)
    ap.add_argument("--texels", type=int, default=150)
    ap.add_argument("--colors", nargs="+", default=["0.8,0.6,0.4", "0.3,0.2,0.1"])
    ap.add_argument("--mitsuba-rays", type=int, default=0)
    ap.add_argument("--reference-seed", type=int, default=7,
                    help="the path tracer's seed (the isotropic model's: one more); a "
                         "figure that hangs on a few texels' rare paths moves with it")
    ap.add_argument("--second-seed", action="store_true",
                    help="also bake with other seeds: rows {exitance}_systematic (both "
                         "the reference's and the fast path's noise removed) and "
                         "{exitance}_noise (the fast path's own per-texel noise)")
    ap.add_argument("--exitances", nargs="+", choices=EXITANCE, default=list(EXITANCE))
    ap.add_argument("--directions", nargs="*", choices=DIRECTIONS, default=list(DIRECTIONS),
                    help="also denoise with these fibre-direction terms: rows "
                         "{exitance}_denoised_{direction}")
    ap.add_argument("--projected", type=int, nargs="*", default=[],
                    help="diagnostic: also carry linear/quadratic exitance through only "
                         "the first P bounces, the direction average after")
    args = ap.parse_args()
    results = {}
    for color in args.colors:
        rgb = [float(c) for c in color.split(",")]
        if args.scene == "hairball":
            hair, lights = hairball(args.strands or 10_000), hairball_lights()
        elif args.scene == "head":
            hair, lights = head_hair(args.strands or 500, "curly"), head_lights()
        else:
            hair, lights = tangle(args.strands or 1000), tangle_lights()
        hair = dataclasses.replace(hair, color=np.tile(rgb, (hair.point_count, 1)))
        space = build_strand_space(hair, args.texels_per_strand)
        tracer, mesh = hair_tracer(space)
        fibre = chiang_fibre(ChiangSpec(), space)
        fast, seconds = fast_path(space, tracer, mesh, fibre, args, lights)
        again = fast_path(space, tracer, mesh, fibre, args, lights, 1)[0] \
            if args.second_seed else {}
        kernels = {"": neighbour_kernel(space.position, args.neighbours)}
        for d in args.directions:
            kernels[f"_{d}"] = neighbour_kernel(space.position, args.neighbours,
                                                tangent=space.tangent, direction=d)
        rho = texel_albedo(fibre)
        for e in list(fast):
            for name, kernel in kernels.items():
                fast[f"{e}_denoised{name}"] = denoise_irradiance(
                    kernel, fast[e].astype(np.float32), rho).astype(np.float64)
                if again:
                    again[f"{e}_denoised{name}"] = denoise_irradiance(
                        kernel, again[e].astype(np.float32), rho).astype(np.float64)
        sel = np.random.default_rng(5).choice(space.count, args.texels, replace=False)
        t0 = time.perf_counter()
        ref = chiang_reference(space, tracer, mesh, 0, lights, sel, args.paths,
                               args.reference_seed, fibre.params, fibre.sigma_points)
        ref_s = time.perf_counter() - t0
        iso = chiang_reference(space, tracer, mesh, 0, lights, sel, args.paths,
                               args.reference_seed + 1, fibre.params, fibre.sigma_points,
                               exitance="isotropic") \
            if "isotropic" in fast else None
        rows = {e: noise_corrected_error(fast[e][sel], *ref) for e in fast}
        if "isotropic" in fast:
            rows["isotropic_model"] = noise_corrected_error(fast["isotropic"][sel], *iso)
        for e, x in again.items():  # the fast path's own noise removed too
            rows[f"{e}_systematic"] = noise_corrected_error((fast[e][sel], x[sel]), *ref)
            rows[f"{e}_noise"] = {
                "rrmse": float(np.sqrt(np.mean((fast[e][sel] - x[sel]) ** 2) / 2)
                               / np.sqrt(np.mean(((ref[0] + ref[1]) / 2) ** 2))),
                "raw_rrmse": float("nan"), "reference_noise": 0.0, "bias": float("nan"),
                "bias_se": float("nan")}
        if args.mitsuba_rays:
            from prtcore.reference.mitsuba_fibres import mitsuba_fibre_indirect
            mit = mitsuba_fibre_indirect(space, lights, sel, args.mitsuba_rays, 9,
                                         chiang=dataclasses.replace(
                                             fibre.params,
                                             sigma_a=tuple(fibre.sigma_texels[0])))
            rows["pathtracer_vs_mitsuba"] = noise_corrected_error(ref, *mit)
            for e in args.exitances:
                rows[f"{e}_vs_mitsuba"] = noise_corrected_error(fast[e][sel], *mit)
        print(f"colour {color} (σ_a {np.round(fibre.sigma_texels[0], 3).tolist()}), "
              f"{space.count} texels")
        for name, e in rows.items():
            print(f"  {name:20}: rRMSE {e['rrmse']:.3f} (raw {e['raw_rrmse']:.3f}, reference "
                  f"noise {e['reference_noise']:.3f})  bias {e['bias']:+.3f} ± "
                  f"{e['bias_se']:.3f}")
        print("  fast path " + ", ".join(f"{e} {s:.1f} s" for e, s in seconds.items())
              + f"; reference {ref_s:.1f} s for {args.texels} texels × {args.paths} paths "
              f"(load {os.getloadavg()[0]:.1f})")
        results[color] = {"errors": rows, "fast_seconds": seconds,
                          "reference_seconds": ref_s, "texels": space.count,
                          "sigma_a": fibre.sigma_texels[0].tolist()}
    out = ROOT / "benchmarks" / "results" / (
        "hair_chiang_accuracy.json" if args.scene == "tangle"
        else f"hair_chiang_accuracy_{args.scene}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"args": vars(args), "results": results}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
