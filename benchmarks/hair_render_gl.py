"""Benchmark: a hair bundle drawn by the GL renderer against the CPU drawing.

Bakes the test tangle (prtcore.scenes.hair.tangle, ``--strands`` strands × 4 texels, the
spec of tests/test_hairbake.py) and draws it through one camera under one point light with
``prtcore.runtime.strands_gl`` (fibre tubes, shadow maps, basis blended in the fragment
shader) and ``prtcore.runtime.strands`` (the tubes ray traced on the CPU). Over the pixels
both cover, per mode: the means and their ratio, and the mean absolute per-pixel
difference relative to the CPU's mean; the fraction of pixels whose coverage differs; the
wall time of each drawing (the GL one includes shader compilation). Prints and writes
benchmarks/results/hair_render_gl.json.

Usage: python benchmarks/hair_render_gl.py [--strands 200] [--size 96]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from prtcore.core.scene import Light  # noqa: E402
from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.io.hair import write_hair  # noqa: E402
from prtcore.pipeline import bake  # noqa: E402
from prtcore.reference.camera import camera_from_dict  # noqa: E402
from prtcore.runtime.strands import render_strands  # noqa: E402
from prtcore.runtime.strands_gl import render_strands_gl  # noqa: E402
from prtcore.scenes.hair import tangle  # noqa: E402

SPEC = {"hair": {"texels_per_strand": 4, "albedo": [0.8, 0.6, 0.4]},
        "measurement_points": {"count": 32, "supersample": 2},
        "lights": {"count": 24, "holdout": 4,
                   "families": [{"type": "point", "position": {"shell": [1.5, 3.0]},
                                 "intensity": {"uniform": [0.02, 0.1]}}]},
        "transport": {"gather_rays": 16}, "fit": {"basis": 8}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strands", type=int, default=200)
    ap.add_argument("--size", type=int, default=96)
    args = ap.parse_args()
    work = ROOT / "benchmarks" / "results" / f"hair_render_gl_{args.strands}"
    work.mkdir(parents=True, exist_ok=True)
    asset = write_hair(work / "tangle.hair", tangle(args.strands))
    out = bake(asset, parse_spec(SPEC), work / "bundle", quiet=True, force=True)
    lights = [Light(type="point", color=np.ones(3), intensity=0.05,
                    position=np.array([0.06, 0.04, 0.02]))]
    cam = camera_from_dict({"position": [0, 0.02, 0.12], "target": [0, 0, 0],
                            "fov_y_deg": 40, "width": args.size, "height": args.size})
    row: dict = {"strands": args.strands, "size": args.size, "modes": {}}
    for mode in ("indirect", "direct", "full"):
        t0 = time.perf_counter()
        res, label = render_strands_gl(out, lights, cam, mode=mode)
        t1 = time.perf_counter()
        cpu = render_strands(out, lights, cam, mode=mode)
        t2 = time.perf_counter()
        g, c = res.image, cpu
        seen_g, seen_c = g[:, :, 3] > 0.5, c[:, :, 3] > 0.5
        both = seen_g & seen_c
        gm, cm = float(g[both, :3].mean()), float(c[both, :3].mean())
        rel = float(np.abs(g[both, :3] - c[both, :3]).mean() / cm)
        row["renderer"] = label
        row["modes"][mode] = {"gl_mean": gm, "cpu_mean": cm, "mean_ratio": gm / cm,
                              "per_pixel_rel": rel,
                              "coverage_differs": float((seen_g != seen_c).mean()),
                              "covered": float(both.mean()),
                              "gl_seconds": t1 - t0, "cpu_seconds": t2 - t1}
        print(f"{mode:8s}: GL/CPU mean {gm / cm:.4f}, per-pixel |Δ|/mean {100 * rel:.2f} %, "
              f"coverage differs at {100 * (seen_g != seen_c).mean():.2f} % of pixels "
              f"({100 * both.mean():.1f} % covered by both); GL {t1 - t0:.2f} s, CPU "
              f"{t2 - t1:.2f} s ({label})")
    path = ROOT / "benchmarks" / "results" / "hair_render_gl.json"
    path.write_text(json.dumps(row, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
