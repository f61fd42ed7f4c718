"""Benchmark: learnt SH transfer σ(p, n̂) against transfer textures (issue 18, thesis
Tables 4.1–4.4 in part).

Scene: the project's object on a floor (:mod:`prtcore.scenes.floor_object`), its key
light (directional) projected on L = 4 bands (:func:`prtcore.emitters.environment.light_sh`).
Baseline: transfer textures (:func:`prtcore.methods.sh_prt.bake_sh_prt`, storage
"texture", shadowed, no bounce, the same bands, ``--baseline-strata``² rays per texel) at
the floor_object spec's atlas. Learnt: :func:`prtcore.fit.learnt_sh.fit_learnt_sh` for each size of
``SIZES`` (k = 64 and 128, l = 4), trained on area-uniform samples of the same scene
(``--strata``² rays per sample). Both are shaded diffuse: ``albedo · (T · l)`` per channel at the
surface point each pixel centre sees, for ``--views`` cameras on an orbit around the
scene; the images are clipped to [0, 1] and sRGB-encoded, then compared (learnt against
the baseline, as the thesis does): MAE, PSNR (peak 1) and SSIM (luminance, Gaussian window
σ = 1.5), averaged over the views. The baseline baked again from independent rays is
compared the same way: its figures are the ceiling set by the reference's own noise. Also
the weights' size (float32) against the textures'
(half), and the times.

Not covered here (said in the issue's note): glossy Phong (triple product), the GL frame
time, SDF scenes, a high-frequency-visibility mesh, ``prtcore report`` output.

Usage: python benchmarks/learnt_sh.py [--views 30] [--samples 8000] [--strata 6]
       [--baseline-strata 16]
       [--steps 1500] [--batch 512] [--sizes k64_l4,k128_l4] [--out FILE.json]
Writes benchmarks/results/learnt_sh.json and learnt_sh_views.png (first view: baseline,
each size, |difference| × 4).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from prtcore.core.geometry import shading_normals  # noqa: E402
from prtcore.core.materials import albedo_at, clamp_albedo, linear_to_srgb  # noqa: E402
from prtcore.core.raytrace import RayTracer  # noqa: E402
from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.emitters.environment import light_sh  # noqa: E402
from prtcore.fit.learnt_sh import SIZES, evaluate, fit_learnt_sh  # noqa: E402
from prtcore.io.imageio import write_png  # noqa: E402
from prtcore.methods.sh_prt import TEXTURE_BYTES, bake_sh_prt, evaluate_texture  # noqa: E402
from prtcore.pipeline import run_intake  # noqa: E402
from prtcore.reference.camera import Camera  # noqa: E402
from prtcore.scenes import floor_object  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
BANDS = 4


def orbit(scene, views: int, width: int, height: int) -> list[Camera]:
    """``views`` cameras on a circle around the scene, 30° above its centre."""
    c, r = np.asarray(scene.center, float), float(scene.radius)
    cams = []
    for k in range(views):
        a = 2 * np.pi * k / views
        eye = c + 2.2 * r * np.array([np.cos(a) * np.cos(0.5), np.sin(0.5),
                                      np.sin(a) * np.cos(0.5)])
        cams.append(Camera(position=eye, target=c, up=np.array([0.0, 1.0, 0.0]),
                           fov_y_deg=40.0, width=width, height=height))
    return cams


def ssim(a: np.ndarray, b: np.ndarray, sigma: float = 1.5) -> float:
    """Mean SSIM (Wang et al. 2004) of two (h, w) images in [0, 1]."""
    c1, c2 = 0.01**2, 0.03**2
    mu_a, mu_b = gaussian_filter(a, sigma), gaussian_filter(b, sigma)
    va = gaussian_filter(a * a, sigma) - mu_a**2
    vb = gaussian_filter(b * b, sigma) - mu_b**2
    cov = gaussian_filter(a * b, sigma) - mu_a * mu_b
    s = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (va + vb + c2))
    return float(s.mean())


def display(rgb: np.ndarray) -> np.ndarray:
    return linear_to_srgb(np.clip(rgb, 0.0, 1.0))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--views", type=int, default=30)
    ap.add_argument("--width", type=int, default=96)
    ap.add_argument("--height", type=int, default=64)
    ap.add_argument("--samples", type=int, default=8000)
    ap.add_argument("--strata", type=int, default=6, help="training rays = strata²")
    ap.add_argument("--baseline-strata", type=int, default=16,
                    help="the textures' rays per texel = this²")
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--batch", type=int, default=512)
    ap.add_argument("--sizes", default=",".join(sorted(SIZES)))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=RESULTS / "learnt_sh.json")
    args = ap.parse_args(argv)
    sizes = args.sizes.split(",")

    with tempfile.TemporaryDirectory() as tmp:
        asset = floor_object.write_floor_object(Path(tmp) / "scene.glb")
        intake = run_intake(asset, parse_spec(floor_object.SPEC), quiet=True)
    scene, texels = intake.scene, intake.texels
    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    lsh = light_sh(floor_object.key_light(), BANDS)
    t0 = time.perf_counter()
    base = bake_sh_prt(scene, tracer, "texture", BANDS, args.baseline_strata, args.seed,
                       bounce=False, texels=texels)
    seconds = {"baseline": time.perf_counter() - t0}
    # the baseline's own Monte-Carlo noise: the same textures from independent rays
    # (seed + 1) compared with it like a network ("baseline_reseeded": the PSNR ceiling
    # any method reaches against this reference)
    again = bake_sh_prt(scene, tracer, "texture", BANDS, args.baseline_strata, args.seed + 1,
                        bounce=False, texels=texels)
    models = {}
    for name in sizes:
        width, layers = SIZES[name]
        t0 = time.perf_counter()
        models[name] = fit_learnt_sh(scene, tracer, samples=args.samples, bands=BANDS,
                                     strata=args.strata, width=width, layers=layers,
                                     steps=args.steps, batch=args.batch, seed=args.seed)
        seconds[name] = time.perf_counter() - t0
        print(f"{name}: trained in {seconds[name]:.1f} s", flush=True)

    compared = [*sizes, "baseline_reseeded"]
    metrics = {name: {"mae": [], "psnr": [], "ssim": []} for name in compared}
    strip = []
    for v, cam in enumerate(orbit(scene, args.views, args.width, args.height)):
        origins, dirs = cam.primary_rays()
        hits = tracer.intersect(origins, dirs)
        sel = np.flatnonzero(hits.hit & hits.front)
        tri, bary = hits.triangle[sel], hits.barycentric[sel]
        uv1 = np.einsum("mk,mkj->mj", bary, np.asarray(scene.uv1)[scene.faces[tri]])
        pos = tracer.surface_point(tri, bary)
        nrm = shading_normals(scene, tri, bary, tracer.face_normals[tri])
        rho, _ = clamp_albedo(albedo_at(scene, tri, bary))
        images = {"baseline": np.zeros((args.height * args.width, 3))}
        images["baseline"][sel] = evaluate_texture(base.image, uv1, lsh)
        images["baseline_reseeded"] = np.zeros_like(images["baseline"])
        images["baseline_reseeded"][sel] = evaluate_texture(again.image, uv1, lsh)
        for name, model in models.items():
            img = np.zeros((args.height * args.width, 3))
            img[sel] = rho * (evaluate(model, pos, nrm) @ lsh)
            images[name] = img
        shown = {k: display(im.reshape(args.height, args.width, 3))
                 for k, im in images.items()}
        for name in compared:
            a, b = shown[name], shown["baseline"]
            mse = float(np.mean((a - b) ** 2))
            metrics[name]["mae"].append(float(np.mean(np.abs(a - b))))
            metrics[name]["psnr"].append(10 * np.log10(1.0 / mse) if mse > 0 else
                                         float("inf"))
            lum = np.array([0.2126, 0.7152, 0.0722])
            metrics[name]["ssim"].append(ssim(a @ lum, b @ lum))
        if v == 0:
            row = [shown["baseline"]] + [shown[n] for n in sizes]
            diff = [np.clip(4 * np.abs(shown[n] - shown["baseline"]), 0, 1) for n in sizes]
            strip = np.concatenate([np.concatenate(row, axis=1),
                                    np.concatenate([np.zeros_like(row[0]), *diff], axis=1)])
    texture_bytes = texels.width * texels.height * 3 * BANDS**2 * TEXTURE_BYTES
    rows = []
    print(f"{'network':<9s} {'MAE':>7s} {'PSNR dB':>8s} {'SSIM':>6s} {'weights B':>10s} "
          f"{'textures B':>11s} {'train s':>8s} {'holdout mse':>12s}")
    for name in sizes:
        net = models[name].net
        wbytes = 4 * sum(w.size + b.size for w, b in zip(net.weights, net.biases,
                                                          strict=True))
        row = {"network": name, **{k: float(np.mean(v)) for k, v in metrics[name].items()},
               "psnr_min": float(np.min(metrics[name]["psnr"])),
               "weights_bytes": int(wbytes), "texture_bytes": int(texture_bytes),
               "seconds": seconds[name], "diagnostics": models[name].diagnostics}
        rows.append(row)
        print(f"{name:<9s} {row['mae']:>7.4f} {row['psnr']:>8.2f} {row['ssim']:>6.3f} "
              f"{wbytes:>10d} {texture_bytes:>11d} {row['seconds']:>8.1f} "
              f"{row['diagnostics']['holdout_mse']:>12.3g}")
    noise = {k: float(np.mean(v)) for k, v in metrics["baseline_reseeded"].items()}
    print(f"{'baseline reseeded':<9s} {noise['mae']:>7.4f} {noise['psnr']:>8.2f} "
          f"{noise['ssim']:>6.3f}  (the reference's own noise: the ceiling)")
    print(f"{args.views} views {args.width}×{args.height}; baseline: transfer textures "
          f"{texels.width}×{texels.height}, {args.baseline_strata}² rays per texel, "
          f"{seconds['baseline']:.1f} s; learnt: {args.samples} samples × {args.strata}² "
          f"rays, {args.steps} steps of {args.batch}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_png(args.out.with_name("learnt_sh_views.png"),
              np.round(np.asarray(strip) * 255).astype(np.uint8))
    args.out.write_text(json.dumps({"benchmark": "learnt_sh", "issue": 18,
                                    "config": {k: str(v) for k, v in vars(args).items()},
                                    "rows": rows, "baseline_reseeded": noise,
                                    "seconds": seconds}, indent=2,
                                   default=float) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
