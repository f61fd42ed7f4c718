"""Benchmark: how bright a whole strand texel's direct light reads where it is seen.

The first bounce of the hair's light reads, at every fibre a gather ray hits, the direct
light of the texel hit: its mean over the texel's arc and azimuth plus its first
harmonic toward the ray. Here the same rays read it instead at the point hit (the facing
estimator at that arc position, one shadow ray per light: an unbiased estimate of the
light there) and from pieces of the texel (``hair.arc_subdivision``: the texel cut into S
equal arc intervals, each with its own mean and harmonics, from 4 samples a piece).
Printed: Σ read / Σ at the hit over every ray that meets a fibre, for the fibre-to-fibre
rays (by the receiving texel's place along its strand) and for rays from the atlas texels
(the scalp) — 1.00 is no bias. On the 10k curly head the whole texel reads 2–4 % bright
from other fibres and 5–15 % from the scalp: the rays meet the deep part of a texel whose
other end is lit (docs/hair.md, "Transporting each texel in pieces").

Printed and written to benchmarks/results/hair_texel_reads.json.

Usage: python benchmarks/hair_texel_reads.py [--strands 10000] [--style curly]
       [--texels-per-strand 10] [--rays 16] [--scalp-rays 64] [--pieces 2,4]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import types
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
if str(ROOT / "benchmarks") not in sys.path:
    sys.path.insert(0, str(ROOT / "benchmarks"))

from hair_mesh_accuracy import LIGHTS, head_scene  # noqa: E402

from prtcore.core.fibres import transported_frames  # noqa: E402
from prtcore.core.geometry import directions_around  # noqa: E402
from prtcore.receivers.strands import (  # noqa: E402
    axis_frame,
    build_strand_space,
    interp_points,
)
from prtcore.scenes.hair import head_hair  # noqa: E402
from prtcore.transport.fibre import fibre_hits, hair_tracer  # noqa: E402
from prtcore.transport.fibre_facing import (  # noqa: E402
    FacingSamples,
    facing_direct,
    facing_samples,
)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--strands", type=int, default=10000)
    ap.add_argument("--style", default="curly")
    ap.add_argument("--texels-per-strand", type=int, default=10)
    ap.add_argument("--rays", type=int, default=16, help="per strand texel")
    ap.add_argument("--scalp-rays", type=int, default=64, help="per atlas texel")
    ap.add_argument("--pieces", default="2,4")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/hair_texel_reads.json"))
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        scene, texels = head_scene(Path(tmp), 64)
    hair = head_hair(a.strands, a.style, seed=a.seed)
    tps = a.texels_per_strand
    space = build_strand_space(hair, tps)
    tracer, fibres = hair_tracer(space, scene)
    faces, t = scene.triangle_count, space.count
    frame_u = transported_frames(hair)[1]
    rng = np.random.default_rng(a.seed + 3)
    # the texels' own direct light, with 16 arc samples (little noise of its own)
    mean_t, harm_t = facing_direct(space, tracer, LIGHTS, facing_samples(space, 16, 5), 1,
                                   progress=False)
    lo, hi = space.arc[:, 0], space.arc[:, 1]

    def at(texel: np.ndarray, arc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The facing estimator's mean and harmonics at arc positions ``arc`` (metres) of
        ``texel``'s strand, one sample each."""
        strand = space.strand[texel]
        axis, tangent, u = axis_frame(hair, strand, arc, frame_u)
        off = interp_points(hair, space.ray_offset[:, None], strand, arc)[:, 0]
        n = len(texel)
        drawn = FacingSamples(1, np.arange(n), axis, tangent, u, off,
                              2 * rng.random(n) - 1)
        fake = types.SimpleNamespace(count=n, albedo=space.albedo[texel])
        return facing_direct(fake, tracer, LIGHTS, drawn, 1, progress=False)

    pieces = [int(x) for x in a.pieces.split(",") if x]
    per_piece = {}
    for s in pieces:  # each piece's mean and harmonics from 4 samples
        texel = np.repeat(np.arange(t), 4 * s)
        piece = np.tile(np.repeat(np.arange(s), 4), t)
        arc = lo[texel] + (piece + rng.random(len(texel))) / s * (hi[texel] - lo[texel])
        m, h = at(texel, arc)
        per_piece[s] = (m.reshape(t, s, 4, *m.shape[1:]).mean(axis=2),
                        h.reshape(2, t, s, 4, *m.shape[1:]).mean(axis=3))

    def reads(hit) -> dict:
        """Σ over the hits of each read / Σ of the read at the point hit, per light."""
        c, s_ = hit.cs[:, 0][:, None, None], hit.cs[:, 1][:, None, None]
        arc = hit.arc * hair.strand_length[space.strand[hit.texel]]
        m, h = at(hit.texel, arc)
        point = m + h[0] * c + h[1] * s_
        out = {"whole texel": mean_t[hit.texel] + harm_t[0][hit.texel] * c
               + harm_t[1][hit.texel] * s_}
        where = np.clip((arc - lo[hit.texel]) / np.maximum(hi[hit.texel] - lo[hit.texel],
                                                            1e-12), 0, 1 - 1e-9)
        for s in pieces:
            pm, ph = per_piece[s]
            k = (where * s).astype(np.int64)
            out[f"{s} pieces"] = pm[hit.texel, k] + ph[0][hit.texel, k] * c \
                + ph[1][hit.texel, k] * s_
        return {name: (v, point) for name, v in out.items()}

    def ratio(v: np.ndarray, point: np.ndarray, sel=slice(None)) -> list[float]:
        return [float(v[sel, k].sum() / point[sel, k].sum()) for k in range(v.shape[1])]

    result = {"strands": a.strands, "style": a.style, "texels_per_strand": tps,
              "rays": a.rays, "scalp_rays": a.scalp_rays, "fibre": {}, "scalp": {}}
    # fibre to fibre: a.rays cosine rays from every strand texel's surface
    arc0, phi = (x.reshape(-1) for x in space.surface_sample_params(a.rays, a.seed + 9))
    ray = np.arange(t * a.rays)
    origin, normal, _ = space.surface_points(ray // a.rays, arc0, phi, frame_u)
    d = directions_around(normal, np.sqrt(rng.random(len(ray))),
                          2 * np.pi * rng.random(len(ray)))
    hits = tracer.intersect(origin, d)
    fib = hits.triangle >= faces
    hit = fibre_hits(space, fibres, hits.triangle[fib] - faces, hits.barycentric[fib],
                     d[fib], rng, frame_u)
    place = (ray[fib] // a.rays) % tps
    for name, (v, point) in reads(hit).items():
        result["fibre"][name] = {"all": ratio(v, point), "by_place": {
            int(q): ratio(v, point, place == q) for q in range(tps)}}
    # the scalp: a.scalp_rays cosine rays from every atlas texel's sample
    n = texels.count * a.scalp_rays
    o = np.repeat(texels.position, a.scalp_rays, axis=0) \
        + 1e-5 * np.repeat(texels.normal, a.scalp_rays, axis=0)
    d = directions_around(np.repeat(texels.normal, a.scalp_rays, axis=0),
                          np.sqrt(rng.random(n)), 2 * np.pi * rng.random(n))
    hits = tracer.intersect(o, d)
    fib = hits.hit & (hits.triangle >= faces)
    hit = fibre_hits(space, fibres, hits.triangle[fib] - faces, hits.barycentric[fib],
                     d[fib], rng, frame_u)
    for name, (v, point) in reads(hit).items():
        result["scalp"][name] = {"all": ratio(v, point)}
    print(f"{a.strands} {a.style} strands × {tps} texels; reads / the light at the point "
          f"hit, per light (sun, point light)")
    for kind in ("fibre", "scalp"):
        for name, r in result[kind].items():
            line = f"{kind:6s} {name:12s} " + "  ".join(f"{x:.3f}" for x in r["all"])
            if kind == "fibre":
                line += "   root texel " + " ".join(f"{x:.3f}" for x in r["by_place"][0])
            print(line)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(result, indent=1))
    return result


if __name__ == "__main__":
    main()
