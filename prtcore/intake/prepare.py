"""The prepare stage: execute the plan's repair, remesh and uv steps (never decide).

:func:`prtcore.intake.plan.plan_asset` makes every decision; :func:`prepare_scene` runs
what it decided and reports what was done.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING

from prtcore.core.materials import apply_material_spec
from prtcore.core.scene import Scene
from prtcore.intake.mesh import MeshHealth, inspect_mesh, remesh_scene, repair_scene
from prtcore.intake.uv import UVCheck, check_uv1, generate_uv1

#: below this fraction of the atlas covered by charts, the bake warns (a truck at 192² with
#: padding 4 used 5 %: 3.3 texels per metre, silently)
UTILISATION_WARN = 0.2

if TYPE_CHECKING:
    from prtcore.core.progress import StageTimer
    from prtcore.core.spec import BakeSpec
    from prtcore.intake.plan import Plan

# ---------------------------------------------------------------------------------------
# The stage


@dataclass(frozen=True)
class PrepareReport:
    """What the prepare stage did and why (echoed in the manifest).

    repair_counts : see :func:`repair_scene`; seconds : per sub-step (inspect, repair,
    remesh, uv); utilisation, texel_density, charts : of the final TEXCOORD_1 (see
    :class:`UVCheck`); health : the input's :class:`MeshHealth`; uv_check : the final check.
    """

    repaired: bool
    repair_counts: dict
    remeshed: bool
    uv_action: str  # "kept" | "generated"
    uv_reason: str
    utilisation: float
    texel_density: float
    charts: int
    seconds: dict[str, float]
    warnings: tuple[str, ...] = ()
    health: MeshHealth | None = None
    uv_check: UVCheck | None = None
    repair_reason: str = ""


def prepare_scene(scene: Scene, spec: BakeSpec, timer: StageTimer | None = None, *,
                  plan: Plan | None = None) -> tuple[Scene, PrepareReport]:
    """Repair, remesh and lay out TEXCOORD_1 as :func:`prtcore.intake.plan.plan_asset` decides.

    Each sub-step is timed with ``timer.stage("repair" | "remesh" | "uv")`` or recorded as
    ``timer.skip(name, why)``; the mesh inspection is timed as "inspect". UV decisions are
    made on the scene *after* repair (duplicate faces can be the only reason UVs overlap).
    plan : the result of ``plan_asset(scene, spec)`` for this very scene and spec (computed
    here when not given): its decisions are executed, its mesh health and TEXCOORD_1 check
    reused. Prepare never decides.
    The spec's ``materials`` section is applied first
    (:func:`prtcore.core.materials.apply_material_spec`).
    Raises :class:`AssetError` naming TEXCOORD_1 when ``prepare.uv`` is "keep" and the UVs
    are missing or invalid.
    """
    from prtcore.core.progress import StageTimer
    from prtcore.intake.plan import plan_asset

    timer = timer if timer is not None else StageTimer(quiet=True)
    scene = apply_material_spec(scene, spec.materials)
    if plan is None:
        plan = plan_asset(scene, spec)
    seconds: dict[str, float] = {}
    warnings: list[str] = []
    R, pad = spec.atlas.resolution, spec.atlas.padding

    @contextmanager
    def timed(name):
        t0 = time.perf_counter()
        try:
            with timer.stage(name):
                yield
        finally:
            seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - t0

    if plan.health is not None:
        health = plan.health
    else:
        with timed("inspect"):
            health = inspect_mesh(scene)
    step = plan.stage("repair")
    repair_reason = step.reason
    counts: dict = {}
    repaired = False
    if step.action == "run":
        with timed("repair"):
            scene, counts = repair_scene(scene, force=spec.prepare.repair == "always")
        repaired = True
    else:
        timer.skip("repair", step.reason)
        if health.needs_repair:
            warnings.append(f"repair skipped ({step.reason}): {health.describe()}")
    if health.nonmanifold_edges:
        warnings.append(f"{health.nonmanifold_edges} non-manifold edges kept "
                        "(xatlas gives each fin its own chart)")

    step = plan.stage("remesh")
    remeshed = False
    if step.action == "run":
        n_warn = len(scene.warnings)
        with timed("remesh"):
            scene = remesh_scene(scene, float(spec.prepare.remesh))
        warnings.extend(scene.warnings[n_warn:])
        remeshed = True
    else:
        timer.skip("remesh", step.reason)

    check = None if remeshed else plan.uv_check  # computed on the same repaired faces
    step = plan.stage("uv")
    if step.action == "generate":
        with timed("uv"):
            scene = generate_uv1(scene, R, pad)
            check = check_uv1(scene, R, pad)
        uv_action = "generated"
        if not check.valid:
            warnings.append(f"generated TEXCOORD_1 failed its check: {check.reason}")
    else:
        timer.skip("uv", step.reason)
        uv_action = "kept"
    assert check is not None
    if check.min_padding_texels is not None and check.min_padding_texels < pad \
            and uv_action == "kept":
        warnings.append(f"kept TEXCOORD_1 has a min gap of {check.min_padding_texels:.2f} "
                        f"texels, below the requested padding {pad}")
    if check.utilisation < UTILISATION_WARN:
        warnings.append(f"the lightmap atlas is {100 * check.utilisation:.1f} % used "
                        f"({check.texel_density:.1f} texels/m, {check.charts} charts at "
                        f"{R}² with padding {pad}): raise atlas.resolution or lower "
                        "atlas.padding for more texels on the asset")
    report = PrepareReport(
        repaired=repaired, repair_counts=counts, remeshed=remeshed, uv_action=uv_action,
        uv_reason=step.reason, utilisation=check.utilisation,
        texel_density=check.texel_density, charts=check.charts, seconds=seconds,
        warnings=tuple(warnings), health=health, uv_check=check,
        repair_reason=repair_reason)
    return scene, report


