"""Benchmark: classic SH-PRT and transfer textures (issue 17) — memory, bake time, frame
time.

Prints and writes (benchmarks/results/sh_prt.json):

* the poster's Table 1 for assets of the project: bytes of per-vertex storage (float32,
  3 colour channels × L² coefficients per vertex) and of transfer textures (half float,
  the whole W × W atlas) at 3 and 5 bands;
* on the project's comparison scene (prtcore.scenes.floor_object), for each storage:
  the bake time (`prtcore bake` with ``method.name = "sh_prt"``), the CPU relight time
  (``relight_bundle``: T · l over the atlas), and the GL frame time of the vertex- and
  fragment-shader variants (``prtcore/runtime/sh_gl.py``) at ``--width`` × ``--height``,
  median of ``--frames`` frames after one warm-up frame, wall clock between glFinish calls
  and by GL timer query; the GL renderer's name says whether it is a GPU or Mesa's
  software rasteriser;
* the CPU cost of the glossy runtime per point: TP (triple product, then the Phong lobe)
  and TPFL (the lobe only) at 5 bands;
* the CPU cost of turning an environment per frame: ``sh.rotate`` of its (L², 3)
  coefficients by a new rotation (the rotation matrix built each time).

Usage: python benchmarks/sh_prt.py [--width 1920 --height 1080 --frames 5 --atlas 512]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def memory_rows(assets: list[Path], sizes: tuple[int, ...], bands: tuple[int, ...]) -> list:
    from prtcore.io.gltf.loader import load_asset
    from prtcore.methods.sh_prt import memory_table

    rows = []
    for path in assets:
        scene = load_asset(path)
        for r in memory_table(len(scene.positions), sizes, bands):
            rows.append({"asset": path.name, **r})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--atlas", type=int, default=512)
    ap.add_argument("--bands", type=int, default=5)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "sh_prt.json"))
    args = ap.parse_args(argv)

    from prtcore.compare import default_camera
    from prtcore.core import sh
    from prtcore.core.spec import parse_spec
    from prtcore.emitters.environment import light_sh, sky_environment
    from prtcore.io.bundle import read_manifest
    from prtcore.methods.sh_prt import glossy_tp, glossy_tpfl, relight_bundle
    from prtcore.pipeline import bake
    from prtcore.runtime.glcontext import renderer_label
    from prtcore.runtime.sh_gl import ShPrtRenderer
    from prtcore.scenes import floor_object

    result: dict = {"machine": {"python": sys.version.split()[0],
                                "platform": platform.platform()}}
    tmp = Path(tempfile.mkdtemp(prefix="sh_prt_bench."))
    asset = floor_object.write_floor_object(tmp / "floor_object.glb")
    shared = ROOT.parent / "shared" / "assets"
    assets = [asset] + [p for p in (shared / "monkey.glb", shared / "Duck.glb") if p.is_file()]
    result["memory"] = memory_rows(assets, (256, 512, 1024), (3, 5))
    print("poster Table 1 (bytes of transfer, 3 colour channels):")
    for r in result["memory"]:
        print(f"  {r['asset']:<20} {r['storage']:<8} {r['size']:>6} bands {r['bands']} "
              f"({r['coefficients']:>2} coeffs): {r['bytes'] / 2 ** 20:8.2f} MiB")

    env = sky_environment(np.array([0.3, 0.8, 0.2]), 64)
    light = env.sh_coefficients(args.bands) + light_sh(floor_object.key_light(), args.bands)
    camera = default_camera(args.width, args.height)
    result["scene"] = {}
    for storage in ("vertex", "texture"):
        spec = dict(floor_object.SPEC, atlas={"resolution": args.atlas, "padding": 4},
                    method={"name": "sh_prt"},
                    sh_prt={"storage": storage, "bands": args.bands})
        t0 = time.perf_counter()
        out = bake(asset, parse_spec(spec), tmp / f"bundle_{storage}", quiet=True)
        bake_s = time.perf_counter() - t0
        m = read_manifest(out)

        class Fixed:
            @staticmethod
            def sh_coefficients(bands):
                return light

        t0 = time.perf_counter()
        relight_bundle(out, m, Fixed)
        relight_s = time.perf_counter() - t0
        with ShPrtRenderer(out) as r:
            r.render(light, camera)  # warm-up (shader compilation, uploads)
            frames = [r.render(light, camera) for _ in range(args.frames)]
            label = renderer_label(r.ctx)
        key = f"sh_{storage}"
        wall = statistics.median(f.wall_milliseconds[key] for f in frames)
        gpu = [f.milliseconds[key] for f in frames if f.milliseconds[key] is not None]
        row = {"bake_seconds": bake_s, "relight_cpu_seconds": relight_s,
               "frame_wall_ms": wall, "frame_gl_timer_ms": statistics.median(gpu)
               if gpu else None, "renderer": label, "storage_bytes":
               m["sh_prt"]["storage_bytes"], "resolution": [args.width, args.height]}
        result["scene"][storage] = row
        print(f"{storage:>8}: bake {bake_s:.1f} s, CPU relight {1e3 * relight_s:.1f} ms, "
              f"GL frame {wall:.2f} ms wall ({args.width}×{args.height}, {label}), "
              f"{row['storage_bytes'] / 1024:.1f} KiB")

    n = 200_000
    rng = np.random.default_rng(0)
    vis = rng.normal(size=(n, args.bands ** 2))
    fixed = rng.normal(size=(n, 3, args.bands ** 2))
    r_dir = rng.normal(size=(n, 3))
    r_dir /= np.linalg.norm(r_dir, axis=1, keepdims=True)
    spec_c = np.full((n, 3), 0.5)
    t0 = time.perf_counter()
    glossy_tp(vis, light, r_dir, 8.0, spec_c)
    tp = (time.perf_counter() - t0) / n
    t0 = time.perf_counter()
    glossy_tpfl(fixed, r_dir, 8.0, spec_c)
    tpfl = (time.perf_counter() - t0) / n
    result["glossy_cpu_ns_per_point"] = {"tp": 1e9 * tp, "tpfl": 1e9 * tpfl,
                                         "bands": args.bands, "points": n,
                                         "triple_product_nonzeros": int(
                                             np.count_nonzero(sh.triple_product_tensor(
                                                 args.bands)))}
    print(f"glossy on the CPU (numpy, {n} points): TP {1e9 * tp:.0f} ns/point, TPFL "
          f"{1e9 * tpfl:.0f} ns/point")
    from prtcore.emitters.environment import rotation_about_y

    t0 = time.perf_counter()
    reps = 200
    for i in range(reps):
        sh.rotate(light, rotation_about_y(360.0 * i / reps))
    rot_ms = 1e3 * (time.perf_counter() - t0) / reps
    result["rotate_ms_per_frame"] = {"bands": args.bands, "ms": rot_ms}
    print(f"environment rotation per frame (sh.rotate, {args.bands} bands, matrix rebuilt): "
          f"{rot_ms:.3f} ms")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
