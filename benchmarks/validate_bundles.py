"""Judge finished bundles against the path tracer, its noise removed (issue 13).

For each bundle: path-trace ``--lights`` of its held-out lights at ``--spp`` samples per
texel (:func:`prtcore.validate.validate_bundle`, two independent half-sample estimates, so
the reference's noise is estimated and subtracted), and print the noise-corrected error at
the shipped n against the projection bound at that n of the same path-traced references,
noise removed alike (the verdict's ratio with a path-traced reference), beside the fast
transport's own error and bound and its measured noise. Writes
benchmarks/results/validate_bundles.json.

    .venv/bin/python benchmarks/validate_bundles.py BUNDLE [BUNDLE ...] [--spp 64]
        [--lights 4]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from default_bakes import pct, write_rows  # noqa: E402

from prtcore.core.progress import StageTimer  # noqa: E402
from prtcore.io.bundle import read_manifest  # noqa: E402
from prtcore.validate import validate_bundle  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bundles", nargs="+")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--lights", type=int, default=4)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" /
                                        "validate_bundles.json"))
    args = ap.parse_args()
    rows = []
    print(f"{'bundle':<24s} {'P':>5s} {'K':>4s} {'n':>3s} {'noise':>7s} {'error':>7s} "
          f"{'bound':>7s} {'ratio':>6s} {'fast':>7s} {'f.bound':>7s} {'t.noise':>7s} "
          f"{'time s':>7s}")
    for b in args.bundles:
        m = read_manifest(Path(b))
        n = m["verdict"]["n"]
        t0 = time.perf_counter()
        v = validate_bundle(Path(b), args.spp, count=args.lights, timer=StageTimer(quiet=True))
        seconds = time.perf_counter() - t0
        row = next(r for r in v["rows"] if r["n"] == n)
        fast = next(r for r in m["metrics"]["error_vs_runtime"] if r["n"] == n)
        err = row.get("rmse_noise_corrected_mean")
        bound = row.get("projection_bound_noise_corrected_mean")
        ratio = err / bound if err is not None and bound else None
        out = {"bundle": str(b), "P": m["points"]["count"], "K": m["fit"]["configurations"],
               "n": n, "spp": args.spp, "lights": args.lights,
               "reference_noise": v.get("reference_noise_mean"), "error": err, "bound": bound,
               "ratio": ratio, "fast_transport_error": fast.get("heldout_rmse_mean"),
               "fast_transport_bound": fast.get("projection_bound_mean"),
               "transport_noise": (m.get("transport_noise") or {}).get("transport_noise"),
               "seconds": seconds}
        rows.append(out)
        print(f"{Path(b).name:<24s} {out['P']:>5d} {out['K']:>4d} {n:>3d} "
              f"{pct(out['reference_noise']):>7s} {pct(err):>7s} {pct(bound):>7s} "
              f"{'—' if ratio is None else f'{ratio:.2f}':>6s} "
              f"{pct(out['fast_transport_error']):>7s} {pct(out['fast_transport_bound']):>7s} "
              f"{pct(out['transport_noise']):>7s} {seconds:>7.1f}", flush=True)
    write_rows(rows, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
