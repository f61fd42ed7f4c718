"""Benchmark: does the gather's per-texel noise enter the basis, and what removes it?

Issue 13 ("noise in the dataset stays out of the basis"). One scene (default: the open
room of :mod:`prtcore.scenes.open_room`), its light family, K training + H held-out
lights, P blue-noise points. The dataset is computed three ways:

* ``rays M``   — the fast transport at the spec's default gather count (64 rays / texel);
* ``filtered`` — the same dataset, indirect lightmaps smoothed in texel space before the
  fit by the seam-aware filter :func:`prtcore.receivers.smoothing.smooth_texels`;
* ``more``     — the fast transport at ``--more-rays`` (256) rays / texel, the other
  remedy (a gather count sized to the atlas), at about 4× the gather's cost;
* ``ref``      — the fast transport at ``--ref-rays`` (1024) rays / texel, the
  low-noise stand-in for the reference.

Printed (and written to benchmarks/results/basis_noise.json): the noise of each dataset
against ``ref`` (pooled relative RMSE over the training lights); per basis element the
roughness ‖U − W U‖ / ‖U‖ (W: the filter, so this is the energy above the filter's
band, noise-dominated) and the cosine to the reference element; and the held-out error at
n = 16 against the ``ref`` held-out lightmaps. Images (PNG, benchmarks/results/):
basis_noise_before.png (elements 1–4 at 64 rays), basis_noise_after.png (filtered),
basis_noise_ref.png (1024 rays), each with a nearest-neighbour zoom of one region, signs
aligned with the reference, one colour scale per element across the three.

Usage: python benchmarks/basis_noise.py [--scene open_room|cornell] [--resolution 128]
       [--lights 64] [--rays 64] [--ref-rays 1024] [--radius 1.5]
About a minute on 2 cores at the defaults.
"""

from __future__ import annotations

import argparse
import copy
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
from prtcore.emitters.families import sample_configurations  # noqa: E402
from prtcore.fit.model import relative_rmse  # noqa: E402
from prtcore.fit.transfer import fit_transfer, projection_bound, reconstruct  # noqa: E402
from prtcore.pipeline import run_intake  # noqa: E402
from prtcore.receivers.smoothing import smooth_texels, smoothing_operator  # noqa: E402
from prtcore.receivers.texels import texels_to_image  # noqa: E402
from prtcore.scenes import open_room  # noqa: E402
from prtcore.scenes.cornell import EXAMPLE_SPEC, write_cornell_box  # noqa: E402
from prtcore.transport.dataset import bake_dataset  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
SCENES = {"open_room": (open_room.write_open_room, open_room.LIGHT_FAMILIES),
          "cornell": (write_cornell_box, EXAMPLE_SPEC["lights"]["families"])}
N_BASIS = 16
ELEMENTS = (1, 2, 3, 4)


def pooled(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a.astype(np.float64) - b) / np.linalg.norm(b))


def heldout(model, Dh: np.ndarray, Ih_ref: np.ndarray) -> dict:
    errs, bounds = [], []
    for h in range(Dh.shape[1]):
        x, ref = Dh[:, h].astype(np.float64), Ih_ref[:, h].astype(np.float64)
        if not (np.linalg.norm(x) > 0 and np.linalg.norm(ref) > 0):
            continue
        errs.append(relative_rmse(reconstruct(model, x, n=N_BASIS), ref))
        bounds.append(projection_bound(model, ref, x, n=N_BASIS))
    return {"heldout_rmse_mean": float(np.mean(errs)), "heldout_rmse_max": float(np.max(errs)),
            "projection_bound_mean": float(np.mean(bounds))}


