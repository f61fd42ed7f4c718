"""Data-driven PRT (Belcour et al. 2022): mean + basis of indirect lightmaps, a transfer
matrix from the direct light at the measurement points, and the error-vs-run-time table.

Files: basis_XX.exr (4 planes per RGBA file), coverage.exr, transfer.bin and
transfer_offset.bin (and the learnt residual's layers, transfer_learnt_*.bin, with
``fit.transfer: "mlp"``), the points files, per-keyframe files for animated bakes. The runtime
is :mod:`prtcore.runtime.cpu` (and the GLSL of :mod:`prtcore.runtime.gl`); its formula is
written into the manifest's ``runtime`` section.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prtcore.core.errors import PrtError
from prtcore.core.formula import LEARNT_FORMULA, RUNTIME_FORMULA
from prtcore.core.materials import clamp_albedo
from prtcore.core.progress import StageTimer
from prtcore.emitters.lightfile import save_light_file
from prtcore.fit.model import TransferModel
from prtcore.fit.transfer import heldout_errors, reconstruct
from prtcore.io.bundle import (
    basis_planes,
    learnt_files,
    planes_layout,
    points_files,
    raw_file,
    write_basis_files,
)
from prtcore.io.imageio import write_exr
from prtcore.keyframes.pose import keyframe_files
from prtcore.methods.base import BakeInputs, Method, register
from prtcore.receivers.smoothing import denoise_lightmaps, smoothing_operator
from prtcore.report import (
    error_vs_runtime,
    fit_for_table,
    format_table,
    plot,
    plot_atlas,
    plot_worst,
)
from prtcore.runtime.family import direct_span, family_residual, warn_above
from prtcore.verdict import judge


@dataclass(frozen=True, eq=False)
class DataDrivenResult:
    """model : the shipped model (the spec's n); full : the fit the report table uses
    (≥ max(TABLE_N) elements where the data allows); table : error vs run time;
    diagnostics : the shipped model's fit diagnostics as JSON data; verdict :
    :func:`prtcore.verdict.judge` at the shipped n."""

    model: TransferModel
    full: TransferModel
    table: dict[str, Any]
    diagnostics: dict[str, Any]
    verdict: dict[str, Any]
    warnings: tuple[str, ...] = ()


@register
class DataDriven(Method):
    name = "data_driven"

    def fit(self, inputs: BakeInputs, timer: StageTimer) -> DataDrivenResult:
        spec, kfs, data = inputs.spec, inputs.keyframes, inputs.data
        if spec.fit.denoise == "auto":
            raise ValueError("DataDriven.fit: fit.denoise 'auto' must be resolved to a radius "
                             "first (prtcore.transport.noise.measure_noise / with_denoise)")
        texels = inputs.intake.texels
        K = len(inputs.train)
        D, I = data.direct_points[:, :K], data.indirect[:, :K]
        Dh, Ih = data.direct_points[:, K:], data.indirect[:, K:]
        reference = "fast transport of the held-out lights"
        if inputs.indirect is not None:  # prepared by automatic sizing (prtcore/sizing.py)
            I, Ih = inputs.indirect
            if spec.fit.denoise > 0:
                reference += f", denoised (radius {spec.fit.denoise:g} texels)"
        elif spec.fit.denoise > 0:
            # the gather's per-texel noise stays out of the basis; the held-out lightmaps
            # carry the same noise and are filtered alike, or the table would count that
            # noise as error (against the path tracer, noise removed, the Cornell example
            # at n = 16 goes from 4.06 % to 3.71 % with the filter)
            with timer.stage("denoise"):  # one filter for training and held-out lightmaps
                W = inputs.denoise_operator if inputs.denoise_operator is not None else \
                    smoothing_operator(texels, radius=spec.fit.denoise)
                # the training lightmaps in place (nothing after reads them raw: a copy of
                # the largest array of the bake saved); the held-out ones stay raw for the
                # report's worst-light image
                I = denoise_lightmaps(texels, I, operator=W, out=I)
                Ih = denoise_lightmaps(texels, Ih, operator=W)
            reference += f", denoised (radius {spec.fit.denoise:g} texels)"
        holdout = (Dh, Ih) if len(inputs.hold) else None
        per_group = kfs is not None and kfs.transfer == "per_keyframe"
        if per_group and holdout is not None:
            holdout = (Dh, Ih, kfs.holdout)

        with timer.stage("fit"):
            kw = {} if kfs is None else {  # one basis for all keyframes (paper 5.4)
                "groups": kfs.train, "per_group": per_group}
            if inputs.models is not None:  # automatic sizing fitted exactly these
                model, full = inputs.models
            else:
                model, full = fit_for_table(D, I, spec.fit, holdout, timer, **kw)
        if per_group and model.group_ids != tuple(range(kfs.count)):
            raise PrtError(f"fit: per-keyframe transfers for keyframes {model.group_ids}, "
                           f"expected all {kfs.count}")

        with timer.stage("report"):
            dtype_bytes = 2 if spec.output.dtype == "half" else 4
            if holdout is not None:
                table = error_vs_runtime(full, Dh, Ih, texels.width * texels.height,
                                         texels.width * texels.height * dtype_bytes,
                                         reference=reference,
                                         groups=kfs.holdout if per_group else None,
                                         shipped=model.n_basis)
            else:
                table = {"reference": None, "heldout_configurations": 0, "rows": []}
        diag = model.diagnostics.to_dict()
        warnings = (*inputs.intake.prepare.warnings, *(diag.get("warnings") or ()))
        return DataDrivenResult(model=model, full=full, table=table, diagnostics=diag,
                                verdict=self._judge(inputs, model, table, diag),
                                warnings=tuple(warnings))

    def _judge(self, inputs: BakeInputs, model: TransferModel, table: dict, diag: dict,
               reference: dict | None = None) -> dict[str, Any]:
        albedo = inputs.intake.texels.albedo
        black = tuple(c for c, a in zip("RGB", albedo.max(axis=0) if len(albedo) else (),
                                        strict=False) if a <= 0)
        return judge(table, diag, model.n_basis, inputs.spec.validate,
                     points=inputs.intake.points.count, configurations=len(inputs.train),
                     black_channels=black, reference=reference)

    def revalidate(self, result: DataDrivenResult, inputs: BakeInputs, validation: dict
                   ) -> DataDrivenResult:
        verdict = self._judge(inputs, result.model, result.table, result.diagnostics,
                              validation)
        return dataclasses.replace(result, verdict=verdict)

    def write(self, directory: Path, inputs: BakeInputs, result: DataDrivenResult
              ) -> tuple[dict, dict]:
        spec, kfs, data = inputs.spec, inputs.keyframes, inputs.data
        texels, points = inputs.intake.texels, inputs.intake.points
        model, diag, table = result.model, result.diagnostics, result.table
        planes = basis_planes(model.mean, model.basis, model.channels)
        img = texels.to_image(planes, dilate=True)  # the receiver's stored image
        files = write_basis_files(directory, img[:, :, :planes.shape[1]], spec.output.dtype)
        write_exr(directory / "coverage.exr", img[:, :, -1:], dtype="half",
                  channel_names=("Y",))
        el, ch = planes_layout(model.channels, model.basis.shape[1])
        cl_albedo, _ = clamp_albedo(points.cluster_albedo)
        pts = points_files(directory, points, cl_albedo)
        transfer = {
            "matrix": raw_file(directory / "transfer.bin", model.transfer),
            "offset": raw_file(directory / "transfer_offset.bin", model.offset),
            "layout": "matrix[c, i, p]: channel c (R, G, B), element i+1, point p; "
                      "offset[c, i]" + ("; leading axis: keyframe" if
                                        model.transfer.ndim == 4 else ""),
        }
        if model.learnt is not None:
            transfer["learnt"] = learnt_files(directory, model.learnt)
        save_light_file(inputs.hold, directory / "holdout_lights.json")
        K = len(inputs.train)
        span = direct_span(data.direct_points[:, :K])
        held = np.array([family_residual(span, data.direct_points[:, K + h])
                         for h in range(len(inputs.hold))])
        family = {"span": raw_file(directory / "direct_span.bin", span.T),
                  "layout": "span[r, 3p + c]: orthonormal rows spanning the training "
                            "lights' unit direct vectors x.ravel() (point p, channel c)",
                  "heldout_residual_max": float(held.max()) if len(held) else None,
                  "warn_above": warn_above(held),
                  "measure": "||x - span^T span x|| / ||x|| for a light's direct vector x"}
        sections = {
            "basis": {"count": model.n_basis, "channels": model.channels,
                      "files": files, "planes": int(planes.shape[1]),
                      "plane_element": el.tolist(), "plane_channel": ch.tolist(),
                      "packing": "4 planes per RGBA file in order; planes 0-2 are the mean "
                                 "(element 0) for R, G, B; plane_channel -1 = shared by R, "
                                 "G, B",
                      "dtype": spec.output.dtype, "dilated": True},
            "fit": {"channels": model.channels, "gamma": model.gamma, "ridge": model.ridge,
                    "transfer": diag.get("transfer", "ridge"),
                    "n_basis": model.n_basis, "n_method": diag.get("n_basis_method"),
                    "ridge_method": diag.get("ridge_method"),
                    "energy_kept": diag.get("energy_kept"), "warnings": diag.get("warnings"),
                    "configurations": len(inputs.train), "used": diag.get("used")},
            "transfer": transfer,
            "points": pts,
            "keyframes": None if kfs is None else keyframe_files(directory, kfs,
                                                                 inputs.intake.scene),
            "runtime": {"formula": RUNTIME_FORMULA} if model.learnt is None else
            {"formula": RUNTIME_FORMULA, "learnt": LEARNT_FORMULA},
            "diagnostics": diag,
            "metrics": {"error_vs_runtime": table["rows"],
                        "transport_iterations": data.iterations,
                        "transport_residual": data.residual},
            "validation": {"holdout_lights": "holdout_lights.json",
                           "reference": table["reference"]},
            "verdict": result.verdict,
            "family": family,
        }
        self._report_images(directory, inputs, result)
        report = {"table": table, "verdict": result.verdict, "transport": data.stats,
                  "fit": diag}
        return sections, report

    def summary(self, result: DataDrivenResult, seconds: dict[str, float],
                with_verdict: bool = True) -> str:
        lines = [format_table(result.table, seconds)]
        lines += [f"warning: {w}" for w in result.warnings]  # prepare's and the fit's
        if with_verdict:
            lines.append(result.verdict["line"])  # the verdict is the last line
        return "\n".join(lines)

    def verdict(self, result: DataDrivenResult) -> dict[str, Any]:
        return result.verdict

    def plot(self, result: DataDrivenResult, path: Path) -> None:
        plot(result.table, path, result.verdict)

    def _report_images(self, directory: Path, inputs: BakeInputs,
                       result: DataDrivenResult) -> None:
        """report_worst.png (the worst held-out light at the shipped n) and
        report_atlas.png (UV layout, texel density, utilisation)."""
        texels, data, model = inputs.intake.texels, inputs.data, result.model
        K = len(inputs.train)
        worst = None
        X, R = data.direct_points[:, K:], data.indirect[:, K:]
        use = np.flatnonzero([np.linalg.norm(X[:, h]) > 0 and np.linalg.norm(R[:, h]) > 0
                              for h in range(R.shape[1])])
        if len(use):  # every light's error in one pass (fit/transfer.py), then the worst
            groups = None if model.group_ids is None else inputs.keyframes.holdout[use]
            e = heldout_errors(model, X[:, use], R[:, use], [model.n_basis], groups)
            i = int(np.argmax(e.sse[0] / e.ref_ss))
            h = int(use[i])
            g = None if groups is None else int(groups[i])
            rec = reconstruct(model, X[:, h].astype(np.float64), group=g).astype(np.float64)
            worst = h, R[:, h].astype(np.float64), rec
            worst_err = float(np.sqrt(e.sse[0, i] / e.ref_ss[i]))
        if worst is not None:
            h, ref, rec = worst
            plot_worst(texels.to_image(ref, dilate=False)[:, :, :3],
                       texels.to_image(rec, dilate=False)[:, :, :3],
                       f"worst held-out light {h}: {100 * worst_err:.1f} % at "
                       f"n = {model.n_basis}", directory / "report_worst.png")
        fp = texels.footprint
        area = np.linalg.norm(np.cross(fp[:, 0], fp[:, 1]), axis=1)
        density = np.divide(1.0, np.sqrt(area), out=np.zeros_like(area), where=area > 0)
        plot_atlas(texels.to_image(density, dilate=False)[:, :, 0],
                   inputs.intake.prepare.utilisation,
                   f"{texels.width}×{texels.height} atlas, {texels.count} texels",
                   directory / "report_atlas.png")
