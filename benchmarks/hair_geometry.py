"""Benchmark: fibres as triangles for Embree — tubes or ribbons, at 10k and 140k strands.

For the procedural hairball (prtcore.scenes.hair.hairball, 16 segments per strand) and each
representation (3- and 4-sided tubes, flat ribbons; prtcore.core.fibres) it prints and
writes (benchmarks/results/hair_geometry.json):

* triangles, vertices, build time of the triangle arrays and of the Embree scene;
* memory: resident-set growth while building the Embree scene (the BVH and embreex's
  float32 copies) and the bytes of the float64 triangle arrays prtcore keeps;
* ray throughput of RayTracer on gather-like rays (origins on fibre surfaces, cosine
  directions) — closest-hit and occlusion queries — in rays per second;
* occlusion fidelity: the fraction of random rays across a lone straight fibre that are
  blocked, relative to the cylinder's (Cauchy: mean projected width = diameter); ribbons
  miss rays travelling in their plane.

Usage: python benchmarks/hair_geometry.py [--strands 10000 140000] [--rays 400000]
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from prtcore.core.fibres import fibre_ribbons, fibre_tubes  # noqa: E402
from prtcore.core.geometry import directions_around  # noqa: E402
from prtcore.core.hair import make_hair  # noqa: E402
from prtcore.core.raytrace import RayTracer  # noqa: E402
from prtcore.receivers.strands import build_strand_space  # noqa: E402
from prtcore.scenes.hair import hairball  # noqa: E402

KINDS = {"tubes3": lambda h: fibre_tubes(h, 3), "tubes4": lambda h: fibre_tubes(h, 4),
         "ribbons": fibre_ribbons}


def rss() -> int:
    """Resident set size in bytes (Linux /proc)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def fidelity(kind: str, m: int = 200_000) -> float:
    """Blocked fraction of random rays across one straight fibre / the cylinder's."""
    r, w = 0.01, 0.1
    h = make_hair([np.array([[0, 0, -1], [0, 0, 0], [0, 0, 1.0]])], 2 * r)
    mesh = KINDS[kind](h)
    tracer = RayTracer(mesh.positions, mesh.faces, scale=1.0)
    rng = np.random.default_rng(1)
    d = rng.normal(size=(m, 3))
    d[:, 2] *= 0.3  # mostly across the fibre
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    perp = np.linalg.norm(d[:, :2], axis=1)
    across = np.stack([-d[:, 1], d[:, 0], np.zeros(m)], axis=1) / perp[:, None]
    o = -0.5 * d + (rng.random(m) - 0.5)[:, None] * w * across
    o[:, 2] = rng.uniform(-0.5, 0.5, m)
    return float(tracer.occluded(o, d, 1.0).mean() / (2 * r / w))


def run(strands: int, rays: int) -> list[dict]:
    hair = hairball(strands=strands, seed=0)
    space = build_strand_space(hair, 10)
    per = max(1, rays // space.count)
    origin, normal, _, _ = space.surface_samples(per, seed=1)
    origin, normal = origin.reshape(-1, 3)[:rays], normal.reshape(-1, 3)[:rays]
    rng = np.random.default_rng(2)
    u = rng.random(len(origin))
    d = directions_around(normal, np.sqrt(1 - u), 2 * np.pi * rng.random(len(origin)))
    rows = []
    for kind, make in KINDS.items():
        gc.collect()
        t0 = time.perf_counter()
        mesh = make(hair)
        t1 = time.perf_counter()
        before = rss()
        tracer = RayTracer(mesh.positions, mesh.faces, scale=0.1)
        tracer.occluded(origin[:1], d[:1])  # Embree builds the BVH at the first query
        t2 = time.perf_counter()
        grown = rss() - before
        t3 = time.perf_counter()
        tracer.intersect(origin, d)
        t4 = time.perf_counter()
        tracer.occluded(origin, d)
        t5 = time.perf_counter()
        row = {"strands": strands, "kind": kind, "triangles": len(mesh.faces),
               "vertices": len(mesh.positions), "mesh_seconds": t1 - t0,
               "embree_build_seconds": t2 - t1, "embree_rss_bytes": grown,
               "prtcore_arrays_bytes": mesh.positions.nbytes + mesh.faces.nbytes
               + tracer.positions.nbytes + tracer.faces.nbytes + tracer.face_normals.nbytes,
               "rays": len(origin), "intersect_rays_per_s": len(origin) / (t4 - t3),
               "occluded_rays_per_s": len(origin) / (t5 - t4),
               "load_average": os.getloadavg()[0]}
        rows.append(row)
        print(f"{strands:>7} {kind:8} tris {row['triangles']:>9,}  build "
              f"{row['mesh_seconds']:.2f}+{row['embree_build_seconds']:.2f} s  Embree RSS "
              f"+{grown / 2**20:7.1f} MiB  arrays {row['prtcore_arrays_bytes'] / 2**20:7.1f} "
              f"MiB  intersect {row['intersect_rays_per_s'] / 1e6:.3f} Mray/s  occluded "
              f"{row['occluded_rays_per_s'] / 1e6:.3f} Mray/s  (load {os.getloadavg()[0]:.1f})",
              flush=True)
        del tracer, mesh
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strands", type=int, nargs="+", default=[10_000, 140_000])
    ap.add_argument("--rays", type=int, default=400_000)
    args = ap.parse_args()
    fid = {k: fidelity(k) for k in KINDS}
    for k, v in fid.items():
        print(f"occlusion fidelity {k:8}: blocked / cylinder's = {v:.3f}")
    rows = [r for s in args.strands for r in run(s, args.rays)]
    out = ROOT / "benchmarks" / "results" / "hair_geometry.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": platform.machine(), "cpus": os.cpu_count(),
                               "fidelity": fid, "rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