def save_panel(path: Path, texels, bases: np.ndarray, scales: list[float], title: str,
               zoom: tuple[slice, slice]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ne = bases.shape[1]
    img = texels_to_image(texels, bases, dilate=False)  # (H, W, ne + 1): last = coverage
    cov = img[:, :, -1] > 0
    fig, axes = plt.subplots(2, ne, figsize=(3.2 * ne, 6.6), squeeze=False)
    for e in range(ne):
        plane = np.where(cov, img[:, :, e], np.nan)
        for row, (a, sl) in enumerate(((axes[0, e], (slice(None), slice(None))),
                                       (axes[1, e], zoom))):
            a.imshow(plane[sl], cmap="RdBu_r", vmin=-scales[e], vmax=scales[e],
                     interpolation="nearest")
            a.set_xticks([])
            a.set_yticks([])
            if row == 0:
                a.set_title(f"element {ELEMENTS[e]}")
                y, x = zoom
                a.add_patch(matplotlib.patches.Rectangle(
                    (x.start - 0.5, y.start - 0.5), x.stop - x.start, y.stop - y.start,
                    fill=False, ec="k", lw=1))
            else:
                a.set_title("zoom (texels)", fontsize=9)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="open_room", choices=list(SCENES))
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--lights", type=int, default=64)
    ap.add_argument("--holdout", type=int, default=16)
    ap.add_argument("--points", type=int, default=256)
    ap.add_argument("--rays", type=int, default=64)
    ap.add_argument("--more-rays", type=int, default=256)
    ap.add_argument("--ref-rays", type=int, default=1024)
    ap.add_argument("--radius", type=float, default=1.5,
                    help="filter radius in texel sizes")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args(argv)

    write, families = SCENES[args.scene]
    spec_d = {
        "atlas": {"resolution": args.resolution, "padding": 2},
        "measurement_points": {"count": args.points, "supersample": 4, "seed": 1},
        "lights": {"count": args.lights, "holdout": args.holdout, "seed": 2,
                   "families": copy.deepcopy(families)},
        "transport": {"gather_rays": args.rays, "max_bounces": 16, "tolerance": 0.001},
        "fit": {"basis": N_BASIS, "ridge": "auto", "channels": "mono"},
    }
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        spec = parse_spec(spec_d)
        intake = run_intake(write(Path(tmp) / f"{args.scene}.glb"), spec, quiet=True)
    sc, texels, points = intake.scene, intake.texels, intake.points
    tracer = RayTracer(sc.positions, sc.faces, sc.radius, threads=args.threads)
    train, hold = sample_configurations(spec.lights, sc.center, sc.radius, sc.lights)
    K = len(train)
    data = {}
    seconds = {}
    for label, rays in (("rays", args.rays), ("more", args.more_rays), ("ref", args.ref_rays)):
        ts = time.perf_counter()
        sp_ = parse_spec({**spec_d, "transport": {**spec_d["transport"], "gather_rays": rays}})
        ds = bake_dataset(sc, texels, points, train, hold, sp_.transport, tracer=tracer)
        data[label] = (ds.direct_points, ds.indirect)
        seconds[f"transport_{label}"] = time.perf_counter() - ts
    ts = time.perf_counter()
    W = smoothing_operator(texels, radius=args.radius)
    data["filtered"] = (data["rays"][0], smooth_texels(texels, data["rays"][1], operator=W))
    seconds["filter"] = time.perf_counter() - ts
    I_ref = data["ref"][1]

    results = {}
    models = {}
    for label in ("rays", "filtered", "more", "ref"):
        D, I = data[label]
        model = fit_transfer(D[:, :K], I[:, :K], basis=N_BASIS, ridge="auto", channels="mono")
        models[label] = model
        results[label] = {
            "dataset_noise_vs_ref": pooled(I[:, :K], I_ref[:, :K]) if label != "ref" else 0.0,
            **heldout(model, D[:, K:], I_ref[:, K:]),
        }
    U_ref = models["ref"].basis.astype(np.float64)
    for label, model in models.items():
        U = model.basis.astype(np.float64)
        rough = np.linalg.norm(U - W @ U, axis=0) / np.linalg.norm(U, axis=0)
        cos = np.abs(np.sum(U * U_ref, axis=0)) / (np.linalg.norm(U, axis=0)
                                                   * np.linalg.norm(U_ref, axis=0))
        results[label]["roughness"] = [float(v) for v in rough[:8]]
        results[label]["cos_to_ref"] = [float(v) for v in cos[:8]]

    # images: elements 1..4, signs aligned with the reference, one scale per element
    cols = [e - 1 for e in ELEMENTS]
    panels = {}
    for label, model in models.items():
        U = model.basis[:, cols].astype(np.float64)
        sign = np.sign(np.sum(U * U_ref[:, cols], axis=0))
        panels[label] = U * np.where(sign == 0, 1.0, sign)
    scales = [float(np.percentile(np.abs(panels["ref"][:, e]), 99.5)) for e in range(len(cols))]
    # zoom: the 32 × 32 texel window around the densest covered region's centre
    h = w = 32
    cy, cx = (np.median(texels.xy[:, 1]).astype(int), np.median(texels.xy[:, 0]).astype(int))
    y0 = int(np.clip(cy - h // 2, 0, texels.height - h))
    x0 = int(np.clip(cx - w // 2, 0, texels.width - w))
    zoom = (slice(y0, y0 + h), slice(x0, x0 + w))
    args.out.mkdir(parents=True, exist_ok=True)
    names = {"rays": "basis_noise_before.png", "filtered": "basis_noise_after.png",
             "ref": "basis_noise_ref.png"}
    titles = {"rays": f"{args.scene} basis, {args.rays} gather rays (before)",
              "filtered": f"{args.scene} basis, {args.rays} rays + seam-aware filter "
                          f"r = {args.radius} texels (after)",
              "ref": f"{args.scene} basis, {args.ref_rays} gather rays (reference)"}
    for label in names:
        save_panel(args.out / names[label], texels, panels[label], scales, titles[label], zoom)

    print(f"{args.scene}: {texels.count} texels at {args.resolution}², K = {K} + "
          f"H = {len(hold)}, P = {points.count}; " + ", ".join(
              f"{k} {v:.1f} s" for k, v in seconds.items()))
    print(f"{'dataset':<10s} {'noise':>7s} {'held-out':>9s} {'(max)':>7s} {'bound':>7s}   "
          f"roughness of elements 1-4        cos to ref 1-4")
    for label, r in results.items():
        print(f"{label:<10s} {100 * r['dataset_noise_vs_ref']:>6.1f}% "
              f"{100 * r['heldout_rmse_mean']:>8.1f}% {100 * r['heldout_rmse_max']:>6.0f}% "
              f"{100 * r['projection_bound_mean']:>6.1f}%   "
              + " ".join(f"{v:5.2f}" for v in r["roughness"][:4]) + "    "
              + " ".join(f"{v:5.3f}" for v in r["cos_to_ref"][:4]))
    print("noise: pooled relative RMSE of the training lightmaps against ref; held-out "
          f"and bound at n = {N_BASIS} against ref's held-out lightmaps; roughness "
          "‖U − W U‖/‖U‖ with W the filter")
    out = {"benchmark": "basis_noise", "issue": 13, "config": {
        k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "texels": texels.count, "seconds": seconds, "results": results,
        "images": {k: str((args.out / v).relative_to(ROOT)) if args.out.is_relative_to(ROOT)
                   else str(args.out / v) for k, v in names.items()},
        "total_seconds": time.perf_counter() - t0}
    (args.out / "basis_noise.json").write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.out / 'basis_noise.json'} and the images")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
