"""The bake of a hair asset (``.hair``, USD BasisCurves; paper 6.3): hair → strand texels
→ measurement points on the hull of the hair → lights → the fibre dataset → the
data-driven fit → a bundle whose basis images are strand textures (docs/hair.md).

:func:`prtcore.pipeline.bake` hands hair assets here. The method and its files are the
surface bake's (:mod:`prtcore.methods.data_driven`); what differs is the receiver
(:class:`~prtcore.receivers.strands.StrandSpace`: its layout and sampling rule go to the
manifest's ``strands`` section, its image size to ``atlas``), the transport
(:func:`prtcore.transport.hair.bake_hair_dataset`) and the asset (``asset.hair``, the hair
as baked, written by :func:`prtcore.io.hair.write_hair`).

With ``mesh`` (a glTF asset: a head, a body), the mesh is baked with the hair: it goes
through the surface intake (its lightmap atlas, TEXCOORD_1), the receiver is a
:class:`~prtcore.receivers.combined.CombinedSpace` (atlas texels, then strand texels), the
measurement points lie on the convex hull of both, the transport is
:func:`prtcore.transport.hair_mesh.bake_hair_mesh_dataset` (light both ways between hair
and mesh) and the bundle holds both textures: the atlas's basis (``basis_XX.exr``, as a
surface bundle) and the strand texture's (``strand_basis_XX.exr``), driven by one transfer
matrix.

``validate.reference_spp`` > 0 validates the bundle inside the bake against the fibre's
path tracer, as ``prtcore report BUNDLE --reference-spp N`` does (hair alone:
:mod:`prtcore.reference.fibres` or :mod:`prtcore.reference.chiang`; with a mesh:
:mod:`prtcore.reference.hair_mesh`), and the verdict is judged on it.

The strand texels' indirect light is denoised before the fit
(:mod:`prtcore.transport.strand_denoise`, ``hair.denoise_neighbours``): each texel's
irradiance fitted by a plane through its nearest texels in space (for the Chiang fibre,
a plane and the second band of the fibre's direction, ``hair.denoise_direction``).

A mesh baked with the hair has its atlas rows filtered by the surfaces' seam-aware
lightmap filter (``fit.denoise``: "auto" is :data:`~prtcore.transport.noise.DENOISE_FALLBACK`
texels, as for keyframe bakes, which trace no second transport either); the strand rows
are not (hair alone: ``fit.denoise`` is 0).

Not yet: keyframes, and ``measurement_points.placement`` other than the hull.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prtcore.core.errors import AssetError, LimitExceeded, SpecError
from prtcore.core.hair import Hair
from prtcore.core.limits import IntakeLimits
from prtcore.core.progress import ProgressCallback, StageTimer
from prtcore.core.spec import BakeSpec, spec_hash, spec_to_dict
from prtcore.emitters.families import sample_configurations
from prtcore.intake.hair import hair_scene, with_hair
from prtcore.intake.plan import fixed_counts
from prtcore.intake.points import MeasurementPoints, place_measurement_points
from prtcore.io.bundle import (
    atlas_section,
    basis_planes,
    check_output,
    manifest_base,
    sha256_file,
    write_basis_files,
    write_bundle,
)
from prtcore.io.hair import load_hair, write_hair
from prtcore.io.imageio import write_exr
from prtcore.methods.base import BakeInputs, Method, method
from prtcore.receivers.combined import CombinedSpace
from prtcore.receivers.smoothing import denoise_lightmaps
from prtcore.receivers.strands import StrandSpace, build_strand_space, texel_turn
from prtcore.receivers.texels import TexelSpace
from prtcore.transport.base import operator_for
from prtcore.transport.dataset import (
    MEM_PER_TEXEL,
    MEM_PER_TEXEL_CONFIG,
    MEM_PROCESS,
    Dataset,
    direct_at_points,
    estimate_bake_bytes,
)
from prtcore.transport.fibre import (
    FIRST_BOUNCE_LIGHTS,
    HARMONICS,
    MEM_PER_FIBRE_SEGMENT,
    MEM_PER_OPERATOR_ENTRY,
    SPARSE_FIBRE_SHARE,
    STACKED_HARMONICS,
    STRAIGHT_TURN_DEG,
    HairDensity,
    direct_block_bytes,
    direct_sample_count,
    hair_density,
    hair_tracer,
    harmonic_blocks_bound,
)
from prtcore.transport.fibre_chiang import (
    CHIANG_BYTES_PER_RAY,
    EXITANCE_TERMS,
    check_lights,
    chiang_fibre,
    chiang_samples,
    texel_albedo,
)
from prtcore.transport.fibre_near import near_hits_reach
from prtcore.transport.hair import bake_hair_dataset
from prtcore.transport.hair_mesh import bake_hair_mesh_dataset, per_piece
from prtcore.transport.hair_mesh_chiang import bake_chiang_hair_mesh_dataset, chiang_mesh_bytes
from prtcore.transport.noise import DENOISE_FALLBACK
from prtcore.transport.solve import SOLVE_BLOCK_BYTES, SOLVE_WORK_ARRAYS
from prtcore.transport.strand_denoise import DEFAULT_NEIGHBOURS, denoise_dataset

METHOD = "data_driven"
#: writes a run's report files: (directory, method, result, report, seconds, t_start)
RunFiles = Callable[[Path, Method, Any, dict, dict, float], None]


@dataclass(frozen=True)
class HairPrepare:
    """What the surface bake's prepare report holds, for a hair asset (nothing repaired,
    the strand texture is fully used but for the last row's tail)."""

    utilisation: float
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class HairIntake:
    """The intake of a hair bake, in the shape the method reads (``texels`` is the strand
    space)."""

    source: str
    spec: BakeSpec
    hair: Hair
    texels: StrandSpace | CombinedSpace
    points: MeasurementPoints
    prepare: HairPrepare
    #: the mesh baked with the hair (its prepared scene), or None
    scene: object = None
    seconds: dict = field(default_factory=dict)
    #: the strand texels (``texels`` itself for hair alone)
    strands: StrandSpace | None = None


