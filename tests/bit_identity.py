"""Bundles that must stay bit-identical across refactors (issue 12).

``python tests/bit_identity.py record`` bakes each case and writes the checksums of every
result file (everything in the bundle's manifest ``checksums``) to
``tests/data/bundle_checksums.json``; ``tests/test_bit_identity.py`` bakes the same cases
and compares. Re-record only for a change that is meant to alter numbers, and say in the
commit which change and what it measured against the path tracer.

The bytes depend on the machine's floating point paths, not only on the code: numpy picks
its SIMD kernels (exp, sin, sums) and OpenBLAS its LAPACK kernels (the Q-DEIM pivots of the
measurement points) by CPU at run time, and they round differently (the same commit gives
other bundles on an AVX-512 machine than on an AVX2 one). So the record holds one set of
checksums per platform (:func:`platform_key`), and a bake passes when it matches the set
recorded for any platform: a regression would have to reproduce another machine's bytes.
``record`` replaces the whole file with this platform's set (after a numerical change the
others are stale); ``record --add`` adds or replaces this platform's set and keeps the
others (a new machine, the code unchanged — check first that the recorded platforms pass).
"""

from __future__ import annotations

import json
import platform
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


#: numpy's SIMD dispatch tiers (``__cpu_features__`` flag → label), widest first
SIMD_TIERS = (("avx512_spr", "AVX512_SPR"), ("avx512_icl", "AVX512_ICL"),
              ("avx512_skx", "AVX512_SKX"), ("avx2", "AVX2"), ("sse4", "SSE42"))


def blas_cores() -> str:
    """The kernel family the bundled OpenBLAS libraries (numpy's and scipy's) chose for this
    CPU at load time, e.g. "haswell" or "skylakex"; "blas_unknown" where none reports it."""
    import ctypes
    import glob

    import numpy as np
    import scipy

    names = set()
    for pkg in (np, scipy):
        libs = Path(pkg.__file__).resolve().parent.parent / f"{pkg.__name__}.libs"
        for lib in sorted(glob.glob(str(libs / "*openblas*"))):
            handle = ctypes.CDLL(lib)
            for sym in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename",
                        "openblas_get_corename64_", "openblas_get_corename"):
                fn = getattr(handle, sym, None)
                if fn is not None:
                    fn.restype = ctypes.c_char_p
                    names.add(fn().decode().lower())
                    break
    return "+".join(sorted(names)) or "blas_unknown"


def platform_key() -> str:
    """The floating point paths this machine takes: the architecture, the widest SIMD tier
    numpy dispatches to, and OpenBLAS's kernel family (an AMD Zen 4 has numpy's AVX-512
    kernels with OpenBLAS's Haswell ones, an Intel Skylake-X both AVX-512: other bytes).

    The first two sets of the record were filed under coarser keys, ``x86_64-avx2`` (an
    AMD EPYC without AVX-512) and ``x86_64-avx512`` (a machine with AVX-512 whose OpenBLAS
    kernels were not recorded); the keys only name the sets, a bake matches any of them."""
    from numpy._core._multiarray_umath import __cpu_features__ as cpu

    simd = next((name for name, flag in SIMD_TIERS if cpu.get(flag)), "baseline")
    return f"{platform.machine()}-{simd}-{blas_cores()}"


def recorded() -> dict[str, dict]:
    """platform key → case name → checksums."""
    return json.loads(RECORD.read_text())["platforms"]


def record(add: bool = False) -> None:
    result = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in cases():
            result[name] = bake_checksums(name, Path(tmp))
            print(f"{name}: {len(result[name])} files")
    platforms = dict(recorded()) if add else {}
    platforms[platform_key()] = result
    RECORD.write_text(json.dumps({"platforms": dict(sorted(platforms.items()))}, indent=1)
                      + "\n")
    print(f"wrote {RECORD} ({platform_key()}; platforms: {', '.join(sorted(platforms))})")


if __name__ == "__main__":
    if sys.argv[1:] not in (["record"], ["record", "--add"]):
        sys.exit("usage: python tests/bit_identity.py record [--add]")
    record(add=sys.argv[2:] == ["--add"])
