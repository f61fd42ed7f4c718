"""Benchmark: how much light the Chiang + mesh solve leaves out when it stops at a bake's
``transport.max_bounces`` instead of converging.

The test head of benchmarks/hair_mesh_chiang_accuracy.py (curly strands, the 512² atlas,
its sun and point light), baked by prtcore.transport.hair_mesh_chiang with the second
order and the fibre gather's ``--rays`` (M_h), once stopping at ``--cap`` bounces and once
at ``--full`` (where it converges to ``transport.tolerance`` first). Printed per hair and
receiver: the mean of the capped light over the converged one, minus 1, with each
solve's bounces and last relative change. Same rays and seed, so the difference is the
truncation alone.

Printed and written to benchmarks/results/hair_mesh_chiang_bounces.json.

Usage: python benchmarks/hair_mesh_chiang_bounces.py [--strands 10000] [--rays 128]
       [--atlas-rays 64] [--cap 16] [--full 64] [--hairs light dark]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.hair_mesh_chiang_accuracy import HAIRS, LIGHTS, head_setup  # noqa: E402
from prtcore.core.progress import StageTimer  # noqa: E402
from prtcore.core.spec import TransportSpec  # noqa: E402
from prtcore.transport.fibre_chiang import chiang_fibre  # noqa: E402
from prtcore.transport.hair_mesh_chiang import bake_chiang_hair_mesh_dataset  # noqa: E402


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--strands", type=int, default=10000)
    ap.add_argument("--texels-per-strand", type=int, default=10)
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--rays", type=int, default=128, help="M_h, the fibre gather's rays")
    ap.add_argument("--atlas-rays", type=int, default=64)
    ap.add_argument("--samples", type=int, default=4, help="direct samples J")
    ap.add_argument("--cap", type=int, default=16, help="a bake's transport.max_bounces")
    ap.add_argument("--full", type=int, default=64, help="bounces allowed to converge")
    ap.add_argument("--hairs", nargs="+", default=list(HAIRS), choices=list(HAIRS))
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/"
                                         "hair_mesh_chiang_bounces.json"))
    args = ap.parse_args(argv)
    scene, texels, space, tracer, fibres, points, _, _ = head_setup(
        args.strands, args.texels_per_strand, args.resolution, 1)
    t_m = texels.count
    out: dict = {"args": vars(args), "results": {}}
    for name in args.hairs:
        fibre = chiang_fibre(HAIRS[name], space)
        runs = {}
        for cap in (args.cap, args.full):
            d = bake_chiang_hair_mesh_dataset(
                scene, texels, space, fibres, points, tracer, LIGHTS, (),
                TransportSpec(gather_rays=args.atlas_rays, direct_samples=args.samples,
                              seed=0, max_bounces=cap), StageTimer(quiet=True), fibre,
                exitance="second_order", fibre_rays=args.rays)
            runs[cap] = (d.indirect.astype(np.float64), d.iterations, float(d.residual))
        a, b = runs[args.cap][0], runs[args.full][0]
        for part, sl in (("atlas", slice(0, t_m)), ("strands", slice(t_m, None))):
            short = float(a[sl].mean() / b[sl].mean() - 1)
            out["results"][f"{name}/{part}"] = {
                "short": short, "bounces": [runs[args.cap][1], runs[args.full][1]],
                "residual": [runs[args.cap][2], runs[args.full][2]]}
            print(f"{name:5s} {part:7s}: {args.cap} bounces against converged "
                  f"{short:+.4f}; bounces {runs[args.cap][1]} / {runs[args.full][1]}, "
                  f"last relative change {runs[args.cap][2]:.2e} / "
                  f"{runs[args.full][2]:.2e}", flush=True)
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2))
    print(f"wrote {path}")
    return out


if __name__ == "__main__":
    main()
