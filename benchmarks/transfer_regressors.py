"""Benchmark: ridge against the learnt ("mlp") transfer on the fidelity scenes (issue 18).

For each scene of :mod:`benchmarks.fidelity` (its light families, its fast transport of
K training and H held-out lights, blue-noise measurement points) and each P, K, the
transfer is fitted by ``fit_transfer(..., basis 16, ridge "auto", mono)`` once per
regressor — ``ridge`` (linear) and ``mlp`` (the same ridge plus the learnt residual of
:mod:`prtcore.fit.mlp`) — on the same data, and judged on the same held-out lights as
:func:`fidelity.evaluate` judges it: mean and pooled relative RMSE at n = 16 against the
fast transport, the projection bound and their ratio. Also the CPU cost per frame of the
coefficients (``prtcore.fit.transfer.coefficients``: u = M·x' + s·b, plus s·r(x'/s) for
mlp; median µs), the fit time, and for mlp the step count chosen on its validation fifth
and the validation MSE of the ridge's leave-one-out residuals before and after.

"wins" (mlp rows): the pooled held-out error of mlp is below ridge's by more than
WIN_MARGIN (relative); the default regressor changes only where it wins.

Usage: python benchmarks/transfer_regressors.py [--scenes cornell,open_room,...]
       [--points 64,256] [--lights 128] [--room-lights 128,512] [--holdout 32]
       [--mlp-width 64] [--mlp-layers 2] [--mlp-steps 2000] [--seed 0] [--out FILE.json]
Writes benchmarks/results/transfer_regressors.json. The defaults' table (mlp wins 1 row of
12, the open room at P = 64, K = 512; ridge stays the default): docs/learnt_sh.md,
"Measured".
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from fidelity import (  # noqa: E402
    N_BASIS,
    RESULTS,
    evaluate,
    load_scene,
    scene_arguments,
    scene_names,
)

#: mlp wins a row when its pooled held-out error is below ridge's by more than this
WIN_MARGIN = 0.01

HEADER = (f"{'scene':<10s} {'P':>4s} {'K':>4s} {'transfer':<8s} {'held-out':>8s} "
          f"{'bound':>6s} {'ratio':>5s} | {'pooled':>6s} {'ratio':>5s} | {'coef µs':>8s} "
          f"{'fit s':>6s} | {'steps':>5s} {'val mse ridge → mlp':>21s} {'wins':>4s}")


def format_row(r: dict) -> str:
    learnt = r.get("learnt") or {}
    steps = f"{learnt['steps']:>5d}" if learnt else f"{'':>5s}"
    val = (f"{learnt['validation_mse_ridge']:.3g} → {learnt['validation_mse_mlp']:.3g}"
           if learnt.get("validation_mse_ridge") is not None else "")
    wins = "" if r["transfer"] == "ridge" else ("yes" if r["wins"] else "no")
    return (f"{r['scene']:<10s} {r['P']:>4d} {r['K']:>4d} {r['transfer']:<8s} "
            f"{100 * r['heldout_rmse_mean']:>7.2f}% {100 * r['projection_bound_mean']:>5.1f}% "
            f"{r['ratio']:>5.2f} | {100 * r['heldout_rmse_pooled']:>5.2f}% "
            f"{r['ratio_pooled']:>5.2f} | {r['coefficients_us']:>8.1f} {r['fit_seconds']:>6.2f}"
            f" | {steps} {val:>21s} {wins:>4s}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    scene_arguments(ap)
    ap.add_argument("--mlp-width", type=int, default=64)
    ap.add_argument("--mlp-layers", type=int, default=2)
    ap.add_argument("--mlp-steps", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=RESULTS / "transfer_regressors.json")
    args = ap.parse_args(argv)
    args.candidates = max(args.points)  # load_scene's candidate set: unused here
    names = scene_names(ap, args)
    options = {"width": args.mlp_width, "layers": args.mlp_layers, "steps": args.mlp_steps,
               "seed": args.seed}

    def log(msg: str) -> None:
        print(msg, flush=True)

    rows = []
    t_all = time.perf_counter()
    log(HEADER)
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            ks = args.room_lights if name == "open_room" else [args.lights]
            sd = load_scene(name, args, max(ks), Path(tmp), log)
            for p in args.points:
                D = sd.blue[p][1]
                for k in ks:
                    ridge = evaluate(D, sd.indirect, k, sd.k_max, N_BASIS)
                    mlp = evaluate(D, sd.indirect, k, sd.k_max, N_BASIS, "mlp", options)
                    gain = 1.0 - mlp["heldout_rmse_pooled"] / ridge["heldout_rmse_pooled"]
                    for r in (ridge, mlp):
                        r.update(scene=name, P=p, K=k, gain=gain, wins=gain > WIN_MARGIN)
                        if r["learnt"]:
                            r["learnt"] = {k_: v for k_, v in r["learnt"].items()
                                           if k_ != "curve"}
                        rows.append(r)
                        log(format_row(r))
            del sd
    total = time.perf_counter() - t_all
    log("")
    log(HEADER)
    for r in rows:
        log(format_row(r))
    wins = [r for r in rows if r["transfer"] == "mlp" and r["wins"]]
    log(f"total {total:.0f} s; n = {N_BASIS}; mlp {args.mlp_layers} × {args.mlp_width}, at "
        f"most {args.mlp_steps} steps, seed {args.seed}; mlp wins {len(wins)} of "
        f"{len(rows) // 2} rows (pooled held-out error lower by > {100 * WIN_MARGIN:g} %)")
    result = {"benchmark": "transfer_regressors", "issue": 18,
              "config": {k: (str(v) if isinstance(v, Path) else v)
                         for k, v in vars(args).items()},
              "n": N_BASIS, "win_margin": WIN_MARGIN, "rows": rows,
              "seconds": total, "machine": platform.platform(),
              "cpus": os.cpu_count()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2, default=float) + "\n")
    log(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
