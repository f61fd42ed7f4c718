"""Measurement points chosen for the transfer vs blue noise, at equal P (issue 13).

Per scene: the intake places 2 × the largest P blue-noise candidates; transport lights them once (K
training + 16 held-out lights of the scene's family); then for each P the same fit is
judged on the held-out lights with P points chosen two ways from the same candidates:

* ``qdeim`` — pivoted QR on the candidates' training direct light (intake/sensors.py),
* ``blue noise`` — the first P of a farthest-point order of the candidates (nested blue
  noise, what placement "surface" gives when the bake chooses P).

Prints the pooled held-out error, the projection bound and their ratio for both, and
writes benchmarks/results/placement.json.

    .venv/bin/python benchmarks/placement.py [--scenes cornell,open_room,...]
        [--resolution 256] [--lights 128] [--points 128,256,512,1024]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from default_bakes import pct, scenes, write_rows  # noqa: E402

from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.emitters.families import sample_configurations  # noqa: E402
from prtcore.fit.transfer import fit_transfer  # noqa: E402
from prtcore.pipeline import run_intake  # noqa: E402
from prtcore.receivers.smoothing import denoise_lightmaps  # noqa: E402
from prtcore.report import heldout_metrics  # noqa: E402
from prtcore.sizing import select_points  # noqa: E402
from prtcore.transport.dataset import light_configurations, open_transport  # noqa: E402
from prtcore.transport.noise import DENOISE_FALLBACK, with_denoise  # noqa: E402


def judge(spec, data, K, I, Ih, rows) -> dict:
    D = data.direct_points[rows]
    f = spec.fit
    model = fit_transfer(D[:, :K], I, basis=f.basis, ridge=f.ridge, channels=f.channels,
                         gamma=f.gamma)
    m = heldout_metrics(model, D[:, K:], Ih, [model.n_basis])[0]
    e, b = m["heldout_rmse_pooled"], m["projection_bound_pooled"]
    return {"error": e, "bound": b, "ratio": None if e is None or not b else e / b}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=None)
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--lights", type=int, default=128)
    ap.add_argument("--points", default="128,256,512,1024")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "placement.json"))
    args = ap.parse_args()
    counts = [int(p) for p in args.points.split(",")]
    tmp = Path(tempfile.mkdtemp(prefix="prt-placement-"))
    todo = scenes(tmp)
    if args.scenes:
        todo = {k: v for k, v in todo.items() if k in args.scenes.split(",")}
    rows = []
    print(f"{'scene':<16s} {'P':>5s} {'K':>4s} {'qdeim':>8s} {'blue':>8s} {'bound':>7s} "
          f"{'q ratio':>8s} {'b ratio':>8s}")
    for name, (asset, families) in todo.items():
        t0 = time.perf_counter()
        spec = parse_spec({"atlas": {"resolution": args.resolution},
                           "lights": {"families": families, "count": args.lights},
                           "measurement_points": {"candidates": 2 * max(counts)},
                           "sizing": {"max_points": max(counts)}})
        intake = run_intake(asset, spec, quiet=True)
        cand = intake.points
        train, hold = sample_configurations(spec.lights, intake.scene.center,
                                            intake.scene.radius, intake.scene.lights)
        tr = open_transport(intake.scene, intake.texels, cand, spec.transport)
        data = light_configurations(tr, (*train, *hold), len(train))
        K = len(train)
        radius = with_denoise(spec, DENOISE_FALLBACK).fit.denoise  # as the bake's fallback
        both = denoise_lightmaps(intake.texels, data.indirect, radius)
        I, Ih = both[:, :K], both[:, K:]
        for p in counts:
            p = min(p, cand.count)
            row = {"scene": name, "P": p, "K": K, "candidates": cand.count}
            for how in ("qdeim", "surface"):
                picked = select_points(cand, data.direct_points[:, :K], p, how,
                                       spec.measurement_points.seed)
                row[how] = judge(spec, data, K, I, Ih, picked)
            rows.append(row)

            def rat(x):
                return "—" if x is None else f"{x:.2f}"
            q, b = row["qdeim"], row["surface"]
            print(f"{name:<16s} {p:>5d} {K:>4d} {pct(q['error'], 2):>8s} {pct(b['error'], 2):>8s} "
                  f"{pct(q['bound'], 2):>7s} {rat(q['ratio']):>8s} {rat(b['ratio']):>8s}",
                  flush=True)
        print(f"  ({name}: {time.perf_counter() - t0:.0f} s)", flush=True)
    write_rows(rows, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
