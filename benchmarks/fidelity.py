"""Benchmark: how close the transfer gets to the projection bound, per scene and placement.

Issue 13 ("Trustworthy bakes"). For each scene — the Cornell box, the open L-shaped room
(:mod:`prtcore.scenes.open_room`), the house on a ground plane
(:mod:`prtcore.scenes.exterior`) and the shared assets Duck and monkey — with the light
family that suits it, the fast transport is computed once for K_max training and H
held-out lights (one :func:`bake_dataset` pass lighting the N candidates and every
blue-noise set together, with the families' lights, ``gather_rays`` 64 = the default),
then for each measurement-point placement and each P, K:

* ``blue`` — the existing placement: P blue-noise points by sample elimination
  (:func:`prtcore.intake.points.place_measurement_points`, ``supersample`` S);
* ``qdeim`` — P of N dense blue-noise candidates (same placement with count N, same S)
  chosen by :func:`prtcore.intake.sensors.select_sensors` with its defaults: Q-DEIM on
  the candidates' direct light over the K training lights, on the modes carrying 99.9 %
  of its energy and for at most half the points, the rest by farthest-point coverage;
* ``qdeim-all`` — pure Q-DEIM: every one of the P points by the pivoted QR (as many
  modes as points, up to the rank; farthest-point fill only beyond the rank);
* ``goal`` — as ``qdeim`` with the modes ranked by the training basis coefficients they
  carry (targets: coefficients of a basis fitted with all N candidates);
* ``random`` — a control: P of the same candidates drawn at random (seeded), so that
  what Q-DEIM gains is told apart from what the candidates' own (smaller) supersample
  clusters change.

The transfer is fitted by :func:`prtcore.fit.transfer.fit_transfer` (basis 16, ridge
"auto", mono) on the first K training lights; the table gives, at n = 16 over the H
held-out lights, the mean (and max) per-light relative RMSE against the fast transport,
the mean projection bound (:func:`prtcore.fit.transfer.projection_bound`), their ratio
("ok": ≤ 1.25, issue 13's target), the same pooled over the held-out set
(√(Σ‖error‖² / Σ‖reference‖²): a light with almost no indirect light, e.g. from below the
Duck, does not read as 5000 %), and the time of the row (selection, fit, evaluation; the
shared intake and transport times are printed per scene). Training lights of a smaller K
are the first K of the K_max draw (the families' stream is sequential). The reference is
the fast transport of the held-out lights, noise included.

Note that the projection bound depends on the points: the fit normalises configuration k
by the norm of its direct vector at the P points, so the basis itself changes with them.

Usage: python benchmarks/fidelity.py [--scenes cornell,open_room,exterior,duck,monkey]
       [--resolution 128] [--points 64,256] [--lights 128] [--room-lights 128,512]
       [--holdout 32] [--candidates 2048] [--placements blue,random,qdeim,qdeim-all,goal]
       [--pillar-clearance 0.05] [--threads 2] [--out FILE.json]
Writes benchmarks/results/fidelity.json. The defaults take about 5 minutes on 2 shared
cores (most of it the open room's K = 512 rows).
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from prtcore.core.raytrace import RayTracer  # noqa: E402
from prtcore.core.spec import PointsSpec, parse_spec  # noqa: E402
from prtcore.emitters.families import sample_configurations  # noqa: E402
from prtcore.fit.model import relative_rmse  # noqa: E402
from prtcore.fit.transfer import (  # noqa: E402
    coefficients,
    fit_transfer,
    projection_bound,
    reconstruct,
)
from prtcore.intake.points import place_measurement_points  # noqa: E402
from prtcore.intake.sensors import concat_points, restrict_points, select_sensors  # noqa: E402
from prtcore.pipeline import run_intake  # noqa: E402
from prtcore.scenes import exterior, open_room  # noqa: E402
from prtcore.scenes.cornell import EXAMPLE_SPEC, write_cornell_box  # noqa: E402
from prtcore.transport.dataset import bake_dataset  # noqa: E402

SHARED = ROOT.parent / "shared" / "assets"
RESULTS = ROOT / "benchmarks" / "results"
#: basis elements (mean included) at which the table is read
N_BASIS = 16
#: the ratio to the projection bound a bake must reach (issue 13, "Done means")
TARGET_RATIO = 1.25

#: point lights on a shell of 1.5–3 bounding radii around an object, lit from every side
SHELL_POINTS = [{"type": "point", "position": {"shell": [1.5, 3.0]},
                 "intensity": {"uniform": [0.5, 3.0]}, "color": "white"}]

#: scene → (asset writer or shared file, light families)
SCENES = {
    "cornell": (write_cornell_box, EXAMPLE_SPEC["lights"]["families"]),
    "open_room": (open_room.write_open_room, open_room.LIGHT_FAMILIES),
    "exterior": (exterior.write_exterior, exterior.LIGHT_FAMILIES),
    "duck": (SHARED / "Duck.glb", SHELL_POINTS),
    "monkey": (SHARED / "monkey.glb", SHELL_POINTS),
}


def scene_spec(name: str, args, lights: int) -> dict:
    return {
        "atlas": {"resolution": args.resolution, "padding": 2},
        "measurement_points": {"count": args.candidates, "supersample": args.supersample,
                               "seed": 1},
        "lights": {"count": lights, "holdout": args.holdout, "seed": 2,
                   "families": open_room.light_families(args.pillar_clearance)
                   if name == "open_room" else copy.deepcopy(SCENES[name][1])},
        "transport": {"gather_rays": args.gather_rays, "max_bounces": 16,
                      "tolerance": 0.001},
        "fit": {"basis": N_BASIS, "ridge": "auto", "channels": "mono"},
    }


@dataclass
class SceneData:
    """One scene's intake and transport for K_max training then H held-out lights: the
    direct light at the N candidates and at the blue-noise sets, the texels' indirect."""

    name: str
    intake: object
    k_max: int
    holdout: int
    direct_candidates: np.ndarray  # (N, K_max + H, 3) float32
    blue: dict                     # P → (points, (P, K_max + H, 3) float32 direct)
    indirect: np.ndarray           # (T, K_max + H, 3) float32
    seconds: dict


