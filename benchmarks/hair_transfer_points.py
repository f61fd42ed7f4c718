"""Benchmark: a hair bake's transfer against its projection bound, by measurement points
and training lights, from one transport.

The strand texels' light does not depend on the measurement points, so one transport of
K training (+ H held-out) lights serves every point count: for each P of ``--points`` the
hull points a spec asking for P gets are placed (``prtcore.hairbake.hair_points``), their
direct light computed (``prtcore.transport.dataset.direct_at_points``) and the bake's fit
run (``prtcore.report.fit_for_table``). With ``--more-lights-seed S`` a second transport
of K lights drawn with seed S is added to the training set (2K lights on the same
operator: the gather's rays come from ``transport.seed``, not from the lights), the
held-out lights staying the first's. Printed per (K, P): the held-out error and the
projection bound at n = 4 … 64 (pooled over the held-out lights, as the verdict judges),
and their ratio; written to benchmarks/results/hair_transfer_points.json.

The bake's own choice (``prtcore.hairbake._more_points``) is the first P of 256, 512, 1024
whose ratio at the shipped n is within ``validate.target_ratio``.

Usage: python benchmarks/hair_transfer_points.py [--strands 10000] [--fibre chiang]
       [--lights 512] [--holdout 16] [--points 256 512 1024] [--more-lights-seed 7]
       [--spec '{"hair": {...}}']
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from prtcore import hairbake  # noqa: E402
from prtcore.core.limits import IntakeLimits  # noqa: E402
from prtcore.core.progress import StageTimer  # noqa: E402
from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.io.hair import write_hair  # noqa: E402
from prtcore.report import TABLE_N, fit_for_table, heldout_metrics  # noqa: E402
from prtcore.scenes.hair import hairball  # noqa: E402
from prtcore.transport.dataset import direct_at_points  # noqa: E402
from prtcore.transport.fibre import hair_tracer  # noqa: E402


class _Keep:
    """A method whose fit keeps the inputs (the transport's dataset) and fits nothing."""

    inputs = None

    def fit(self, inputs, timer):
        self.inputs = inputs
        return None


def transport(asset: Path, spec_dict: dict, timer: StageTimer):
    """(the run spec, the intake, the tracer, the inputs) of one transport pass, as
    ``prtcore.hairbake.bake_hair`` runs it (hair alone)."""
    limits = IntakeLimits.from_env()
    spec = hairbake.hair_spec(parse_spec(spec_dict))
    intake = hairbake.run_hair_intake(asset, spec, timer, limits)
    space = intake.strands
    spec, lines = hairbake.strand_spec(spec, space, with_mesh=False)
    for line in lines:
        print(line, flush=True)
    spec, why = hairbake.chiang_exitance(asset, space, spec, limits.max_bake_bytes)
    if why:
        print(why, flush=True)
    hairbake.check_hair_memory(asset, space, spec, limits.max_bake_bytes)
    intake = dataclasses.replace(intake, spec=spec)
    tracer, fibres = hair_tracer(space, None)
    keep = _Keep()
    hairbake._transport_and_fit(spec, intake, tracer, fibres, keep, timer)
    return spec, intake, tracer, keep.inputs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--strands", type=int, default=10_000)
    ap.add_argument("--fibre", default="chiang", choices=("chiang", "diffuse"))
    ap.add_argument("--lights", type=int, default=512)
    ap.add_argument("--holdout", type=int, default=16)
    ap.add_argument("--points", type=int, nargs="+", default=[256, 512, 1024])
    ap.add_argument("--more-lights-seed", type=int, default=None)
    ap.add_argument("--spec", default="{}", help="more spec keys (JSON), merged into hair")
    ap.add_argument("--work", type=Path, default=ROOT / "benchmarks" / "results" / "work")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    asset = write_hair(args.work / f"hairball-{args.strands}.hair", hairball(args.strands))
    extra = json.loads(args.spec)
    spec_dict = {**extra, "hair": {**extra.get("hair", {}), "fibre": args.fibre},
                 "lights": {**extra.get("lights", {}), "count": args.lights,
                            "holdout": args.holdout},
                 "measurement_points": {"count": max(args.points)}}
    timer = StageTimer(quiet=False)
    t0 = time.perf_counter()
    spec, intake, tracer, inputs = transport(asset, spec_dict, timer)
    seconds = {"transport": time.perf_counter() - t0}
    data, k = inputs.data, len(inputs.train)
    indirect_train, indirect_hold = data.indirect[:, :k], data.indirect[:, k:]
    lights, hold = data.lights, data.lights[k:]
    out = ROOT / "benchmarks" / "results" / "hair_transfer_points.json"
    rows: list[dict] = []
    print(f"{'K':>5} {'P':>5}  " + "  ".join(f"n={n}: error/bound (ratio)" if n == 4
                                          else f"n={n}" for n in TABLE_N), flush=True)

    def fits(kk: int, train_indirect, train_lights) -> None:
        """Every P of ``--points`` on these training lights; the JSON rewritten after each."""
        for p in args.points:
            pspec = dataclasses.replace(spec, measurement_points=dataclasses.replace(
                spec.measurement_points, count=p))
            t1 = time.perf_counter()
            points = hairbake.hair_points(intake.hair, None, pspec, timer)
            direct = direct_at_points(None, tracer, (*train_lights, *hold), points, timer)
            _, full = fit_for_table(direct[:, :kk], train_indirect, spec.fit,
                                    (direct[:, kk:], indirect_hold))
            ns = [n for n in TABLE_N if n <= full.n_basis]
            table = heldout_metrics(full, direct[:, kk:], indirect_hold, ns)
            row = {"lights": kk, "points": p, "seconds": time.perf_counter() - t1,
                   "ridge": full.diagnostics.ridge, "by_n": {}}
            for n, r in zip(ns, table, strict=True):
                e, b = r["heldout_rmse_pooled"], r["projection_bound_pooled"]
                row["by_n"][n] = {"error": e, "bound": b, "ratio": e / b if b else None}
            rows.append(row)
            print(f"{kk:>5} {p:>5}  " + "  ".join(
                f"{100 * v['error']:.1f}/{100 * v['bound']:.1f} ({v['ratio']:.2f}×)"
                for v in row["by_n"].values()) + f"   {row['seconds']:.0f} s", flush=True)
            out.write_text(json.dumps({
                "args": {k_: str(v) for k_, v in vars(args).items()}, "spec": spec_dict,
                "exitance": spec.hair.chiang.exitance,
                "denoise_neighbours": spec.hair.denoise_neighbours,
                "shipped_n": spec.fit.basis, "rows": rows, "seconds": seconds,
                "stages": dict(timer.seconds)}, indent=1))

    fits(k, indirect_train, lights[:k])
    if args.more_lights_seed is not None:
        t1 = time.perf_counter()
        more = {**spec_dict, "lights": {**spec_dict["lights"],
                                        "seed": args.more_lights_seed, "holdout": 0}}
        _, _, _, inputs2 = transport(asset, more, timer)
        seconds["second transport"] = time.perf_counter() - t1
        k2 = len(inputs2.train)
        both = np.concatenate([indirect_train, inputs2.data.indirect[:, :k2]], axis=1)
        second = inputs2.data.lights[:k2]
        del inputs2
        fits(k + k2, both, (*lights[:k], *second))
    print(f"written {out}")


if __name__ == "__main__":
    main()
