"""Benchmark: prtcore's light in hair against Mitsuba 3's round fibres, per tube proxy.

The tangle (prtcore.scenes.hair.tangle, 1000 strands, one colour (0.8, 0.6, 0.4)) under
its sun and point light (tangle_lights). Mitsuba 3 (prtcore.reference.mitsuba_fibres:
round ``linearcurve`` fibres, ``diffuse`` BSDF, its ``path`` integrator) estimates the
indirect light of ``--texels`` random strand texels with ``--mitsuba-rays`` rays each, in
two independent halves. Against it, noise of both sides removed
(prtcore.reference.fibres.noise_corrected_error), for every tube proxy of ``--sides``
(prtcore.core.fibres.fibre_tubes: an N-sided prism whose mean projected width is the
fibre's diameter, rays leaving from its circumradius):

* ``pathtracer``: prtcore's fibre path tracer through those tubes (``--paths`` per texel);
* ``harmonic``: the fast path a bake uses by default (direct light's first azimuthal
  harmonic in the first bounce; ``--samples`` direct samples J, ``--rays`` gather rays M);
* ``all_bounces``: the fast path with ``hair.harmonics = "all_bounces"``;
* ``harmonic_denoised``, ``all_bounces_denoised``: those after the bake's denoising of the
  strand texels (prtcore.transport.strand_denoise, ``--neighbours`` k, by default what a
  bake ships: a local linear fit); ``harmonic_averaged``: the plain kernel average of the
  same k neighbours instead (the filter before the local fit).

``--scene hairball``: the bake's 10k hairball under ``hairball_lights`` instead of the
tangle (``--rays 64 --samples 4 --texels-per-strand 10``: the bake's defaults).

``--scene head``: the 10k curly head of hair (``head_hair(10000, "curly", seed=0)``, one
colour) on the head mesh (``write_head``, its 64² unwrapped atlas), under ``head_lights``;
Mitsuba's scene holds the head too (:func:`mitsuba_fibre_indirect`'s ``scene=``). Rows:
``pathtracer`` (prtcore.reference.hair_mesh, ``--paths``), and with ``--fast`` the hair +
mesh bake's transport at its defaults (``hair.harmonics = "mesh_bounces"``, the facing
direct light, ``--rays`` M, ``--samples`` J of the mesh) as traced (``mesh_bounces``) and
denoised as a bake ships it (``mesh_bounces_denoised``). ``--atlas-texels N``: N of the
head's atlas texels too (:func:`mitsuba_mesh_indirect`), the fast path's as traced and
through the bake's atlas filter (``fit.denoise`` 1.5 texels).

The path tracer's row isolates what the tubes cost: both sides trace the same diffuse-fibre
model, so the difference is the geometry (prism vs round, and where rays leave a fibre).
Prints a table and writes benchmarks/results/hair_mitsuba_<texels per strand>.json.

Usage: python benchmarks/hair_mitsuba.py [--scene tangle|hairball|head] [--texels 600]
       [--mitsuba-rays 2048] [--texels-per-strand 12] [--sides 3,6] [--paths 2048]
       [--rays 256] [--samples 16] [--fast]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from prtcore.receivers.strands import build_strand_space  # noqa: E402
from prtcore.reference.fibres import fibre_reference, noise_corrected_error  # noqa: E402
from prtcore.reference.mitsuba_fibres import mitsuba_fibre_indirect  # noqa: E402
from prtcore.scenes.hair import hairball, hairball_lights, tangle, tangle_lights  # noqa: E402
from prtcore.transport.fibre import (  # noqa: E402
    fibre_direct,
    fibre_gather,
    hair_tracer,
    harmonic_first_bounce,
)
from prtcore.transport.solve import solve_indirect  # noqa: E402
from prtcore.transport.strand_denoise import (  # noqa: E402
    DEFAULT_NEIGHBOURS,
    denoise_irradiance,
    neighbour_kernel,
)


def fast_path(space, tracer, mesh, lights, rays: int, samples: int,
              neighbours: int = DEFAULT_NEIGHBOURS, direct: str = "facing") -> dict:
    """name → (T, K, 3) the fast path's indirect lightmaps, both harmonic variants;
    ``direct`` the direct light's estimator (``hair.direct``) with ``samples``."""
    direct = fibre_direct(space, tracer, lights, samples, seed=1, estimator=direct)
    term = fibre_gather(space, tracer, mesh, 0, rays, seed=2, all_bounces=True)
    harm, *_ = solve_indirect(term.matrix, space.albedo, direct.mean, 64, 1e-4,
                              first_bounce=harmonic_first_bounce(term, direct))
    every, *_ = solve_indirect(
        term.block, np.tile(space.albedo, (3, 1)),
        np.concatenate([direct.mean, direct.harmonics[0], direct.harmonics[1]]), 64, 1e-4,
        method="neumann")
    every = np.maximum(every[:space.count], 0)
    kernel = neighbour_kernel(space.position, neighbours)
    average = neighbour_kernel(space.position, neighbours, local_linear=False)
    return {"harmonic": harm, "all_bounces": every,
            "harmonic_averaged": denoise_irradiance(average, harm.copy(), space.albedo),
            "harmonic_denoised": denoise_irradiance(kernel, harm.copy(), space.albedo),
            "all_bounces_denoised": denoise_irradiance(kernel, every.copy(), space.albedo)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", choices=("tangle", "hairball", "head"), default="tangle")
    ap.add_argument("--texels", type=int, default=600)
    ap.add_argument("--atlas-texels", type=int, default=0,
                    help="--scene head: also this many of the head's atlas texels")
    ap.add_argument("--mitsuba-rays", type=int, default=2048)
    ap.add_argument("--texels-per-strand", type=int, default=12)
    ap.add_argument("--sides", type=lambda s: [int(x) for x in s.split(",")],
                    default=[3, 6])
    ap.add_argument("--paths", type=int, default=2048)
    ap.add_argument("--rays", type=int, default=256)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--fast", action="store_true", help="also the fast path's rows")
    ap.add_argument("--direct", choices=("facing", "sampled"), default="facing",
                    help="the fast path's direct-light estimator (hair.direct); --samples "
                         "its arc samples (facing, the bake's default 2) or points (sampled)")
    ap.add_argument("--neighbours", type=int, default=DEFAULT_NEIGHBOURS,
                    help="k of the denoised rows")
    args = ap.parse_args()
    if args.scene == "head":
        return head(args)
    hair, lights = ((hairball(10_000), hairball_lights()) if args.scene == "hairball"
                    else (tangle(1000), tangle_lights()))
    hair = dataclasses.replace(hair, color=np.tile([0.8, 0.6, 0.4], (hair.point_count, 1)))
    space = build_strand_space(hair, args.texels_per_strand)
    sel = np.random.default_rng(0).choice(space.count, args.texels, replace=False)
    t0 = time.perf_counter()
    mit = mitsuba_fibre_indirect(space, lights, sel, args.mitsuba_rays, seed=9)
    print(f"Mitsuba: {args.texels} texels × {args.mitsuba_rays} rays in "
          f"{time.perf_counter() - t0:.1f} s ({space.count} strand texels, "
          f"{args.texels_per_strand} per strand)")
    rows = []
    for sides in args.sides:
        tracer, mesh = hair_tracer(space, sides=sides)
        t0 = time.perf_counter()
        found = {"pathtracer": fibre_reference(space, tracer, mesh, 0, lights, sel,
                                               args.paths, seed=7)}
        if args.fast:
            found.update({k: v[sel].astype(np.float64) for k, v in
                          fast_path(space, tracer, mesh, lights, args.rays,
                                    args.samples, args.neighbours,
                                    args.direct).items()})
        seconds = time.perf_counter() - t0
        for name, est in found.items():
            e = noise_corrected_error(est, *mit)
            rows.append({"sides": sides, "estimate": name, **e})
            print(f"sides {sides:2}  {name:20} against Mitsuba: rRMSE {100 * e['rrmse']:5.2f} %"
                  f"  bias {100 * e['bias']:+5.2f} ± {100 * e['bias_se']:.2f} %")
        print(f"  ({seconds:.1f} s)")
    out = ROOT / "benchmarks" / "results" / (
        f"hair_mitsuba_{args.texels_per_strand}.json" if args.scene == "tangle"
        else f"hair_mitsuba_{args.scene}_{args.texels_per_strand}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"args": vars(args), "rows": rows,
                               "load": os.getloadavg()[0]}, indent=1))
    print(f"wrote {out} (load {os.getloadavg()[0]:.1f})")


