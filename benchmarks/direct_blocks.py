"""Benchmark: the Chiang fibre's direct light (prtcore.transport.fibre_chiang.chiang_direct)
in texel blocks bounded in bytes (``fibre.DIRECT_BLOCK_BYTES``, what a bake runs) against
the fixed 16 384-texel blocks it took until 2026-12-07, whose (J + F)·K float32 triples a
texel grew with the samples, the lights and the exitance.

The procedural tangle (prtcore.scenes.hair.tangle, 10 texels a strand), K lights drawn
from a spec's default family, J direct samples, one exitance. The two block rules run
alternately, ``--repeats`` times each, in one process, so their time ratio is measured on
one machine state. Printed per rule: the texels a block, the blocks, the seconds (each
run and the median), and the peak of numpy's traced allocations during the call
(tracemalloc: numpy reports its buffers to it), beside the block's own bytes. The results
must be equal bit for bit; the benchmark says so or fails. Written to
benchmarks/results/direct_blocks.json.

Figures (2026-12-07, 2 cores, the bake's tangle: 1000 strands, K = 528, J = 32, second
order): see docs/hair.md, "The direct light's blocks bounded in bytes".

Usage: python benchmarks/direct_blocks.py [--strands 1000] [--lights 528] [--samples 32]
       [--exitance second_order] [--repeats 2]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import prtcore.transport.fibre as fibre_module  # noqa: E402
from prtcore.core.spec import ChiangSpec, parse_spec  # noqa: E402
from prtcore.emitters.families import sample_configurations  # noqa: E402
from prtcore.receivers.strands import build_strand_space  # noqa: E402
from prtcore.scenes.hair import tangle  # noqa: E402
from prtcore.transport.fibre import hair_tracer  # noqa: E402
from prtcore.transport.fibre_chiang import EXITANCE_TERMS, chiang_direct, chiang_fibre  # noqa: E402

#: the rule until 2026-12-07: 16 384 texels a block whatever J, K and F
FIXED_BYTES = 1 << 62


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strands", type=int, default=1000)
    ap.add_argument("--lights", type=int, default=528)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--exitance", default="second_order", choices=sorted(EXITANCE_TERMS))
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    hair = tangle(args.strands)
    space = build_strand_space(hair, 10)
    tracer, _ = hair_tracer(space)
    fibre = chiang_fibre(ChiangSpec(eumelanin=1.3), space)
    b = hair.bounds()
    lights, _ = sample_configurations(parse_spec({"lights": {"count": args.lights}}).lights,
                                      b.mean(axis=0), float(np.linalg.norm(b[1] - b[0]) / 2))
    f = EXITANCE_TERMS[args.exitance]
    k, j = len(lights), args.samples
    rules = {"fixed 16 384": FIXED_BYTES, "bounded": fibre_module.DIRECT_BLOCK_BYTES}
    runs: dict[str, dict] = {name: {"seconds": [], "traced_peak_gib": []} for name in rules}
    first: dict[str, np.ndarray] = {}
    for _ in range(args.repeats):
        for name, budget in rules.items():
            fibre_module.DIRECT_BLOCK_BYTES = budget
            block = min(space.count, fibre_module.direct_block(j, k, f))
            tracemalloc.start()
            t0 = time.perf_counter()
            out = chiang_direct(space, tracer, lights, j, 1, fibre, args.exitance)
            seconds = time.perf_counter() - t0
            peak = tracemalloc.get_traced_memory()[1] - out.nbytes
            tracemalloc.stop()
            runs[name]["seconds"].append(seconds)
            runs[name]["traced_peak_gib"].append(peak / 2**30)
            runs[name].update(block_texels=block, blocks=-(-space.count // block),
                              block_gib=block * (j + f) * k * 12 / 2**30)
            if name in first and not np.array_equal(first[name], out):
                raise SystemExit(f"{name}: a repeat differs from the first run")
            first.setdefault(name, out)
    equal = bool(np.array_equal(*first.values()))
    print(f"tangle {args.strands} strands, {space.count} texels; K = {k}, J = {j}, "
          f"{args.exitance} (F = {f})")
    for name, r in runs.items():
        r["median_s"] = float(np.median(r["seconds"]))
        print(f"  {name:<14s} {r['block_texels']:6d} texels a block ({r['blocks']} blocks, "
              f"{r['block_gib']:.2f} GiB each): "
              f"{', '.join(f'{s:.1f}' for s in r['seconds'])} s (median {r['median_s']:.1f}), "
              f"traced peak beyond the result {max(r['traced_peak_gib']):.2f} GiB")
    a, c = (runs[n]["median_s"] for n in rules)
    print(f"  bounded / fixed time: {c / a:.2f}; results equal bit for bit: {equal}")
    out_path = ROOT / "benchmarks" / "results" / "direct_blocks.json"
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps({"args": vars(args), "texels": space.count, "runs": runs,
                                    "time_ratio": c / a, "equal": equal}, indent=1))
    print(f"→ {out_path}")
    return 0 if equal else 1


if __name__ == "__main__":
    raise SystemExit(main())
