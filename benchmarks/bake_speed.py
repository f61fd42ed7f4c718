"""Benchmark: how fast a whole bake is, stage by stage, and at what accuracy.

Issue 20's figures, from one run (benchmarks/results/bake_speed.json):

* the **whole bake** (:func:`prtcore.pipeline.bake`, intake to export, report included) of
  the bundled Cornell box (examples/cornell_box.glb, its example spec) at a 512² atlas,
  K = 128 training + 16 held-out lights, P = 256, M = 64 gather rays: wall time of every
  stage and in total, peak RSS, each bake in its own child process (numba kernels are
  compiled on first use and cached on disk; a fresh cache costs a few seconds once);
* the same bake at 1024²: its time as a ratio to the 512² bake, and its peak RSS;
* **direct texels against raw Embree on the same rays**: the 512² bake records the shadow
  rays of its first ``--record-calls`` occlusion queries in the direct-texels stage and
  replays them through embreex ``scene.run`` (float32 arrays ready, chunks on the bake's
  threads, no numpy): seconds per ray of the stage against seconds per ray of the raw queries;
* the **indirect solve**: products, residual, seconds; ``--before FILE`` (a JSON this
  script wrote for an earlier commit) prints before/after columns for every stage;
* **transport against the path tracer** (unless ``--skip-reference``): at a low resolution
  the fast dataset and the reference path tracer are both compared with a high-spp
  reference; the reference's error follows c/√spp (fitted on a few spp levels), which gives
  the spp at which its noise equals the fast path's error; that spp × the 512² texel count ×
  the measured time per path is the reference's time for one configuration. Errors are
  per-configuration relative RMSE over the lightmap, noise-corrected: the high-spp
  reference's own variance (from its standard errors) is subtracted.

Figures (``--skip-reference``, one run each on an otherwise idle 2-core machine, the first
with ``--coarse-grid 1`` and its JSON given to the second as ``--before``): whole 512² bake
51.3 → 33.4 s wall (65.2 → 43.8 CPU s), indirect solve 20.8 → 6.0 s wall (27.3 → 9.4 CPU
s: 2.9×), report 1.23 → 0.47 s, held-out rRMSE at every n unchanged (3.13 % at n = 16);
1024² bake 204.5 → 148.1 s (×3.98 → ×4.43 the 512² bake), peak RSS 6.13 → 6.12 GiB
(the transport-noise and denoise stages set it); direct texels ×1.41 raw embreex CPU per ray.

2026-12-03, another machine (AMD EPYC, AVX2; ``--skip-reference``, each run alone on it):
222b269 → c351fd1 (compiled hit records and UV lookup, the gather's and the filters' memory):
whole 512² bake 30.7 → 27.5 s wall (42.0 → 40.6 CPU s; gather operator 5.1 → 3.4 s, transport
noise 8.0 → 6.7 s), 1024² bake 121.2 → 112.1 s (×3.95 → ×4.07 the 512² bake), 1024² peak RSS
3.66 → 3.48 GiB, held-out rRMSE unchanged; direct texels ×1.21 raw embreex CPU per ray.

Then 222b269 against cb4b1d0 (also the fused closing steps, the parallel hit lookup, report
images without pyplot), 512² alternated twice on the same machine, which was noisier by then:
whole bake 40.9 / 34.0 s before against 31.0 / 28.6 s after; gather operator 5.4 / 4.6 →
3.7 / 3.4 s, indirect solve 10.6 / 7.8 → 5.6 / 4.8 s, transport noise 8.7 / 7.8 → 8.0 / 7.1 s.
At 1024² the light stages alone (light_configurations, K = 144 in 4 solve blocks): solve
44.2 s (c351fd1, numba compiling in its first block) against 36.7 s; whole 1024² bake
156.0 s at cb4b1d0 in a run whose 512² bake took 32.5 s (×4.79; ×4.07 in the quieter run
above), peak RSS 3.48 GiB.

2026-12-04 (AMD EPYC, AVX-512, 2 cores, shared; load 1.2-1.8), every issue 20 target in one
run (``python benchmarks/bake_speed.py``, at 0777680): whole 512² bake **18.97 s** (32.6 CPU
s; peak RSS 1.67 GiB); 1024² 78.9 s = **×4.16**, peak RSS **3.40 GiB**; direct texels ×1.28
wall / ×1.30 CPU raw embreex per ray (×1.28-1.60 wall over six runs that day: the raw
replay is noisy too); indirect solve 4.04 s; report 0.44 s; transport vs the path tracer at
64² 8.1 / 7.6 / 8.1 % rRMSE, bias −0.2 / +0.2 / −0.2 % (noise-corrected), held-out rRMSE
3.13 % at n = 16. Against the code the issue was filed on (f589c26, in a worktree:
``--code /tmp/old --record-calls 0 --skip-reference --big-resolution 0``, its JSON given
as ``--before`` to the next run): whole bake 44.03 → 18.86 s (70.6 → 32.6 CPU s); gather
4.20 → 2.15 s, direct texels 10.21 → 3.72 s, near field 1.48 → 0.86 s, indirect solve
17.13 → 4.37 s (×3.9 wall, ×3.5 CPU), denoise 3.03 → 0.42 s, report 4.28 → 0.53 s, export
1.28 → 0.96 s; fit 1.62 → 1.76 s; and a stage the old code lacked, transport noise (issue
13's second transport), 3.35 s. Held-out rRMSE at n = 16 3.20 → 3.13 %.

The machine's load average is recorded at start and end: on a shared machine compare
ratios measured in one run, not absolute seconds across runs.

Usage: python benchmarks/bake_speed.py [--resolution 512] [--big-resolution 1024] ...
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
#: the prtcore the bakes run: this checkout's, or with --code another's (an older commit)
CODE = Path(os.environ.get("PRT_BENCH_CODE", ROOT)).resolve()
if str(CODE) not in sys.path:
    sys.path.insert(0, str(CODE))

from prtcore.core.raytrace import RayTracer  # noqa: E402
from prtcore.core.spec import TransportSpec, parse_spec  # noqa: E402
from prtcore.emitters.families import sample_configurations  # noqa: E402
from prtcore.pipeline import run_intake  # noqa: E402
from prtcore.reference.pathtracer import reference_lightmaps  # noqa: E402
from prtcore.scenes.cornell import EXAMPLE_SPEC, write_cornell_box  # noqa: E402
from prtcore.transport.dataset import bake_dataset  # noqa: E402

RAY_CHUNK = 1 << 20


def make_spec(resolution: int, lights: int, holdout: int, points: int,
              padding: int | None = None, gather_rays: int | None = None,
              coarse_grid: int | str = "auto"):
    d = copy.deepcopy(EXAMPLE_SPEC)
    if coarse_grid != "auto":  # the default; older code (--code) does not know the key
        d["transport"]["coarse_grid"] = coarse_grid
    d["atlas"]["resolution"] = resolution
    if gather_rays is not None:
        d["transport"]["gather_rays"] = gather_rays
    if padding is not None:
        d["atlas"]["padding"] = padding
    d["lights"]["count"] = lights
    d["lights"]["holdout"] = holdout
    d["measurement_points"]["count"] = points
    return parse_spec(d)


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


def record_direct_rays(calls: int, store: list) -> None:
    """Make the direct-texels stage keep the shadow rays of its first ``calls`` occlusion
    queries (a few lights' worth): (origins, directions, tmax) float32 as handed to
    embreex."""
    from prtcore.core import raytrace
    from prtcore.transport import dataset

    state = {"on": False}
    inner, occluded = dataset.direct_radiance, raytrace.RayTracer.occluded

    def direct_radiance(scene, tracer, lights, positions, *a, **kw):
        state["on"] = np.asarray(positions).ndim == 3  # texels: (T, J, 3); points: (P, 3)
        try:
            return inner(scene, tracer, lights, positions, *a, **kw)
        finally:
            state["on"] = False

    def recording(self, origins, directions, tmax=None):
        if state["on"] and len(store) < calls:
            o, d = self._prep(origins, directions)
            store.append((o.copy(), d.copy(), self._tmax(tmax, len(o))))
        return occluded(self, origins, directions, tmax)

    dataset.direct_radiance = direct_radiance
    raytrace.RayTracer.occluded = recording


def raw_seconds(scene, rays: list, threads: int) -> tuple[float, float]:
    """Wall and CPU seconds of raw embreex occlusion queries on ``rays`` (RayTracer's
    chunking and threads, arrays prepared beforehand)."""
    from embreex import mesh_construction, rtcore_scene

    from prtcore.core.raytrace import CHUNK

    raw = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(raw, scene.positions.astype(np.float32),
                                   scene.faces.astype(np.int32))
    jobs = [(o[a:a + CHUNK], d[a:a + CHUNK], tm[a:a + CHUNK].copy())
            for o, d, tm in rays for a in range(0, len(o), CHUNK)]
    t0, c0 = time.perf_counter(), time.process_time()
    with ThreadPoolExecutor(threads) as ex:
        list(ex.map(lambda j: raw.run(j[0], j[1], dists=j[2], query="OCCLUDED"), jobs))
    return time.perf_counter() - t0, time.process_time() - c0


def child_bake(args) -> int:
    """One whole bake in this process; prints one JSON line."""
    import resource

    from prtcore.pipeline import bake

    spec = make_spec(args.child_bake, args.lights, args.holdout, args.points,
                     gather_rays=args.gather_rays, coarse_grid=args.coarse_grid)
    cpu_stage: dict[str, float] = {}
    started: dict[str, float] = {}

    def on_progress(stage: str, fraction: float) -> None:  # CPU seconds per stage
        if fraction == 0.0 and stage not in started:
            started[stage] = time.process_time()
        elif fraction == 1.0 and stage in started:
            cpu_stage[stage] = time.process_time() - started[stage]

    rays: list = []
    if args.record_calls:
        record_direct_rays(args.record_calls, rays)
    with tempfile.TemporaryDirectory() as tmp:
        t0, c0 = time.perf_counter(), time.process_time()
        out = bake(ROOT / "examples" / "cornell_box.glb", spec, Path(tmp) / "bundle",
                   quiet=True, force=True, callback=on_progress)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        report = json.loads((out / "report.json").read_text())
        manifest = json.loads((out / "manifest.json").read_text())
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    tr = report["transport"]
    result = {"resolution": args.child_bake, "seconds": manifest["timings"], "total": wall,
              "cpu_seconds": cpu, "cpu_stage_seconds": cpu_stage, "peak_rss_bytes": peak,
              "texels": tr["texels"],
              "rays": tr["rays"], "solve": {k: v for k, v in tr["solve"].items()
                                            if k != "blocks"},
              "table": [{k: r[k] for k in ("n", "heldout_rmse_mean", "projection_bound_mean")}
                        for r in report["table"]["rows"]]}
    if rays:
        from prtcore.core.raytrace import default_threads
        from prtcore.io.gltf.loader import load_asset

        scene = load_asset(ROOT / "examples" / "cornell_box.glb")

        n = sum(len(o) for o, _, _ in rays)
        raw, raw_cpu = min(raw_seconds(scene, rays, default_threads()) for _ in range(2))
        count = max(tr["rays"]["direct_texels"], 1)
        stage = manifest["timings"]["direct texels"] / count
        stage_cpu = cpu_stage.get("direct texels", float("nan")) / count
        result["direct_vs_raw"] = {"recorded_rays": n, "raw_seconds_per_ray": raw / n,
                                   "stage_seconds_per_ray": stage,
                                   "ratio": stage / max(raw / n, 1e-30),
                                   "raw_cpu_seconds_per_ray": raw_cpu / n,
                                   "stage_cpu_seconds_per_ray": stage_cpu,
                                   "cpu_ratio": stage_cpu / max(raw_cpu / n, 1e-30)}
    print(json.dumps(result, default=float))
    return 0


def run_child(args, resolution: int, record: int) -> dict:
    """A whole bake in a child process (its own peak RSS, its own numba cache reads)."""
    import subprocess

    cmd = [sys.executable, str(Path(__file__).resolve()), "--child-bake", str(resolution),
           "--lights", str(args.lights), "--holdout", str(args.holdout), "--points",
           str(args.points), "--gather-rays", str(args.gather_rays), "--record-calls",
           str(record), "--coarse-grid", str(args.coarse_grid)]
    env = {**os.environ, "PYTHONPATH": str(args.code), "PRT_BENCH_CODE": str(args.code)}
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if done.returncode:
        raise SystemExit(f"child bake at {resolution}² failed:\n{done.stderr[-4000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--big-resolution", type=int, default=1024,
                    help="the second whole bake (0: none)")
    ap.add_argument("--lights", type=int, default=128)
    ap.add_argument("--holdout", type=int, default=16)
    ap.add_argument("--points", type=int, default=256)
    ap.add_argument("--gather-rays", type=int, default=TransportSpec().gather_rays,
                    help="M (default: the spec's default, DESIGN 3.5)")
    ap.add_argument("--record-calls", type=int, default=16,
                    help="occlusion queries of the direct-texels stage replayed through raw "
                         "embreex (two per light at 512²)")
    add_equal_accuracy_args(ap, ref_spp_high=4096, ref_spp_timing=64)
    ap.add_argument("--before", type=Path, help="an earlier run's JSON: before/after columns")
    ap.add_argument("--coarse-grid", type=lambda v: v if v == "auto" else int(v),
                    default="auto", help="transport.coarse_grid of the bakes (1: the solve "
                    "at full resolution, as before issue 20's coarse grid)")
    ap.add_argument("--code", type=Path, default=ROOT,
                    help="the checkout whose prtcore bakes (e.g. `git worktree add "
                         "/tmp/old REV`): a run whose JSON another run takes as --before "
                         "(use with --record-calls 0 --skip-reference)")
    ap.add_argument("--child-bake", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" /
                    "bake_speed.json")
    args = ap.parse_args(argv)
    if args.child_bake:
        return child_bake(args)

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    before = json.loads(args.before.read_text()) if args.before else None
    load_start = os.getloadavg()
    log(f"whole bake at {args.resolution}² …")
    small = run_child(args, args.resolution, args.record_calls)
    big = None
    if args.big_resolution:
        log(f"whole bake at {args.big_resolution}² …")
        big = run_child(args, args.big_resolution, 0)
    result = {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "load_average_at_start": load_start},
        "scene": {"asset": "examples/cornell_box.glb", "atlas": args.resolution,
                  "texels": small["texels"], "train": args.lights, "holdout": args.holdout,
                  "points": args.points, "gather_rays": args.gather_rays},
        "bake": small, "big_bake": big,
        "big_over_small": big["total"] / small["total"] if big else None,
    }
    if not args.skip_reference:
        spec = make_spec(args.resolution, args.lights, args.holdout, args.points,
                         gather_rays=args.gather_rays)
        eq = reference_equivalence(args, spec, small["texels"], log)
        t_dataset = sum(small["seconds"].get(k, 0.0) for k in DATASET_STAGES)
        eq["speedup"] = eq["reference_seconds_one_configuration_at_full_resolution"] * \
            args.lights / max(t_dataset, 1e-9)
        result["reference"] = eq
    result["machine"]["load_average_at_end"] = os.getloadavg()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2, default=float) + "\n")
    report(result, before, args)
    return 0


#: the transport stages (the dataset), for the speed-up over the path tracer
DATASET_STAGES = ("gather operator", "direct points", "direct texels", "near field",
                  "indirect solve")


def report(result: dict, before: dict | None, args) -> None:
    small, big = result["bake"], result["big_bake"]
    b = before["bake"] if before else None
    print(f"Cornell box {args.resolution}², {small['texels']} texels, K = {args.lights} + "
          f"{args.holdout} lights, P = {args.points}, M = {args.gather_rays}; load average "
          f"{result['machine']['load_average_at_start'][0]:.1f} at start, "
          f"{result['machine']['load_average_at_end'][0]:.1f} at end "
          f"({result['machine']['cpus']} CPUs)")
    print(f"  {'stage':<18s} {'wall':>9s} {'CPU':>8s}" + (
        f"   before: {'wall':>8s} {'CPU':>8s}  CPU ratio" if b else ""))
    rows = [*small["seconds"].items(), ("whole bake", small["total"])]

    def cpu(run, name):
        return run.get("cpu_seconds") if name == "whole bake" else \
            run.get("cpu_stage_seconds", {}).get(name)

    def fmt(v):
        return f"{v:7.2f}s" if v is not None else f"{'—':>8s}"

    for name, sec in rows:
        line = f"  {name:<18s} {sec:8.2f}s {fmt(cpu(small, name))}"
        if b:
            old = b["total"] if name == "whole bake" else b["seconds"].get(name)
            c_new, c_old = cpu(small, name), cpu(b, name)
            ratio = f"{c_old / c_new:8.1f}×" if c_new and c_old else ""
            line += f"           {fmt(old)} {fmt(c_old)} {ratio}"
        print(line)
    print(f"  whole bake CPU time {small['cpu_seconds']:.1f} s (all threads); peak RSS "
          f"{small['peak_rss_bytes'] / 2**30:.2f} GiB")
    sv = small["solve"]
    print(f"  solve: {sv.get('method')}, converged {sv.get('converged')}, "
          f"interval {sv.get('interval')}")
    if "direct_vs_raw" in small:
        d = small["direct_vs_raw"]
        print(f"  direct texels: {d['stage_seconds_per_ray'] * 1e9:.0f} ns/ray in the stage, "
              f"{d['raw_seconds_per_ray'] * 1e9:.0f} ns/ray raw embreex on the same "
              f"{d['recorded_rays']:,} rays: ×{d['ratio']:.2f} wall"
              + (f"; CPU {d['stage_cpu_seconds_per_ray'] * 1e9:.0f} against "
                 f"{d['raw_cpu_seconds_per_ray'] * 1e9:.0f} ns/ray: ×{d['cpu_ratio']:.2f}"
                 if "cpu_ratio" in d else ""))
    if big:
        print(f"  {args.big_resolution}² whole bake {big['total']:.1f} s = "
              f"×{result['big_over_small']:.2f} the {args.resolution}² bake; peak RSS "
              f"{big['peak_rss_bytes'] / 2**30:.2f} GiB; stages: " + ", ".join(
                  f"{k} {v:.1f}" for k, v in big["seconds"].items()))
    print("  held-out rRMSE (fit vs fast transport): " + ", ".join(
        f"n={r['n']}: {100 * r['heldout_rmse_mean']:.2f}%" for r in small["table"]
        if r["heldout_rmse_mean"] is not None))
    if "reference" in result:
        eq = result["reference"]
        print(f"  transport vs path tracer at {eq['resolution']}²: rel. RMSE "
              f"{[round(x, 4) for x in eq['fast_rel_rmse']]}, bias "
              f"{[round(x, 4) for x in eq['fast_bias']]} (noise-corrected)")
        print("  reference error by spp: " + ", ".join(
            f"{k}: {[round(x, 3) for x in v]}" for k, v in
            eq["reference_rel_rmse_by_spp"].items()))
        print(f"  equal-accuracy spp ≈ {eq['spp_star']:.0f}; reference for one "
              f"configuration at {args.resolution}²: "
              f"{eq['reference_seconds_one_configuration_at_full_resolution']:.0f} s; "
              f"speed-up ×{eq['speedup']:.0f} over {args.lights} configurations")
    print(f"  → {args.out}")


if __name__ == "__main__":
    raise SystemExit(main())
