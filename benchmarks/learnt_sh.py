"""Benchmark: learnt SH transfer σ(p, n̂) against transfer textures (issue 18, thesis
Tables 4.1–4.4).

Scene (``--scene``): ``floor_object``, the project's object on a floor
(:mod:`prtcore.scenes.floor_object`, the default); ``plant``, leaf cards on a floor, the
mesh with high-frequency visibility (:mod:`prtcore.scenes.plant`); ``bunny`` and
``old_car``, the SDF scenes (:mod:`prtcore.scenes.sdf_scenes`, ``*.sdf.json``), each at its
module's spec's atlas. An SDF scene goes the way a ``learnt_sh`` bake of the file goes:
intake gives its marching-cubes mesh, the training samples are projected onto the
field's zero level set (:func:`prtcore.io.sdf.asset_sdf`), and the metrics are measured
on the mesh against transfer textures on the same mesh.

For each network size of ``--sizes`` (thesis: k = 64 and 128, l = 4) and each training
configuration of ``--configs`` (``SAMPLESxSTRATA``: area-uniform samples × strata² rays
each — fewer samples with more rays give less noisy targets at a similar ray count), the
network is trained (:func:`prtcore.fit.learnt_sh.fit_learnt_sh`, glossy
outputs with ``--specular`` > 0) and measured by the very function a ``learnt_sh`` bake
stores its metrics with (:func:`prtcore.methods.learnt_sh.view_metrics`): ``--views``
orbit cameras under a sky with a sun, the diffuse material and (glossy) diffuse + Phong,
MAE / PSNR / SSIM of the display images against transfer textures of
``--baseline-strata``² rays per texel, and the same textures from independent rays (the
ceiling the reference's own noise sets).

With ``--cells nx,ny,nz`` each size is one network per grid cell (sub-scenes, thesis
4.1.5, :mod:`prtcore.fit.subscenes`), trained on its cell grown by ``--overlap``.

Usage: python benchmarks/learnt_sh.py [--scene floor_object|plant|bunny|old_car]
       [--views 30] [--configs 8000x6,8000x16]
       [--steps 1500] [--batch 512] [--sizes k64_l4,k128_l4] [--specular 0.5]
       [--baseline-strata 16] [--cells 1,1,1] [--overlap 0.1] [--out FILE.json]
Writes benchmarks/results/learnt_sh_<scene>.json and learnt_sh_<scene>_views.png (first
view of the last row: baseline | learnt | |difference| × 4, one row per material).
The tables of all four scenes (defaults, and 16000x16): docs/learnt_sh.md, "Measured".
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

from prtcore.core.raytrace import RayTracer  # noqa: E402
from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.fit.learnt_sh import SIZES  # noqa: E402
from prtcore.fit.subscenes import fit_scenes  # noqa: E402
from prtcore.io.imageio import write_png  # noqa: E402
from prtcore.io.sdf import asset_sdf  # noqa: E402
from prtcore.methods.learnt_sh import albedo_atlas, format_metrics, view_metrics  # noqa: E402
from prtcore.pipeline import run_intake  # noqa: E402
from prtcore.scenes import floor_object, plant, sdf_scenes  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
#: --scene: the asset's file name, its writer and the bake spec intake takes
SCENES = {
    "floor_object": ("scene.glb", floor_object.write_floor_object, floor_object.SPEC),
    "plant": ("scene.glb", plant.write_plant, plant.SPEC),
    "bunny": ("bunny.sdf.json", sdf_scenes.write_bunny, sdf_scenes.BUNNY_SPEC),
    "old_car": ("old_car.sdf.json", sdf_scenes.write_old_car, sdf_scenes.OLD_CAR_SPEC),
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", choices=sorted(SCENES), default="floor_object")
    ap.add_argument("--views", type=int, default=30)
    ap.add_argument("--width", type=int, default=96)
    ap.add_argument("--height", type=int, default=64)
    ap.add_argument("--configs", default="8000x6,8000x16",
                    help="training samples x strata (rays per sample = strata²), comma-separated")
    ap.add_argument("--bands", type=int, default=4)
    ap.add_argument("--baseline-strata", type=int, default=16,
                    help="the textures' rays per texel = this²")
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--batch", type=int, default=512)
    ap.add_argument("--sizes", default=",".join(sorted(SIZES)))
    ap.add_argument("--specular", type=float, default=0.5,
                    help="ρ_s of the glossy material (0: diffuse only)")
    ap.add_argument("--exponent", type=float, default=8.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cells", default="1,1,1",
                    help="sub-scenes: nx,ny,nz grid cells, one network each (thesis 4.1.5)")
    ap.add_argument("--overlap", type=float, default=0.1,
                    help="δ: each cell's training box grows by this share of its size")
    ap.add_argument("--out", type=Path, help="default: benchmarks/results/learnt_sh_<scene>.json")
    args = ap.parse_args(argv)
    if args.out is None:
        args.out = RESULTS / f"learnt_sh_{args.scene}.json"

    file, write, spec = SCENES[args.scene]
    with tempfile.TemporaryDirectory() as tmp:
        asset = write(Path(tmp) / file)
        intake = run_intake(asset, parse_spec(spec), quiet=True)
        sdf = asset_sdf(asset)  # an SDF scene: samples on its zero level set
    scene, texels = intake.scene, intake.texels
    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    _, albedo_image = albedo_atlas(scene, texels)
    results, strip = [], None
    cells = tuple(int(c) for c in args.cells.split(","))
    for config in args.configs.split(","):
        samples, strata = (int(v) for v in config.split("x"))
        for name in args.sizes.split(","):
            width, layers = SIZES[name]
            t0 = time.perf_counter()
            model = fit_scenes(scene, tracer, cells=cells, overlap=args.overlap,
                               samples=samples, bands=args.bands, strata=strata, width=width,
                               layers=layers, steps=args.steps, batch=args.batch,
                               seed=args.seed, glossy=args.specular > 0, sdf=sdf)
            seconds = time.perf_counter() - t0
            metrics, strip = view_metrics(
                scene, tracer, texels, model, albedo_image, views=args.views,
                width=args.width, height=args.height, strata=args.baseline_strata,
                seed=args.seed, specular=args.specular, exponent=args.exponent)
            print(f"\n== {name}, {samples} samples × {strata}² rays, {args.steps} steps of "
                  f"{args.batch}: trained in {seconds:.1f} s, held-out MSE "
                  f"{model.diagnostics['holdout_mse']:.3g}")
            print(format_metrics(metrics), flush=True)
            results.append({"network": name, "cells": list(cells), "samples": samples,
                            "strata": strata,
                            "train_seconds": seconds, "diagnostics": model.diagnostics,
                            "metrics": metrics})
    print(f"\nsummary, {args.scene} (PSNR dB / SSIM, learnt vs transfer textures; "
          "ceiling = textures reseeded)")
    for r in results:
        cells = [f"{row['material']} {row['psnr']:.2f} / {row['ssim']:.3f}"
                 for row in r["metrics"]["rows"] if row["method"].startswith("learnt")]
        ceiling = [f"{row['psnr']:.2f}" for row in r["metrics"]["rows"]
                   if row["method"] == "baseline_reseeded"]
        print(f"{r['network']:<8s} {r['samples']:>6d} × {r['strata']:>2d}²: "
              f"{'; '.join(cells)}  (ceiling {', '.join(ceiling)})")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if strip is not None:
        write_png(args.out.with_name(f"{args.out.stem}_views.png"),
                  np.round(strip * 255).astype(np.uint8))
    args.out.write_text(json.dumps({"benchmark": "learnt_sh", "issue": 18,
                                    "scene": args.scene,
                                    "config": {k: str(v) for k, v in vars(args).items()},
                                    "results": results}, indent=2, default=float) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
