"""Benchmark: the indirect solve on a coarse texel grid (prtcore.transport.coarse, issue 20).

Per scene, one intake and one tracing of the operators, one direct light and near-field
correction for K lights; then the same system ``(I − Gρ) E = b`` solved

* at full resolution with ``--exact-tolerance`` (the discrete system's solution: what the
  grid is measured against; it carries the operator's Monte Carlo noise, which the coarse
  solve shares, so the difference is the grid's own error),
* at full resolution with the bake's tolerance (today's solve: its time is the "before"),
* with ``transport.coarse_grid`` = each of ``--factors``.

Printed per row: seconds (wall, CPU), products, the pooled relative RMSE of the indirect
outgoing radiance against the exact solution (√(Σ‖x − x*‖² / Σ‖x*‖²) over texels, lights
and channels) and the worst light's, and the speed-up over today's solve. Against the path
tracer, ``benchmarks/bake_speed.py --coarse-grid N`` prints the whole transport's error
beside its time.

Usage: python benchmarks/coarse_solve.py [--scenes cornell,open_room,exterior,duck]
       [--resolution 512] [--lights 64] [--factors 2,4,8]
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
sys.path.insert(0, str(ROOT / "benchmarks"))

import fidelity  # noqa: E402

from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.emitters.families import sample_configurations  # noqa: E402
from prtcore.pipeline import run_intake  # noqa: E402
from prtcore.transport import dataset as ds  # noqa: E402
from prtcore.transport.coarse import coarsen_texels  # noqa: E402
from prtcore.transport.solve import solve_indirect  # noqa: E402


def cpu() -> float:
    return time.process_time()


def pooled(x: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """(pooled, worst-light) relative RMSE of x (T, K, 3) against ref."""
    d = (x.astype(np.float64) - ref) ** 2
    r = ref.astype(np.float64) ** 2
    per = np.sqrt(d.sum(axis=(0, 2)) / np.maximum(r.sum(axis=(0, 2)), 1e-300))
    return float(np.sqrt(d.sum() / max(r.sum(), 1e-300))), float(per.max())


def run_scene(name: str, args, tmp: Path, log) -> dict:
    args.candidates, args.supersample, args.holdout = 64, 1, 0
    args.pillar_clearance = 0.05
    src = fidelity.SCENES[name][0]
    asset = src if isinstance(src, Path) else src(tmp / f"{name}.glb")
    d = fidelity.scene_spec(name, args, args.lights)
    d["measurement_points"]["count"] = 64
    spec = parse_spec(d)
    intake = run_intake(asset, spec, quiet=True)
    sc, tx = intake.scene, intake.texels
    tr = ds.open_transport(sc, tx, intake.points, spec.transport)
    lights, _ = sample_configurations(spec.lights, sc.center, sc.radius, sc.lights)
    positions = next((p for p in (t.operator.direct_position(t.term) for t in tr.traced)
                      if p is not None), None)
    if positions is None:
        positions = np.asarray(tx.position, dtype=np.float64)[:, None, :]
    timer = ds.StageTimer(quiet=True)
    direct = ds.direct_radiance(sc, tr.tracer, lights, positions, tx.normal, tx.albedo,
                                timer, "direct texels")
    first = None
    for t in tr.traced:
        first = ds._add_first_bounce(first, t.operator.first_bounce(
            t.term, sc, tr.tracer, tuple(lights), direct, timer))
    g = ds.operator_matrix(tr.traced)
    log(f"{name}: {tx.count} texels, K = {len(lights)}, nnz(G) = {g.nnz:,}")

    def solve(tolerance: float, factor: int) -> tuple[np.ndarray, dict]:
        w0, c0 = time.perf_counter(), cpu()
        coarse = coarsen_texels(tx.xy, tx.position, tx.normal, tx.footprint, tx.coverage,
                                factor)
        x, n, resid, stats = solve_indirect(g, tx.albedo, direct, 64, tolerance,
                                            first_bounce=first, threads=args.threads,
                                            coarse=coarse)
        return x, {"factor": factor, "tolerance": tolerance, "seconds": time.perf_counter()
                   - w0, "cpu_seconds": cpu() - c0, "products": n, "residual": resid,
                   "coarse": stats.get("coarse")}

    exact, row = solve(args.exact_tolerance, 1)
    rows = [dict(row, label="exact")]
    for f in [1, *args.factors]:
        x, row = solve(spec.transport.tolerance, f)
        row["rel_rmse"], row["worst_light"] = pooled(x, exact)
        row["label"] = "full" if f == 1 else f"coarse {f}"
        rows.append(row)
    base = rows[1]["seconds"]
    for r in rows:
        r["speedup"] = base / r["seconds"]
        cells = r["coarse"]["cells"] if r.get("coarse") else tx.count
        log(f"  {r['label']:>9}  {r['seconds']:6.2f} s wall {r['cpu_seconds']:6.2f} s CPU  "
            f"{r['products']:3d} products  cells {cells:>7}  "
            f"rRMSE {100 * r.get('rel_rmse', 0):6.3f} % (worst light "
            f"{100 * r.get('worst_light', 0):6.3f} %)  ×{r['speedup']:.2f}")
    return {"scene": name, "texels": tx.count, "lights": len(lights), "nnz": int(g.nnz),
            "rows": rows}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="cornell,open_room,exterior,duck")
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--lights", type=int, default=64)
    ap.add_argument("--gather-rays", type=int, default=64)
    ap.add_argument("--factors", type=lambda s: [int(x) for x in s.split(",")],
                    default=[2, 4, 8])
    ap.add_argument("--exact-tolerance", type=float, default=1e-6)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path,
                    default=ROOT / "benchmarks" / "results" / "coarse_solve.json")
    args = ap.parse_args(argv)
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scenes.split(","):
            out.append(run_scene(name, args, Path(tmp), lambda s: print(s, flush=True)))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"resolution": args.resolution, "scenes": out},
                                   indent=1))
    print(f"→ {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