def load_scene(name: str, args, k_max: int, tmp: Path, log) -> SceneData:
    """Intake with N candidates, the blue-noise sets of every P, and one transport pass
    (:func:`bake_dataset`) lighting all of them."""
    src = SCENES[name][0]
    t0 = time.perf_counter()
    asset = src if isinstance(src, Path) else src(tmp / f"{name}.glb")
    spec = parse_spec(scene_spec(name, args, k_max))
    intake = run_intake(asset, spec, quiet=True)
    sc = intake.scene
    blue = {p: place_measurement_points(sc, PointsSpec(count=p, supersample=args.supersample,
                                                       seed=1))
            for p in args.points}
    t1 = time.perf_counter()
    tracer = RayTracer(sc.positions, sc.faces, sc.radius, threads=args.threads)
    train, hold = sample_configurations(spec.lights, sc.center, sc.radius, sc.lights)
    pts, rows = concat_points(intake.points, *blue.values())
    data = bake_dataset(sc, intake.texels, pts, train, hold, spec.transport, tracer=tracer)
    t2 = time.perf_counter()
    D = data.direct_points
    sd = SceneData(name=name, intake=intake, k_max=k_max, holdout=len(hold),
                   direct_candidates=D[rows[0]],
                   blue={p: (b, D[r]) for (p, b), r in zip(blue.items(), rows[1:],
                                                           strict=True)},
                   indirect=data.indirect,
                   seconds={"intake": t1 - t0, "transport": t2 - t1,
                            **{f"transport_{k}": v for k, v in
                               data.stats.get("seconds", {}).items()}})
    log(f"{name}: {intake.texels.count} texels, {len(sc.faces)} triangles, "
        f"{intake.points.count} candidates, K = {k_max} + H = {len(hold)}; intake "
        f"{t1 - t0:.1f} s, transport {t2 - t1:.1f} s")
    return sd


def training_coefficients(D: np.ndarray, I: np.ndarray, basis: int) -> np.ndarray:
    """The mono basis coefficients (basis − 1, K, 3) of the training snapshots, as the fit
    computes them: configuration k normalised by ‖D[:, k]‖, mean subtracted, projected on
    the basis fitted to (D, I)."""
    model = fit_transfer(D, I, basis=basis, ridge=0.0, channels="mono")
    D64 = np.asarray(D, dtype=np.float64)
    s = np.sqrt(np.sum(D64 * D64, axis=(0, 2)))
    s = np.where(s > 0, s, 1.0)
    U = model.basis.astype(np.float64)
    mean = model.mean.astype(np.float64)
    out = np.empty((U.shape[1], D.shape[1], 3))
    for c in range(3):
        A = np.asarray(I[:, :, c], dtype=np.float64) / s[None, :] - mean[:, c:c + 1]
        out[:, :, c] = U.T @ A
    return out


