"""Intake benchmark: time per stage (load, plan, repair, uv, texels, points) for the shared
assets and the Cornell box at 512² and 1024² atlases.

    .venv/bin/python benchmarks/intake.py [--sizes 512 1024] [--assets DIR]

Prints a table and writes benchmarks/results/intake.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from prtcore.core.progress import StageTimer  # noqa: E402
from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.pipeline import INTAKE_STAGES as STAGES  # noqa: E402
from prtcore.pipeline import run_intake  # noqa: E402
from prtcore.scenes.cornell import write_cornell_box  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[512, 1024])
    ap.add_argument("--assets", default=str(ROOT.parent / "shared" / "assets"))
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "intake.json"))
    args = ap.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="prt-intake-"))
    assets = [write_cornell_box(tmp / "cornell_box.glb")]
    assets += sorted(Path(args.assets).glob("*.glb"))
    rows = []
    header = f"{'asset':<22s}{'atlas':>6s}{'tris':>8s}{'texels':>9s}" + "".join(
        f"{s:>9s}" for s in STAGES) + f"{'total':>9s}"
    print(header)
    print("-" * len(header))
    for size in args.sizes:
        spec = parse_spec({"atlas": {"resolution": size, "padding": 4}})
        for asset in assets:
            timer = StageTimer(quiet=True)
            t0 = time.perf_counter()
            res = run_intake(asset, spec, quiet=True, timer=timer)
            total = time.perf_counter() - t0
            row = {"asset": asset.name, "atlas": size, "triangles": res.scene.triangle_count,
                   "texels": res.texels.count, "uv": res.prepare.uv_action,
                   "utilisation": res.prepare.utilisation,
                   "seconds": {s: timer.seconds.get(s, 0.0) for s in STAGES},
                   "skipped": dict(timer.skipped), "total_s": total}
            rows.append(row)
            print(f"{asset.name:<22s}{size:>6d}{row['triangles']:>8d}{row['texels']:>9d}"
                  + "".join(f"{row['seconds'][s]:>9.3f}" for s in STAGES)
                  + f"{total:>9.3f}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": platform.uname()._asdict(), "rows": rows},
                              indent=2))
    print(f"\nwritten: {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
