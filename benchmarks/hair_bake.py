"""Benchmark: the dataset of a hair bake — the 10k-strand hairball, K = 128 — and memory.

The procedural hairball (prtcore.scenes.hair.hairball: 16 segments per strand, 10 texels
per strand) baked through prtcore.hairbake's stages with K training + 16 held-out point
lights: strand texels, hull measurement points, then the dataset
(prtcore.transport.hair.bake_hair_dataset: fibre gather, direct at points and fibres, the
solve). Prints and writes (benchmarks/results/hair_bake.json): stage seconds, the
dataset's seconds, rays traced, the bake's memory estimate
(prtcore.hairbake.check_hair_memory) and the measured peak RSS of the process, and the
machine's load average (the 2-core machine is shared: timings under load are upper
bounds).

``--estimate-only`` stops after the memory estimate (no transport): for 140k strands,
whose bake may not fit. ``--path-tracer-texels N`` (instead of the dataset) times the
fibre path tracer (prtcore.reference.fibres) on N random texels × 256 paths for one point
light and prints the time per path and the per-texel relative noise it reaches.

Usage: python benchmarks/hair_bake.py [--strands 10000] [--lights 128] [--rays 64]
       [--estimate-only] [--path-tracer-texels N] [--direct facing|sampled]
       [--direct-samples auto|N]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from prtcore.core.limits import IntakeLimits  # noqa: E402
from prtcore.core.progress import StageTimer  # noqa: E402
from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.emitters.families import sample_configurations  # noqa: E402
from prtcore.hairbake import check_hair_memory, hair_spec, run_hair_intake  # noqa: E402
from prtcore.io.hair import write_hair  # noqa: E402
from prtcore.scenes.hair import hairball  # noqa: E402
from prtcore.transport.fibre import hair_tracer  # noqa: E402
from prtcore.transport.hair import bake_hair_dataset  # noqa: E402
from prtcore.transport.strand_denoise import denoise_dataset  # noqa: E402


def peak_rss() -> int:
    """Peak resident set size of this process, bytes (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strands", type=int, default=10_000)
    ap.add_argument("--lights", type=int, default=128)
    ap.add_argument("--rays", type=int, default=64)
    ap.add_argument("--estimate-only", action="store_true")
    ap.add_argument("--path-tracer-texels", type=int, default=0)
    ap.add_argument("--direct", choices=("facing", "sampled"), default="facing",
                    help="hair.direct, the direct light's estimator")
    ap.add_argument("--direct-samples", default="auto", help="hair.direct_samples")
    args = ap.parse_args()
    tmp = ROOT / "benchmarks" / "results" / f"hairball-{args.strands}.hair"
    tmp.parent.mkdir(parents=True, exist_ok=True)
    write_hair(tmp, hairball(strands=args.strands, seed=0))
    spec = hair_spec(parse_spec({
        "hair": {"texels_per_strand": 10, "direct": args.direct,
                 "direct_samples": (args.direct_samples if args.direct_samples == "auto"
                                    else int(args.direct_samples))},
        "lights": {"count": args.lights, "holdout": 16,
                   "families": [{"type": "point", "position": {"shell": [1.5, 3.0]},
                                 "intensity": {"uniform": [0.5, 2.0]}}]},
        "transport": {"gather_rays": args.rays}}))
    timer = StageTimer(quiet=True)
    limits = IntakeLimits.from_env()
    intake = run_hair_intake(tmp, spec, timer, limits)
    space = intake.texels
    estimate = check_hair_memory(tmp, space, spec, 1 << 62)
    row = {"strands": args.strands, "texels": space.count, "lights": args.lights + 16,
           "gather_rays": args.rays, "direct": spec.hair.direct,
           "direct_samples": spec.hair.direct_samples, "estimate_bytes": estimate,
           "limit_bytes": limits.max_bake_bytes, "fits_limit": estimate <= limits.max_bake_bytes}
    print(f"{args.strands} strands: {space.count} strand texels ({space.width}×{space.height}),"
          f" K = {args.lights} + 16: memory estimate {estimate / 2**30:.2f} GiB "
          f"(limit {limits.max_bake_bytes / 2**30:.0f} GiB)", flush=True)
    if args.path_tracer_texels:
        from prtcore.core.scene import Light
        from prtcore.reference.fibres import fibre_reference

        tracer, mesh = hair_tracer(space)
        tracer.occluded(space.position[:1], space.normal[:1])
        light = [Light(type="point", color=np.ones(3), intensity=1.0,
                       position=np.array([0.2, 0.15, 0.1]))]
        sel = np.random.default_rng(0).choice(space.count, args.path_tracer_texels,
                                              replace=False)
        t0 = time.perf_counter()
        a, b = fibre_reference(space, tracer, mesh, 0, light, sel, 256, seed=1)
        dt = time.perf_counter() - t0
        ref = (a + b) / 2
        noise = float(np.sqrt(np.mean((a - b) ** 2) / 4 / np.mean(ref ** 2)))
        row.update(path_seconds=dt / (len(sel) * 256), path_noise_256=noise,
                   load_average=os.getloadavg()[0])
        print(f"path tracer: {dt:.1f} s for {len(sel)} texels × 256 paths × 1 light = "
              f"{1e6 * dt / (len(sel) * 256):.0f} µs per path; per-texel relative noise at "
              f"256 paths {100 * noise:.1f} %; load {os.getloadavg()[0]:.1f}")
    elif not args.estimate_only:
        b = intake.hair.bounds()
        train, hold = sample_configurations(spec.lights, b.mean(axis=0),
                                            float(np.linalg.norm(b[1] - b[0]) / 2), ())
        t0 = time.perf_counter()
        tracer, _ = hair_tracer(space)
        tracer.occluded(space.position[:1], space.normal[:1])  # Embree's lazy BVH build
        t1 = time.perf_counter()
        data = bake_hair_dataset(space, intake.points, tracer, train, hold,
                                 spec.transport, timer, keep_direct_texels=False,
                                 direct_estimator=spec.hair.direct,
                                 direct_samples=spec.hair.direct_samples)  # the bake's
        # and the bake's denoising of the strand texels (part of the dataset it fits)
        data = denoise_dataset(data, space, spec.hair.denoise_neighbours, timer=timer,
                               threads=tracer.threads)
        t2 = time.perf_counter()
        row.update(tracer_seconds=t1 - t0, dataset_seconds=t2 - t1,
                   stage_seconds=dict(timer.seconds), rays=tracer.rays_traced,
                   bounces=data.iterations, peak_rss_bytes=peak_rss(),
                   load_average=os.getloadavg()[0])
        print(f"tracer {t1 - t0:.1f} s; dataset {t2 - t1:.1f} s "
              f"({', '.join(f'{k} {v:.1f} s' for k, v in timer.seconds.items())}); "
              f"{tracer.rays_traced / 1e6:.1f} M rays; {data.iterations} bounces; peak RSS "
              f"{peak_rss() / 2**30:.2f} GiB; load {os.getloadavg()[0]:.1f}")
    suffix = "_path_tracer" if args.path_tracer_texels else ""
    out = ROOT / "benchmarks" / "results" / f"hair_bake_{args.strands}{suffix}.json"
    out.write_text(json.dumps(row, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
