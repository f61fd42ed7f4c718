"""Benchmark (diagnostic): where the Chiang strand texels' bias on the test head comes
from. The first bounce of the hair + mesh transport, as baked and with the light that one
fibre sends to another read from the BCSDF itself.

This is the test head of benchmarks/hair_mesh_chiang_accuracy.py (500 curly strands × 8
texels on the 10 cm icosphere, a sun and a point light). Its strand texels are biased
against the exact path tracer: −6 % on light hair at one bounce, while against the
reference that makes the fast path's exitance assumption (the "twin") they agree within
the noise (docs/hair.md, "The Chiang fibre with a mesh"). The first bounce is light that
reaches a strand texel B from the scalp (read exactly: the scalp is Lambertian) or from
another fibre A that the light lit directly. A gather ray from B toward d that hits A reads
A's exitance toward −d as transport models it, ``exitance_reads`` of the direct light's
coefficients: with isotropic exitance, A's direction average L̄_d(A).

Here every such ray also reads A's direct light exactly, each light on its own:
``L_o(A, −d) = L̄_d(A) · π² f̄(ωl, −d) / (Ā(t·ωl) cos θl)``. f̄ is the BCSDF
(:func:`prtcore.core.bcsdf.scattering`) averaged over the offset h (Gauss–Legendre), ωl
the light's direction at A's middle, and Ā the bake's directional albedo table. The
denominator is ``(1/π²) ∫ f̄ cos θo dωo``, so L̄ is unchanged. This needs rays × K BCSDF
evaluations; a bake has ≈ 10⁹ of them. The ``exact_hh`` rows are the bake's first bounce
with that difference added. Rows, strand texels against the exact first-bounce reference
(``exact``) and against the twin (``twin``: the path tracer with the exitance's own
model at every fibre hit), noise removed: ``{exitance}`` as baked and
``{exitance}+exact_hh``. Also printed: the share of the strand texels' first bounce that
comes from other fibres.

Printed and written to benchmarks/results/hair_mesh_chiang_first_bounce.json.

Usage: python benchmarks/hair_mesh_chiang_first_bounce.py [--rays 256] [--paths 4096]
       [--texels 2000] [--resolution 32] [--hairs light dark] [--exitance isotropic linear]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.hair_mesh_accuracy import LIGHTS  # noqa: E402
from benchmarks.hair_mesh_chiang_accuracy import HAIRS, head_setup  # noqa: E402
from prtcore.core.bcsdf import scattering  # noqa: E402
from prtcore.core.progress import StageTimer  # noqa: E402
from prtcore.core.spec import TransportSpec  # noqa: E402
from prtcore.reference.fibres import noise_corrected_error  # noqa: E402
from prtcore.reference.hair_mesh import chiang_hair_mesh_reference  # noqa: E402
from prtcore.transport.fibre_chiang import (  # noqa: E402
    EXITANCE_TERMS,
    chiang_direct,
    chiang_fibre,
    chiang_gather,
    exitance_reads,
    ray_weights,
    texel_frames,
)
from prtcore.transport.gather import HitMapper  # noqa: E402
from prtcore.transport.hair_mesh_chiang import bake_chiang_hair_mesh_dataset  # noqa: E402

#: Gauss–Legendre nodes over the offset h of the BCSDF's average
H_NODES = 8


def to_light(light, position: np.ndarray) -> np.ndarray:
    """(n, 3) unit directions toward a punctual ``light`` from ``position`` (n, 3)."""
    if light.type == "directional":
        d = -np.asarray(light.direction, np.float64)
        return np.tile(d / np.linalg.norm(d), (len(position), 1))
    d = np.asarray(light.position, np.float64) - position
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def exact_over_model(space, fibre, direct, rays, m: int, exitance: str) -> np.ndarray:
    """(T, K, 3) float64: what the first bounce of every strand texel's direction average
    gains when each fibre-to-fibre ray ``rays`` (rows, cols, data) reads its fibre's direct
    light from the BCSDF instead of the ``exitance`` coefficients ``direct`` (F, T, K, 3)."""
    rows, cols, data = (np.asarray(a) for a in rays)
    rows, cols, data = rows.astype(np.int64), cols.astype(np.int64), data.astype(np.float64)
    d = data[:, :3]
    u, v = texel_frames(space)
    tangent = np.cross(u, v)
    f = EXITANCE_TERMS[exitance]
    reads = np.stack(exitance_reads(d, (u[cols], v[cols]), f), axis=0)  # (F, n)
    weight = ray_weights(fibre, rows, data, "isotropic")[0]  # B's Ā(t·d) per channel
    hs, hw = np.polynomial.legendre.leggauss(H_NODES)
    out = np.zeros(direct.shape[1:])
    sigma = fibre.sigma_texels[cols]
    for k, light in enumerate(LIGHTS):
        wl_mid = to_light(light, space.position)
        sin_l = np.einsum("ij,ij->i", tangent, wl_mid)
        norm = fibre.albedo(sin_l, fibre.sigma_texels) * np.sqrt(
            np.maximum(1 - sin_l ** 2, 1e-12))[:, None] / np.pi ** 2  # (1/π²)∫ f̄ cos θo
        f_bar = np.zeros((len(rows), 3))
        for h, w in zip(hs, hw / 2, strict=True):
            f_bar += w * scattering(tangent[cols], -d, wl_mid[cols], np.full(len(rows), h),
                                    fibre.params, sigma)
        exact = direct[0, cols, k] * f_bar / np.maximum(norm[cols], 1e-30)
        model = np.einsum("fn,fnc->nc", reads, direct[:, cols, k])
        np.add.at(out[:, k], rows, weight * (exact - model) / m)
    return out


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--strands", type=int, default=500)
    ap.add_argument("--rays", type=int, default=256)
    ap.add_argument("--paths", type=int, default=4096)
    ap.add_argument("--texels", type=int, default=2000)
    ap.add_argument("--resolution", type=int, default=32,
                    help="the head's atlas (the first bounce's figures in docs/hair.md "
                         "are on 32²; a bake's is 512²)")
    ap.add_argument("--samples", type=int, default=8, help="direct samples J")
    ap.add_argument("--hairs", nargs="+", default=["light", "dark"], choices=list(HAIRS))
    ap.add_argument("--exitance", nargs="+", default=["isotropic", "linear"],
                    choices=["isotropic", "linear", "quadratic", "second_order"])
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/"
                                         "hair_mesh_chiang_first_bounce.json"))
    args = ap.parse_args(argv)
    scene, texels, space, tracer, fibres, points, rows, n_m = head_setup(
        args.strands, 8, args.resolution, args.texels)
    t_m = texels.count
    rows = rows[n_m:]  # the strand texels of hair_mesh_chiang_accuracy.py
    picked = rows - t_m
    out: dict = {"args": vars(args), "results": {}}
    for hair in args.hairs:
        fibre = chiang_fibre(HAIRS[hair], space)
        t0 = time.perf_counter()
        refs = {e: chiang_hair_mesh_reference(
            scene, texels, space, tracer, fibres, LIGHTS, rows, args.paths, 101 + i,
            fibre.params, fibre.sigma_points, max_depth=1, exitance=e)
            for i, e in enumerate(("exact", *args.exitance))}  # the exact one, the twins
        ref_s = time.perf_counter() - t0
        term = chiang_gather(space, tracer, fibres, scene.triangle_count, args.rays, 0, fibre,
                             mesh_texels=HitMapper(scene, texels, tracer), mesh_columns=t_m)
        print(f"{hair} hair: {len(term.rays[0])} of {space.count * args.rays} gather rays "
              f"from strand texels hit another fibre; reference {ref_s:.0f} s")
        for exitance in args.exitance:
            data = bake_chiang_hair_mesh_dataset(
                scene, texels, space, fibres, points, tracer, LIGHTS, (),
                TransportSpec(gather_rays=args.rays, direct_samples=args.samples, seed=0,
                              max_bounces=1), StageTimer(quiet=True), fibre,
                exitance=exitance)
            fast = data.indirect[rows].astype(np.float64)
            direct = chiang_direct(space, tracer, LIGHTS, max(4, args.samples), 1, fibre,
                                   exitance).astype(np.float64)  # the bake's direct light
            t1 = time.perf_counter()
            gain = exact_over_model(space, fibre, direct, term.rays, args.rays, exitance)
            exact_s = time.perf_counter() - t1
            model = np.zeros_like(gain)  # the fibre-to-fibre part as baked, for its share
            r, c = (np.asarray(a, np.int64) for a in term.rays[:2])
            w = ray_weights(fibre, r, np.asarray(term.rays[2], np.float64), "isotropic")[0]
            for k in range(len(LIGHTS)):
                np.add.at(model[:, k], r, w * direct[0, c, k] / args.rays)
            share = float(model[picked].sum() / fast.sum()) if exitance == "isotropic" \
                else None
            res = {"exact_hh_seconds": exact_s, "fibre_share": share}
            for name, x in ((exitance, fast), (f"{exitance}+exact_hh", fast + gain[picked])):
                for against, (a, b) in (("exact", refs["exact"]), ("twin", refs[exitance])):
                    e = noise_corrected_error(x, a, b)
                    res[f"{name} vs {against}"] = e
                    print(f"  {name:22s} vs {against:5s}: rRMSE {e['rrmse']:.3f}  bias "
                          f"{e['bias']:+.3f} ± {e['bias_se']:.3f}")
            if share is not None:
                print(f"  other fibres bring {share:.0%} of the strand texels' first bounce")
            out["results"][f"{hair}/{exitance}"] = res
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2, default=float))
    print(f"wrote {path}")
    return out


if __name__ == "__main__":
    main()
