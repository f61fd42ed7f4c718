"""Benchmark: the GPU runtime per pass at 1280×720 for n = 4, 16, 64 basis elements.

Bakes the example Cornell box (prtcore.scenes.cornell.EXAMPLE_SPEC with 64 basis elements; or
uses ``--bundle DIR``), renders it through the example camera at 1280×720 under the
example point light, and times each pass of a frame (prtcore.runtime.gl):

* shadow_maps — six 1024² views of the light;
* points — fake G-buffer: shade the measurement-point supersamples, average clusters;
* coefficients — u = M·x per channel and the plane weights (compute shader);
* camera — direct light with shadows + the basis blend in the fragment shader;
* atlas_blend — the basis blend alone over the whole lightmap atlas.

Each figure is the median over ``--repeat`` frames after one warm-up frame, measured
twice: by GL timer query (GPU clock) and by the wall clock between glFinish calls. The
GL renderer string is printed and stored: on Mesa's llvmpipe the "GPU" is the CPU
(labelled "(software)"), and llvmpipe runs compute dispatches outside its timer queries,
so its compute rows read ~0 by query — the wall-clock column is the one to read there.

Usage: python benchmarks/runtime.py [--bundle DIR] [--repeat 10]
Writes benchmarks/results/runtime.json.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import platform
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from prtcore import pipeline  # noqa: E402
from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.emitters.lightfile import load_light_file  # noqa: E402
from prtcore.reference.camera import load_camera  # noqa: E402
from prtcore.runtime.gl import BundleRenderer, gpu_runtime_table  # noqa: E402
from prtcore.scenes.cornell import EXAMPLE_SPEC  # noqa: E402

PASSES = ("shadow_maps", "points", "coefficients", "camera", "atlas_blend")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", type=Path, default=None,
                    help="bundle with ≥ 64 basis elements (default: bake the example box)")
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=720)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" /
                    "runtime.json")
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        bundle = args.bundle
        if bundle is None:
            spec = copy.deepcopy(EXAMPLE_SPEC)
            spec["fit"]["basis"] = 64
            print("baking the example Cornell box with 64 basis elements …", flush=True)
            bundle = pipeline.bake(ROOT / "examples" / "cornell_box.glb", parse_spec(spec),
                                   Path(tmp) / "bundle", quiet=True)
        camera = dataclasses.replace(load_camera(ROOT / "examples" / "cameras" /
                                                 "cornell.json"),
                                     width=args.width, height=args.height)
        lights = load_light_file(ROOT / "examples" / "lights" / "point_center.json")
        with BundleRenderer(bundle) as r:
            ns = [n for n in (4, 16, 64) if n <= r.n_basis]
            table = gpu_runtime_table(r, lights, ns, camera=camera, repeat=args.repeat)
            info = {k: str(r.ctx.info[k]) for k in ("GL_RENDERER", "GL_VENDOR", "GL_VERSION")}
            atlas = r.data.coverage.shape
            points = r.data.point_count
            supersamples = len(r.data.cluster_owner)
            shadow = r.shadow_resolution

    print(f"renderer: {table['renderer']}  ({info['GL_VERSION']})")
    print(f"frame {args.width}×{args.height}, atlas {atlas[1]}×{atlas[0]}, P = {points} "
          f"points ({supersamples} supersamples), one point light, shadow views "
          f"6×{shadow}²; median of {args.repeat} frames, ms")
    print(f"{'n':>4s} " + " ".join(f"{p:>22s}" for p in PASSES))
    print(f"{'':>4s} " + " ".join(f"{'query / wall':>22s}" for _ in PASSES))
    for row in table["rows"]:
        cells = []
        for p in PASSES:
            q, w = row.get(p), row["wall"].get(p)
            cells.append(f"{'—' if q is None else f'{q:.3f}'} / "
                         f"{'—' if w is None else f'{w:.3f}'}")
        print(f"{row['n']:>4d} " + " ".join(f"{c:>22s}" for c in cells))

    result = {"renderer": table["renderer"], "gl": info, "frame": [args.width, args.height],
              "atlas": [atlas[1], atlas[0]], "points": points, "supersamples": supersamples,
              "shadow_resolution": shadow, "repeat": args.repeat,
              "timing": "median ms; pass: GL timer query (None: no valid result), wall: "
                        "wall clock between glFinish calls",
              "rows": table["rows"], "platform": platform.platform(),
              "python": platform.python_version()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    print(f"written: {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
