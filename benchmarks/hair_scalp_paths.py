"""Diagnostic benchmark: the Chiang head's scalp light by the kind of path it took, the fast
path against the project's path tracer.

The test head of benchmarks/hair_mesh_chiang_accuracy.py (10k curly strands by default,
dark hair: eumelanin 1.3, second-order exitance, M_h fibre rays, the atlas's own rays),
baked to two bounces with one source of light switched off, against
:func:`prtcore.reference.hair_mesh.chiang_hair_mesh_reference` tallying only the matching
next-event estimates (``tally``). Parts, each baked with seeds 0 and 1 (systematic error:
both bakes' noise and the reference's removed):

* ``loop``: light → scalp → fibre → atlas texel. The fibres' direct light is off (the
  bake's ``chiang_direct`` is replaced by a no-op for the run), so an atlas texel's
  second bounce is the scalp's light that the hair sends back to it; the reference
  tallies the depth-2 mesh vertices.
* ``loop_strands``: the first half of that loop, light → scalp → strand texel: the strand
  texels' mean exitance at one bounce with the fibres' direct light off, against the
  reference's depth-1 mesh vertices from the strand texels.
* ``fibres``: light → fibre → atlas texel and light → fibre → fibre → atlas texel. The
  mesh's direct light is off (``direct_radiance`` returns zeros, and the fibre gather's
  near field on the mesh is off with it); the reference tallies depth-1 and depth-2
  fibre vertices.
* ``fibres_all``: the same to every bounce (64): all the fibres' direct light that
  reaches an atlas texel, by any path (through the scalp too); with ``fibres`` it gives
  the third bounce onward.

The near fibre hits of the atlas (``hair.chiang.near_fibres``) are off by default here
(``--near-fibres 0``): their rays fold a second bounce into the first, which would mix
the parts. The switched-off sources are patched into the bake's module for the run and
restored after it; the library has no such option, because a bake never wants it.

Printed and written to benchmarks/results/hair_scalp_paths.json.

Usage: python benchmarks/hair_scalp_paths.py [--strands 10000] [--parts loop fibres fibres_all]
       [--hairs dark] [--rays 128] [--atlas-rays 64] [--paths 2048] [--texels 2000]
       [--near-fibres 0]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import prtcore.transport.hair_mesh_chiang as hair_mesh_chiang  # noqa: E402
from benchmarks.hair_mesh_chiang_accuracy import (  # noqa: E402
    HAIRS,
    LIGHTS,
    _bake,
    _per_light,
    head_setup,
)
from prtcore.core.spec import TransportSpec  # noqa: E402
from prtcore.reference.fibres import noise_corrected_error  # noqa: E402
from prtcore.reference.hair_mesh import chiang_hair_mesh_reference  # noqa: E402
from prtcore.transport.fibre_chiang import EXITANCE_TERMS, chiang_fibre  # noqa: E402

#: part -> (source switched off, bounces baked, receivers "mesh" | "hair", the
#: reference's tally, the fibre gather's near field on the mesh: None the spec's, 0 off)
PARTS = {
    "loop": ("fibres", 2, "mesh", frozenset({(2, "mesh")}), None),
    "loop_strands": ("fibres", 1, "hair", frozenset({(1, "mesh")}), None),
    "fibres": ("mesh", 2, "mesh", frozenset({(1, "fibre"), (2, "fibre")}), 0.0),
    "fibres_all": ("mesh", 64, "mesh", frozenset((d, "fibre") for d in range(1, 65)), 0.0),
}


@contextlib.contextmanager
def source_off(source: str):
    """The bake's direct light of the fibres or of the mesh switched off for the block."""
    name = "chiang_direct" if source == "fibres" else "direct_radiance"
    kept = getattr(hair_mesh_chiang, name)

    def no_fibre_light(*args, **kwargs) -> None:  # the views stay zero
        return None

    def no_mesh_light(scene, tracer, lights, position, *args) -> np.ndarray:
        return np.zeros((len(position), len(lights), 3), np.float32)
    setattr(hair_mesh_chiang, name, no_fibre_light if source == "fibres" else no_mesh_light)
    try:
        yield
    finally:
        setattr(hair_mesh_chiang, name, kept)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--strands", type=int, default=10_000)
    ap.add_argument("--texels-per-strand", type=int, default=10)
    ap.add_argument("--parts", nargs="+", default=["loop", "loop_strands", "fibres"],
                    choices=list(PARTS))
    ap.add_argument("--hairs", nargs="+", default=["dark"], choices=list(HAIRS))
    ap.add_argument("--rays", type=int, default=128, help="fibre gather rays M_h")
    ap.add_argument("--atlas-rays", type=int, default=64)
    ap.add_argument("--samples", type=int, default=4, help="direct samples J")
    ap.add_argument("--paths", type=int, default=2048)
    ap.add_argument("--texels", type=int, default=2000)
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--exitance", default="second_order", choices=list(EXITANCE_TERMS))
    ap.add_argument("--near-fibres", type=float, default=0.0)
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/hair_scalp_paths.json"))
    args = ap.parse_args(argv)
    scene, texels, space, tracer, fibres, points, rows, n_m = head_setup(
        args.strands, args.texels_per_strand, args.resolution, args.texels)
    setup = (scene, texels, space, fibres, points, tracer)
    out: dict = {"args": vars(args), "results": {}}
    for hair in args.hairs:
        fibre = chiang_fibre(HAIRS[hair], space)
        for part in args.parts:
            source, bounces, receivers, tally, hair_near = PARTS[part]
            sl = slice(0, n_m) if receivers == "mesh" else slice(n_m, None)
            t0 = time.perf_counter()
            with source_off(source):
                runs = [_bake({}, setup, fibre, TransportSpec(
                    gather_rays=args.atlas_rays, direct_samples=args.samples, seed=seed,
                    max_bounces=bounces), args.exitance, rows, 0, args.rays, None,
                    hair_near, args.near_fibres)[0][sl] for seed in (0, 1)]
            t1 = time.perf_counter()
            a, b = chiang_hair_mesh_reference(
                scene, texels, space, tracer, fibres, LIGHTS, rows[sl], args.paths, 101,
                fibre.params, fibre.sigma_points, max_depth=bounces, tally=tally)
            e = noise_corrected_error(runs[0], a, b)
            s = noise_corrected_error((runs[0], runs[1]), a, b)
            per, text = _per_light((runs[0], runs[1]), a, b)
            fast, ref = (runs[0] + runs[1]) / 2, (a + b) / 2
            res = {"rrmse": e["rrmse"], "bias": e["bias"], "bias_se": e["bias_se"],
                   "systematic": s["rrmse"], "per_light": per,
                   "fast_mean": fast.mean(axis=(0, 2)).tolist(),
                   "reference_mean": ref.mean(axis=(0, 2)).tolist(),
                   "fast_s": t1 - t0, "reference_s": time.perf_counter() - t1}
            out["results"][f"{hair}/{part}"] = res
            print(f"{hair:5s} {part:13s} {receivers}: rRMSE {e['rrmse']:.3f}  bias "
                  f"{e['bias']:+.3f} ± {e['bias_se']:.3f}  systematic {s['rrmse']:.3f}  "
                  + text + "  mean fast / reference " + ", ".join(
                      f"{x:.2e} / {y:.2e}" for x, y in zip(res["fast_mean"],
                                                           res["reference_mean"],
                                                           strict=True)), flush=True)
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2, default=float))
    print(f"wrote {path}")
    return out


if __name__ == "__main__":
    main()
