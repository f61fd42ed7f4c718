"""The pipeline: stages wired in order, each timed, skipped when the plan says so.

The CLI, the service workers and the benchmarks all call these functions.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from prtcore.core.limits import IntakeLimits
from prtcore.core.progress import ProgressCallback, StageTimer
from prtcore.core.scene import Scene
from prtcore.core.spec import BakeSpec
from prtcore.intake.plan import Plan
from prtcore.intake.points import MeasurementPoints
from prtcore.intake.prepare import PrepareReport
from prtcore.receivers.texels import TexelSpace
from prtcore.transport.dataset import STAGES as TRANSPORT_STAGES

#: timed stages of :func:`run_intake`, in the order they run (repair, remesh and uv are
#: the plan's prepare steps; each is run or recorded as skipped)
INTAKE_STAGES = ("load", "plan", "repair", "remesh", "uv", "texels", "points")

#: every timed stage of :func:`bake`, in the order they run: the one list progress reports
#: (the service's workers) and benchmarks use
STAGES = (*INTAKE_STAGES, "lights", "keyframes", *TRANSPORT_STAGES, "fit", "report", "export")


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
    if spec.atlas.resolution > limits.max_atlas_resolution:
        from prtcore.core.errors import SpecError
        raise SpecError("atlas.resolution", f"{spec.atlas.resolution} exceeds the configured "
                        f"limit max_atlas_resolution={limits.max_atlas_resolution}")
    with timer.stage("load"):
        scene = load_asset(asset, limits)
    with timer.stage("plan"):
        plan = plan_asset(scene, spec)
    scene, report = prepare_scene(scene, spec, timer=timer, plan=plan)
    with timer.stage("texels"):
        texels = build_texel_space(scene, spec.atlas.resolution, spec.atlas.resolution,
                                   padding=spec.atlas.padding)
    with timer.stage("points"):
        points = place_measurement_points(scene, spec.measurement_points)
    return IntakeResult(source=str(asset), spec=spec, plan=plan, scene=scene, prepare=report,
                        texels=texels, points=points, seconds=dict(timer.seconds))


# ---------------------------------------------------------------------------------------
# The whole bake

#: Files that describe the run rather than the result: left out of the checksums, so two
#: bakes of the same asset + spec + seed have identical checksummed files.
RUN_FILES = ("report.json", "report.png", "report.txt", "manifest.json")


def bake(asset: str | Path, spec: BakeSpec, out: Path, *, quiet: bool = False,
         force: bool = False, limits: IntakeLimits | None = None,
         callback: ProgressCallback | None = None) -> Path:
    """asset + spec → bundle directory ``out`` (DESIGN 3.4). Returns ``out``."""
    import time

    from prtcore.core.materials import clamp_albedo
    from prtcore.core.spec import spec_hash, spec_to_dict
    from prtcore.emitters.families import sample_configurations
    from prtcore.emitters.lightfile import save_light_file
    from prtcore.fit.transfer import fit_transfer
    from prtcore.io.bundle import (
        RUNTIME_FORMULA,
        basis_planes,
        check_output,
        manifest_base,
        planes_layout,
        points_files,
        write_basis_files,
        write_bundle,
    )
    from prtcore.io.gltf.export import write_glb
    from prtcore.io.imageio import write_exr
    from prtcore.keyframes.pose import keyframe_files
    from prtcore.receivers.texels import texels_to_image
    from prtcore.report import TABLE_N, error_vs_runtime, format_table, plot, truncate
    from prtcore.transport.dataset import bake_dataset, check_bake_memory

    check_output(out, force, inputs=(asset,))  # before any work: nothing lost, nothing wasted
    t_start = time.perf_counter()
    timer = StageTimer(quiet=quiet, callback=callback)
    intake = run_intake(asset, spec, timer=timer, limits=limits)
    scene, texels, points = intake.scene, intake.texels, intake.points
    check_bake_memory(asset, texels, spec, (limits or IntakeLimits.from_env()).max_bake_bytes)

    with timer.stage("lights"):
        train, hold = sample_configurations(spec.lights, scene.center, scene.radius,
                                            scene.lights)
    kfs = _keyframe_set(intake, len(train), len(hold), timer)
    if kfs is None:
        data = bake_dataset(scene, texels, points, train, hold, spec.transport, timer)
    else:
        from prtcore.keyframes.pose import bake_keyframe_dataset

        data = bake_keyframe_dataset(kfs, texels, train, hold, spec.transport, timer)
    K = len(train)
    D, I = data.direct_points[:, :K], data.indirect[:, :K]
    Dh, Ih = data.direct_points[:, K:], data.indirect[:, K:]
    holdout = (Dh, Ih) if len(hold) else None
    per_group = kfs is not None and kfs.transfer == "per_keyframe"
    if per_group and holdout is not None:
        holdout = (Dh, Ih, kfs.holdout)

    with timer.stage("fit"):
        n_table = max(TABLE_N)
        fit_kw = {"ridge": spec.fit.ridge, "channels": spec.fit.channels,
                  "gamma": spec.fit.gamma}
        if kfs is not None:  # one basis for all keyframes (paper 5.4)
            fit_kw.update(groups=kfs.train, per_group=per_group)
        if spec.fit.basis == "auto":
            model = fit_transfer(D, I, basis="auto", holdout=holdout, **fit_kw)
            full = model if model.n_basis >= n_table else fit_transfer(
                D, I, basis=n_table, **fit_kw)
        else:
            full = fit_transfer(D, I, basis=max(spec.fit.basis, n_table), **fit_kw)
            model = truncate(full, spec.fit.basis)
    diag = model.diagnostics.to_dict()
    if per_group and model.group_ids != tuple(range(kfs.count)):
        from prtcore.core.errors import PrtError
        raise PrtError(f"fit: per-keyframe transfers for keyframes {model.group_ids}, "
                       f"expected all {kfs.count}")

    with timer.stage("report"):
        dtype_bytes = 2 if spec.output.dtype == "half" else 4
        if holdout is not None:
            table = error_vs_runtime(full, Dh, Ih, texels.width * texels.height,
                                     texels.width * texels.height * dtype_bytes,
                                     reference="fast transport of the held-out lights",
                                     groups=kfs.holdout if per_group else None)
        else:
            table = {"reference": None, "heldout_configurations": 0, "rows": []}

    def write(tmp: Path) -> dict:
        write_glb(scene, tmp / "asset.glb")
        planes = basis_planes(model.mean, model.basis, model.channels)
        img = texels_to_image(texels, planes, dilate=True)
        files = write_basis_files(tmp, img[:, :, :planes.shape[1]], spec.output.dtype)
        write_exr(tmp / "coverage.exr", img[:, :, -1:], dtype="half", channel_names=("Y",))
        el, ch = planes_layout(model.channels, model.basis.shape[1])
        cl_albedo, _ = clamp_albedo(points.cluster_albedo)
        pts = points_files(tmp, points, cl_albedo)
        transfer = {
            "matrix": _raw_desc(tmp / "transfer.bin", model.transfer),
            "offset": _raw_desc(tmp / "transfer_offset.bin", model.offset),
            "layout": "matrix[c, i, p]: channel c (R, G, B), element i+1, point p; "
                      "offset[c, i]" + ("; leading axis: keyframe" if
                                        model.transfer.ndim == 4 else ""),
        }
        save_light_file(hold, tmp / "holdout_lights.json")
        seconds = dict(timer.seconds)
        report = {"table": table, "stage_seconds": seconds,
                  "transport": data.stats, "fit": diag,
                  "total_seconds": time.perf_counter() - t_start}
        (tmp / "report.json").write_text(json.dumps(_jsonable(report), indent=2) + "\n")
        plot(table, tmp / "report.png")
        (tmp / "report.txt").write_text(format_table(table, seconds) + "\n")
        return manifest_base(
            asset={"source": Path(str(asset)).name, "sha256": _file_sha256(Path(asset)),
                   "file": "asset.glb", "triangles": scene.triangle_count},
            units={"length": "m", "up": "+Y", "handedness": "right",
                   "radiance": "linear RGB outgoing radiance (albedo/pi * E)",
                   "light_intensity": "KHR_lights_punctual: cd (point/spot), lux "
                                      "(directional), no 683 lm/W conversion"},
            atlas={"width": texels.width, "height": texels.height,
                   "padding": spec.atlas.padding, "uv": "TEXCOORD_1",
                   "texel_center": "((x+0.5)/W, (y+0.5)/H), y from the top row",
                   "covered_texels": texels.count, "coverage": "coverage.exr"},
            basis={"count": model.n_basis, "channels": model.channels,
                   "files": files, "planes": int(planes.shape[1]),
                   "plane_element": el.tolist(), "plane_channel": ch.tolist(),
                   "packing": "4 planes per RGBA file in order; planes 0-2 are the mean "
                              "(element 0) for R, G, B; plane_channel -1 = shared by R, G, B",
                   "dtype": spec.output.dtype, "dilated": True},
            fit={"channels": model.channels, "gamma": model.gamma, "ridge": model.ridge,
                 "n_basis": model.n_basis, "n_method": diag.get("n_basis_method"),
                 "ridge_method": diag.get("ridge_method"),
                 "energy_kept": diag.get("energy_kept"), "warnings": diag.get("warnings"),
                 "configurations": K, "used": diag.get("used")},
            transfer=transfer,
            points=pts,
            keyframes=None if kfs is None else keyframe_files(tmp, kfs, scene),
            runtime={"formula": RUNTIME_FORMULA},
            spec=spec_to_dict(spec), spec_sha256=spec_hash(spec),
            plan=[{"stage": s.name, "action": s.action, "reason": s.reason}
                  for s in intake.plan.stages],
            prepare=_jsonable(intake.prepare.__dict__),
            timings=seconds,
            diagnostics=diag,
            metrics={"error_vs_runtime": table["rows"],
                     "transport_iterations": data.iterations,
                     "transport_residual": data.residual},
            validation={"holdout_lights": "holdout_lights.json",
                        "reference": table["reference"]},
            run_files=list(RUN_FILES),
        )

    with timer.stage("export"):
        out = write_bundle(out, write, force=force, exclude=RUN_FILES, inputs=(asset,))
    if not quiet:
        print(format_table(table, dict(timer.seconds)))
    return out


def _keyframe_set(intake: IntakeResult, n_train: int, n_holdout: int, timer: StageTimer):
    """The keyframe set when the plan runs the keyframes stage, else None (static bake)."""
    if not any(s.name == "keyframes" and s.action == "run" for s in intake.plan.stages):
        return None
    from prtcore.keyframes.pose import build_keyframes

    with timer.stage("keyframes"):
        return build_keyframes(intake.scene, intake.points, intake.spec, n_train, n_holdout)


def _raw_desc(path: Path, array) -> dict:
    import numpy as np

    a = np.ascontiguousarray(array, dtype="<f4")
    path.write_bytes(a.tobytes())
    return {"file": path.name, "dtype": "<f4", "shape": list(a.shape)}


def _file_sha256(path: Path) -> str:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


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


def texel_space_for(source: str | Path, spec_path: str | Path | None = None, *,
                    quiet: bool = True, timer: StageTimer | None = None
                    ) -> tuple[Scene, TexelSpace]:
    """The scene and texel space of an asset (prepared with the spec) or of a bundle
    (its asset.glb at the bundle's atlas size), so that outputs line up texel for texel."""
    from prtcore.core.spec import load_spec
    from prtcore.intake.prepare import prepare_scene
    from prtcore.io.gltf.loader import load_asset
    from prtcore.receivers.texels import build_texel_space

    timer = timer or StageTimer(quiet=quiet)
    source = Path(source)
    if source.is_dir():
        from prtcore.io.bundle import read_manifest

        m = read_manifest(source)
        with timer.stage("load"):
            scene = load_asset(source / m["asset"]["file"])
        w, h, pad = m["atlas"]["width"], m["atlas"]["height"], m["atlas"]["padding"]
    else:
        spec = load_spec(spec_path)
        with timer.stage("load"):
            scene = load_asset(source)
        scene, _ = prepare_scene(scene, spec, timer=timer)
        w = h = spec.atlas.resolution
        pad = spec.atlas.padding
    with timer.stage("texels"):
        texels = build_texel_space(scene, w, h, padding=pad)
    return scene, texels


def reference_to_exr(source: str | Path, light_path: str | Path, out: Path, *, spp: int,
                     seed: int = 0, spec_path: str | Path | None = None,
                     quiet: bool = False) -> Path:
    """``prtcore reference``: the path-traced indirect lightmap as an RGBA EXR."""
    from prtcore.core.errors import PrtError
    from prtcore.emitters.lightfile import load_light_file
    from prtcore.io.imageio import write_exr
    from prtcore.receivers.texels import texels_to_image
    from prtcore.reference.pathtracer import reference_lightmap

    if spp < 1:
        raise PrtError(f"--spp must be ≥ 1, got {spp}")
    lights = load_light_file(light_path)  # validate before the expensive part
    timer = StageTimer(quiet=quiet)
    scene, texels = texel_space_for(source, spec_path, timer=timer)
    values = reference_lightmap(scene, texels, lights, spp, seed=seed, timer=timer)
    write_exr(out, texels_to_image(texels, values, dilate=False), dtype="float")
    return Path(out)
