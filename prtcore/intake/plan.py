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
class Plan:
    """The stages in execution order, plus what the decisions were based on."""

    stages: tuple[StagePlan, ...]
    health: MeshHealth | None = None
    uv_check: UVCheck | None = None

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

    mp, lt, tr, fit = spec.measurement_points, spec.lights, spec.transport, spec.fit
    types = sorted({f.type for f in lt.families})
    fams = f"{len(lt.families)} famil{'y' if len(lt.families) == 1 else 'ies'}"
    gamma = "" if fit.gamma is None else f", gamma {fit.gamma:g}"
    near = f"within {tr.near_field:g}× the texel footprint" if tr.near_field > 0 else "off"
    stages = [
        repair, remesh, uv, keyframes,
        StagePlan("texels", "run", f"{R}×{R} atlas, padding {pad}"),
        StagePlan("points", "run", f"{mp.count} measurement points, {mp.placement}"
                  + (f" from {mp.candidates or 8 * mp.count} candidates after transport"
                     if mp.placement == "qdeim" else "")
                  + f", supersample {mp.supersample}"),
        StagePlan("lights", "run", f"{lt.count} lights + {lt.holdout} held out, {fams} "
                  f"({', '.join(types)})"),
        StagePlan("transport", "run", f"{tr.gather_rays} gather rays, "
                  f"{tr.direct_samples} direct samples per texel, near field {near}, "
                  f"≤ {tr.max_bounces} bounces, tolerance {tr.tolerance:g}"),
        StagePlan("fit", "run", f"basis {fit.basis}, ridge {fit.ridge}, {fit.channels}{gamma}"),
        StagePlan("export", "run", f"bundle with {spec.output.dtype} EXRs"),
    ]
    if lt.holdout > 0:
        stages.append(StagePlan("validate", "run", f"{lt.holdout} held-out lights against "
                                "the reference"))
    else:
        stages.append(StagePlan("validate", "skip", "no held-out lights (lights.holdout = 0)"))
    return Plan(stages=tuple(stages), health=health, uv_check=check)
