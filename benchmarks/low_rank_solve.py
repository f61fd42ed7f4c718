"""Benchmark: the Chiang fibre's indirect solve on a basis of the light columns
(prtcore.transport.low_rank.solve_low_rank, what a bake runs) against the full-width
Neumann series of the same operator (what a bake ran before), per exitance.

The procedural tangle (prtcore.scenes.hair.tangle) coloured (0.8, 0.6, 0.4), K lights
drawn from a spec's default family (spot lights about the hair), M gather rays, J direct
samples, tolerance 1e-4 and up to 64 bounces. Both solves get the same direct light and
operator in one run, so their time ratio is measured on one machine state. Printed, per
exitance and rank tolerance: seconds and the ratio, bounces, the basis' size after each
bounce (and the basis each full-width bounce would have needed), and the error of the
basis solve against the full one (relative Frobenius; the worst and the median light;
the 99th percentile over texels of the mean over lights).
Written to benchmarks/results/low_rank_solve.json.

Usage: python benchmarks/low_rank_solve.py [--strands 1000] [--lights 256] [--rays 256]
       [--samples 16] [--exitance isotropic linear quadratic] [--tolerances 1e-2 3e-3]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from prtcore.core.spec import ChiangSpec, parse_spec  # noqa: E402
from prtcore.emitters.families import sample_configurations  # noqa: E402
from prtcore.receivers.strands import build_strand_space  # noqa: E402
from prtcore.scenes.hair import tangle  # noqa: E402
from prtcore.transport.fibre import hair_tracer  # noqa: E402
from prtcore.transport.fibre_chiang import (  # noqa: E402
    chiang_direct,
    chiang_fibre,
    chiang_gather,
    chiang_operator,
)
from prtcore.transport.low_rank import RANK_TOLERANCE, solve_low_rank  # noqa: E402
from prtcore.transport.solve import solve_indirect  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strands", type=int, default=1000)
    ap.add_argument("--lights", type=int, default=256)
    ap.add_argument("--rays", type=int, default=256)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--exitance", nargs="+", default=["isotropic", "linear", "quadratic"])
    ap.add_argument("--tolerances", type=float, nargs="+", default=[RANK_TOLERANCE])
    args = ap.parse_args()
    hair = tangle(args.strands)
    hair = dataclasses.replace(hair, color=np.tile([0.8, 0.6, 0.4], (hair.point_count, 1)))
    space = build_strand_space(hair, 12)
    tracer, mesh = hair_tracer(space)
    fibre = chiang_fibre(ChiangSpec(), space)
    b = hair.bounds()
    lights, _ = sample_configurations(parse_spec({"lights": {"count": args.lights}}).lights,
                                      b.mean(axis=0), float(np.linalg.norm(b[1] - b[0]) / 2))
    term = chiang_gather(space, tracer, mesh, 0, args.rays, 2, fibre)
    t = space.count
    results = {}
    for exitance in args.exitance:
        product, rho = chiang_operator(space, term, fibre, args.rays, exitance)
        t0 = time.perf_counter()
        direct = chiang_direct(space, tracer, lights, args.samples, 1, fibre, exitance)
        direct_s = time.perf_counter() - t0
        stacked = direct.reshape(-1, *direct.shape[2:])
        t0 = time.perf_counter()
        full, n_full, _, _ = solve_indirect(None, rho, stacked.copy(), 64, 1e-4,
                                            method="neumann", product=product)
        full_s = time.perf_counter() - t0
        full = full[:t]
        row = {"direct_seconds": direct_s, "full_seconds": full_s, "full_bounces": n_full,
               "basis": {}}
        print(f"{exitance}: {t} texels × {len(lights)} lights; direct {direct_s:.1f} s; "
              f"full-width solve {full_s:.1f} s, {n_full} bounces")
        for tol in args.tolerances:
            t0 = time.perf_counter()
            got, n, _, stats = solve_low_rank(product, rho, stacked.copy(), 64, 1e-4,
                                              rows=t, rank_tolerance=tol)
            secs = time.perf_counter() - t0
            per_light = (np.linalg.norm(got - full, axis=(0, 2))
                         / np.maximum(np.linalg.norm(full, axis=(0, 2)), 1e-30))
            per_texel = (np.abs(got - full).mean(axis=1).sum(axis=-1)
                         / np.maximum(np.abs(full).mean(axis=1).sum(axis=-1), 1e-30))
            err = {"relative": float(np.linalg.norm(got - full) / np.linalg.norm(full)),
                   "worst_light": float(per_light.max()),
                   "median_light": float(np.median(per_light)),
                   "texel_p99": float(np.percentile(per_texel, 99))}
            row["basis"][str(tol)] = {"seconds": secs, "speedup": full_s / secs,
                                      "bounces": n, "ranks": stats["ranks"],
                                      "needed": stats["needed"], "error": err}
            print(f"  rank tolerance {tol:g}: {secs:.1f} s ({full_s / secs:.1f}× faster), "
                  f"{n} bounces, basis {stats['ranks'][:8]}… (needed at full width "
                  f"{stats['needed']}); error {err['relative']:.1e} "
                  f"(worst light {err['worst_light']:.1e}, median {err['median_light']:.1e}, "
                  f"texel p99 {err['texel_p99']:.1e})")
        results[exitance] = row
    out = ROOT / "benchmarks" / "results" / "low_rank_solve.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"args": vars(args), "texels": t, "results": results},
                              indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