#: training lights of a Chiang-fibre bake whose ``lights.count`` is "auto": its indirect
#: light is smoother than the diffuse fibre's (the 10k hairball's projection bound at
#: n = 16: 7.6 %), and the transfer from 256 hull points fitted on the diffuse default of
#: 128 lights stays near 10 %: 1.52× the bound, a failed verdict; 512 lights pass at 1.21×
#: (docs/hair.md)
CHIANG_FIXED_LIGHTS = 512
#: what ``hair.chiang.exitance = "auto"`` takes where memory allows (docs/hair.md: 11 % per
#: texel on the tangle against the isotropic 38 %, 1.9× the isotropic bake's time)
AUTO_EXITANCE = "linear"
#: with at least this many gather rays per texel, or with the strand texels denoised
#: (``hair.denoise_neighbours`` > 1), "auto" takes second-order exitance where memory
#: allows. Its truncation is the smallest (light tangle at M = 256: 4.2 % against
#: linear's 8.3 %), its noise the largest; undenoised, at M = 64 the three exitances are
#: alike (15.8, 16.1, 16.3 %), and from M = 256 the second order is best (8.5 % against
#: 10.9 %; dark 10.3 against 13.8 %). The denoiser takes the noise: the 10k hairball at
#: the bake's defaults, denoised with the fibre's direction, second order 6.8 % (light)
#: and 7.3 % (dark) against linear's 8.3 and 9.4 % (docs/hair.md, "Denoising the Chiang
#: fibre"; hair alone is denoised by default, hair with a mesh is not)
SECOND_ORDER_RAYS = 256
#: the fewest fibre-gather rays a strand texel needs for "auto" to take the second order:
#: its ten weights a ray (16 Ā_z and 16 Ā_s among them) from fewer make a noisy operator
#: whose series diverges (the 200-strand tangle at 16 rays grew 1.095× a bounce, at 32 it
#: converges in 9; the 300-strand head at 16 grew 1.67×, at 32 converges in 15; linear
#: and quadratic converge at 16 on both). Until 2026-12-06 nothing watched for it, and the
#: tangle's test bakes at 16 rays shipped the series' first 16 terms
SECOND_ORDER_MIN_RAYS = 32
#: ``hair.max_bounces`` "auto" for the Chiang fibre: its low-rank solve on light hair
#: needed 20 bounces to converge on the 10k head (16 left the atlas 0.31 % and the strand
#: texels 0.43 % short, benchmarks/hair_mesh_chiang_bounces.py), and its late bounces run
#: on about ten columns of the basis
CHIANG_MAX_BOUNCES = 64
#: training lights of a hair + mesh bake (diffuse fibre) whose ``lights.count`` is "auto".
#: The 10k curly head with its head mesh at 128 lights (the hair-alone default) passed at
#: 1.25× its projection bound, on the gate; with its atlas rows filtered (``fit.denoise``,
#: :func:`denoise_atlas`) the bound falls and 128 lights fail at 1.28× (128 points: 1.32×),
#: while 256 pass at 1.09× (12.0 %; 236 s instead of 163–241 s, peak 4.4 GiB instead of
#: 3.8; docs/hair.md, "One head, several bake seeds")
MESH_FIXED_LIGHTS = 256
#: pieces per strand texel in the transport of a hair + mesh bake with the diffuse fibre
#: (``hair.arc_subdivision = "auto"``): on the 10k curly head the scalp's indirect light
#: goes from +4.4 % to +2 % against the path tracer (filtered atlas, the mean of four
#: bakes) with about the same rays (docs/hair.md, "Transporting each texel in pieces")
MESH_ARC_SUBDIVISION = 2
#: the most measurement points a hair bake whose ``measurement_points.count`` is "auto"
#: is fitted on (:func:`_more_points`: 256, then 512, then 1024 while the verdict fails on
#: the transfer's ratio). Each is one more direct light per point for the engine to shade
#: each frame, and a (3, n − 1, P) transfer
MAX_AUTO_POINTS = 1024


def hair_spec(spec: BakeSpec, with_mesh: bool = False) -> BakeSpec:
    """The spec as a hair bake runs it: points on the hull, ``fit.denoise`` resolved (with a
    mesh, "auto" is :data:`~prtcore.transport.noise.DENOISE_FALLBACK` texels, the filter of
    the mesh's atlas rows; hair alone has no atlas: 0),
    ``hair.denoise_neighbours = "auto"`` resolved for the diffuse fibre (64; the Chiang
    fibre's once its strands are counted: with a mesh by how dense the hair is,
    :func:`dense_hair`, without by the rays its texels get, :func:`small_hair`), likewise
    ``hair.gather_rays`` (``transport.gather_rays``), ``hair.max_bounces``
    (:data:`CHIANG_MAX_BOUNCES` for the Chiang fibre, ``transport.max_bounces`` for the
    diffuse one) and
    ``hair.denoise_direction``
    ("t2" for the Chiang fibre, "none" for the diffuse one), ``hair.direct_samples =
    "auto"`` resolved for the diffuse fibre
    (:func:`prtcore.transport.fibre.direct_sample_count`) and the Chiang fibre with a mesh
    (:func:`~prtcore.transport.fibre_chiang.chiang_samples`; alone: :func:`small_hair`),
    ``hair.harmonics = "auto"`` resolved (adaptive with a mesh: the
    light that goes head → hair → head needs the side of the fibre that faced the head,
    and the fibre-to-fibre harmonics hold where the fibre is straight along a texel or
    the hair is sparse, docs/hair.md; mesh_bounces without a mesh is exactly first_bounce,
    and says so), ``hair.arc_subdivision = "auto"`` resolved to 1 without a mesh or with
    the Chiang fibre (with a mesh and the diffuse fibre the hair's curl decides it,
    :func:`arc_pieces`),
    "auto" light counts fixed (:data:`CHIANG_FIXED_LIGHTS` for the Chiang fibre,
    :data:`MESH_FIXED_LIGHTS` with a mesh);
    keys a hair bake cannot honour yet are refused by name."""
    if spec.keyframes.animation is not None:
        raise SpecError("keyframes.animation", "hair bakes are static (no keyframes yet)")
    if spec.measurement_points.placement == "qdeim":
        raise SpecError("measurement_points.placement", "hair bakes place their points "
                        "on the hull of the hair ('surface' and 'hull' both mean that)")
    if spec.lights.count == "auto" and (spec.hair.fibre == "chiang" or with_mesh):
        spec = dataclasses.replace(spec, lights=dataclasses.replace(
            spec.lights, count=CHIANG_FIXED_LIGHTS if spec.hair.fibre == "chiang"
            else MESH_FIXED_LIGHTS))
    spec = fixed_counts(spec)  # hair bakes do not size themselves (yet)
    harmonics = spec.hair.harmonics
    denoise = spec.hair.denoise_neighbours
    if denoise == "auto" and spec.hair.fibre == "diffuse":
        # measured in docs/hair.md, "Denoising the strand texels" (hair alone within the
        # per-texel bounds, and the verdict passes on more points: "More measurement
        # points, no more transport"); the Chiang fibre's is decided once its strands
        # are counted: by how dense the hair is with a mesh (dense_hair), by the rays
        # its texels get without (small_hair)
        denoise = DEFAULT_NEIGHBOURS
    direction = spec.hair.denoise_direction
    if direction == "auto":  # docs/hair.md, "Denoising the Chiang fibre"
        direction = "t2" if spec.hair.fibre == "chiang" else "none"
    if spec.hair.fibre == "chiang":
        harmonics = "auto"  # the Chiang fibre carries no harmonics (its own transport)
    elif harmonics == "auto":
        harmonics = "adaptive" if with_mesh else "first_bounce"
    elif harmonics == "mesh_bounces" and not with_mesh:
        harmonics = "first_bounce"  # no mesh light for the harmonics to carry
    pieces = spec.hair.arc_subdivision
    if pieces == "auto" and not (with_mesh and spec.hair.fibre == "diffuse"):
        pieces = 1  # with a mesh and the diffuse fibre, the hair decides (arc_pieces)
    elif pieces != "auto" and pieces > 1 and not with_mesh:
        raise SpecError("hair.arc_subdivision", f"{pieces} pieces per texel are "
                        "transported for hair with a mesh only; hair alone is "
                        "transported by whole texels (leave it 'auto' or 1)")
    rays = spec.hair.gather_rays
    if rays == "auto" and spec.hair.fibre == "diffuse":
        rays = spec.transport.gather_rays  # the Chiang fibre: dense_hair or small_hair
    bounces = spec.hair.max_bounces
    if bounces == "auto":
        bounces = CHIANG_MAX_BOUNCES if spec.hair.fibre == "chiang" \
            else spec.transport.max_bounces
    samples = spec.hair.direct_samples
    if spec.hair.fibre == "diffuse":
        samples = direct_sample_count(spec.hair.direct, samples,
                                      spec.transport.direct_samples)
    elif with_mesh:  # the Chiang fibre with a mesh; alone, small_hair resolves it
        samples = chiang_samples(samples, spec.transport.direct_samples)
    return dataclasses.replace(
        spec, measurement_points=dataclasses.replace(spec.measurement_points,
                                                     placement="hull"),
        fit=dataclasses.replace(spec.fit, denoise=atlas_radius(spec, with_mesh)),
        hair=dataclasses.replace(spec.hair, harmonics=harmonics,
                                 denoise_neighbours=denoise, denoise_direction=direction,
                                 direct_samples=samples, gather_rays=rays,
                                 max_bounces=bounces,
                                 arc_subdivision=pieces))