def evaluate(D: np.ndarray, I: np.ndarray, k: int, k_max: int, n: int,
             transfer: str = "ridge", transfer_options: dict | None = None) -> dict:
    """Fit on the first k training lights; held-out error and bound at n elements.

    transfer, transfer_options : the transfer regressor and its options (fit_transfer's).

    Per held-out light h: e_h = relative_rmse(reconstruction, reference) and b_h its
    projection bound; the table's error and bound are their means (as the bake's report).
    Also pooled over the held-out set (issue 13's "honest" metric: near-zero lights do
    not dominate): sqrt(Σ‖error_h‖² / Σ‖reference_h‖²), the same for the bound.
    """
    t0 = time.perf_counter()
    model = fit_transfer(D[:, :k], I[:, :k], basis=n, ridge="auto", channels="mono",
                         transfer=transfer, transfer_options=transfer_options)
    t1 = time.perf_counter()
    errs, bounds, skipped = [], [], 0
    sse = bse = ref_ss = 0.0
    for h in range(k_max, D.shape[1]):
        x = D[:, h].astype(np.float64)
        ref = I[:, h].astype(np.float64)
        rn = float(np.linalg.norm(ref))
        if not (np.linalg.norm(x) > 0 and rn > 0):
            skipped += 1
            continue
        e = relative_rmse(reconstruct(model, x, n=n), ref)
        b = projection_bound(model, ref, x, n=n)
        errs.append(e)
        bounds.append(b)
        sse += (e * rn) ** 2
        bse += (b * rn) ** 2
        ref_ss += rn ** 2
    err, bound = float(np.mean(errs)), float(np.mean(bounds))
    pooled, pooled_bound = float(np.sqrt(sse / ref_ss)), float(np.sqrt(bse / ref_ss))
    return {"n": model.n_basis, "heldout_rmse_mean": err,
            "heldout_rmse_max": float(np.max(errs)), "projection_bound_mean": bound,
            "ratio": err / bound if bound > 0 else float("inf"),
            "heldout_rmse_pooled": pooled, "projection_bound_pooled": pooled_bound,
            "ratio_pooled": pooled / pooled_bound if pooled_bound > 0 else float("inf"),
            "heldout_used": len(errs), "heldout_skipped": skipped,
            "ridge": model.ridge, "used": model.diagnostics.used,
            "direct_condition": model.diagnostics.direct_condition[1],
            "fit_seconds": t1 - t0, "eval_seconds": time.perf_counter() - t1,
            "transfer": transfer, "coefficients_us": coefficients_us(model, D[:, k_max]),
            "learnt": model.diagnostics.learnt}


def coefficients_us(model, x: np.ndarray, repeat: int = 200) -> float:
    """Median µs of the runtime's coefficients (s, u) for one direct vector x (P, 3): the
    per-frame CPU cost that depends on the transfer regressor."""
    x = np.asarray(x, dtype=np.float64)
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        coefficients(model, x)
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)) * 1e6


def run_scene(sd: SceneData, args, ks: list[int], log) -> list[dict]:
    rows = []
    I = sd.indirect
    cand = sd.intake.points
    Dc = sd.direct_candidates
    coef = {}
    for k in ks if "goal" in args.placements else ():
        t0 = time.perf_counter()
        coef[k] = (training_coefficients(Dc[:, :k], I[:, :k], N_BASIS),
                   time.perf_counter() - t0)
    for p in args.points:
        if p > cand.count:
            log(f"  skip P = {p} > {cand.count} candidates")
            continue
        D_blue = sd.blue[p][1]
        for k in ks:
            for placement in args.placements:
                t0 = time.perf_counter()
                extra = {}
                if placement == "blue":
                    D, prep = D_blue, 0.0
                elif placement == "random":
                    rows_r = np.random.default_rng(p).choice(cand.count, p, replace=False)
                    D, prep = Dc[np.sort(rows_r)], 0.0
                else:
                    targets = coef[k][0] if placement == "goal" else None
                    kw = {"energy": 1.0, "qr_fraction": 1.0} if placement == "qdeim-all" \
                        else {}
                    sel = select_sensors(Dc[:, :k], p, targets,
                                         positions=cand.position, seed=0, **kw)
                    pts = restrict_points(cand, sel.indices)
                    D = Dc[sel.indices]
                    prep = time.perf_counter() - t0 + (coef[k][1] if targets is not None
                                                       else 0.0)
                    extra = {"qr_points": sel.qr_count, "direct_rank": sel.rank,
                             "fill": sel.fill, "cluster_samples": len(pts.cluster_owner)}
                r = evaluate(D, I, k, sd.k_max, N_BASIS)
                row = {"scene": sd.name, "placement": placement, "P": p, "K": k,
                       **r, **extra, "points_seconds": prep,
                       "seconds": prep + r["fit_seconds"] + r["eval_seconds"]}
                rows.append(row)
                log(format_row(row))
    return rows


