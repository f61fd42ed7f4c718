"""Benchmark: where the hair dataset's time goes — Embree's throughput on the fibre tubes.

On the procedural hairball (``--strands``, 16 segments per strand, 10 texels per strand):
400k shadow rays from strand texels toward one point light at twice the hair's radius, and
the same rays as closest-hit queries, through (a) the bake's 3-sided fibre tubes and
(b) the same polylines with every segment split into ``--split`` collinear pieces (more,
shorter triangles: tighter bounding boxes), each on one thread, timed in CPU seconds of
this process (the 2-core machine is shared: CPU time is steadier than wall time); and, for
scale, the same queries against a single triangle (embreex's per-ray overhead). The same
rays through the tubes in three orders: as drawn (random texels), strand by strand, and
along the 3-D Morton curve of their origins (how ``fibre_direct`` orders its texels). Then
``fibre_direct`` for ``--lights`` point lights with its CPU time split into Embree's
occlusion queries and the rest, and ``fibre_gather`` with ``--gather-rays`` rays per
texel likewise (closest-hit queries, with :mod:`prtcore.core.raytrace`'s hit records, and
the rest). Prints and writes benchmarks/results/hair_rays.json.

Usage: python benchmarks/hair_rays.py [--strands 10000] [--split 4] [--lights 4]
       [--gather-rays 8]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from prtcore.core.fibres import fibre_tubes  # noqa: E402
from prtcore.core.hair import Hair  # noqa: E402
from prtcore.core.raytrace import RayTracer  # noqa: E402
from prtcore.core.scene import Light  # noqa: E402
from prtcore.receivers.strands import build_strand_space  # noqa: E402
from prtcore.receivers.texels import morton_order  # noqa: E402
from prtcore.scenes.hair import hairball  # noqa: E402
from prtcore.transport.fibre import fibre_direct, fibre_gather, hair_tracer  # noqa: E402


def split_segments(hair: Hair, pieces: int) -> Hair:
    """The same polylines with every segment cut into ``pieces`` collinear segments
    (thickness and colour interpolated)."""
    f = np.arange(pieces) / pieces
    seg = hair.segment_start
    last = hair.offsets[1:] - 1

    def fill(a: np.ndarray) -> np.ndarray:
        inner = a[seg][:, None] + f.reshape(1, -1, *([1] * (a.ndim - 1))) * \
            (a[seg + 1] - a[seg])[:, None]
        # strand by strand: its segments' pieces, then its last point
        per = np.diff(hair.offsets) - 1
        chunks = np.split(inner.reshape(-1, *a.shape[1:]), np.cumsum(per * pieces)[:-1])
        return np.concatenate([np.concatenate([c, a[k:k + 1]]) for c, k in
                               zip(chunks, last, strict=True)])

    counts = (np.diff(hair.offsets) - 1) * pieces + 1
    return dataclasses.replace(hair, points=fill(hair.points), thickness=fill(hair.thickness),
                               color=fill(hair.color),
                               offsets=np.concatenate([[0], np.cumsum(counts)]))


def rays_per_cpu_second(tracer: RayTracer, o, d, dist) -> tuple[float, float, float]:
    tracer.occluded(o[:1], d[:1])  # Embree's lazy BVH build
    t0 = time.process_time()
    blocked = tracer.occluded(o, d, dist)
    t1 = time.process_time()
    tracer.intersect(o, d)
    t2 = time.process_time()
    return len(o) / (t1 - t0), len(o) / (t2 - t1), float(blocked.mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strands", type=int, default=10_000)
    ap.add_argument("--split", type=int, default=4)
    ap.add_argument("--lights", type=int, default=4)
    ap.add_argument("--gather-rays", type=int, default=8)
    args = ap.parse_args()
    hair = hairball(strands=args.strands, seed=0)
    space = build_strand_space(hair, 10)
    rng = np.random.default_rng(0)
    n = 400_000
    i = rng.integers(0, space.count, n)
    o = space.position[i] + space.normal[i] * space.radius[i, None] * 1.3
    c = space.position.mean(axis=0)
    r = float(np.linalg.norm(space.position.max(axis=0) - space.position.min(axis=0)) / 2)
    w = np.array([0.3, 0.8, 0.5]) / np.linalg.norm([0.3, 0.8, 0.5])
    d = c + 2 * r * w - o
    dist = np.linalg.norm(d, axis=1)
    d /= dist[:, None]
    row: dict = {"strands": args.strands, "rays": n, "geometry": {}}
    one = RayTracer(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]), np.array([[0, 1, 2]]),
                    scale=1.0, threads=1)
    far = o + np.array([0.0, 0.0, 10.0 * r])
    tubes = RayTracer(*_tubes(hair), scale=r, threads=1)
    for name, tracer in (("one triangle", one), ("tubes", tubes),
                         (f"tubes, segments split {args.split}×",
                          RayTracer(*_tubes(split_segments(hair, args.split)), scale=r,
                                    threads=1))):
        occ, hit, blocked = rays_per_cpu_second(tracer, far if name == "one triangle" else o,
                                                d, dist)
        row["geometry"][name] = {"triangles": len(tracer.faces), "occluded_per_cpu_s": occ,
                                 "intersect_per_cpu_s": hit, "blocked": blocked}
        print(f"{name:28s} {len(tracer.faces) / 1e6:6.2f} M triangles: occlusion "
              f"{occ / 1e6:.3f} M rays/CPU-s, closest hit {hit / 1e6:.3f} M rays/CPU-s "
              f"({100 * blocked:.1f} % blocked)")
    # the same rays through the tubes in three orders: as drawn (random texels), strand by
    # strand (how fibre_direct took them before dbdb2c4), along the Morton curve (since)
    row["order"] = {}
    for name, idx in (("random texels", np.arange(n)),
                      ("strand order", np.argsort(i, kind="stable")),
                      ("Morton order", morton_order(o, np.stack([o.min(axis=0),
                                                                 o.max(axis=0)])))):
        occ, hit, _ = rays_per_cpu_second(tubes, o[idx], d[idx], dist[idx])
        row["order"][name] = {"occluded_per_cpu_s": occ, "intersect_per_cpu_s": hit}
        print(f"tubes, rays in {name:14s}: occlusion {occ / 1e6:.3f} M rays/CPU-s, closest "
              f"hit {hit / 1e6:.3f} M rays/CPU-s")
    tracer, _ = hair_tracer(space, threads=1)
    tracer.occluded(o[:1], d[:1])
    spent = [0.0, 0]
    occluded = tracer.occluded

    def timed(*a):
        t0 = time.process_time()
        out = occluded(*a)
        spent[0] += time.process_time() - t0
        spent[1] += len(a[0])
        return out

    tracer.occluded = timed
    dirs = rng.normal(size=(args.lights, 3))
    lights = [Light(type="point", color=np.ones(3), intensity=1.0,
                    position=c + 2 * r * v / np.linalg.norm(v)) for v in dirs]
    t0 = time.process_time()
    fibre_direct(space, tracer, lights, 4, 1)
    total = time.process_time() - t0
    row["fibre_direct"] = {"lights": args.lights, "cpu_seconds": total,
                           "occlusion_cpu_seconds": spent[0], "shadow_rays": spent[1],
                           "load_average": os.getloadavg()[0]}
    print(f"fibre_direct, {args.lights} lights, J = 4: {total:.2f} CPU-s, of which Embree's "
          f"occlusion {spent[0]:.2f} CPU-s for {spent[1] / 1e6:.2f} M shadow rays; load "
          f"{os.getloadavg()[0]:.1f}")
    spent[:] = [0.0, 0]
    intersect = tracer.intersect

    def timed_hits(*a):
        t0 = time.process_time()
        out = intersect(*a)
        spent[0] += time.process_time() - t0
        spent[1] += len(a[0])
        return out

    tracer.intersect = timed_hits
    t0 = time.process_time()
    fibre_gather(space, tracer, fibre_tubes(hair), 0, args.gather_rays, 5)
    total = time.process_time() - t0
    row["fibre_gather"] = {"rays_per_texel": args.gather_rays, "cpu_seconds": total,
                           "intersect_cpu_seconds": spent[0], "rays": spent[1]}
    print(f"fibre_gather, M = {args.gather_rays}: {total:.2f} CPU-s, of which Embree's "
          f"closest hits (with raytrace.py's hit records) {spent[0]:.2f} CPU-s for "
          f"{spent[1] / 1e6:.2f} M rays")
    out = ROOT / "benchmarks" / "results" / "hair_rays.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(row, indent=1))
    print(f"wrote {out}")


def _tubes(hair: Hair) -> tuple[np.ndarray, np.ndarray]:
    m = fibre_tubes(hair)
    return m.positions, m.faces


if __name__ == "__main__":
    main()
