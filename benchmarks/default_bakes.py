"""Bakes with a spec that names only the light family (issue 13): every other key at its
default. Prints, per scene, P, K, n, the pooled held-out error and projection bound, their
ratio, the verdict and the bake time; writes benchmarks/results/default_bakes.json.

    .venv/bin/python benchmarks/default_bakes.py [--scenes cornell,open_room,...]
        [--reference-spp N]   # judge against the path tracer, noise removed (slow)
        [--baseline]          # also bake with the fixed sizes used before automatic
                              # sizing (P = 256 blue noise, K = 128), same run: time ratio
        [--resolution R]      # atlas resolution (default: the spec's default)
        [--fixed-denoise R]   # also bake with fit.denoise = R instead of "auto", same run
        [--reference-lights L]  # held-out lights path-traced (default: the spec's)
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.io.bundle import read_manifest  # noqa: E402
from prtcore.pipeline import bake  # noqa: E402
from prtcore.scenes import exterior, open_room  # noqa: E402
from prtcore.scenes.cornell import EXAMPLE_SPEC, write_cornell_box  # noqa: E402

SHARED = ROOT.parent / "shared" / "assets"
AROUND = [{"type": "point", "position": {"shell": [1.5, 3.0]},
           "intensity": {"uniform": [1.0, 10.0]}}]
SUN = [{"type": "directional", "position": {"shell": [2.0, 2.0]},
        "aim": {"jitter": 0.2}, "intensity": {"uniform": [1.0, 3.0]}}]


def pct(x: float | None, digits: int = 1) -> str:
    """A fraction as a percentage for the printed tables; "—" for None."""
    return "—" if x is None else f"{100 * x:.{digits}f}%"


def write_rows(rows: list[dict], out: str) -> None:
    """The benchmark's rows as JSON at ``out`` (its folder made)."""
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps(rows, indent=2) + "\n")
    print(f"wrote {out}")


def scenes(tmp: Path) -> dict[str, tuple[Path, list]]:
    return {
        "cornell": (write_cornell_box(tmp / "cornell.glb"),
                    EXAMPLE_SPEC["lights"]["families"]),
        "open_room": (open_room.write_open_room(tmp / "room.glb"), open_room.LIGHT_FAMILIES),
        "exterior": (exterior.write_exterior(tmp / "house.glb"), exterior.LIGHT_FAMILIES),
        "Duck": (SHARED / "Duck.glb", AROUND),
        "monkey": (SHARED / "monkey.glb", AROUND),
        "BoxTextured": (SHARED / "BoxTextured.glb", AROUND),
        "CesiumMilkTruck": (SHARED / "CesiumMilkTruck.glb", SUN),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=None)
    ap.add_argument("--reference-spp", type=int, default=0)
    ap.add_argument("--baseline", action="store_true")
    ap.add_argument("--resolution", type=int, default=0)
    ap.add_argument("--fixed-denoise", type=float, default=None)
    ap.add_argument("--reference-lights", type=int, default=0)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" /
                                        "default_bakes.json"))
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="prt-defaults-"))
    todo = scenes(tmp)
    if args.scenes:
        todo = {k: v for k, v in todo.items() if k in args.scenes.split(",")}
    rows = []
    print(f"{'scene':<16s} {'sizes':<9s} {'P':>4s} {'K':>4s} {'n':>3s} {'error':>7s} "
          f"{'bound':>7s} {'ratio':>6s} {'verdict':>8s} {'t.noise':>7s} {'radius':>6s} "
          f"{'time s':>7s} {'CPU s':>7s}")
    kinds = {"auto": {}}
    if args.baseline:
        kinds["fixed"] = {"measurement_points": {"count": 256, "placement": "surface"},
                          "lights_count": 128}
    if args.fixed_denoise is not None:
        kinds[f"r{args.fixed_denoise:g}"] = {"fit": {"denoise": args.fixed_denoise}}
    for name, (asset, families) in todo.items():
        for kind, extra in kinds.items():
            spec = {"lights": {"families": families}}
            if "lights_count" in extra:
                spec["lights"]["count"] = extra["lights_count"]
            if "measurement_points" in extra:
                spec["measurement_points"] = extra["measurement_points"]
            if args.resolution:
                spec["atlas"] = {"resolution": args.resolution}
            if "fit" in extra:
                spec["fit"] = extra["fit"]
            if args.reference_spp:
                spec["validate"] = {"reference_spp": args.reference_spp}
                if args.reference_lights:
                    spec["validate"]["reference_lights"] = args.reference_lights
            t0, c0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
            out = bake(asset, parse_spec(spec), tmp / f"{name}-{kind}", quiet=True)
            seconds = time.perf_counter() - t0
            c1 = resource.getrusage(resource.RUSAGE_SELF)  # every thread of the process
            cpu = (c1.ru_utime + c1.ru_stime) - (c0.ru_utime + c0.ru_stime)
            m = read_manifest(out)
            v = m["verdict"]
            row = {"scene": name, "sizes": kind, "P": m["points"]["count"],
                   "K": m["fit"]["configurations"], "n": v["n"], "error": v["error"],
                   "bound": v["bound"], "ratio": v["ratio"], "verdict": v["status"],
                   "against": v["against"], "seconds": seconds, "cpu_seconds": cpu,
                   "causes": v["causes"],
                   "sizing": m.get("sizing", {}).get("reason"),
                   "transport_noise": m.get("transport_noise"),
                   "denoise": m["spec"]["fit"]["denoise"] if "transport_noise" not in m
                   else m["transport_noise"]["radius"],
                   "stage_seconds": m.get("timings")}
            rows.append(row)
            print(f"{name:<16s} {kind:<9s} {row['P']:>4d} {row['K']:>4d} {row['n']:>3d} "
                  f"{pct(row['error']):>7s} {pct(row['bound']):>7s} "
                  f"{row['ratio'] if row['ratio'] is None else round(row['ratio'], 2)!s:>6s} "
                  f"{row['verdict']:>8s} "
                  f"{pct((row['transport_noise'] or {}).get('transport_noise')):>7s} "
                  f"{row['denoise']!s:>6s} {seconds:>7.1f} {cpu:>7.1f}", flush=True)
        mine = {r["sizes"]: r for r in rows if r["scene"] == name}
        for kind in kinds:
            if kind != "auto":
                a, o = mine["auto"], mine[kind]
                print(f"  {name}: the defaults take {a['seconds'] / o['seconds']:.2f}× the "
                      f"wall time and {a['cpu_seconds'] / o['cpu_seconds']:.2f}× the CPU "
                      f"time of {kind}", flush=True)
    write_rows(rows, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
