"""Bundles that must stay bit-identical across refactors (issue 12).

``python tests/bit_identity.py record`` bakes each case and writes the checksums of every
result file (everything in the bundle's manifest ``checksums``) to
``tests/data/bundle_checksums.json``; ``tests/test_bit_identity.py`` bakes the same cases
and compares. Re-record only for a change that is meant to alter numbers, and say in the
commit which change and what it measured against the path tracer.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "assets"
RECORD = ROOT / "tests" / "data" / "bundle_checksums.json"

#: A small bake of a shared asset: a point family around the asset's bounding sphere.
SMALL = {
    "atlas": {"resolution": 128, "padding": 2},
    "measurement_points": {"count": 64, "supersample": 4, "seed": 3},
    "lights": {"count": 48, "holdout": 8, "seed": 4, "families": [
        {"type": "point", "position": {"shell": [1.2, 2.0]},
         "intensity": {"uniform": [0.5, 3.0]}}]},
    "transport": {"gather_rays": 32, "max_bounces": 8},
    "fit": {"basis": 8},
    "output": {"dtype": "float"},
}


def cases() -> dict[str, tuple[Path, dict]]:
    """name → (asset, spec dict)."""
    cornell_spec = json.loads((ROOT / "examples" / "cornell_box.spec.json").read_text())
    return {
        "cornell_example": (ROOT / "examples" / "cornell_box.glb", cornell_spec),
        "monkey": (SHARED / "monkey.glb", SMALL),
        "BoxTextured": (SHARED / "BoxTextured.glb", SMALL),
    }


def bake_checksums(name: str, out: Path) -> dict[str, str]:
    from prtcore.core.spec import parse_spec
    from prtcore.io.bundle import read_manifest
    from prtcore.pipeline import bake

    asset, spec = cases()[name]
    bundle = bake(asset, parse_spec(spec), out / name, quiet=True)
    return dict(sorted(read_manifest(bundle)["checksums"].items()))


def record() -> None:
    result = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in cases():
            result[name] = bake_checksums(name, Path(tmp))
            print(f"{name}: {len(result[name])} files")
    RECORD.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {RECORD}")


if __name__ == "__main__":
    if sys.argv[1:] != ["record"]:
        sys.exit("usage: python tests/bit_identity.py record")
    record()