HEADER = (f"{'scene':<10s} {'placement':<9s} {'P':>4s} {'K':>4s} {'n':>3s} "
          f"{'held-out':>8s} {'(max)':>7s} {'bound':>6s} {'ratio':>5s} {'ok':>3s} | "
          f"{'pooled':>6s} {'bound':>6s} {'ratio':>5s} | {'time s':>6s}")


def format_row(r: dict) -> str:
    ok = "yes" if r["ratio"] <= TARGET_RATIO else "no"
    return (f"{r['scene']:<10s} {r['placement']:<9s} {r['P']:>4d} {r['K']:>4d} "
            f"{r['n']:>3d} {100 * r['heldout_rmse_mean']:>7.1f}% "
            f"{100 * r['heldout_rmse_max']:>6.0f}% {100 * r['projection_bound_mean']:>5.1f}% "
            f"{r['ratio']:>5.2f} {ok:>3s} | {100 * r['heldout_rmse_pooled']:>5.1f}% "
            f"{100 * r['projection_bound_pooled']:>5.1f}% {r['ratio_pooled']:>5.2f} | "
            f"{r['seconds']:>6.2f}")


def scene_arguments(ap: argparse.ArgumentParser) -> None:
    """The options that choose the scenes, their lights and their transport (shared with
    benchmarks/transfer_regressors.py)."""

    def ints(s: str) -> list[int]:
        return [int(x) for x in s.split(",")]

    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--points", type=ints, default=[64, 256])
    ap.add_argument("--lights", type=int, default=128, help="K for every scene")
    ap.add_argument("--room-lights", type=ints, default=[128, 512],
                    help="the K compared on the open room")
    ap.add_argument("--holdout", type=int, default=32)
    ap.add_argument("--pillar-clearance", type=float, default=0.05,
                    help="open room: how far (m) the lights stay from the pillar")
    ap.add_argument("--supersample", type=int, default=4)
    ap.add_argument("--gather-rays", type=int, default=64)
    ap.add_argument("--threads", type=int, default=int(os.environ.get("PRT_THREADS", 2)))


def scene_names(ap: argparse.ArgumentParser, args) -> list[str]:
    """The --scenes list, unknown names refused."""
    names = args.scenes.split(",")
    unknown = set(names) - set(SCENES)
    if unknown:
        ap.error(f"unknown scenes {sorted(unknown)}; known: {list(SCENES)}")
    return names


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    scene_arguments(ap)
    ap.add_argument("--candidates", type=int, default=2048,
                    help="N dense blue-noise candidates the selection chooses from")
    ap.add_argument("--placements", default="blue,random,qdeim,qdeim-all,goal")
    ap.add_argument("--out", type=Path, default=RESULTS / "fidelity.json")
    args = ap.parse_args(argv)
    args.placements = args.placements.split(",")
    names = scene_names(ap, args)

    def log(msg: str) -> None:
        print(msg, flush=True)

    rows, scenes = [], {}
    t_all = time.perf_counter()
    log(HEADER)
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            ks = args.room_lights if name == "open_room" else [args.lights]
            sd = load_scene(name, args, max(ks), Path(tmp), log)
            scenes[name] = {"texels": int(sd.intake.texels.count),
                            "triangles": len(sd.intake.scene.faces),
                            "candidates": int(sd.intake.points.count),
                            "k_max": sd.k_max, "holdout": sd.holdout,
                            "seconds": sd.seconds}
            rows += run_scene(sd, args, ks, log)
            del sd
    total = time.perf_counter() - t_all
    log("")
    log(HEADER)
    for r in rows:
        log(format_row(r))
    log(f"total {total:.0f} s. held-out, (max), bound: mean and max over the held-out lights "
        f"of the per-light relative RMSE at n = {N_BASIS}, mean bound; ok: ratio ≤ "
        f"{TARGET_RATIO}; pooled: √(Σ‖error‖² / Σ‖reference‖²) over the held-out lights")
    for name, sc in scenes.items():
        log(f"{name}: {sc['texels']} texels, {sc['triangles']} triangles, "
            f"{sc['candidates']} candidates, K_max = {sc['k_max']}, H = {sc['holdout']}, "
            f"intake {sc['seconds']['intake']:.1f} s, transport "
            f"{sc['seconds']['transport']:.1f} s")
    result = {
        "benchmark": "fidelity", "issue": 13,
        "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "n": N_BASIS, "target_ratio": TARGET_RATIO,
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "python": platform.python_version()},
        "scenes": scenes, "rows": rows, "total_seconds": total,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2, default=float) + "\n")
    log(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
