"""Benchmark: the bake's resident memory stage by stage (issue 20's 1024² memory target).

One whole bake of the bundled Cornell box (:func:`prtcore.pipeline.bake`, its example spec
at ``--resolution``, K = 128 + 16, P = 256), or of ``--asset`` (a glTF or hair file, with
``--mesh`` for a hair + mesh bake, ``--spec`` a spec file, default K = 128 + 16), with a
thread sampling VmRSS every 50 ms; each sample counts towards the stage running then (the
stage timer's start callback). Prints the peak resident memory per stage, and the bake's
own memory estimate (the one its limit is checked against) beside the peak; writes
benchmarks/results/stage_memory.json. A bake whose estimate is over the limit needs
``PRT_LIMIT_MAX_BAKE_BYTES`` raised.

Figures (2026-12-03, 1024²): before the memory work (peak set by the noise and denoise
stages) solve 5.04, transport noise 6.33, denoise 6.54, fit 5.42 GiB; after (solve written
over the direct light, operators dropped before the second trace, in-place denoise) 3.97,
4.45, 3.63, 2.68 GiB; the gather operator stage 2.68 GiB both times. After the gather's and
the filters' temporaries were cut (dbc0eca, f80ecec; AMD EPYC machine): gather operator
2.43, solve 3.85, transport noise 3.65, denoise 2.54, fit 2.47 GiB — the solve sets the peak.

Usage: python benchmarks/stage_memory.py [--resolution 1024]
       python benchmarks/stage_memory.py --asset hairball.hair [--mesh head.glb]
       [--spec spec.json]
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
    ap.add_argument("--asset", type=Path, default=None,
                    help="bake this asset instead of the Cornell box")
    ap.add_argument("--mesh", type=Path, default=None,
                    help="with a hair --asset: the glTF mesh baked with it")
    ap.add_argument("--spec", type=Path, default=None,
                    help="with --asset: the spec file (default K = 128 + 16)")
    ap.add_argument("--out", type=Path,
                    default=ROOT / "benchmarks" / "results" / "stage_memory.json")
    args = ap.parse_args(argv)
    d = copy.deepcopy(EXAMPLE_SPEC)
    d["atlas"]["resolution"] = args.resolution
    d["lights"]["count"], d["lights"]["holdout"] = 128, 16
    d["measurement_points"]["count"] = 256
    state = {"stage": "start", "peak": {}, "run": True, "estimate": None}
    _record_estimates(state)

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
        if args.asset is None:
            asset, spec = write_cornell_box(Path(tmp) / "cornell.glb"), parse_spec(d)
            title = f"Cornell box {args.resolution}², K = 128 + 16, P = 256"
        else:
            asset = args.asset
            spec = parse_spec(json.loads(args.spec.read_text()) if args.spec else
                              {"lights": {"count": 128, "holdout": 16}})
            title = f"{asset.name}{f' + {args.mesh.name}' if args.mesh else ''}, " \
                f"K = {spec.lights.count} + {spec.lights.holdout}"
        bake(asset, spec, Path(tmp) / "bundle", quiet=True, callback=on_stage,
             mesh=args.mesh)
    state["run"] = False
    sampler.join()
    print(f"{title}: {time.perf_counter() - t0:.1f} s")
    for stage, peak in state["peak"].items():
        print(f"  {stage:<20s} {peak:6.2f} GiB")
    peak = max(state["peak"].values())
    est = state["estimate"] / 2**30
    print(f"  peak {peak:.2f} GiB; the bake's estimate {est:.2f} GiB ({est / peak:.2f}× the "
          "peak)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"asset": str(args.asset or "cornell"),
                                    "mesh": str(args.mesh) if args.mesh else None,
                                    "resolution": args.resolution,
                                    "estimate_gib": est, "peak_gib": state["peak"]},
                                   indent=1))
    print(f"→ {args.out}")
    return 0


def _record_estimates(state: dict) -> None:
    """Wrap the bakes' memory checks (surface and hair) so that ``state["estimate"]``
    receives the estimate the bake compared with its limit."""
    import prtcore.hairbake as hairbake
    import prtcore.transport.dataset as dataset

    def recording(check):
        def wrapped(*a, **k):
            state["estimate"] = check(*a, **k)
            return state["estimate"]
        return wrapped

    for module, name in ((dataset, "check_bake_memory"), (hairbake, "check_hair_memory")):
        setattr(module, name, recording(getattr(module, name)))


if __name__ == "__main__":
    raise SystemExit(main())
