"""The atlas's near field on the fibres: a hair + mesh bake with the Chiang fibre
(``hair.chiang.near_fibres``).

An atlas gather ray that meets a fibre reads that strand texel's exitance toward the ray
(:func:`prtcore.transport.hair_mesh_chiang.chiang_mesh_product`): the fibre's light
averaged over the texel's arc and truncated to the exitance's terms. The scalp sees the
fibres' nearest millimetres, not their texels' centimetres of arc. In the reference,
reading the texels' means for the scalp's own fibre hits made the dark 10k head's
point-light error, and keeping the hits within 5 mm at their own point took half of it
away (docs/hair.md, "What the dark scalp's error is not, and where it is").

So a gather ray that meets a fibre closer than ``near_fibres`` footprints of its texel
(:func:`~prtcore.transport.gather.near_field_reach`) is shaded at the point it meets:

* **The light the fibre gets from the mesh and from other fibres**
  (:func:`near_fibre_rays`):
  ``rays`` rays from the point, as the reference continues a path from a fibre vertex
  (:mod:`prtcore.reference.chiang`): ωi drawn by :func:`prtcore.core.bcsdf.
  sample_scattering` toward the gather ray (ωo = −d, an impact offset h uniform in
  [−1, 1], σ_a of the hair's points), each weighted by S/pdf per channel over the rays
  and over the texel's valid gather rays. One whose first hit is the front of the mesh
  reads that atlas texel; one that meets a fibre reads that strand texel's exitance
  toward it (:func:`~prtcore.transport.fibre_chiang.exitance_reads`). They are operator
  entries, so every bounce takes them.
* **Its direct light from punctual lights** (:func:`near_fibre_shaded`): the strand
  texels' direct exitance coefficients, computed at the point (its own tangent and
  frame, on the side facing the light), read toward the ray: the first bounce's
  correction. The hits on one arc piece of a strand texel (a 32nd of it,
  :func:`shadow_pieces`) share one shadow ray a light, from one of them drawn at random
  (:func:`piece_visibility`), and the weights are one compiled pass
  (:func:`prtcore.transport.fibre_chiang.shaded_reads`).
* **Its direct light from environment lights** (:func:`near_fibre_direct`): its strand
  texel's direct exitance toward the ray, the read it had before.

Beyond that reach, to ``shaded_fibres`` footprints, a hit is a **shaded hit**
(:func:`shaded_fibre_correction`): it stays its strand texel's read for every bounce,
and its first bounce swaps the texel's direct light from punctual lights for the light
shaded at the point, as the second bullet shades it. The scalp sees a fibre's nearest
part, deeper in the hair and more shadowed than its texel's mean, at every distance: on
the dark 10k head the shaded hits to 20 footprints took the scalp's bias from +2.2 to
+0.8 % (to every hit: the same), for 0.88 s a light (docs/hair.md, "The fibres' direct
light at the point the scalp sees"). They are off by default since the near hits reach
20 footprints: the fibre's light from the scalp, gathered at the point, is brighter there
than its texel's mean too, and the light scalp's bias went from −1.8 to −1.2 % (to −0.3 %
with every hit near, at 4.5 s a light; docs/hair.md, "The fibres' light from the scalp at
the point").

Measured on the 10k curly head with dark hair (docs/hair.md, "The scalp's reads of the
fibres near it"): 5 footprints take 0.13 of the atlas's rays; the dark scalp's error per
texel went from 15.0 % to 12.3 % (systematic 11.1 → 9.8 %, noise 10.1 → 7.5 %), its
bias from +1.5 to +2.1 %; with light hair from 9.4 to 7.4 % (bias −1.6 → −0.5 %). The
direct light at the point is most of that (the scalp's read of the fibres' direct
light is where its error is); the rays alone moved it to 14.9 %. With the shadow rays
shared by arc pieces (166 k rays a light for 1.1 M hits) the dark scalp reads 12.4 %,
the light one 7.7 % / −0.5 %, and the direct light at the point costs 0.36 s a light
(3.1 min at 528 lights, where a ray a hit in numpy took 23.8 min:
benchmarks/near_fibres_cost.py).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from prtcore.core.bcsdf import sample_scattering
from prtcore.core.fibres import FibreMesh, facing, fibre_at_hits, outside_offset
from prtcore.core.geometry import orthonormal_frame
from prtcore.core.progress import bar
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Light
from prtcore.emitters.base import emitter_for
from prtcore.emitters.punctual import irradiance, unshadowed_irradiance
from prtcore.receivers.strands import StrandSpace, arc_of_hit, texel_of_hit
from prtcore.transport.fibre_chiang import (
    EXITANCE_TERMS,
    ChiangFibre,
    exitance_reads,
    shaded_reads,
)

#: rays from each near fibre hit (its light from the mesh and the other fibres)
NEAR_FIBRE_RAYS = 2
#: near hits per chunk of :func:`near_fibre_rays` (its rays' float64 temporaries)
NEAR_FIBRE_CHUNK = 1 << 15
#: lights per block of :func:`near_fibre_direct` (bounds its (T_h, block, 3) copy)
NEAR_DIRECT_LIGHTS = 64
#: arc pieces a strand texel whose near hits share one shadow ray a light
#: (:func:`shadow_pieces`): on the dark 10k head 166 k pieces for 1.1 M hits, the scalp's
#: error as with a ray a hit (12.4 % against 12.3 %; 8 pieces: 48 k, 13.2 %, the shared
#: rays' noise; docs/hair.md)
NEAR_SHADOW_PIECES = 32
#: bytes each near ray keeps until the product is made (:class:`NearFibreRays`)
NEAR_RAY_BYTES = 48
#: shaded hits per chunk of :func:`shaded_fibre_correction`'s texel reads
SHADED_CHUNK = 1 << 19
#: bytes each shaded hit keeps until its correction is made (:class:`NearFibreHits`: row,
#: texel, triangle int64, barycentric, direction float32 × 3; the gather batches' masks)
SHADED_HIT_BYTES = 60


def near_hits_reach(near_fibres: float, gathered_fibres: float) -> float:
    """The reach (footprints) within which an atlas fibre hit is a near hit, its rays
    traced at the point met: ``near_fibres`` (direct light at the point too), or
    ``gathered_fibres`` beyond it (direct light read from the texel)."""
    return max(near_fibres, gathered_fibres)


def shaded_at_point(light: Light) -> bool:
    """Whether a near hit's direct light from ``light`` is shaded at the point met
    (:func:`near_fibre_shaded`: one direction, one shadow ray) rather than read from its
    texel (:func:`near_fibre_direct`): every light but an environment."""
    return light.type != "environment"


@dataclass(frozen=True)
class NearFibreHits:
    """The atlas gather's rays that first meet a fibre within reach, in gather order:
    ``row`` (n,) int64 the receiving atlas texel, ``texel`` (n,) int64 the strand texel
    met, ``triangle`` (n,) int64 the tube triangle (the fibre mesh's own index),
    ``barycentric`` (n, 3) float32 and ``direction`` (n, 3) float32 the gather ray's."""

    row: np.ndarray
    texel: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    direction: np.ndarray

    @property
    def count(self) -> int:
        return len(self.row)

    def subset(self, mask: np.ndarray | slice) -> NearFibreHits:
        """The hits ``mask`` ((n,) bool, or a slice) picks, in order."""
        return NearFibreHits(self.row[mask], self.texel[mask], self.triangle[mask],
                             self.barycentric[mask], self.direction[mask])


@dataclass(frozen=True)
class NearFibreRays:
    """:func:`near_fibre_rays`' rays that meet something: ``row`` (n,) int64 the atlas
    texel that receives, ``col`` (n,) int64 the texel read (an atlas texel in [0, T_m),
    or T_m + a strand texel: the rays that met a fibre), ``weight`` (n, 3) float32 per
    channel, ``direction`` (n, 3) float32 the ray's (a strand texel is read toward it).
    ``stats``: hits, rays, and what the rays met."""

    row: np.ndarray
    col: np.ndarray
    weight: np.ndarray
    direction: np.ndarray
    stats: dict


def near_fibre_rays(near: NearFibreHits, valid_rays: np.ndarray, space: StrandSpace,
                    fibres: FibreMesh, fibre: ChiangFibre, tracer: RayTracer,
                    mesh_faces: int, mesh_texels: Callable, t_m: int, seed: int,
                    rays: int = NEAR_FIBRE_RAYS) -> NearFibreRays:
    """The first bullet of the module docstring: ``rays`` rays from each of ``near``'s
    hits. valid_rays (T_m,): the atlas gather's valid rays per texel
    (:attr:`prtcore.transport.gather.Gather.valid_rays`); ``mesh_faces``: the scene
    triangles before the tubes in ``tracer``; ``mesh_texels``: a
    :class:`~prtcore.transport.gather.HitMapper` of the T_m atlas texels. Draws from
    ``seed`` chunk by chunk (the same hits and seed: the same rays)."""
    hair = space.hair
    off = outside_offset(hair, fibres.sides)
    parts: list[tuple] = []
    met = np.zeros(3, np.int64)  # mesh front, fibre, nothing (a miss or a back face)
    starts = range(0, near.count, NEAR_FIBRE_CHUNK)
    for c, a in enumerate(bar(starts, "near fibres", total=len(starts))):
        rng = np.random.default_rng([seed, 23, c])
        idx = np.repeat(np.arange(a, min(a + NEAR_FIBRE_CHUNK, near.count)), rays)
        tangent, centre, radius, sigma = fibre_at_hits(
            hair, fibres, off, fibre.sigma_points, near.triangle[idx],
            near.barycentric[idx].astype(np.float64))
        wo = -near.direction[idx].astype(np.float64)
        h = 2 * rng.random(len(idx)) - 1
        wi, w = sample_scattering(tangent, wo, h, fibre.params, rng, sigma)
        origin = centre + radius[:, None] * facing(tangent, wi)
        hits = tracer.intersect(origin, wi)
        row = near.row[idx]
        w *= (1.0 / (rays * np.maximum(valid_rays[row], 1)))[:, None]
        on_fibre = np.flatnonzero(hits.triangle >= mesh_faces)
        on_mesh = np.flatnonzero(hits.hit & (hits.triangle < mesh_faces) & hits.front)
        col = np.empty(len(idx), np.int64)
        col[on_mesh] = mesh_texels(hits.triangle, hits.barycentric, on_mesh,
                                   origin.astype(np.float32), wi.astype(np.float32), hits.t,
                                   index=on_mesh)
        col[on_fibre] = t_m + texel_of_hit(space, fibres, hits.triangle[on_fibre] - mesh_faces,
                                           hits.barycentric[on_fibre])
        keep = np.sort(np.concatenate([on_mesh, on_fibre]))
        met += (len(on_mesh), len(on_fibre), len(idx) - len(keep))
        parts.append((row[keep], col[keep], w[keep].astype(np.float32),
                      wi[keep].astype(np.float32)))
    if parts:
        row, col, weight, direction = (np.concatenate(p) for p in zip(*parts, strict=True))
    else:
        row, col = np.zeros(0, np.int64), np.zeros(0, np.int64)
        weight, direction = np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32)
    stats = {"hits": near.count, "rays": near.count * rays, "mesh": int(met[0]),
             "fibres": int(met[1]), "nothing": int(met[2])}
    return NearFibreRays(row, col, weight, direction, stats)