def fibre_gather_rays(spec: BakeSpec) -> int:
    """M_h, the fibre gather's rays per strand texel: ``hair.gather_rays``, or
    ``transport.gather_rays`` (the atlas's) while it is "auto"."""
    rays = spec.hair.gather_rays
    return spec.transport.gather_rays if rays == "auto" else int(rays)


def arc_pieces(spec: BakeSpec, space: StrandSpace) -> BakeSpec:
    """``hair.arc_subdivision = "auto"`` left by :func:`hair_spec` (the diffuse fibre with
    a mesh) resolved by the hair: :data:`MESH_ARC_SUBDIVISION` pieces per texel where the
    median texel's fibre turns at least
    :data:`~prtcore.transport.fibre.STRAIGHT_TURN_DEG` along it
    (:func:`~prtcore.receivers.strands.texel_turn`: curly hair, whose texels go in and out
    of the hair), 1 where it is straighter. Measured (docs/hair.md, "Transporting each
    texel in pieces"): the 10k curly head (median 60°) and the sparse 2000-strand curly
    head (71°) within the bounds with two pieces, the straight 10k head (10°) with whole
    texels and two pieces alike, for 1.33× the bake's time and 1.25× its peak."""
    if spec.hair.arc_subdivision != "auto":
        return spec
    curly = space.count > 0 and float(np.median(texel_turn(space))) >= STRAIGHT_TURN_DEG
    return dataclasses.replace(spec, hair=dataclasses.replace(
        spec.hair, arc_subdivision=MESH_ARC_SUBDIVISION if curly else 1))


#: Chiang-fibre hair alone, "auto" rays and samples: the strand texels of the 10k
#: hairball (100 000), the largest hair they were measured on, whose fibre gather at
#: ``transport.gather_rays`` rays a texel (64: 6.4 M rays) and direct light at 4 samples
#: are the budget smaller hair spends too, at most :data:`MAX_RAY_SCALE` times the rays
#: and samples a texel (:func:`small_hair`)
RAY_BUDGET_TEXELS = 100_000
MAX_RAY_SCALE = 8
#: from this many fibre-gather rays a texel, Chiang-fibre hair alone is denoised with
#: :data:`MANY_RAYS_NEIGHBOURS` neighbours by default, not 64: on the 1000-strand tangle
#: at 512 rays (with t2, against 16 384 paths a texel) k = 64 reads 7.9 % / 8.9 % per
#: texel (light / dark, 16 samples; its blur −1.0 % / −1.6 % of bias), undenoised 7.7 % /
#: 7.8 % and k = 16 7.4 % / 7.6 % (32 samples; docs/hair.md, "Small hair spends the
#: hairball's rays")
MANY_RAYS = 512
MANY_RAYS_NEIGHBOURS = 16


