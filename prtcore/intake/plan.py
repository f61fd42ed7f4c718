"""The planner: which stages an asset needs under a spec, and why (docs/architecture.md).

Cheap: it inspects the mesh (:func:`prtcore.intake.mesh.inspect_mesh`), checks TEXCOORD_1
(:func:`prtcore.intake.uv.check_uv1`, on the repaired mesh when repair will run) and looks at
animations. This is the single place where decisions are made;
:func:`prtcore.intake.prepare.prepare_scene` executes the plan.

>>> print(plan.format())                                    # doctest: +SKIP
repair    skip — mesh clean
remesh    skip — not requested
uv        generate — TEXCOORD_1 missing
keyframes skip — asset has no animation
texels    run — 512×512 atlas, padding 4
...
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from prtcore.core.errors import AssetError, SpecError
from prtcore.core.scene import Scene
from prtcore.core.spec import BakeSpec
from prtcore.intake.mesh import MeshHealth, inspect_mesh, repair_scene
from prtcore.intake.uv import UVCheck, check_uv1


@dataclass(frozen=True)
class StagePlan:
    """One stage: ``action`` is "run" | "skip" | "generate" | "keep"; ``reason`` says why."""

    name: str
    action: str
    reason: str


@dataclass(frozen=True)
class Sizing:
    """How many measurement points P and training lights K the bake uses, resolved from
    the spec's counts (``"auto"`` or numbers) by :func:`decide_sizing`; carried out by
    :mod:`prtcore.sizing`.

    placement : "surface" | "hull" | "qdeim" (the spec's "auto" resolved)
    candidates : points the intake places (blue noise); equal to the largest of ``points``
        when nothing is chosen after transport
    points : the P values tried, ascending (one value: P is fixed)
    select : the points are chosen from the candidates after transport (qdeim, or nested
        farthest-point subsets of the blue-noise candidates for "surface" / "hull")
    lights_start, lights_max : K of the first transport pass and the most it may grow to
        (equal: K is fixed)
    max_seconds : transport time budget for growing K (0: none)
    grow_candidates : more candidates (2P) are placed when P outgrows them (count "auto"
        without measurement_points.candidates)
    reason : one line for the plan
    """

    placement: str
    candidates: int
    points: tuple[int, ...]
    select: bool
    lights_start: int
    lights_max: int
    max_seconds: float
    reason: str
    grow_candidates: bool = False

    @property
    def candidate_placement(self) -> str:
        """How candidates are placed: blue noise on the surface for "qdeim"."""
        return "surface" if self.placement == "qdeim" else self.placement

    @property
    def automatic(self) -> bool:
        """Whether anything is chosen from the data (P or K not fixed)."""
        return len(self.points) > 1 or self.lights_max > self.lights_start


#: the smallest P automatic sizing tries; P doubles from here to sizing.max_points. The
#: fixed default before automatic sizing: a smaller P that barely meets the target ships a
#: worse bake than the old default did (open room, 128 points: 1.23× the bound, 8.9 %;
#: 256 blue-noise points: 1.05×, 8.2 %), for a negligible saving at run time
AUTO_POINTS_START = 256
#: P and K a bake uses for "auto" where sizing does not run (keyframe and hair bakes)
FIXED_POINTS, FIXED_LIGHTS = 256, 128


def fixed_counts(spec: BakeSpec) -> BakeSpec:
    """``spec`` with "auto" counts replaced by FIXED_POINTS / FIXED_LIGHTS, for bakes that
    do not size themselves (hair bakes)."""
    mp, lt = spec.measurement_points, spec.lights
    return dataclasses.replace(
        spec,
        measurement_points=dataclasses.replace(
            mp, count=FIXED_POINTS if mp.count == "auto" else mp.count),
        lights=dataclasses.replace(lt, count=FIXED_LIGHTS if lt.count == "auto"
                                   else lt.count))


@dataclass(frozen=True)
class Plan:
    """The stages in execution order, plus what the decisions were based on."""

    stages: tuple[StagePlan, ...]
    health: MeshHealth | None = None
    uv_check: UVCheck | None = None
    sizing: Sizing | None = None

    def format(self) -> str:
        """One line per stage: ``name action — reason``."""
        return "\n".join(f"{s.name:<9s} {s.action} — {s.reason}" for s in self.stages)

    def stage(self, name: str) -> StagePlan:
        """The stage called ``name`` (KeyError when absent)."""
        for s in self.stages:
            if s.name == name:
                return s
        raise KeyError(name)


# ---------------------------------------------------------------------------------------
# Decisions shared with prepare_scene


def decide_repair(health: MeshHealth, spec: BakeSpec) -> StagePlan:
    """Repair when the spec forces it, or ("auto") when the mesh has something to remove."""
    mode = spec.prepare.repair
    if mode == "never":
        found = "" if not health.needs_repair else f" ({health.describe()} left as is)"
        return StagePlan("repair", "skip", "disabled by spec prepare.repair = never" + found)
    if mode == "always":
        return StagePlan("repair", "run", "forced by spec prepare.repair = always"
                         + ("" if not health.needs_repair else f": {health.describe()}"))
    if health.needs_repair:
        return StagePlan("repair", "run", health.describe())
    return StagePlan("repair", "skip", "mesh clean")


def decide_remesh(spec: BakeSpec) -> StagePlan:
    if spec.prepare.remesh is None:
        return StagePlan("remesh", "skip", "not requested")
    return StagePlan("remesh", "run", f"requested: target edge {spec.prepare.remesh:g} × "
                     "bounding-box diagonal (drops TEXCOORD_1)")


def decide_uv(check: UVCheck | None, spec: BakeSpec, source: str = "",
              remeshed: bool = False) -> StagePlan:
    """Keep a valid TEXCOORD_1 or generate one; refuse ("keep") when it cannot be kept.

    check : the TEXCOORD_1 check of the (repaired) scene, None when remeshing will run.
    Raises :class:`SpecError` for ``keep`` with remeshing and :class:`AssetError` naming
    TEXCOORD_1 for ``keep`` with missing or invalid UVs.
    """
    mode = spec.prepare.uv
    if remeshed or check is None:
        if mode == "keep":
            raise SpecError("prepare.uv", "'keep' conflicts with prepare.remesh (remeshing "
                            "drops TEXCOORD_1)")
        return StagePlan("uv", "generate", "remeshing drops TEXCOORD_1")
    if mode == "generate":
        return StagePlan("uv", "generate", "forced by spec prepare.uv = generate")
    if check.valid:
        return StagePlan("uv", "keep", f"TEXCOORD_1 {check.reason}")
    if mode == "keep":
        raise AssetError(source, "TEXCOORD_1", f"cannot keep the lightmap UVs "
                         f"(spec prepare.uv = keep): {check.reason}")
    if not check.present:
        return StagePlan("uv", "generate", "TEXCOORD_1 missing")
    return StagePlan("uv", "generate", f"TEXCOORD_1 invalid: {check.reason}")


def animation_index(scene: Scene, spec: BakeSpec) -> int | None:
    want = spec.keyframes.animation
    if want is None:
        return None
    n = len(scene.animations)
    if isinstance(want, str):
        names = [a.name for a in scene.animations]
        if want not in names:
            raise SpecError("keyframes.animation", f"asset has no animation named {want!r} "
                            f"(it has {', '.join(map(repr, names)) or 'none'})")
        return names.index(want)
    if not 0 <= want < n:
        raise SpecError("keyframes.animation", f"asset has {n} animations, no index {want}")
    return int(want)


def decide_keyframes(scene: Scene, spec: BakeSpec) -> StagePlan:
    """Keyframe sets only when the spec names an animation the asset has."""
    idx = animation_index(scene, spec)
    if idx is None:
        if not scene.animations:
            return StagePlan("keyframes", "skip", "asset has no animation")
        n = len(scene.animations)
        return StagePlan("keyframes", "skip", f"static bake: spec keyframes.animation not "
                         f"set (asset has {n} animation{'s' if n > 1 else ''})")
    anim = scene.animations[idx]
    k = spec.keyframes
    count = len(k.times) if k.times is not None else k.count
    return StagePlan("keyframes", "run", f"animation {idx} {anim.name!r} "
                     f"({anim.duration:g} s), {count} keyframes, transfer {k.transfer}")


def decide_sizing(spec: BakeSpec, keyframed: bool) -> Sizing:
    """Resolve the spec's P, K and placement ("auto" or given) for a static or keyframe
    bake (keyframe bakes take fixed FIXED_POINTS / FIXED_LIGHTS for "auto": their
    per-pose transport is not grown)."""
    mp, lt, z = spec.measurement_points, spec.lights, spec.sizing
    p_auto, k_auto = mp.count == "auto", lt.count == "auto"
    placement = mp.placement
    if placement == "auto":  # chosen for the transfer when the bake chooses P
        placement = "qdeim" if p_auto and not keyframed else "surface"
    why = []
    if keyframed:
        if placement == "qdeim":
            raise SpecError("measurement_points.placement", "'qdeim' is not available for "
                            "keyframe bakes yet (use 'surface')")
        points = (FIXED_POINTS if p_auto else int(mp.count),)
        k0 = k1 = FIXED_LIGHTS if k_auto else int(lt.count)
        if p_auto or k_auto:
            why.append(f"keyframe bake: auto counts are P = {FIXED_POINTS}, "
                       f"K = {FIXED_LIGHTS} (no sizing)")
    else:
        if p_auto:
            top = max(z.max_points, 1)
            points = (*(p for p in (AUTO_POINTS_START << i for i in range(21)) if p < top),
                      top)
        else:
            points = (int(mp.count),)
        k0, k1 = (z.lights_start, z.max_lights) if k_auto else (int(lt.count),) * 2
    select = not keyframed and (placement == "qdeim" or len(points) > 1)
    grow = select and p_auto and not mp.candidates
    if grow:  # 2P for the first P tried; more when P outgrows them (prtcore/sizing.py)
        candidates = 2 * points[0]
    elif select:
        candidates = mp.candidates or (2 * points[-1] if p_auto else 8 * points[-1])
        candidates = max(candidates, points[-1])
    else:
        candidates = points[-1]
    if not keyframed:
        p_txt = (f"P ∈ {{{', '.join(map(str, points))}}}" if len(points) > 1
                 else f"P = {points[0]}")
        k_txt = f"K from {k0} up to {k1}" if k1 > k0 else f"K = {k0}"
        if p_auto or k_auto:
            why.append(f"auto: {p_txt}, {k_txt} until the held-out error is within "
                       f"{spec.validate.target_ratio:g}× the projection bound"
                       + (f" (transport budget {z.max_seconds:g} s)" if k1 > k0 else ""))
    return Sizing(placement=placement, candidates=int(candidates), points=points,
                  select=select, lights_start=int(k0), lights_max=int(k1),
                  max_seconds=float(z.max_seconds), reason="; ".join(why),
                  grow_candidates=grow)


# ---------------------------------------------------------------------------------------
# The plan


def plan_asset(scene: Scene, spec: BakeSpec) -> Plan:
    """The stages this asset needs under ``spec`` and why (no heavy work is done).

    Raises :class:`SpecError` for an animation the asset lacks or for ``keep`` with
    remeshing, and :class:`AssetError` (TEXCOORD_1) for ``keep`` with unusable UVs.
    """
    R, pad = spec.atlas.resolution, spec.atlas.padding
    health = inspect_mesh(scene)
    repair = decide_repair(health, spec)
    remesh = decide_remesh(spec)
    check = None
    if remesh.action != "run":
        after = scene
        if repair.action == "run" and health.needs_repair:
            after, _ = repair_scene(scene)
        check = check_uv1(after, R, pad)
    uv = decide_uv(check, spec, scene.source, remeshed=remesh.action == "run")
    keyframes = decide_keyframes(scene, spec)
    sizing = decide_sizing(spec, keyframes.action == "run")

    mp, lt, tr, fit = spec.measurement_points, spec.lights, spec.transport, spec.fit
    types = sorted({f.type for f in lt.families})
    fams = f"{len(lt.families)} famil{'y' if len(lt.families) == 1 else 'ies'}"
    gamma = "" if fit.gamma is None else f", gamma {fit.gamma:g}"
    near = f"within {tr.near_field:g}× the texel footprint" if tr.near_field > 0 else "off"
    stages = [
        repair, remesh, uv, keyframes,
        StagePlan("texels", "run", f"{R}×{R} atlas, padding {pad}"),
        StagePlan("points", "run", (
            f"{sizing.candidates} blue-noise candidates"
            + (" (2P as P grows)" if sizing.grow_candidates else "")
            + f", P chosen after transport ({sizing.placement})" if sizing.select else
            f"{sizing.points[0]} measurement points, {sizing.placement}")
            + f", supersample {mp.supersample}"),
        StagePlan("lights", "run", (
            f"{sizing.lights_start}–{sizing.lights_max}" if sizing.lights_max >
            sizing.lights_start else f"{sizing.lights_start}")
            + f" lights + {lt.holdout} held out, {fams} ({', '.join(types)})"),
        StagePlan("transport", "run", f"{tr.gather_rays} gather rays, "
                  f"{tr.direct_samples} direct samples per texel, near field {near}, "
                  f"≤ {tr.max_bounces} bounces, tolerance {tr.tolerance:g}"),
        StagePlan("fit", "run", f"basis {fit.basis}, ridge {fit.ridge}, {fit.channels}{gamma}"),
        StagePlan("export", "run", f"bundle with {spec.output.dtype} EXRs"),
    ]
    if sizing.automatic:
        stages.insert(stages.index(keyframes) + 1, StagePlan("sizing", "run", sizing.reason))
    if lt.holdout > 0:
        stages.append(StagePlan("validate", "run", f"{lt.holdout} held-out lights against "
                                "the reference"))
    else:
        stages.append(StagePlan("validate", "skip", "no held-out lights (lights.holdout = 0)"))
    return Plan(stages=tuple(stages), health=health, uv_check=check, sizing=sizing)