def near_fibre_direct(near: NearFibreHits, valid_rays: np.ndarray, direct: np.ndarray,
                      coefficient_rows: Callable[[int], slice], t_m: int, t_h: int,
                      terms: int, frames: tuple | None = None,
                      lights: Sequence[int] | None = None
                      ) -> tuple[np.ndarray, np.ndarray] | None:
    """The third bullet of the module docstring: each near hit's strand texel's direct
    exitance toward its gather ray, over the texel's valid rays, summed per receiving
    atlas texel: a first-bounce correction (rows (r,) int64 sorted unique, values
    (r, K, 3) float32; :func:`prtcore.transport.dataset.add_first_bounce`), or None
    without hits.

    direct (N, K, 3) float32: the stacked direct light of the product's layout
    (``coefficient_rows(a)``: coefficient a's rows, the strand texels' after the first
    T_m for a = 0, :meth:`~prtcore.core.sparse.RayBlockProduct.coefficient_rows`);
    ``terms`` F coefficients; ``frames``: the strand texels' (quadratic exitance); ``lights``: the
    light columns read (None: every one; the others are left 0)."""
    if not near.count:
        return None
    rows, slot = np.unique(near.row, return_inverse=True)
    frame = None if frames is None else (frames[0][near.texel], frames[1][near.texel])
    reads = exitance_reads(near.direction.astype(np.float64), frame, terms)
    scale = 1.0 / np.maximum(valid_rays[near.row], 1)
    out = np.zeros((len(rows), direct.shape[1], 3), np.float32)
    cols = np.arange(direct.shape[1]) if lights is None else np.asarray(lights, np.int64)
    for a in range(terms):
        span = coefficient_rows(a)
        base = span.start + (t_m if a == 0 else 0)
        d = sp.csr_matrix(((reads[a] * scale).astype(np.float32), (slot, near.texel)),
                          shape=(len(rows), t_h))
        for b in range(0, len(cols), NEAR_DIRECT_LIGHTS):
            block = cols[b:b + NEAR_DIRECT_LIGHTS]
            x = direct[base:base + t_h][:, block].reshape(t_h, -1)
            out[:, block] += (d @ x).reshape(len(rows), len(block), 3)
    return rows, out


