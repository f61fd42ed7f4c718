"""Benchmark: how fast the bake's dataset is, and how much faster than path tracing.

Cornell box (prtcore.scenes.cornell) at a 512² atlas, K = 128 training + 16 held-out lights from
the box's example spec, P = 256 measurement points. One run prints and writes
(benchmarks/results/bake_speed.json):

* wall time per stage: load, plan, uv, texels, points (the intake), then the transport
  sub-stages gather operator, direct texels, direct points, indirect solve, and totals;
* ray throughput: the bake's own (rays / seconds of the tracing sub-stages, numpy work
  included), our RayTracer on random rays, and a raw ``embreex`` ``scene.run`` loop on the
  same random rays (same count and mix of closest-hit and occlusion rays as the bake);
* the reference path tracer's time for ONE configuration at the fast path's accuracy: at a
  low resolution both are compared with a high-spp reference; the reference's error
  follows c/√spp (fitted on a few spp levels), which gives the spp at which its noise
  equals the fast path's error; that spp × the 512² texel count × the measured time per
  path is the estimate. Speed-up = reference time × K / the fast dataset's time.

Errors are per-configuration relative RMSE over the lightmap, noise-corrected: the
high-spp reference's own variance (from its standard errors) is subtracted.

Usage: python benchmarks/bake_speed.py [--resolution 512] [--low-resolution 64] ...
The full run takes several minutes on 2 cores (most of it the high-spp reference).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import platform
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from prtcore.core.progress import StageTimer  # noqa: E402
from prtcore.core.raytrace import RayTracer  # noqa: E402
from prtcore.core.spec import TransportSpec, parse_spec  # noqa: E402
from prtcore.emitters.families import sample_configurations  # noqa: E402
from prtcore.pipeline import run_intake  # noqa: E402
from prtcore.reference.pathtracer import reference_lightmaps  # noqa: E402
from prtcore.scenes.cornell import EXAMPLE_SPEC, write_cornell_box  # noqa: E402
from prtcore.transport.dataset import bake_dataset  # noqa: E402

RAY_CHUNK = 1 << 20


def make_spec(resolution: int, lights: int, holdout: int, points: int,
              padding: int | None = None, gather_rays: int | None = None):
    d = copy.deepcopy(EXAMPLE_SPEC)
    d["atlas"]["resolution"] = resolution
    if gather_rays is not None:
        d["transport"]["gather_rays"] = gather_rays
    if padding is not None:
        d["atlas"]["padding"] = padding
    d["lights"]["count"] = lights
    d["lights"]["holdout"] = holdout
    d["measurement_points"]["count"] = points
    return parse_spec(d)


def random_rays(rng: np.random.Generator, n: int, lo: np.ndarray, hi: np.ndarray):
    o = (lo + (hi - lo) * rng.random((n, 3))).astype(np.float32)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d.astype(np.float32)


def throughput(scene, tracer: RayTracer, closest: int, occlusion: int, threads: int
               ) -> dict:
    """Rays/s of our RayTracer and of a raw embreex loop on the same random rays."""
    from embreex import mesh_construction, rtcore_scene

    raw = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(raw, scene.positions.astype(np.float32),
                                   scene.faces.astype(np.int32))
    lo, hi = scene.bounds[0], scene.bounds[1]
    sub = 1 << 17
    out = {}
    for label, count, query in (("closest_hit", closest, "INTERSECT"),
                                ("occlusion", occlusion, "OCCLUDED")):
        rng = np.random.default_rng(0)
        t_ours = t_raw1 = t_rawn = 0.0
        for s in range(0, count, RAY_CHUNK):
            o, d = random_rays(rng, min(RAY_CHUNK, count - s), lo, hi)
            t0 = time.perf_counter()
            if query == "INTERSECT":
                tracer.intersect(o, d)
            else:
                tracer.occluded(o, d)
            t1 = time.perf_counter()
            for a in range(0, len(o), sub):
                raw.run(o[a:a + sub], d[a:a + sub], query=query)
            t2 = time.perf_counter()
            def run(a, o=o, d=d, query=query):
                return raw.run(o[a:a + sub], d[a:a + sub], query=query)

            with ThreadPoolExecutor(threads) as ex:
                list(ex.map(run, range(0, len(o), sub)))
            t3 = time.perf_counter()
            t_ours += t1 - t0
            t_raw1 += t2 - t1
            t_rawn += t3 - t2
        out[label] = {"rays": count, "ours_rays_per_s": count / max(t_ours, 1e-9),
                      "raw_embreex_1thread_rays_per_s": count / max(t_raw1, 1e-9),
                      f"raw_embreex_{threads}threads_rays_per_s": count / max(t_rawn, 1e-9)}
    return out


def rel_rmse(fast: np.ndarray, ref: np.ndarray, err: np.ndarray) -> float:
    """Noise-corrected relative RMSE of one configuration's (T, 3) lightmap."""
    ms = float(((fast - ref) ** 2).mean())
    noise = float((err ** 2).mean())
    return math.sqrt(max(ms - noise, 0.0) / max(float((ref ** 2).mean()), 1e-300))


