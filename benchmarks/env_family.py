"""Benchmark: data-driven PRT trained on an environment family vs transfer textures, on
the same held-out skies, against the environment path tracer (issue 17).

Scene: prtcore.scenes.floor_object. Family: the analytic sky with a random sun
(``{"type": "environment", "environment": "sky"}``, sun directions drawn like the scene's
directional family). Held-out: ``--lights`` skies from an independent seed. For each:

* data-driven: the engine's direct light (``EnvironmentEmitter.irradiance``, the shared
  64-direction estimate) + the bundle's relit indirect lightmap (``runtime.cpu.relight``);
* transfer textures: SH-PRT T⁰ + T¹ (bands 5) dotted with the sky's SH;
* reference: ``reference.environment`` (the map's own pixels, ``--depth`` bounces,
  ``--spp`` paths), noise removed from two halves.

Prints relative rms errors per method and the bake times; writes
benchmarks/results/env_family.json.

Usage: python benchmarks/env_family.py [--atlas 32 --lights 3 --spp 256 --depth 6]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--atlas", type=int, default=32)
    ap.add_argument("--lights", type=int, default=3)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--depth", type=int, default=6)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "env_family.json"))
    args = ap.parse_args(argv)

    from prtcore.core.materials import clamp_albedo
    from prtcore.core.spec import parse_spec
    from prtcore.emitters.environment_light import environment_of
    from prtcore.emitters.families import sample_configurations
    from prtcore.emitters.punctual import irradiance
    from prtcore.io.bundle import load_runtime
    from prtcore.methods import sh_prt
    from prtcore.pipeline import bake, run_intake
    from prtcore.reference.environment import reference_environment
    from prtcore.reference.pathtracer import default_tracer
    from prtcore.runtime.cpu import relight
    from prtcore.scenes import floor_object

    family = {"type": "environment", "environment": "sky",
              "position": {"box": [[-6.0, 1.6, -6.0], [6.0, 6.0, 6.0]]},
              "aim": {"target": [0.0, 0.0, 0.0], "jitter": 0.0},
              "intensity": {"constant": 1.0}}
    spec_d = {"atlas": {"resolution": args.atlas, "padding": 2},
              "measurement_points": {"count": 64, "supersample": 2, "seed": 1},
              "lights": {"count": 48, "holdout": 4, "seed": 2, "families": [family]},
              "transport": {"gather_rays": 64, "max_bounces": 8},
              "fit": {"basis": 16}}
    spec = parse_spec(spec_d)
    tmp = Path(tempfile.mkdtemp(prefix="env_family_"))
    asset = floor_object.write_floor_object(tmp / "fo.glb")
    t0 = time.perf_counter()
    bundle = bake(asset, spec, tmp / "bundle", quiet=True)
    dd_seconds = time.perf_counter() - t0
    verdict = json.loads((bundle / "report.json").read_text())["verdict"]["line"]
    intake = run_intake(asset, spec, quiet=True)
    scene, tx = intake.scene, intake.texels
    tracer = default_tracer(scene)
    data = load_runtime(bundle)
    t0 = time.perf_counter()
    shp = sh_prt.bake_sh_prt(scene, tracer, "texture", 5, 16, seed=3, bounce=True, texels=tx)
    sh_seconds = time.perf_counter() - t0
    _, held = sample_configurations(parse_spec(dict(spec_d, lights=dict(
        spec_d["lights"], seed=99, holdout=args.lights))).lights, scene.center, scene.radius)
    rho, _ = clamp_albedo(tx.albedo)
    rows = []
    for i, light in enumerate(held):
        env = environment_of(light)
        ref = reference_environment(scene, tracer, env, tx.position, tx.normal,
                                    tx.geometric_normal, tx.albedo, args.spp, seed=10 + i,
                                    max_depth=args.depth)
        direct = rho / math.pi * irradiance(light, tx.position, tx.normal, tracer)
        indirect = relight(data, [light], tracer)[tx.xy[:, 1], tx.xy[:, 0], :3]
        preds = {"data-driven": direct + indirect,
                 "transfer textures": shp.transfer.radiance(env.sh_coefficients(5))}
        mean_sq = float((ref.mean ** 2).mean())
        row = {"light": i, "sun": (-np.asarray(light.direction)).round(3).tolist(),
               "noise": math.sqrt(ref.noise2.mean() / mean_sq)}
        for name, p in preds.items():
            raw2 = ((p - ref.mean) ** 2).mean(axis=1).mean()
            row[name] = math.sqrt(max(0.0, raw2 - ref.noise2.mean()) / mean_sq)
        rows.append(row)
        print(f"sky {i} (sun {row['sun']}): data-driven {row['data-driven']:.4f}, "
              f"transfer textures {row['transfer textures']:.4f} "
              f"(relative rms, reference noise {row['noise']:.4f})", flush=True)
    result = {"atlas": args.atlas, "spp": args.spp, "depth": args.depth, "rows": rows,
              "bake_seconds": {"data-driven": dd_seconds, "transfer textures": sh_seconds},
              "verdict": verdict}
    print(f"bake: data-driven {dd_seconds:.1f} s (48 skies), transfer textures "
          f"{sh_seconds:.1f} s; {verdict}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    sys.exit(main())
