"""Benchmark: the bake's resident memory stage by stage (issue 20's 1024² memory target).

One whole bake of the bundled Cornell box (:func:`prtcore.pipeline.bake`, its example spec
at ``--resolution``, K = 128 + 16, P = 256) with a thread sampling VmRSS every 50 ms; each
sample counts towards the stage running then (the stage timer's start callback). Prints
the peak resident memory per stage and writes benchmarks/results/stage_memory.json.

Figures (2026-12-03, 1024²): before the memory work (peak set by the noise and denoise
stages) solve 5.04, transport noise 6.33, denoise 6.54, fit 5.42 GiB; after (solve written
over the direct light, operators dropped before the second trace, in-place denoise) 3.97,
4.45, 3.63, 2.68 GiB; the gather operator stage 2.68 GiB both times. After the gather's and
the filters' temporaries were cut (dbc0eca, f80ecec; AMD EPYC machine): gather operator
2.43, solve 3.85, transport noise 3.65, denoise 2.54, fit 2.47 GiB — the solve sets the peak.

Usage: python benchmarks/stage_memory.py [--resolution 1024]
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.pipeline import bake  # noqa: E402
from prtcore.scenes.cornell import EXAMPLE_SPEC, write_cornell_box  # noqa: E402


def rss_gib() -> float:
    """This process's resident set (VmRSS) in GiB."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS"):
                return int(line.split()[1]) / 2**20
    return 0.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--resolution", type=int, default=1024)
    ap.add_argument("--out", type=Path,
                    default=ROOT / "benchmarks" / "results" / "stage_memory.json")
    args = ap.parse_args(argv)
    d = copy.deepcopy(EXAMPLE_SPEC)
    d["atlas"]["resolution"] = args.resolution
    d["lights"]["count"], d["lights"]["holdout"] = 128, 16
    d["measurement_points"]["count"] = 256
    state = {"stage": "start", "peak": {}, "run": True}

    def sample() -> None:
        while state["run"]:
            stage = state["stage"]
            state["peak"][stage] = max(state["peak"].get(stage, 0.0), rss_gib())
            time.sleep(0.05)

    def on_stage(name: str, fraction: float) -> None:
        if fraction == 0.0:
            state["stage"] = name

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        asset = write_cornell_box(Path(tmp) / "cornell.glb")
        bake(asset, parse_spec(d), Path(tmp) / "bundle", quiet=True, callback=on_stage)
    state["run"] = False
    sampler.join()
    print(f"Cornell box {args.resolution}², K = 128 + 16, P = 256: "
          f"{time.perf_counter() - t0:.1f} s")
    for stage, peak in state["peak"].items():
        print(f"  {stage:<20s} {peak:6.2f} GiB")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"resolution": args.resolution,
                                    "peak_gib": state["peak"]}, indent=1))
    print(f"→ {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