def reference_equivalence(args, spec, res_high_texels: int, log) -> dict:
    """Reference spp and time for one configuration at the fast path's accuracy."""
    low = make_spec(args.low_resolution, spec.lights.count, spec.lights.holdout,
                    spec.measurement_points.count, padding=2)
    with tempfile.TemporaryDirectory() as tmp:
        intake = run_intake(write_cornell_box(Path(tmp) / "cornell.glb"), low, quiet=True)
    scene, texels, points = intake.scene, intake.texels, intake.points
    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    train, _ = sample_configurations(spec.lights, scene.center, scene.radius)
    # the first configurations that light the room at all (a light inside a block does not)
    from prtcore.emitters.punctual import irradiance
    configs = []
    for light in train:
        if irradiance(light, texels.position, texels.normal, tracer).max() > 0:
            configs.append(light)
        if len(configs) == args.configs:
            break
    log(f"reference equivalence at {args.low_resolution}²: {texels.count} texels, "
        f"{len(configs)} configurations, high-spp reference {args.ref_spp_high} spp …")
    out = equal_accuracy(scene, texels, points, tracer, configs, spec.transport, args)
    out["reference_seconds_one_configuration_at_full_resolution"] = \
        out["spp_star"] * res_high_texels * out["seconds_per_path"]
    return out


def equal_accuracy(scene, texels, points, tracer: RayTracer, configs, transport, args
                   ) -> dict:
    """The fast transport's noise-corrected error against a high-spp reference, the
    reference's error at ``args.ref_spp`` levels fitted as c/√spp, the spp at which it
    equals the fast path's, and the reference's time per path (one configuration)."""
    t0 = time.perf_counter()
    hi, hi_err = reference_lightmaps(scene, texels, [[c] for c in configs],
                                     spp=args.ref_spp_high, seed=1, tracer=tracer)
    t_hi = time.perf_counter() - t0
    ds = bake_dataset(scene, texels, points, configs, (), transport, tracer=tracer)
    fast_err = [rel_rmse(ds.indirect[:, k].astype(np.float64), hi[k], hi_err[k])
                for k in range(len(configs))]
    fast_bias = [float(ds.indirect[:, k].mean() / hi[k].mean() - 1)
                 for k in range(len(configs))]
    levels = {}
    for spp in args.ref_spp:
        m, _ = reference_lightmaps(scene, texels, [[c] for c in configs], spp=spp, seed=2,
                                   tracer=tracer)
        levels[spp] = [rel_rmse(m[k], hi[k], hi_err[k]) for k in range(len(configs))]
    # error ≈ c/√spp per configuration; c from the levels (least squares on c)
    c = []
    for k in range(len(configs)):
        s = np.array(list(levels), dtype=np.float64)
        e = np.array([levels[x][k] for x in levels])
        c.append(float((e / np.sqrt(s)).sum() / (1.0 / s).sum()))
    spp_equal = [(ck / max(fk, 1e-9)) ** 2 for ck, fk in zip(c, fast_err, strict=True)]
    # time per path of ONE configuration (no sharing of paths between configurations)
    t0 = time.perf_counter()
    reference_lightmaps(scene, texels, [[configs[0]]], spp=args.ref_spp_timing, seed=3,
                        tracer=tracer)
    per_path = (time.perf_counter() - t0) / (args.ref_spp_timing * texels.count)
    spp_star = float(np.median(spp_equal))
    return {
        "resolution": args.low_resolution, "texels": texels.count,
        "configurations": len(configs), "high_spp": args.ref_spp_high,
        "high_spp_seconds": t_hi,
        "high_spp_noise": [float(np.sqrt((hi_err[k] ** 2).mean() / (hi[k] ** 2).mean()))
                           for k in range(len(configs))],
        "fast_rel_rmse": fast_err, "fast_bias": fast_bias,
        "reference_rel_rmse_by_spp": {str(k): v for k, v in levels.items()},
        "reference_c": c, "spp_at_equal_error": spp_equal, "spp_star": spp_star,
        "seconds_per_path": per_path,
    }