def small_hair(spec: BakeSpec, space: StrandSpace) -> tuple[BakeSpec, list[str]]:
    """Chiang-fibre hair alone: ``hair.gather_rays``, ``hair.direct_samples`` and
    ``hair.denoise_neighbours`` "auto" (left by :func:`hair_spec`) resolved once the
    strand texels are counted. With s the largest power of two such that s·T ≤
    :data:`RAY_BUDGET_TEXELS` (T strand texels), at least 1 and at most
    :data:`MAX_RAY_SCALE`:

    * ``hair.gather_rays``: ``transport.gather_rays`` × s;
    * ``hair.direct_samples``: :func:`~prtcore.transport.fibre_chiang.chiang_samples`'s
      J × s;
    * ``hair.denoise_neighbours``: :data:`MANY_RAYS_NEIGHBOURS` from :data:`MANY_RAYS`
      fibre rays, else :data:`~prtcore.transport.strand_denoise.DEFAULT_NEIGHBOURS`.

    So small hair gets the rays and samples the 10k hairball spends: the fast path's
    noise is what kept the 1000-strand tangle over the per-texel bounds at 64 rays and 4
    samples (10.0 % / 10.9 %, denoised with k = 64); at 512 and 32, with k = 16, it is
    inside them. Returns the spec and the lines saying what was chosen and why; the
    diffuse fibre and given values come back as they are."""
    if spec.hair.fibre != "chiang":
        return spec, []
    lines = []
    scale = min(MAX_RAY_SCALE, max(1, RAY_BUDGET_TEXELS // max(1, space.count)))
    scale = 1 << (scale.bit_length() - 1)  # a power of two, rounded down
    why = (f"(the budget of {RAY_BUDGET_TEXELS} texels, at most {MAX_RAY_SCALE}×)"
           if scale > 1 else f"(more only at {RAY_BUDGET_TEXELS // 2} texels or fewer)")
    rays = spec.hair.gather_rays
    if rays == "auto":
        rays = spec.transport.gather_rays * scale
        lines.append(f"hair.gather_rays auto → {rays}: {space.count} strand texels, "
                     f"{scale}× transport.gather_rays {why}")
    samples = spec.hair.direct_samples
    if samples == "auto":
        base = chiang_samples(samples, spec.transport.direct_samples)
        samples = base * scale
        lines.append(f"hair.direct_samples auto → {samples}: {space.count} strand "
                     f"texels, {scale}× the fibre's {base} {why}")
    denoise = spec.hair.denoise_neighbours
    if denoise == "auto":
        denoise = MANY_RAYS_NEIGHBOURS if rays >= MANY_RAYS else DEFAULT_NEIGHBOURS
        lines.append(f"hair.denoise_neighbours auto → {denoise}: {rays} fibre rays a "
                     f"texel ({MANY_RAYS_NEIGHBOURS} from {MANY_RAYS}: the strand texels' "
                     "noise is lower, and a wider kernel's blur costs more)")
    return dataclasses.replace(spec, hair=dataclasses.replace(
        spec.hair, gather_rays=rays, direct_samples=samples,
        denoise_neighbours=denoise)), lines


def strand_spec(spec: BakeSpec, space: StrandSpace, with_mesh: bool
                ) -> tuple[BakeSpec, list[str]]:
    """The "auto" keys :func:`hair_spec` leaves until the strands are counted and before
    the memory check: :func:`arc_pieces`, and :func:`small_hair` for hair alone (with a
    mesh, the Chiang fibre's wait for the hair's density, :func:`dense_hair`). Returns
    the spec and the lines saying what was chosen."""
    spec = arc_pieces(spec, space)
    return (spec, []) if with_mesh else small_hair(spec, space)


def atlas_radius(spec: BakeSpec, with_mesh: bool) -> float:
    """The radius (texels) of the seam-aware filter on a hair + mesh bake's atlas rows:
    ``fit.denoise``, "auto" → :data:`~prtcore.transport.noise.DENOISE_FALLBACK`; 0 without
    a mesh. On the 10k curly head (``benchmarks/hair_mesh_accuracy.py --atlas-radii``) 1.5
    takes the scalp's atlas texels from 14–15 % to 9–10 % against the path tracer."""
    if not with_mesh:
        return 0.0
    return DENOISE_FALLBACK if spec.fit.denoise == "auto" else float(spec.fit.denoise)


def denoise_atlas(data: Dataset, texels: TexelSpace, radius: float,
                  timer: StageTimer) -> Dataset:
    """``data`` with its first ``texels.count`` rows (a hair + mesh bake's atlas texels)
    through the seam-aware lightmap filter of ``radius`` texels
    (:func:`~prtcore.receivers.smoothing.denoise_lightmaps`), in place, training and
    held-out lights alike; ``stats["atlas_denoise"]`` records the radius and the seconds.
    ``radius`` 0: ``data`` unchanged."""
    if radius <= 0:
        return data
    with timer.stage("denoise"):
        t0 = time.perf_counter()
        rows = data.indirect[:texels.count]  # a view: contiguous rows
        denoise_lightmaps(texels, rows, radius, out=rows)
        seconds = time.perf_counter() - t0
    return dataclasses.replace(data, stats={**data.stats, "atlas_denoise": {
        "radius_texels": radius, "seconds": round(seconds, 3)}})


def hair_points(hair: Hair, scene, spec: BakeSpec, timer: StageTimer) -> MeasurementPoints:
    """``spec.measurement_points`` on the hull of the hair, or of the hair and the mesh's
    prepared ``scene`` (None: hair alone)."""
    return place_measurement_points(hair_scene(hair) if scene is None
                                    else with_hair(scene, hair),
                                    spec.measurement_points, timer)


def run_hair_intake(asset: str | Path, spec: BakeSpec, timer: StageTimer,
                    limits: IntakeLimits, mesh: str | Path | None = None,
                    mesh_intake: Callable | None = None) -> HairIntake:
    """load → colour from the spec → strand texels → hull measurement points; with
    ``mesh``, the mesh's surface intake too (``mesh_intake``: the pipeline's
    :func:`prtcore.pipeline.run_intake`, its lightmap atlas) and the points on the hull of
    both."""
    with timer.stage("load"):
        hair = load_hair(asset, limits)
        if spec.hair.albedo is not None:
            hair = dataclasses.replace(hair, color=np.tile(np.asarray(spec.hair.albedo),
                                                           (hair.point_count, 1)))
    with timer.stage("texels"):
        space = build_strand_space(hair, spec.hair.texels_per_strand)
    if mesh is None:
        points = hair_points(hair, None, spec, timer)
        return HairIntake(source=str(asset), spec=spec, hair=hair, texels=space,
                          points=points, prepare=HairPrepare(
                              utilisation=space.count / (space.width * space.height)),
                          seconds=dict(timer.seconds), strands=space)
    if mesh_intake is None:
        raise ValueError("run_hair_intake: a mesh needs mesh_intake (prtcore.pipeline's "
                         "run_intake)")
    surface = mesh_intake(mesh, spec, limits=limits, timer=timer)
    points = hair_points(hair, surface.scene, spec, timer)
    return HairIntake(source=str(asset), spec=spec, hair=hair,
                      texels=CombinedSpace(surface.texels, space), points=points,
                      prepare=HairPrepare(utilisation=surface.prepare.utilisation,
                                          warnings=tuple(surface.prepare.warnings)),
                      scene=surface.scene, seconds=dict(timer.seconds), strands=space)


def _near_reach(spec: BakeSpec) -> float:
    """The Chiang fibre's near hits' reach in the atlas's footprints (their rays)."""
    return near_hits_reach(spec.hair.chiang.near_fibres, spec.hair.chiang.gathered_fibres)


def check_hair_memory(asset: str | Path, space: StrandSpace, spec: BakeSpec,
                      limit_bytes: int, mesh_texels: int = 0,
                      density: HairDensity | None = None) -> int:
    """The bake's estimated peak memory against ``limit_bytes``; returns the estimate.
    ``density``: the Chiang fibre with a mesh, how dense the hair is
    (:func:`~prtcore.transport.fibre.hair_density`; None before it is traced: every
    gather ray an entry, every strand texel with near-field rows).

    **Phases.** The transport's arrays do not all live at once, so the estimate is the
    larger of two phases, each on top of what the whole transport holds (the process,
    ``MEM_PER_TEXEL`` per strand texel, the fibre tubes):

    * the fibre gather: its rays' (row, column, azimuth) triples before they are summed
      (the fibre operator's :meth:`~prtcore.transport.fibre.FibreOperator.estimate_bytes`);
    * after it, the texels' direct light and its first bounce, (T, K, 3) float32 each
      (:data:`~prtcore.transport.dataset.MEM_PER_TEXEL_CONFIG`; without stacked harmonics
      the solve writes the indirect light over the direct, ``bake_hair_dataset``'s
      ``keep_direct_texels=False``, so the third array is not held), and the largest of:
      the direct light's stage (the operator's mean and two harmonic matrices, and the
      harmonics of the k = :data:`~prtcore.transport.fibre.FIRST_BOUNCE_LIGHTS` lights
      held at once, two more (T, k, 3) float32), the solve's Morton-order copy of the
      operator made before the three are dropped, and the solve (the copy and its working
      arrays, :func:`~prtcore.transport.dataset.estimate_bake_bytes`'s bound). An operator
      matrix holds at most one entry per gather ray, :data:`MEM_PER_OPERATOR_ENTRY` bytes.

    Until 2026-12-05 the gather's triples were counted at the solve too, and the 140k
    hairball's estimate (17.1 GiB) was 1.30× its measured peak (13.2 GiB), over the
    default limit; docs/hair.md has the stage peaks this model was checked against.

    The other variants add their own arrays to both phases (conservatively). Stacked
    harmonics (``hair.harmonics`` "all_bounces", "mesh_bounces", "turn_bounces",
    "adaptive"): the
    (3T, 3T) operator's blocks before they are summed (20 bytes per gather ray and block;
    nine, three for mesh_bounces' mean rows, 3 + 6 × the straight texels' share for
    turn_bounces, :func:`~prtcore.transport.fibre.harmonic_blocks_bound`), the stacked
    (3T, K, 3) float32 direct light in
    place of the T rows, the direct light's mean and harmonics beside it and, for hair
    alone, the solve's result (with a mesh the solve writes over the direct light); the
    solve's working arrays over 3T rows, bounded alike. The Chiang fibre: each hit's data,
    and the direct light's largest block at its J samples
    (:func:`~prtcore.transport.fibre.direct_block_bytes`, at most 0.5 GiB; until
    2026-12-07 it was not counted, and the tangle's J = 32 block held 2.5 GiB).
    ``mesh_texels`` T_m > 0 (a hair + mesh bake): the surface bake's estimate of T_m
    texels less its process and its solve (one of each, counted above: the solve's rows
    include the atlas), and the atlas rows of the direct light. Measured
    (benchmarks/stage_memory.py, the 10k head + mesh at the bake's 139k-texel atlas):
    K = 144 peak 3.78 GiB against 6.08 GiB (9.66 until 2026-12-05, whose stacked and
    solve terms were counted twice or three times), K = 272 4.45 against 7.74 (15.41).
    The Chiang fibre with a mesh has its own transport and its own model
    (:func:`~prtcore.transport.hair_mesh_chiang.chiang_mesh_bytes`) on top of the whole
    transport's fixed costs; until 2026-12-06 it took this one's terms with its own added,
    about twice its peak.
    With ``hair.arc_subdivision`` S every strand term counts S·T pieces of ⌈M/S⌉ rays."""
    k = spec.lights.count + spec.lights.holdout
    if spec.hair.chiang.exitance == "auto":  # estimated at what it may resolve to
        spec = _with_exitance(spec, AUTO_EXITANCE)
    spec = strand_spec(spec, space, with_mesh=mesh_texels > 0)[0]  # "auto" as the bake
    samples = chiang_samples(spec.hair.direct_samples, spec.transport.direct_samples)
    pieces = spec.hair.arc_subdivision  # resolves it
    space = space.subdivided(pieces)  # the texels the transport holds: S pieces each,
    t = space.count  # ⌈M/S⌉ fibre-gather rays per piece
    m = per_piece(fibre_gather_rays(spec), pieces)
    segments = space.hair.point_count - space.hair.strand_count
    everything = spec.hair.harmonics in STACKED_HARMONICS
    # the mean rows' three blocks, and six more for the texels whose harmonic rows
    # take other fibres' light
    blocks = harmonic_blocks_bound(spec.hair.harmonics, space) if everything and t else 3
    held = k if everything else min(k, FIRST_BOUNCE_LIGHTS)  # lights' harmonics at once
    whole = MEM_PROCESS + t * MEM_PER_TEXEL + segments * MEM_PER_FIBRE_SEGMENT
    if spec.hair.fibre == "chiang" and mesh_texels:  # its own transport's phases
        return _checked(asset, space, mesh_texels, k, limit_bytes, whole + chiang_mesh_bytes(
            mesh_texels, t, k, m, spec.hair.chiang.exitance, spec.transport, density,
            _near_reach(spec), samples=samples,
            shaded_fibres=spec.hair.chiang.shaded_fibres))
    gather = operator_for("fibre").estimate_bytes(
        t, k, dataclasses.replace(spec.transport, gather_rays=m))
    entries = t * m * MEM_PER_OPERATOR_ENTRY  # one operator matrix
    light = t * k * (MEM_PER_TEXEL_CONFIG - (0 if everything else 12))
    # one solve over the strand rows (three with stacked harmonics) and the atlas rows
    solve = min(SOLVE_WORK_ARRAYS * ((3 if everything else 1) * t + mesh_texels) * k * 12,
                SOLVE_BLOCK_BYTES)
    after = light + max((1 + 2 * HARMONICS) * entries + 2 * t * held * 12,
                        (2 + 2 * HARMONICS) * entries, entries + solve)
    est = whole + max(gather, after)
    if spec.hair.fibre == "chiang":  # each hit's data; with F > 1 coefficients the stacked
        # direct light's other F − 1 (the solve works in its buffer, transport/low_rank.py;
        # its column blocks are bounded by SOLVE_BLOCK_BYTES) and the first coefficient's
        # sum of bounces beside it (clamped in place); the direct light's largest block
        f = EXITANCE_TERMS[spec.hair.chiang.exitance]
        est += t * m * CHIANG_BYTES_PER_RAY[spec.hair.chiang.exitance] \
            + (f * t * k * 12 if f > 1 else 0) + direct_block_bytes(t, samples, k, f)
    if everything:  # the operator's blocks before they are summed; beside the stacked
        # (3T, K, 3) direct light (``light``) the direct light's mean and harmonics, and
        # for hair alone the solve's result (with a mesh it is written over the direct)
        est += t * m * blocks * 20 + (3 if mesh_texels else 6) * t * k * 12
    if mesh_texels:  # the surface gather of the atlas (one process and one solve: its
        # MEM_PROCESS and working arrays are counted above), and the atlas rows of the
        # direct light the solve works in (its strand rows are ``light``'s)
        est += estimate_bake_bytes(mesh_texels, k, spec.transport, ("surface",)) \
            - MEM_PROCESS - min(SOLVE_WORK_ARRAYS * mesh_texels * k * 12, SOLVE_BLOCK_BYTES) \
            + mesh_texels * k * 12
    return _checked(asset, space, mesh_texels, k, limit_bytes, est)


def _checked(asset, space: StrandSpace, mesh_texels: int, k: int, limit_bytes: int,
             est: float) -> int:
    """``est`` as bytes, or :class:`LimitExceeded` naming the bake when it is over."""
    if est > limit_bytes:
        raise LimitExceeded(str(asset), "", f"the bake of {space.count} strand texels"
                            + (f", {mesh_texels} atlas texels" if mesh_texels else "")
                            + " and "
                            f"{k} lights needs about {est / 2**30:.1f} GiB",
                            limit=f"max_bake_bytes={limit_bytes}")
    return int(est)


def _with_exitance(spec: BakeSpec, exitance: str) -> BakeSpec:
    return dataclasses.replace(spec, hair=dataclasses.replace(
        spec.hair, chiang=dataclasses.replace(spec.hair.chiang, exitance=exitance)))


def chiang_exitance(asset: str | Path, space: StrandSpace, spec: BakeSpec,
                    limit_bytes: int, mesh_texels: int = 0,
                    density: HairDensity | None = None) -> tuple[BakeSpec, str | None]:
    """``hair.chiang.exitance = "auto"`` resolved: second-order exitance when the bake
    denoises its strand texels (``hair.denoise_neighbours`` > 1: the default for hair
    alone, and for dense hair with a mesh, :func:`dense_hair`, which asks again once it
    knows) or traces at
    least :data:`SECOND_ORDER_RAYS` gather rays per texel, with at least
    :data:`SECOND_ORDER_MIN_RAYS` fibre-gather rays either way (fewer make its series
    diverge), and its memory estimate with it is within ``limit_bytes``; else
    :data:`AUTO_EXITANCE` (linear) when that fits, else isotropic (a quarter of the
    stacked direct light; docs/hair.md).
    Returns the spec and a line saying why a lesser exitance than the rays call for was
    taken, or None. Any other value, and the diffuse fibre, are kept."""
    if spec.hair.fibre != "chiang" or spec.hair.chiang.exitance != "auto":
        return spec, None
    # "auto" (dense_hair's to resolve, with a mesh) counts as not denoised
    denoised = spec.hair.denoise_neighbours not in ("auto", 0, 1)
    rays = fibre_gather_rays(spec)
    tried = (["second_order"] if (denoised or rays >= SECOND_ORDER_RAYS)
             and rays >= SECOND_ORDER_MIN_RAYS else []) + [AUTO_EXITANCE]
    refused = []
    for exitance in tried:
        candidate = _with_exitance(spec, exitance)
        try:
            check_hair_memory(asset, space, candidate, limit_bytes, mesh_texels=mesh_texels,
                              density=density)
        except LimitExceeded as e:
            refused.append(f"with {exitance} exitance {e.what} (limit {e.limit})")
            continue
        return candidate, None if not refused else (
            f"hair.chiang.exitance auto → {exitance}: {refused[0]}")
    return _with_exitance(spec, "isotropic"), (
        f"hair.chiang.exitance auto → isotropic: {'; '.join(refused)}; the direction "
        "average alone is less accurate (docs/hair.md)")


def bake_hair(asset: str | Path, spec: BakeSpec, out: Path, *, run_files: RunFiles,
              exclude: tuple[str, ...] = (), quiet: bool = False, force: bool = False,
              limits: IntakeLimits | None = None, callback: ProgressCallback | None = None,
              source_name: str | None = None, mesh: str | Path | None = None,
              mesh_intake: Callable | None = None, validate: Callable | None = None
              ) -> tuple[Path, Method, Any, dict, dict | None]:
    """hair asset (+ a glTF ``mesh`` baked with it) + spec → bundle ``out``.
    ``run_files(directory, method, result, report, seconds, t_start)`` writes the run's
    report files (the pipeline's), ``exclude`` names them (left out of the checksums).
    ``mesh_intake``: the surface intake the mesh goes through (the pipeline's
    ``run_intake``). With ``validate.reference_spp`` > 0 the bundle is validated against
    the fibre's path tracer by ``validate(out, timer)`` (the pipeline's
    :func:`prtcore.validate.validate_bundle`: the hair, or hair + mesh, reference) and the
    verdict judged on it. Returns (out, the method, its result,
    the stage seconds, the validation or None) for the caller's summary."""
    inputs_files = (asset,) if mesh is None else (asset, mesh)
    check_output(out, force, inputs=inputs_files)
    if mesh is not None and not Path(mesh).is_file():  # before the hair's intake
        raise AssetError(str(mesh), "", "cannot read asset: no such file (the --mesh of a "
                         "hair bake)")
    t_start = time.perf_counter()
    grow = spec.lights.count == "auto"  # the bake may double its lights once (below),
    grow_points = spec.measurement_points.count == "auto"  # and refit on more points
    spec = hair_spec(spec, with_mesh=mesh is not None)
    timer = StageTimer(quiet=quiet, callback=callback)
    limits = limits or IntakeLimits.from_env()
    intake = run_hair_intake(asset, spec, timer, limits, mesh, mesh_intake)
    space, hair, scene = intake.strands, intake.hair, intake.scene
    spec, lines = strand_spec(spec, space, with_mesh=scene is not None)
    for line in lines:
        timer.note(f"[prtcore] {line}")
    mesh_texels = intake.texels.mesh.count if scene is not None else 0
    exitance_auto = spec.hair.chiang.exitance == "auto"
    spec, why = chiang_exitance(asset, space, spec, limits.max_bake_bytes, mesh_texels)
    if why is not None:
        timer.note(f"[prtcore] {why}")
    check_hair_memory(asset, space, spec, limits.max_bake_bytes, mesh_texels=mesh_texels)
    tracer, fibres = hair_tracer(space, scene)
    density = None  # every ray an entry, every texel near rows, until hair_density says
    if scene is not None and "auto" in (spec.hair.denoise_neighbours,  # the Chiang
                                        spec.hair.gather_rays):  # fibre's with a mesh
        with timer.stage("hair density"):
            density = hair_density(space, tracer, scene.triangle_count,
                                   spec.transport.gather_rays, spec.transport.seed,
                                   atlas=intake.texels.mesh,
                                   near_field=spec.transport.near_field,
                                   near_fibres=_near_reach(spec)
                                   if spec.hair.fibre == "chiang" else 0.0,
                                   shaded_fibres=spec.hair.chiang.shaded_fibres
                                   if spec.hair.fibre == "chiang" else 0.0)
        spec, lines = dense_hair(asset, space, spec, density, limits.max_bake_bytes,
                                 mesh_texels, exitance_auto)
        for line in lines:
            timer.note(f"[prtcore] {line}")
        intake = dataclasses.replace(intake, spec=spec)
    m = method(METHOD)
    inputs, result = _transport_and_fit(spec, intake, tracer, fibres, m, timer)
    if grow_points:  # refitted on more points first: they need no transport
        inputs, result = _more_points(inputs, result, tracer, m, timer)
        spec, intake = inputs.spec, inputs.intake
    more = _more_lights(spec, result.verdict, asset, space, limits,
                        mesh_texels, density) if grow else None
    if more is not None:  # one more pass with twice the lights; the report lists both
        first = _tried(spec, result)
        timer.note(f"[prtcore] lights             {spec.lights.count} → {more.lights.count}"
                   f": the verdict failed at {first['ratio']:.2f}× the projection bound; "
                   "baked again with twice the training lights")
        spec = more
        intake = dataclasses.replace(intake, spec=more)
        points_tried = inputs.data.stats.get("points_tried")
        del inputs, result  # the first pass's dataset goes before the second is baked
        inputs, result = _transport_and_fit(spec, intake, tracer, fibres, m, timer)
        stats = {**inputs.data.stats, "lights_tried": [first, _tried(spec, result)]}
        if points_tried is not None:
            stats["points_tried"] = points_tried
        inputs = dataclasses.replace(inputs, data=dataclasses.replace(inputs.data,
                                                                      stats=stats))
    spec = inputs.spec  # as the passes ran it

    def write(tmp: Path) -> dict:
        write_hair(tmp / "asset.hair", hair)
        sections, report = m.write(tmp, inputs, result)
        fibre_section = {"model": spec.hair.fibre, "harmonics": spec.hair.harmonics,
                 "geometry": "triangulated tubes, 3 sides, mean projected width = diameter"}
        if scene is None:
            common = {
                "asset": {"source": source_name or Path(str(asset)).name,
                          "sha256": sha256_file(Path(asset)), "file": "asset.hair",
                          "strands": hair.strand_count, "points": hair.point_count},
                "units": {"length": "m", "up": "+Y", "handedness": "right",
                          "radiance": "linear RGB outgoing radiance (albedo/pi * E), "
                                      "averaged over the fibre's azimuth and the texel's "
                                      "arc interval"},
                "atlas": {"width": space.width, "height": space.height, "padding": 0,
                          "uv": "strands", "coverage": "coverage.exr",
                          "covered_texels": space.count},
                "strands": space.layout(),
                "fibre": {"model": spec.hair.fibre, "geometry": fibre_section["geometry"]},
            }
        else:
            common = _mesh_sections(tmp, scene, intake.texels, result, spec, asset, mesh,
                                    source_name, hair)
            common["fibre"] = fibre_section
        if spec.hair.fibre == "chiang":
            common["fibre"].pop("harmonics", None)
            common["fibre"]["chiang"] = spec_to_dict(spec.hair.chiang)
            common["units"]["radiance"] = (
                "linear RGB outgoing radiance" + (" (albedo/pi * E on the mesh)" if scene
                                                  is not None else "")
                + ("; on strands" if scene is not None else "")
                + " averaged over every direction with the fibre's projected width "
                "(1/pi^2 * integral of L_o cos theta), over the texel's arc interval")
        run_files(tmp, m, result, report, dict(timer.seconds), t_start)
        run = {"spec": spec_to_dict(spec), "spec_sha256": spec_hash(spec),
               "timings": dict(timer.seconds)}
        return manifest_base(method=m.name, **common, **sections, **run,
                             run_files=list(exclude))

    with timer.stage("export"):
        out = write_bundle(out, write, force=force, exclude=exclude, inputs=inputs_files)
    validation = None
    if spec.validate.reference_spp > 0 and len(inputs.hold) and validate is not None:
        with timer.stage("validate"):  # the verdict against the fibre path tracer
            validation = validate(out, timer)
        result = m.revalidate(result, inputs, validation)
    return out, m, result, dict(timer.seconds), validation


#: ``hair.denoise_neighbours`` "auto" on dense hair with the Chiang fibre and a mesh: on
#: the 10k curly head (second order, M = 64) k = 64 left 8.5 % / 10.9 % per texel (light
#: / dark hair), k = 128 7.5 % / 8.7 % with the bias within 1.3 %, k = 256 bent 2.7 % in
#: (docs/hair.md, "Dense hair with a mesh: second order, denoised")
DENSE_MESH_NEIGHBOURS = 128
#: ``hair.gather_rays`` "auto" there: the fibre gather's rays per strand texel, twice the
#: default atlas's (the dark hair's strand texels 8.7 % per texel at k = 128 with 64,
#: 7.6 % with 128; the atlas's own rays changed its scalp by no more than its noise)
DENSE_MESH_RAYS = 128


def dense_hair(asset: str | Path, space: StrandSpace, spec: BakeSpec,
               density: HairDensity, limit_bytes: int, mesh_texels: int,
               exitance_auto: bool) -> tuple[BakeSpec, list[str]]:
    """The Chiang fibre with a mesh: "auto" keys resolved from ``density``
    (:func:`~prtcore.transport.fibre.hair_density`, traced before the transport), by the
    share of the fibre gather's rays that meet another fibre (dense hair: at least
    :data:`~prtcore.transport.fibre.SPARSE_FIBRE_SHARE`):

    * ``hair.denoise_neighbours``: :data:`DENSE_MESH_NEIGHBOURS` (128) on dense hair,
      else 0; and, where ``hair.chiang.exitance`` was "auto" (``exitance_auto``) and the
      strand texels are now denoised, the exitance chosen again by
      :func:`chiang_exitance` (second order where its memory estimate fits, its
      near-field rows and entries counted at ``density``'s shares);
    * then ``hair.gather_rays``: :data:`DENSE_MESH_RAYS` (128) on dense hair where the
      bake's memory estimate with them fits ``limit_bytes``, else
      ``transport.gather_rays``.

    Measured on the 10k curly head (share 0.68, docs/hair.md "Dense hair with a mesh:
    second order, denoised"): its light strand texels 11.7 % per texel with linear
    exitance denoised (k = 64), 8.5 % with the second order, 7.5 % with k = 128, the
    bias within 1.3 %; dark hair 8.7 % at k = 128, 7.6 % with 128 fibre rays. On 500
    sparse strands the filter bent 2–4 points of bias in, and undenoised the second
    order is noisier than linear. Returns the spec and the lines saying what was chosen
    and why; any other value of the keys comes back as it is."""
    share = density.fibre_share
    dense = share >= SPARSE_FIBRE_SHARE
    how = (f"{share:.0%} of the fibre gather's rays meet another fibre "
           f"({'dense' if dense else 'sparse'} hair from {SPARSE_FIBRE_SHARE:.0%})")
    lines = []
    if spec.hair.denoise_neighbours == "auto":
        k = DENSE_MESH_NEIGHBOURS if dense else 0
        spec = dataclasses.replace(spec, hair=dataclasses.replace(
            spec.hair, denoise_neighbours=k))
        lines.append(f"hair.denoise_neighbours auto → {k}: {how}")
        if k and exitance_auto:
            spec, why = chiang_exitance(asset, space, _with_exitance(spec, "auto"),
                                        limit_bytes, mesh_texels, density)
            lines.append(why or f"hair.chiang.exitance auto → "
                                f"{spec.hair.chiang.exitance}: the strand texels are "
                                "denoised")
    if spec.hair.gather_rays == "auto":
        rays = spec.transport.gather_rays
        why = "sparse hair: transport.gather_rays"
        if dense and DENSE_MESH_RAYS > rays:
            more = dataclasses.replace(spec, hair=dataclasses.replace(
                spec.hair, gather_rays=DENSE_MESH_RAYS))
            try:
                check_hair_memory(asset, space, more, limit_bytes, mesh_texels=mesh_texels,
                                  density=density)
                rays, why = DENSE_MESH_RAYS, "dense hair (the atlas keeps transport's)"
            except LimitExceeded as e:
                why = (f"dense hair, but with {DENSE_MESH_RAYS} rays {e.what} (limit "
                       f"{e.limit}); transport.gather_rays")
        elif dense:
            why = "dense hair: transport.gather_rays, already as many"
        spec = dataclasses.replace(spec, hair=dataclasses.replace(spec.hair,
                                                                  gather_rays=rays))
        lines.append(f"hair.gather_rays auto → {rays}: {why}")
    return spec, lines


def _transport_and_fit(spec: BakeSpec, intake, tracer, fibres, m: Method,
                       timer: StageTimer) -> tuple[BakeInputs, Any]:
    """One pass of a hair bake after its intake: the lights sampled from ``spec.lights``,
    the transport (hair alone, hair + mesh, either fibre), the strand texels' denoising
    and the atlas filter, and the method's fit. Returns (the fit's inputs, its
    result)."""
    space, hair, scene = intake.strands, intake.hair, intake.scene
    with timer.stage("lights"):
        b = hair.bounds()
        if scene is not None:
            b = np.stack([np.minimum(b[0], scene.bounds[0]), np.maximum(b[1], scene.bounds[1])])
        center, radius = b.mean(axis=0), float(np.linalg.norm(b[1] - b[0]) / 2)
        # the mesh's own lights (KHR_lights_punctual) serve families with from_asset
        train, hold = sample_configurations(spec.lights, center, radius,
                                            scene.lights if scene is not None else ())
    fibre = None
    if spec.hair.fibre == "chiang":
        check_lights((*train, *hold))  # before any ray is traced
        fibre = chiang_fibre(spec.hair.chiang, space)
    # the hair's own rays (hair alone: its one gather) and bounces
    rays = fibre_gather_rays(spec)
    transport = dataclasses.replace(spec.transport, max_bounces=spec.hair.max_bounces)
    if scene is None:
        transport = dataclasses.replace(transport, gather_rays=rays)
        data: Dataset = bake_hair_dataset(space, intake.points, tracer, train, hold,
                                          transport, timer,
                                          harmonics=spec.hair.harmonics,
                                          keep_direct_texels=False, fibre=fibre,
                                          chiang_exitance=spec.hair.chiang.exitance,
                                          direct_estimator=spec.hair.direct,
                                          direct_samples=spec.hair.direct_samples)
    elif fibre is not None:
        data = bake_chiang_hair_mesh_dataset(scene, intake.texels.mesh, space, fibres,
                                             intake.points, tracer, train, hold,
                                             transport, timer, fibre,
                                             exitance=spec.hair.chiang.exitance,
                                             fibre_rays=rays,
                                             near_fibres=spec.hair.chiang.near_fibres,
                                             direct_samples=spec.hair.direct_samples,
                                             shaded_fibres=spec.hair.chiang.shaded_fibres,
                                             gathered_fibres=spec.hair.chiang.gathered_fibres)
    else:
        data = bake_hair_mesh_dataset(scene, intake.texels.mesh, space, fibres, intake.points,
                                      tracer, train, hold, transport, timer,
                                      harmonics=spec.hair.harmonics,
                                      direct_estimator=spec.hair.direct,
                                      direct_samples=spec.hair.direct_samples,
                                      arc_subdivision=spec.hair.arc_subdivision,
                                      fibre_rays=rays)
    data = denoise_dataset(data, space, spec.hair.denoise_neighbours,
                           albedo=None if fibre is None else texel_albedo(fibre),
                           first_row=intake.texels.mesh.count if scene is not None else 0,
                           timer=timer, threads=tracer.threads,
                           direction=spec.hair.denoise_direction)
    indirect = None
    if scene is not None:  # the atlas rows filtered here (the fit's own filter would run
        # over the strand rows too), and handed to the fit as the lightmaps it fits
        data = denoise_atlas(data, intake.texels.mesh, spec.fit.denoise, timer)
        if spec.fit.denoise > 0:
            indirect = (data.indirect[:, :len(train)], data.indirect[:, len(train):])
    inputs = BakeInputs(spec=spec, intake=intake, train=train, hold=hold, keyframes=None,
                        data=data, indirect=indirect)
    return inputs, m.fit(inputs, timer)


def _transfer_failed(spec: BakeSpec, verdict: dict) -> bool:
    """Whether ``verdict`` failed because the transfer is more than
    ``validate.target_ratio`` × the projection bound (what more points or lights mend)."""
    ratio = verdict.get("ratio")
    return verdict.get("status") == "fail" and ratio is not None and \
        ratio > spec.validate.target_ratio


def _more_points(inputs: BakeInputs, result, tracer, m: Method, timer: StageTimer
                 ) -> tuple[BakeInputs, Any]:
    """A bake whose ``measurement_points.count`` was "auto" and whose verdict failed on the
    transfer's ratio (:func:`_transfer_failed`) is fitted again on twice the measurement
    points, up to :data:`MAX_AUTO_POINTS`, until it passes. The texels' light does not
    depend on the points, so no transport runs again: the points are placed afresh on the
    hull (:func:`hair_points` with 2P, the placement a spec asking for 2P gets) and only
    their direct light is computed, for every light
    (:func:`~prtcore.transport.dataset.direct_at_points`, the transport's own). The fit with
    the lowest ratio ships (the last when none is judged); ``stats["points_tried"]`` lists
    every fit. Returns (inputs, result) unchanged when the first fit passes.

    Measured (docs/hair.md, "More measurement points, no more transport"): the 10k
    hairball with the Chiang fibre, denoised, fails at 1.37× on 256 points and passes at
    1.17× on 1024; its held-out error goes from 12.4 % to 10.7 % at n = 16."""
    spec = inputs.spec
    if not _transfer_failed(spec, result.verdict):
        return inputs, result
    intake = inputs.intake
    tried = [_tried(spec, result)]
    best = (inputs, result)
    while _transfer_failed(spec, result.verdict) and \
            2 * spec.measurement_points.count <= MAX_AUTO_POINTS:
        ratio, count = result.verdict["ratio"], spec.measurement_points.count
        spec = dataclasses.replace(spec, measurement_points=dataclasses.replace(
            spec.measurement_points, count=2 * count))
        timer.note(f"[prtcore] points             {count} → {2 * count}: the verdict failed "
                   f"at {ratio:.2f}× the projection bound; fitted again on twice the "
                   "measurement points (their direct light only: the texels' light does "
                   "not depend on them)")
        points = hair_points(intake.hair, intake.scene, spec, timer)
        direct = direct_at_points(intake.scene, tracer, inputs.data.lights, points, timer)
        intake = dataclasses.replace(intake, spec=spec, points=points)
        inputs = dataclasses.replace(inputs, spec=spec, intake=intake,
                                     data=dataclasses.replace(inputs.data,
                                                              direct_points=direct))
        result = m.fit(inputs, timer)
        tried.append(_tried(spec, result))
        if _ratio(result) < _ratio(best[1]):
            best = (inputs, result)
    inputs, result = best
    return dataclasses.replace(inputs, data=dataclasses.replace(
        inputs.data, stats={**inputs.data.stats, "points_tried": tried})), result


def tried_line(transport: dict) -> str:
    """report.txt's line for a hair bake fitted more than once (``transport``: report.json's
    ``transport``, with ``points_tried`` and / or ``lights_tried``), e.g. ``fitted on:
    256 points × 512 lights fail 1.37× → 512 × 512 fail 1.28× → 1024 × 512 pass 1.17×``."""
    tries = list(transport.get("points_tried") or transport.get("lights_tried", [])[:1])
    tries += list(transport.get("lights_tried", [])[1:])

    def one(i: int, t: dict) -> str:
        ratio = "" if t.get("ratio") is None else f" {t['ratio']:.2f}×"
        size = (f"{t['points']} points × {t['lights']} lights" if i == 0
                else f"{t['points']} × {t['lights']}")
        return f"{size} {t.get('status')}{ratio}"

    return "fitted on: " + " → ".join(one(i, t) for i, t in enumerate(tries))


def _ratio(result) -> float:
    """The verdict's ratio to the projection bound; inf where it could not be judged."""
    ratio = result.verdict.get("ratio")
    return np.inf if ratio is None else ratio


def _tried(spec: BakeSpec, result) -> dict:
    return {"lights": spec.lights.count, "points": spec.measurement_points.count,
            "status": result.verdict.get("status"), "ratio": result.verdict.get("ratio")}


def _more_lights(spec: BakeSpec, verdict: dict, asset, space: StrandSpace,
                 limits: IntakeLimits, mesh_texels: int,
                 density: HairDensity | None = None) -> BakeSpec | None:
    """The spec of a second pass with twice the training lights, or None. A bake whose
    ``lights.count`` was "auto" and whose verdict failed because the transfer is more than
    ``validate.target_ratio`` × the projection bound (after :func:`_more_points`, when the
    points were "auto" too) bakes once more with 2K lights on the same points, if the
    memory estimate at 2K is within the limit. Measured: the 2000-strand
    head with its mesh fails at 1.27–1.28× with 256 lights and passes at 1.19× with 512
    (docs/hair.md, "Sparse hair takes every fibre's harmonics"); a 5000-strand head fails
    at 1.31× and still at 1.27× with 512 lights on 256 points, and passes at 1.18× on 512
    ("Transporting each texel in pieces")."""
    if not _transfer_failed(spec, verdict):
        return None
    more = dataclasses.replace(spec, lights=dataclasses.replace(
        spec.lights, count=2 * spec.lights.count))
    try:
        check_hair_memory(asset, space, more, limits.max_bake_bytes, mesh_texels=mesh_texels,
                          density=density)
    except LimitExceeded:
        return None
    return more


def _mesh_sections(tmp: Path, scene, texels: CombinedSpace, result, spec: BakeSpec,
                   asset: str | Path, mesh: str | Path, source_name: str | None,
                   hair: Hair) -> dict:
    """A hair + mesh bundle's own files and manifest sections: ``asset.glb`` (the mesh as
    baked, with its TEXCOORD_1), the strand texture's basis (``strand_basis_XX.exr``, the
    same planes as the atlas's ``basis_XX.exr``: one transfer drives both) and
    ``strand_coverage.exr``; ``asset`` names both files, ``atlas`` is the mesh's lightmap,
    ``strands`` the strand texture's layout, sampling rule and files."""
    from prtcore.io.gltf.export import write_glb
    write_glb(scene, tmp / "asset.glb")
    model = result.model
    planes = basis_planes(model.mean, model.basis, model.channels)
    img = texels.strand_image(planes)
    files = write_basis_files(tmp, img[:, :, :planes.shape[1]], spec.output.dtype,
                              prefix="strand_basis")
    write_exr(tmp / "strand_coverage.exr", img[:, :, -1:], dtype="half",
              channel_names=("Y",))
    return {
        "asset": {"source": source_name or Path(str(mesh)).name,
                  "sha256": sha256_file(Path(mesh)), "file": "asset.glb",
                  "triangles": scene.triangle_count,
                  "hair": {"source": Path(str(asset)).name,
                           "sha256": sha256_file(Path(asset)), "file": "asset.hair",
                           "strands": hair.strand_count, "points": hair.point_count}},
        "units": {"length": "m", "up": "+Y", "handedness": "right",
                  "radiance": "linear RGB outgoing radiance (albedo/pi * E); on strands "
                              "averaged over the fibre's azimuth and the texel's arc "
                              "interval"},
        "atlas": atlas_section(texels.mesh, spec.atlas.padding),
        "strands": {**texels.strands.layout(), "basis_files": files,
                    "coverage": "strand_coverage.exr",
                    "covered_texels": texels.strands.count,
                    "planes": "the atlas basis's planes (basis.plane_element, "
                              "basis.plane_channel), stored in the strand texture"},
    }
