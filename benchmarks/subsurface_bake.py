"""Benchmark: the translucent bake (issue 15) — its dataset's speed, the path tracer's time
at equal accuracy, and linear against gamma-space fitting (paper Fig. 6).

The ≥ 20k-triangle fin blob over a floor (prtcore.scenes.translucent.write_translucent_fin)
at a 512² atlas, K = 128 training + 16 held-out spot lights, P = 256 measurement points.
A sibling of benchmarks/bake_speed.py. One run prints and writes
benchmarks/results/subsurface_bake.json (and the images named below):

* wall time of the intake and of each transport sub-stage ("subsurface walks" among
  them), and the dataset's total (the transport stage: operators, direct light, solve);
* the path tracer at equal accuracy: at a low resolution the fast transport and the
  reference at a few spp are compared with a high-spp reference (noise-corrected relative
  RMSE); the reference's error follows c/√spp, which gives the spp at which it equals the
  fast path's error; that spp × the full-resolution texel count × the measured time per
  path is one configuration's reference time; × K against the dataset's time is the
  speed-up;
* linear vs gamma (g = 2.2) fits of the same dataset at n = 16: held-out relative RMSE
  pooled over the held-out lights, the projection bound, their ratio; and one camera view
  of the indirect light of the brightest held-out light: dataset, linear, gamma and
  their errors (×4), ``subsurface_gamma.png``.

Usage: python benchmarks/subsurface_bake.py [--resolution 512] [--lights 128] ...
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
for _p in (ROOT, ROOT / "benchmarks"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from bake_speed import add_equal_accuracy_args, equal_accuracy  # noqa: E402

from prtcore.core.progress import StageTimer  # noqa: E402
from prtcore.core.raytrace import RayTracer  # noqa: E402
from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.emitters.families import sample_configurations  # noqa: E402
from prtcore.methods.base import BakeInputs  # noqa: E402
from prtcore.methods.data_driven import DataDriven  # noqa: E402
from prtcore.pipeline import run_intake  # noqa: E402
from prtcore.scenes.translucent import write_translucent_fin  # noqa: E402
from prtcore.transport.dataset import bake_dataset  # noqa: E402
from prtcore.transport.noise import DENOISE_FALLBACK, with_denoise  # noqa: E402

OUT = ROOT / "benchmarks" / "results"


def make_spec(resolution: int, lights: int, holdout: int, points: int, walks: int,
              rays: int, gamma: float | None = None, padding: int = 4):
    return parse_spec({
        "atlas": {"resolution": resolution, "padding": padding},
        "measurement_points": {"count": points},
        "lights": {"count": lights, "holdout": holdout, "families": [
            {"type": "spot", "position": {"shell": [1.5, 2.5]}, "aim": {"jitter": 0.2},
             "intensity": {"log_uniform": [5, 50]}}]},
        "transport": {"gather_rays": rays, "subsurface_walks": walks},
        "fit": {"basis": 16, "gamma": gamma},
    })


def camera_view(intake, values: np.ndarray, size: int = 256) -> np.ndarray:
    """(size, size, 3) image of per-texel values seen from a camera in front of the fin
    (nearest texel through TEXCOORD_1 at each primary hit; black elsewhere)."""
    from prtcore.reference.camera import camera_from_dict

    scene, texels = intake.scene, intake.texels
    cam = camera_from_dict({"position": [0.4, 1.0, 4.0], "target": [0.0, 0.4, 0.0],
                            "fov_y_deg": 45.0, "width": size, "height": size})
    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    o, d = cam.primary_rays()
    hits = tracer.intersect(o, d)
    sel = np.flatnonzero(hits.hit & hits.front)
    uv = np.einsum("nk,nkj->nj", hits.barycentric[sel],
                   scene.uv1[scene.faces[hits.triangle[sel]]])
    x = np.clip((uv[:, 0] * texels.width).astype(np.int64), 0, texels.width - 1)
    y = np.clip((uv[:, 1] * texels.height).astype(np.int64), 0, texels.height - 1)
    lut = np.full(texels.width * texels.height, -1, np.int64)
    lut[texels.xy[:, 1].astype(np.int64) * texels.width + texels.xy[:, 0]] = np.arange(
        texels.count)
    t = lut[y * texels.width + x]
    img = np.zeros((size * size, 3))
    ok = t >= 0
    img[sel[ok]] = values[t[ok]]
    return img.reshape(size, size, 3)


def save_strip(images: list[np.ndarray], labels: list[str], path: Path, scale: float) -> None:
    from PIL import Image, ImageDraw

    tiles = []
    for im, label in zip(images, labels, strict=True):
        v = np.clip(im * scale, 0, 1) ** (1 / 2.2)
        tile = Image.fromarray((v * 255).astype(np.uint8))
        ImageDraw.Draw(tile).text((4, 4), label, fill=(255, 255, 0))
        tiles.append(tile)
    strip = Image.new("RGB", (sum(t.width for t in tiles), tiles[0].height))
    x = 0
    for t in tiles:
        strip.paste(t, (x, 0))
        x += t.width
    strip.save(path)


def gamma_comparison(intake, train, hold, data, args, log) -> dict:
    from prtcore.fit.transfer import reconstruct

    out = {}
    models = {}
    for label, g in (("linear", None), ("gamma", 2.2)):
        spec = with_denoise(dataclasses.replace(intake.spec, fit=dataclasses.replace(
            intake.spec.fit, gamma=g)), DENOISE_FALLBACK)  # the bake's radius when unmeasured
        inputs = BakeInputs(spec=spec, intake=dataclasses.replace(intake, spec=spec),
                            train=train, hold=hold, keyframes=None, data=data)
        res = DataDriven().fit(inputs, StageTimer(quiet=True))
        row = next(r for r in res.table["rows"] if r["n"] == 16)
        keys = [k for k in row if "pooled" in k or "rmse" in k or "bound" in k]
        out[label] = {k: row[k] for k in keys}
        models[label] = res.model
        log(f"{label:7s} n = 16: " + ", ".join(f"{k} {row[k]:.4f}" for k in keys
                                                 if isinstance(row[k], float)))
    from prtcore.receivers.smoothing import smooth_texels, smoothing_operator

    k0 = len(train)
    # the brightest held-out light that reaches the measurement points (the table skips
    # the others), against its lightmap through the same filter as the table's reference
    norms = [float(np.linalg.norm(data.indirect[:, k0 + h]))
             if np.linalg.norm(data.direct_points[:, k0 + h]) > 0 else -1.0
             for h in range(len(hold))]
    h = int(np.argmax(norms))
    x = data.direct_points[:, k0 + h].astype(np.float64)
    ref = data.indirect[:, k0 + h:k0 + h + 1].astype(np.float32)
    radius = with_denoise(intake.spec, DENOISE_FALLBACK).fit.denoise
    if radius > 0:
        ref = smooth_texels(intake.texels, ref, operator=smoothing_operator(
            intake.texels, radius=radius))
    ref = np.asarray(ref[:, 0], np.float64)
    rec = {k: reconstruct(m, x, n=16).astype(np.float64) for k, m in models.items()}
    views = [camera_view(intake, v) for v in (ref, rec["linear"], rec["gamma"])]
    errs = [np.abs(views[1] - views[0]) * 4, np.abs(views[2] - views[0]) * 4]
    scale = 1.0 / max(float(np.percentile(views[0][views[0] > 0], 99)), 1e-12) \
        if (views[0] > 0).any() else 1.0
    OUT.mkdir(parents=True, exist_ok=True)
    save_strip([*views, *errs], ["dataset (denoised)", "linear n=16", "gamma 2.2 n=16",
                                 "|linear-data| x4", "|gamma-data| x4"],
               OUT / "subsurface_gamma.png", scale)
    for k in rec:
        out[k]["this_light_rel_rmse"] = float(np.sqrt(((rec[k] - ref) ** 2).mean()
                                                      / (ref ** 2).mean()))
    out["light"] = h
    return out


def reference_equivalence(args, log) -> dict:
    """Reference spp and time per path for the fast path's accuracy at a low resolution."""
    spec = make_spec(args.low_resolution, args.lights, args.holdout, args.points,
                     args.walks, args.gather_rays, padding=2)
    with tempfile.TemporaryDirectory() as tmp:
        intake = run_intake(write_translucent_fin(Path(tmp) / "fin.glb"), spec, quiet=True)
    scene, texels, points = intake.scene, intake.texels, intake.points
    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    train, _ = sample_configurations(spec.lights, scene.center, scene.radius)
    configs = list(train[:args.configs])
    log(f"reference equivalence at {args.low_resolution}²: {texels.count} texels, "
        f"{len(configs)} configurations, high-spp reference {args.ref_spp_high} spp …")
    out = equal_accuracy(scene, texels, points, tracer, configs, spec.transport, args)
    log(f"  fast rRMSE {np.round(out['fast_rel_rmse'], 4).tolist()}, bias "
        f"{np.round(out['fast_bias'], 4).tolist()}; reference c/√spp: c = "
        f"{np.round(out['reference_c'], 3).tolist()} → spp at equal error "
        f"{np.round(out['spp_at_equal_error'], 1).tolist()}; "
        f"{out['seconds_per_path'] * 1e6:.1f} µs per path")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--lights", type=int, default=128)
    ap.add_argument("--holdout", type=int, default=16)
    ap.add_argument("--points", type=int, default=256)
    ap.add_argument("--walks", type=int, default=16)
    ap.add_argument("--gather-rays", type=int, default=32)
    add_equal_accuracy_args(ap, ref_spp_high=2048, ref_spp_timing=32)
    args = ap.parse_args(argv)

    def log(s: str) -> None:
        print(s, flush=True)

    spec = make_spec(args.resolution, args.lights, args.holdout, args.points, args.walks,
                     args.gather_rays)
    timer = StageTimer(quiet=True)
    with tempfile.TemporaryDirectory() as tmp:
        asset = write_translucent_fin(Path(tmp) / "fin.glb")
        t0 = time.perf_counter()
        intake = run_intake(asset, spec, timer=timer)
        t_intake = time.perf_counter() - t0
    scene, texels, points = intake.scene, intake.texels, intake.points
    train, hold = sample_configurations(spec.lights, scene.center, scene.radius)
    log(f"fin blob: {scene.triangle_count} triangles, {texels.count} texels at "
        f"{args.resolution}², intake {t_intake:.1f} s")
    tracer = RayTracer(scene.positions, scene.faces, scene.radius)
    t0 = time.perf_counter()
    data = bake_dataset(scene, texels, points, train, hold, spec.transport, timer,
                        tracer=tracer)
    t_data = time.perf_counter() - t0
    stages = data.stats["seconds"]
    log(f"dataset ({len(train)} + {len(hold)} lights): {t_data:.1f} s — " + ", ".join(
        f"{k} {v:.1f} s" for k, v in stages.items()))
    log(f"  walks: {data.stats['subsurface']}")
    result = {"resolution": args.resolution, "triangles": scene.triangle_count,
              "texels": texels.count, "intake_seconds": t_intake,
              "dataset_seconds": t_data, "stage_seconds": stages,
              "subsurface": data.stats["subsurface"], "iterations": data.iterations,
              "args": vars(args)}
    result["gamma"] = gamma_comparison(intake, train, hold, data, args, log)
    if not args.skip_reference:
        eq = reference_equivalence(args, log)
        one = eq["spp_star"] * texels.count * eq["seconds_per_path"]
        eq["reference_seconds_one_configuration_at_full_resolution"] = one
        eq["speedup"] = one * len(train) / t_data
        log(f"path tracing {len(train)} configurations at equal accuracy ≈ "
            f"{one * len(train):.0f} s → speed-up {eq['speedup']:.1f}×")
        result["reference"] = eq
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "subsurface_bake.json").write_text(json.dumps(result, indent=2, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