@dataclass(frozen=True)
class ShadowPieces:
    """The arc pieces of strand texels that the near hits lie on (:func:`shadow_pieces`):
    ``hit`` (u,) int64 one near hit of each piece, drawn at random, whose shadow rays
    all of the piece's hits share; ``of_hit`` (n,) int64 the piece of each near hit."""

    hit: np.ndarray
    of_hit: np.ndarray

    @property
    def count(self) -> int:
        return len(self.hit)


def shadow_pieces(near: NearFibreHits, space: StrandSpace, fibres: FibreMesh, seed: int,
                  pieces: int = NEAR_SHADOW_PIECES) -> ShadowPieces:
    """Cut every strand into ``pieces`` equal arcs a texel, find those the near hits lie
    on, and draw one hit of each from ``seed``: the hits that share its shadow rays lie
    within an arc of it, and a drawn hit keeps their visibility's expectation (the
    piece's middle would not: the scalp sees a piece's nearest end, the more shadowed)."""
    hair = space.hair
    strand, arc = arc_of_hit(hair, fibres, near.triangle, near.barycentric)
    m = space.texels_per_strand * pieces
    length = hair.strand_length[strand]
    frac = np.divide(arc, length, out=np.zeros_like(arc), where=length > 0)
    key = strand * m + np.clip(np.floor(frac * m), 0, m - 1).astype(np.int64)
    keys, of_hit = np.unique(key, return_inverse=True)
    order = np.lexsort((np.random.default_rng([seed, 29]).random(len(key)), of_hit))
    first = np.searchsorted(of_hit[order], np.arange(len(keys)))
    return ShadowPieces(hit=order[first].astype(np.int64), of_hit=of_hit.astype(np.int64))