def add_equal_accuracy_args(ap: argparse.ArgumentParser, ref_spp_high: int,
                            ref_spp_timing: int) -> None:
    """The options of :func:`equal_accuracy` (and --skip-reference)."""
    ap.add_argument("--low-resolution", type=int, default=64)
    ap.add_argument("--configs", type=int, default=3)
    ap.add_argument("--ref-spp-high", type=int, default=ref_spp_high)
    ap.add_argument("--ref-spp", type=lambda s: [int(x) for x in s.split(",")],
                    default=[16, 64, 256])
    ap.add_argument("--ref-spp-timing", type=int, default=ref_spp_timing)
    ap.add_argument("--skip-reference", action="store_true")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--lights", type=int, default=128)
    ap.add_argument("--holdout", type=int, default=16)
    ap.add_argument("--points", type=int, default=256)
    ap.add_argument("--gather-rays", type=int, default=TransportSpec().gather_rays,
                    help="M (default: the spec's default, DESIGN 3.5)")
    add_equal_accuracy_args(ap, ref_spp_high=4096, ref_spp_timing=64)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" /
                    "bake_speed.json")
    args = ap.parse_args(argv)

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    spec = make_spec(args.resolution, args.lights, args.holdout, args.points,
                     gather_rays=args.gather_rays)
    load_start = os.getloadavg()
    timer = StageTimer(quiet=True)
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        asset = write_cornell_box(Path(tmp) / "cornell.glb")
        intake = run_intake(asset, spec, timer=timer)
    scene, texels, points = intake.scene, intake.texels, intake.points
    train, hold = sample_configurations(spec.lights, scene.center, scene.radius)
    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    log(f"intake done: {texels.count} texels, {points.count} points; transport …")
    t0, c0 = time.perf_counter(), time.process_time()
    ds = bake_dataset(scene, texels, points, train, hold, spec.transport, timer,
                      tracer=tracer)
    t_dataset = time.perf_counter() - t0
    cpu_dataset = time.process_time() - c0  # all threads: compare with wall × cores
    t_total = time.perf_counter() - t_all
    sub = ds.stats["seconds"]
    trace_seconds = sub["gather operator"] + sub["direct texels"] + sub["direct points"]
    rays = ds.stats["rays"]
    log("ray throughput …")
    thr = throughput(scene, tracer, rays["gather"],
                     rays["direct_texels"] + rays["direct_points"], tracer.threads)
    result = {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "load_average_at_start": load_start,
                    "load_average_at_end": os.getloadavg()},
        "scene": {"asset": "cornell box", "atlas": args.resolution,
                  "texels": texels.count, "triangles": scene.triangle_count,
                  "configurations": len(ds.lights), "train": len(train),
                  "holdout": len(hold), "points": points.count,
                  "gather_rays": spec.transport.gather_rays},
        "seconds": {**dict(timer.seconds), "dataset": t_dataset, "total": t_total},
        "cpu_seconds_dataset": cpu_dataset,
        "solve": {"bounces": ds.iterations, "residual": ds.residual,
                  "converged": ds.stats["solve"]["converged"],
                  "method": ds.stats["solve"]["method"]},
        "gather": ds.stats["gather"],
        "rays": {**rays, "bake_rays_per_s": rays["total"] / max(trace_seconds, 1e-9)},
        "throughput": thr,
    }
    if not args.skip_reference:
        eq = reference_equivalence(args, spec, texels.count, log)
        ref_one = eq["reference_seconds_one_configuration_at_full_resolution"]
        eq["speedup"] = ref_one * len(train) / t_dataset
        result["reference"] = eq

    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2, default=float) + "\n")
    print(f"Cornell box {args.resolution}², {texels.count} texels, K = {len(train)} + "
          f"{len(hold)} lights, P = {points.count}, M = {spec.transport.gather_rays}")
    for name, sec in result["seconds"].items():
        print(f"  {name:<18s} {sec:8.2f} s")
    print(f"  dataset CPU time {cpu_dataset:.2f} s (all threads); load average at start "
          f"{load_start[0]:.2f}, at end {result['machine']['load_average_at_end'][0]:.2f}")
    print(f"  solve: {ds.iterations} products ({ds.stats['solve']['method']}), residual "
          f"{ds.residual:.1e}, converged {ds.stats['solve']['converged']}")
    print(f"  rays: {rays['total']:,} traced, bake {result['rays']['bake_rays_per_s']:,.0f}"
          f" rays/s (incl. numpy)")
    for kind, v in thr.items():
        extra = ", ".join(f"{k} {x:,.0f}" for k, x in v.items() if k.endswith("per_s"))
        print(f"  {kind}: {extra}")
    if "reference" in result:
        eq = result["reference"]
        print(f"  reference at {eq['resolution']}²: fast rel. RMSE "
              f"{[round(x, 3) for x in eq['fast_rel_rmse']]}, bias "
              f"{[round(x, 4) for x in eq['fast_bias']]}")
        print("  reference error by spp: " + ", ".join(
            f"{k}: {[round(x, 3) for x in v]}" for k, v in
            eq["reference_rel_rmse_by_spp"].items()))
        print(f"  equal-accuracy spp ≈ {eq['spp_star']:.0f}; reference for one "
              f"configuration at {args.resolution}²: "
              f"{eq['reference_seconds_one_configuration_at_full_resolution']:.0f} s; "
              f"speed-up ×{eq['speedup']:.0f} over {len(train)} configurations")
    print(f"  → {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
