"""The pipeline: stages wired in order, each timed, skipped when the plan says so.

The CLI, the service workers and the benchmarks all call these functions.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

from prtcore.core.limits import IntakeLimits
from prtcore.core.progress import ProgressCallback, StageTimer
from prtcore.core.scene import Scene
from prtcore.core.spec import BakeSpec, PointsSpec
from prtcore.intake.plan import Plan, Sizing
from prtcore.intake.points import MeasurementPoints
from prtcore.intake.prepare import PrepareReport
from prtcore.receivers.texels import TexelSpace
from prtcore.transport.dataset import STAGES as TRANSPORT_STAGES

#: timed stages of :func:`run_intake`, in the order they run (repair, remesh and uv are
#: the plan's prepare steps; each is run or recorded as skipped)
INTAKE_STAGES = ("load", "plan", "repair", "remesh", "uv", "texels", "points")

#: every timed stage of :func:`bake`, in the order they run: the one list progress reports
#: (the service's workers) and benchmarks use
STAGES = (*INTAKE_STAGES, "lights", "keyframes", *TRANSPORT_STAGES, "transport noise",
          "select points", "denoise",
          "fit", "report", "export", "validate")


@dataclass(frozen=True)
class IntakeResult:
    """Everything up to measurement points: the input of transport."""

    source: str
    spec: BakeSpec
    plan: Plan
    scene: Scene
    prepare: PrepareReport
    texels: TexelSpace
    points: MeasurementPoints
    seconds: dict[str, float]

    def summary(self) -> str:
        w, h = self.texels.width, self.texels.height
        lines = [
            f"asset      {self.source}",
            f"triangles  {self.scene.triangle_count}",
            f"uv         {self.prepare.uv_action} ({self.prepare.uv_reason}); utilisation "
            f"{self.prepare.utilisation:.1%}, {self.prepare.texel_density:.1f} texels/m",
            f"texels     {self.texels.count} covered of {w}×{h}, "
            f"{len(self.texels.dilate_xy)} dilated",
            f"points     {self.points.count} measurement points ({self.points.placement}), "
            f"{len(self.points.cluster_owner)} supersamples",
            "stages     " + ", ".join(f"{k} {v:.2f} s" for k, v in self.seconds.items()),
        ]
        return "\n".join(lines)


def run_intake(asset: str | Path, spec: BakeSpec, *, quiet: bool = False,
               limits: IntakeLimits | None = None,
               callback: ProgressCallback | None = None,
               timer: StageTimer | None = None) -> IntakeResult:
    """load → plan → prepare (repair / remesh / uv) → texel space → measurement points."""
    from prtcore.intake.plan import plan_asset
    from prtcore.intake.points import place_measurement_points
    from prtcore.intake.prepare import prepare_scene
    from prtcore.io.gltf.loader import load_asset
    from prtcore.receivers.texels import build_texel_space

    timer = timer or StageTimer(quiet=quiet, callback=callback)
    limits = limits or IntakeLimits.from_env()
    limits.check_spec(spec)
    with timer.stage("load"):
        scene = load_asset(asset, limits)
    with timer.stage("plan"):
        plan = plan_asset(scene, spec)
    scene, report = prepare_scene(scene, spec, timer=timer, plan=plan)
    with timer.stage("texels"):
        texels = build_texel_space(scene, spec.atlas.resolution, spec.atlas.resolution,
                                   padding=spec.atlas.padding)
    with timer.stage("points"):
        points = place_measurement_points(scene, intake_points(spec.measurement_points,
                                                               plan.sizing))
    return IntakeResult(source=str(asset), spec=spec, plan=plan, scene=scene, prepare=report,
                        texels=texels, points=points, seconds=dict(timer.seconds))


# ---------------------------------------------------------------------------------------
# The whole bake

#: Files that describe the run rather than the result: left out of the checksums, so two
#: bakes of the same asset + spec + seed have identical checksummed files.
RUN_FILES = ("report.json", "report.png", "report.txt", "report_worst.png", "report_atlas.png",
             "manifest.json")


def bake(asset: str | Path, spec: BakeSpec, out: Path, *, quiet: bool = False,
         force: bool = False, limits: IntakeLimits | None = None,
         callback: ProgressCallback | None = None, source_name: str | None = None,
         mesh: str | Path | None = None) -> Path:
    """asset + spec → bundle directory ``out`` (docs/bundle.md). Returns ``out``.
    mesh : a hair asset only: a glTF mesh (a head) baked together with the hair, light
    going both ways (docs/hair.md).

    Stages: intake → lights → keyframes → transport → the method's fit and report →
    export. The method (:mod:`prtcore.methods`) writes its own files and manifest
    sections; this function writes the asset and the sections every bundle has.
    source_name : the asset's name as its owner knows it (the service stores uploads
    under a fixed name); the manifest's ``asset.source``, default the file's name.
    """
    import time

    from prtcore.core.spec import spec_hash, spec_to_dict
    from prtcore.emitters.families import sample_configurations
    from prtcore.io.bundle import (
        atlas_section,
        check_output,
        manifest_base,
        sha256_file,
        write_bundle,
    )
    from prtcore.io.gltf.export import write_glb
    from prtcore.io.hair import is_hair_file
    from prtcore.methods.base import BakeInputs, method
    from prtcore.report import preload_plotting
    from prtcore.sizing import size_bake
    from prtcore.transport.dataset import (
        check_bake_memory,
        light_configurations,
        open_transport,
        operators_for,
    )
    from prtcore.transport.noise import (
        DENOISE_FALLBACK,
        measure_noise,
        noise_line,
        with_denoise,
    )

    if is_hair_file(asset):  # strands instead of a lightmap (docs/hair.md)
        from prtcore.hairbake import bake_hair

        out, m, result, seconds, validation = bake_hair(
            asset, spec, out, run_files=_write_run_files, exclude=RUN_FILES, quiet=quiet,
            force=force, limits=limits, callback=callback, source_name=source_name,
            mesh=mesh, mesh_intake=run_intake, validate=_validate(spec))
        _finish_run_files(out, m, result, seconds, validation)
        if not quiet:
            print(m.summary(result, seconds, with_verdict=False))
        return out
    if mesh is not None:
        from prtcore.core.errors import PrtError

        raise PrtError(f"bake --mesh: {Path(str(asset)).name} is not a hair asset; a mesh "
                       "is baked together with hair (.hair, .usd, .usda, .usdc) only")
    check_output(out, force, inputs=(asset,))  # before any work: nothing lost, nothing wasted
    t_start = time.perf_counter()
    timer = StageTimer(quiet=quiet, callback=callback)
    intake = run_intake(asset, spec, timer=timer, limits=limits)
    scene, texels, points = intake.scene, intake.texels, intake.points
    sizing = intake.plan.sizing
    limit_bytes = (limits or IntakeLimits.from_env()).max_bake_bytes
    check_bake_memory(asset, texels, spec, limit_bytes, operators_for(scene),
                      training=sizing.lights_start)

    with timer.stage("lights"):  # a prefix-stable draw: sizing may take more of the pool
        pool, hold = sample_configurations(
            dataclasses.replace(spec.lights, count=sizing.lights_max), scene.center,
            scene.radius, scene.lights)
        train = pool[:sizing.lights_start]
    m = method(spec.method.name)
    preload_plotting()  # the report's figures: imported while the transport runs
    kfs, data = None, None
    record = indirect = models = noise = None
    fit_spec = with_denoise(spec, DENOISE_FALLBACK)  # unless measured below
    if m.needs_dataset:
        kfs = _keyframe_set(intake, len(train), len(hold), timer)
        if kfs is None:
            transport = open_transport(scene, texels, points, spec.transport, timer)
            # the texels' direct light serves the solve only: the solve writes over it
            data = light_configurations(transport, (*train, *hold), len(train), timer,
                                        keep_direct_texels=False)
            if not sizing.automatic:  # nothing lights more configurations on the operators:
                transport = transport.without_operators()  # freed before the second trace
            if spec.fit.denoise == "auto" and len(hold):
                noise = measure_noise(transport, hold, data.indirect[:, len(train):], timer)
                fit_spec = with_denoise(spec, noise.radius)
                if not quiet:
                    print(f"transport noise: {noise_line(noise.to_dict())}")
            if sizing.automatic:
                sized = size_bake(fit_spec, sizing, transport, data, pool, len(hold),
                                  limit_bytes, timer)
                intake = dataclasses.replace(intake, points=sized.points)
                data, train, indirect = sized.data, sized.train, sized.indirect
                models = sized.models
                record = sized.to_dict(sizing)
                if not quiet:
                    print(f"sizing: {sized.stop}")
            elif sizing.select:
                intake, data = _select_points(intake, data, len(train), timer)
        else:
            from prtcore.keyframes.pose import bake_keyframe_dataset

            data = bake_keyframe_dataset(kfs, texels, train, hold, spec.transport, timer)
    inputs = BakeInputs(spec=fit_spec, intake=intake, train=train, hold=hold, keyframes=kfs,
                        data=data, indirect=indirect, sizing=record, models=models,
                        denoise_operator=None if noise is None else noise.operator)
    result = m.fit(inputs, timer)

    def write(tmp: Path) -> dict:
        write_glb(scene, tmp / "asset.glb")
        sections, report = m.write(tmp, inputs, result)
        if record is not None:
            report = {**report, "sizing": record}
        if noise is not None:
            report = {**report, "transport_noise": noise.to_dict()}
        _write_run_files(tmp, m, result, report, dict(timer.seconds), t_start)
        common = {
            "asset": {"source": source_name or Path(str(asset)).name,
                      "sha256": sha256_file(Path(asset)),
                      "file": "asset.glb", "triangles": scene.triangle_count},
            "units": {"length": "m", "up": "+Y", "handedness": "right",
                      "radiance": "linear RGB outgoing radiance (albedo/pi * E)",
                      "light_intensity": "KHR_lights_punctual: cd (point/spot), lux "
                                         "(directional), no 683 lm/W conversion"},
            "atlas": atlas_section(texels, spec.atlas.padding),
        }
        run = {
            "spec": spec_to_dict(spec), "spec_sha256": spec_hash(spec),
            "plan": [{"stage": s.name, "action": s.action, "reason": s.reason}
                     for s in intake.plan.stages],
            "prepare": _jsonable(intake.prepare.__dict__),
            "timings": dict(timer.seconds),
        }
        if record is not None:
            run["sizing"] = record
        if noise is not None:
            run["transport_noise"] = noise.to_dict()
        return manifest_base(method=m.name, **common, **sections, **run,
                             run_files=list(RUN_FILES))

    with timer.stage("export"):
        out = write_bundle(out, write, force=force, exclude=RUN_FILES, inputs=(asset,))
    validation = None
    if spec.validate.reference_spp > 0 and len(hold) and m.path_traced_validation:
        with timer.stage("validate"):  # the verdict against the path tracer, noise removed
            validation = _validate(spec)(out, timer)
        result = m.revalidate(result, inputs, validation)
    seconds = dict(timer.seconds)
    _finish_run_files(out, m, result, seconds, validation)  # export's time, once it ended
    if not quiet:
        print(m.summary(result, seconds, with_verdict=False))
    return out


def _validate(spec: BakeSpec):
    """``validate(bundle, timer)`` → :func:`prtcore.validate.validate_bundle` of the spec's
    ``validate`` section (the bake's held-out lights against the path tracer)."""
    def run(bundle: Path, timer) -> dict:
        from prtcore.validate import validate_bundle

        return validate_bundle(bundle, spec.validate.reference_spp,
                               count=spec.validate.reference_lights, timer=timer)
    return run


def _write_run_files(directory: Path, m, result, report: dict, seconds: dict[str, float],
                     t_start: float) -> None:
    """report.json / .txt / .png: what the run measured (not checksummed: RUN_FILES)."""
    import time

    full = {**report, "stage_seconds": seconds, "total_seconds": time.perf_counter() - t_start}
    (directory / "report.json").write_text(json.dumps(_jsonable(full), indent=2) + "\n")
    m.plot(result, directory / "report.png")
    (directory / "report.txt").write_text(m.summary(result, seconds) + "\n")


def _finish_run_files(out: Path, m, result, seconds: dict[str, float],
                      validation: dict | None = None) -> None:
    """Put the final stage times (export included), and the verdict against the path
    tracer when the spec asked for one, into the bundle's run files."""
    import os

    manifest = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    report = json.loads((out / "report.json").read_text(encoding="utf-8"))
    manifest["timings"] = report["stage_seconds"] = _jsonable(seconds)
    manifest["verdict"] = report["verdict"] = _jsonable(m.verdict(result))
    if validation is not None:
        report["validation"] = _jsonable(validation)
    for name, doc in (("manifest.json", manifest), ("report.json", report)):
        tmp = out / f".{name}.tmp"
        tmp.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        os.replace(tmp, out / name)
    text = m.summary(result, seconds)
    if report.get("sizing"):  # what automatic sizing chose and why (prtcore/sizing.py)
        text = f"sizing: {report['sizing']['reason']}\n{text}"
    if report.get("transport_noise"):  # the chosen filter (prtcore/transport/noise.py)
        from prtcore.transport.noise import noise_line

        text = f"transport noise: {noise_line(report['transport_noise'])}\n{text}"
    transport = report.get("transport") or {}
    if transport.get("points_tried") or transport.get("lights_tried"):  # a hair bake's
        from prtcore.hairbake import tried_line  # fits on more points or lights

        text = f"{tried_line(transport)}\n{text}"
    (out / "report.txt").write_text(text + "\n", encoding="utf-8")


def intake_points(points: PointsSpec, sizing: Sizing) -> PointsSpec:
    """What the intake places: the plan's candidates when points are chosen after
    transport (blue noise on the surface for "qdeim"), else the P points themselves."""
    return dataclasses.replace(points, placement=sizing.candidate_placement,
                               count=sizing.candidates)


def _select_points(intake: IntakeResult, data, n_train: int, timer: StageTimer):
    """Placement "qdeim": choose the spec's P of the candidates by pivoted QR on their
    training direct light (intake/sensors.py), after transport, whose direct values at the
    candidates are the chosen points' own (each point is its cluster's average); the same
    selection automatic sizing makes (:func:`prtcore.sizing.select_points`)."""
    from prtcore.intake.sensors import restrict_points
    from prtcore.sizing import select_points

    with timer.stage("select points"):
        rows = select_points(intake.points, data.direct_points[:, :n_train],
                             intake.plan.sizing.points[0], "qdeim",
                             intake.spec.measurement_points.seed)
        points = restrict_points(intake.points, rows)
        data = dataclasses.replace(data, direct_points=data.direct_points[rows])
    return dataclasses.replace(intake, points=points), data


def _keyframe_set(intake: IntakeResult, n_train: int, n_holdout: int, timer: StageTimer):
    """The keyframe set when the plan runs the keyframes stage, else None (static bake)."""
    if not any(s.name == "keyframes" and s.action == "run" for s in intake.plan.stages):
        return None
    from prtcore.keyframes.pose import build_keyframes

    with timer.stage("keyframes"):
        return build_keyframes(intake.scene, intake.points, intake.spec, n_train, n_holdout)


def _jsonable(x):
    """Plain JSON data from nested dicts/dataclasses/numpy values (non-finite → None)."""
    import dataclasses
    import math

    import numpy as np

    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return _jsonable(dataclasses.asdict(x))
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.generic):
        return _jsonable(x.item())
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    return x