def head(args) -> None:
    """``--scene head``: the hair + mesh transport's strand texels against Mitsuba with
    the head in its scene."""
    import tempfile

    from prtcore.core.progress import StageTimer
    from prtcore.core.spec import TransportSpec, parse_spec
    from prtcore.hairbake import atlas_radius, denoise_atlas
    from prtcore.intake.hair import hair_scene
    from prtcore.intake.points import place_measurement_points
    from prtcore.pipeline import run_intake
    from prtcore.reference.hair_mesh import hair_mesh_reference
    from prtcore.reference.mitsuba_fibres import mitsuba_mesh_indirect
    from prtcore.scenes.hair import head_hair, head_lights, write_head
    from prtcore.transport.hair_mesh import bake_hair_mesh_dataset
    from prtcore.transport.strand_denoise import denoise_dataset

    lights = head_lights()
    with tempfile.TemporaryDirectory() as tmp:
        intake = run_intake(write_head(Path(tmp) / "head.glb"), parse_spec(
            {"atlas": {"resolution": 64}, "measurement_points": {"count": 32}}), quiet=True)
    scene, texels = intake.scene, intake.texels
    hair = head_hair(10_000, "curly", seed=0)
    hair = dataclasses.replace(hair, color=np.tile([0.8, 0.6, 0.4], (hair.point_count, 1)))
    space = build_strand_space(hair, args.texels_per_strand)
    sel = np.sort(np.random.default_rng(0).choice(space.count, args.texels, replace=False))
    t0 = time.perf_counter()
    mit = mitsuba_fibre_indirect(space, lights, sel, args.mitsuba_rays, seed=9, scene=scene)
    print(f"Mitsuba: {args.texels} strand texels × {args.mitsuba_rays} rays in "
          f"{time.perf_counter() - t0:.1f} s ({space.count} strand texels, "
          f"{texels.count} atlas texels)")
    t_m = texels.count
    mesh_rows = np.sort(np.random.default_rng(1).choice(
        t_m, min(args.atlas_texels, t_m), replace=False))
    if len(mesh_rows):
        t0 = time.perf_counter()
        mit_m = mitsuba_mesh_indirect(space, scene, texels, lights, mesh_rows,
                                      args.mitsuba_rays, seed=10)
        print(f"Mitsuba: {len(mesh_rows)} atlas texels × {args.mitsuba_rays} rays in "
              f"{time.perf_counter() - t0:.1f} s")
    tracer, fibres = hair_tracer(space, scene)
    t0 = time.perf_counter()
    nm = len(mesh_rows)
    pa, pb = hair_mesh_reference(scene, texels, space, tracer, fibres, lights,
                                 np.concatenate([mesh_rows, t_m + sel]), args.paths, seed=7)
    found = {"pathtracer": (pa[nm:], pb[nm:])}
    found_m = {"pathtracer": (pa[:nm], pb[:nm])}
    print(f"  path tracer {time.perf_counter() - t0:.1f} s")
    if args.fast:
        points = place_measurement_points(hair_scene(hair), parse_spec(
            {"measurement_points": {"count": 16, "placement": "hull"}}).measurement_points)
        spec = TransportSpec(gather_rays=args.rays, direct_samples=args.samples, seed=0)
        data = bake_hair_mesh_dataset(scene, texels, space, fibres, points, tracer, lights,
                                      (), spec=spec, harmonics="mesh_bounces",
                                      direct_estimator=args.direct)
        found["mesh_bounces"] = data.indirect[t_m + sel].astype(np.float64)
        found_m["mesh_bounces"] = data.indirect[mesh_rows].astype(np.float64)
        data = denoise_atlas(data, texels, atlas_radius(parse_spec({}), with_mesh=True),
                             StageTimer(quiet=True))  # as a bake does, in place
        found_m["mesh_bounces_filtered"] = data.indirect[mesh_rows].astype(np.float64)
        den = denoise_dataset(data, space, args.neighbours, first_row=t_m)
        found["mesh_bounces_denoised"] = den.indirect[t_m + sel].astype(np.float64)
    rows = []
    for kind, table, ref in (("strand", found, mit), ("atlas", found_m,
                                                      mit_m if nm else None)):
        if ref is None:
            continue
        for name, est in table.items():
            e = noise_corrected_error(est, *ref)
            rows.append({"receiver": kind, "estimate": name, **e})
            print(f"{kind:6} {name:24} against Mitsuba: rRMSE {100 * e['rrmse']:5.2f} %  "
                  f"bias {100 * e['bias']:+5.2f} ± {100 * e['bias_se']:.2f} %")
    out = ROOT / "benchmarks" / "results" / f"hair_mitsuba_head_{args.texels_per_strand}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"args": vars(args), "rows": rows,
                               "load": os.getloadavg()[0]}, indent=1))
    print(f"wrote {out} (load {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()