def piece_visibility(pieces: ShadowPieces, near: NearFibreHits, space: StrandSpace,
                     fibres: FibreMesh, fibre: ChiangFibre, tracer: RayTracer,
                     lights: Sequence[Light], label: str = "near fibres") -> np.ndarray:
    """(u, ⌈L/8⌉) uint8, bits packed along the lights (``np.packbits``, big-endian):
    whether each light reaches each piece, by one shadow ray from its drawn hit's fibre
    point facing the light (:func:`prtcore.core.fibres.facing`, the outside radius: as
    the path tracer's next-event estimation leaves a fibre). 66 bytes a piece at 528
    lights. ``label``: the stage its progress bar names."""
    hair = space.hair
    hit = pieces.hit
    tangent, centre, radius, _ = fibre_at_hits(
        hair, fibres, outside_offset(hair, fibres.sides), fibre.sigma_points,
        near.triangle[hit], near.barycentric[hit].astype(np.float64))
    seen = np.zeros((pieces.count, -(-len(lights) // 8)), np.uint8)
    for k, light in enumerate(bar(lights, f"{label} (shadow pieces)", total=len(lights))):
        _, to_light, _ = unshadowed_irradiance(light, centre, tangent)
        e = irradiance(light, centre + radius[:, None] * facing(tangent, to_light), to_light,
                       tracer)
        seen[:, k >> 3] |= (e.sum(axis=1) > 0).astype(np.uint8) << np.uint8(7 - (k & 7))
    return seen


def piece_lit(seen: np.ndarray, k: int) -> np.ndarray:
    """(u,) uint8 0 or 1: light ``k``'s column of :func:`piece_visibility`'s packed
    bits ``seen`` (u, ⌈L/8⌉)."""
    return (seen[:, k >> 3] >> (7 - (k & 7))) & 1


def near_fibre_shaded(near: NearFibreHits, valid_rays: np.ndarray, space: StrandSpace,
                      fibres: FibreMesh, fibre: ChiangFibre, tracer: RayTracer,
                      lights: Sequence[Light], exitance: str,
                      reads: tuple[np.ndarray, np.ndarray], seed: int,
                      pieces: int = NEAR_SHADOW_PIECES,
                      stats: dict | None = None, replace: bool = True,
                      label: str = "near fibres") -> tuple[np.ndarray, np.ndarray]:
    """The second bullet of the module docstring: the near hits' direct light from the
    punctual ``lights`` shaded at the point met, written over their columns of ``reads``
    (:func:`near_fibre_direct`'s rows (r,) and values (r, K, 3), the same hits; the
    environment lights keep their texel reads) and returned.

    Per hit and light, the exitance coefficients the strand texels' direct light takes
    (:func:`prtcore.transport.fibre_chiang.chiang_direct`: ``w(ωl) · E⊥ · cos θl · V / π²``
    with ``exitance``'s weights w, :func:`~prtcore.transport.fibre_chiang.
    exitance_weights`) at the point's own tangent, frame and σ_a (the hair's points'),
    read toward the gather ray (:func:`~prtcore.transport.fibre_chiang.exitance_reads`),
    over the texel's valid rays. V is its arc piece's (``pieces`` a strand texel, one hit
    of each drawn from ``seed``: :func:`shadow_pieces`, :func:`piece_visibility`): one
    shadow ray a piece and punctual light, not one a hit. ``stats``: gets the pieces'
    count (``shadow_pieces``). ``replace`` False: added to ``reads``' punctual columns,
    not written over them (``reads``' rows then only need to hold the hits' rows).
    ``label``: the stage its progress bars name."""
    rows, out = reads
    punctual = [k for k, light in enumerate(lights) if shaded_at_point(light)]
    if not near.count or not punctual:
        return rows, out
    slot = np.searchsorted(rows, near.row)
    hair = space.hair
    off = outside_offset(hair, fibres.sides)
    cut = shadow_pieces(near, space, fibres, seed, pieces)
    seen = piece_visibility(cut, near, space, fibres, fibre, tracer,
                            [lights[k] for k in punctual], label)
    if stats is not None:
        stats["shadow_pieces"] = cut.count
    if replace:
        out[:, punctual] = 0
    table = fibre.albedo
    terms = EXITANCE_TERMS[exitance]
    light_rows = [emitter_for(lights[k]).kernel_row(lights[k]) for k in punctual]
    for a in bar(range(0, near.count, NEAR_FIBRE_CHUNK), f"{label} (direct)",
                 total=-(-near.count // NEAR_FIBRE_CHUNK)):
        idx = np.arange(a, min(a + NEAR_FIBRE_CHUNK, near.count))
        tangent, centre, radius, sigma = fibre_at_hits(
            hair, fibres, off, fibre.sigma_points, near.triangle[idx],
            near.barycentric[idx].astype(np.float64))
        fu, fv = orthonormal_frame(tangent)
        toward = np.stack(exitance_reads(near.direction[idx].astype(np.float64), (fu, fv),
                                         terms), axis=1)
        scale = 1.0 / (np.pi ** 2 * np.maximum(valid_rays[near.row[idx]], 1))
        mine, at = np.unique(slot[idx], return_inverse=True)  # this chunk's rows
        lit = seen[cut.of_hit[idx]]
        sums = np.empty((len(mine), 3))
        for j, k in enumerate(punctual):
            sums[:] = 0
            shaded_reads(light_rows[j], centre, tangent, radius, sigma, fu, fv, toward,
                         scale * piece_lit(lit, j), at,
                         table.values, table.sin_theta, table.root_sigma, sums)
            out[mine, k] += sums.astype(np.float32)
    return rows, out


def shaded_fibre_correction(hits: NearFibreHits, valid_rays: np.ndarray, space: StrandSpace,
                            fibres: FibreMesh, fibre: ChiangFibre, tracer: RayTracer,
                            lights: Sequence[Light], exitance: str, direct: np.ndarray,
                            coefficient_rows: Callable[[int], slice], t_m: int,
                            frames: tuple | None, seed: int,
                            into: tuple[np.ndarray, np.ndarray],
                            stats: dict | None = None) -> None:
    """The shaded hits' first-bounce correction, added into ``into`` (rows (r,) int64
    sorted unique, holding every one of ``hits``' rows, values (r, K, 3) float32): each
    hit's direct light from the punctual lights shaded at the point met
    (:func:`near_fibre_shaded`) less its strand texel's read toward the ray
    (:func:`near_fibre_direct`), which the operator's entry for the hit gives the first
    bounce. A shaded hit keeps that entry (its later bounces read the texel), so only
    its direct light moves from the texel's mean to the point: the part of the near field
    that moves the dark scalp's bias (docs/hair.md). The texel reads go in chunks of
    SHADED_CHUNK hits, so their (F, n) reads stay bounded."""
    punctual = [k for k, light in enumerate(lights) if shaded_at_point(light)]
    if not hits.count or not punctual:
        return
    texel_reads(hits, valid_rays, direct, coefficient_rows, t_m, space.count,
                EXITANCE_TERMS[exitance], frames, punctual, into, -1,
                "shaded fibres (texel reads)")
    near_fibre_shaded(hits, valid_rays, space, fibres, fibre, tracer, lights, exitance,
                      into, seed, stats=stats, replace=False, label="shaded fibres")


def texel_reads(hits: NearFibreHits, valid_rays: np.ndarray, direct: np.ndarray,
                coefficient_rows: Callable[[int], slice], t_m: int, t_h: int, terms: int,
                frames: tuple | None, lights: Sequence[int] | None,
                into: tuple[np.ndarray, np.ndarray], sign: int, label: str) -> None:
    """:func:`near_fibre_direct`'s reads of ``hits``' strand texels for the light columns
    ``lights`` (None: every one), added (``sign`` 1) into or taken (−1) out of ``into``
    (rows (r,) int64 sorted unique, holding every one of the hits' rows, values (r, K, 3)
    float32) in chunks of SHADED_CHUNK hits, so their (F, n) reads stay bounded;
    ``label``: the progress bar's."""
    rows, out = into
    starts = range(0, hits.count, SHADED_CHUNK)
    for a in bar(starts, label, total=len(starts)):
        part = hits.subset(slice(a, a + SHADED_CHUNK))
        mine, read = near_fibre_direct(part, valid_rays, direct, coefficient_rows, t_m, t_h,
                                       terms, frames, lights)
        if sign < 0:
            out[np.searchsorted(rows, mine)] -= read
        else:
            out[np.searchsorted(rows, mine)] += read
