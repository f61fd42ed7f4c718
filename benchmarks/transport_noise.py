"""Benchmark: the lightmap filter's expected error (prtcore/transport/noise.py) against the
path tracer (issue 13).

For each scene (a spec naming only its light family, at ``--resolution``): the fast
transport of ``--lights`` held-out lights twice, with the bake's seed and with
:func:`~prtcore.transport.noise.second_seed`; the estimate R of every candidate radius
(:func:`~prtcore.transport.noise.choose_radius`); and the true error of the filtered bake
lightmaps against the path tracer at ``--spp`` in two independent halves
(:func:`prtcore.validate.two_halves`), the reference's noise removed. Prints, per radius,
the estimate beside the truth, and which radius each picks; writes
benchmarks/results/transport_noise.json.

    .venv/bin/python benchmarks/transport_noise.py [--scenes exterior,CesiumMilkTruck]
        [--resolution 256] [--lights 3] [--spp 256]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from default_bakes import scenes, write_rows  # noqa: E402

from prtcore.core.spec import parse_spec  # noqa: E402
from prtcore.emitters.families import sample_configurations  # noqa: E402
from prtcore.pipeline import run_intake  # noqa: E402
from prtcore.receivers.smoothing import smooth_texels, smoothing_operators  # noqa: E402
from prtcore.reference.pathtracer import reference_lightmaps  # noqa: E402
from prtcore.transport.dataset import light_configurations, open_transport  # noqa: E402
from prtcore.transport.noise import DENOISE_RADII, choose_radius, second_seed  # noqa: E402
from prtcore.validate import two_halves  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="exterior,CesiumMilkTruck")
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--lights", type=int, default=3)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" /
                                        "transport_noise.json"))
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="prt-noise-"))
    todo = scenes(tmp)
    rows = []
    for name in args.scenes.split(","):
        asset, families = todo[name]
        spec = parse_spec({"lights": {"families": families, "count": 4,
                                      "holdout": args.lights},
                           "atlas": {"resolution": args.resolution},
                           "measurement_points": {"count": 64}})
        t0 = time.perf_counter()
        intake = run_intake(asset, spec, quiet=True)
        scene, texels = intake.scene, intake.texels
        _, hold = sample_configurations(spec.lights, scene.center, scene.radius, scene.lights)
        f, g = (light_configurations(open_transport(
            scene, texels, intake.points, dataclasses.replace(spec.transport, seed=s)),
            hold, 0).indirect.astype(np.float64)
            for s in (spec.transport.seed, second_seed(spec.transport.seed)))
        chosen, estimate = choose_radius(texels, f, g)
        configs = [[lt] for lt in hold]
        ref, err = two_halves(lambda n, sd, scene=scene, texels=texels, configs=configs:
                              reference_lightmaps(scene, texels, configs, n, seed=sd),
                              args.spp, 1)
        ref, err = np.moveaxis(ref, 0, 1), np.moveaxis(err, 0, 1)  # (T, H, 3)
        norm2, noise2 = float((ref ** 2).sum()), float((err ** 2).sum())
        ops = dict(zip(DENOISE_RADII[1:], smoothing_operators(texels, DENOISE_RADII[1:]),
                       strict=True))
        truth = []
        for r in DENOISE_RADII:
            wf = f if r == 0 else smooth_texels(texels, f, operator=ops[r])
            truth.append(float(np.sqrt(max(float(((wf - ref) ** 2).sum()) - noise2, 0.0)
                                       / norm2)))
        best = DENOISE_RADII[int(np.argmin(truth))]
        row = {"scene": name, "texels": texels.count, "lights": len(hold), "spp": args.spp,
               "reference_noise": float(np.sqrt(noise2 / norm2)), "radii": DENOISE_RADII,
               "estimate": estimate, "truth": truth, "chosen": chosen, "best": best,
               "seconds": time.perf_counter() - t0}
        rows.append(row)
        print(f"{name}: {texels.count} texels, {len(hold)} lights, reference noise "
              f"{100 * row['reference_noise']:.1f} % ({args.spp} spp, removed)")
        for r, e, t in zip(DENOISE_RADII, estimate, truth, strict=True):
            print(f"  radius {r:<4g} estimate {100 * e:5.1f} %   against the path tracer "
                  f"{100 * t:5.1f} %")
        print(f"  chosen {chosen:g}, best against the path tracer {best:g} "
              f"({row['seconds']:.0f} s)", flush=True)
    write_rows(rows, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
