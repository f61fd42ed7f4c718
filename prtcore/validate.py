"""Validation of a bundle against the independent reference path tracer (docs/architecture.md).

Relights held-out lights with the runtime (from the bundle alone, as an engine would) and
compares each with the path-traced indirect lightmap of the same light, for each basis
count of the error-against-run-time table. The reference's own Monte Carlo noise is
reported with it: an error at or below that noise cannot be resolved.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.emitters.lightfile import load_light_file
from prtcore.fit.model import relative_rmse
from prtcore.io.bundle import RuntimeData, load_runtime, read_manifest
from prtcore.receivers.texels import image_to_texels
from prtcore.reference.pathtracer import reference_lightmaps
from prtcore.report import TABLE_N
from prtcore.runtime.cpu import blend, plane_weights, shade_points


def validate_bundle(bundle: str | Path, spp: int, count: int | None = None, seed: int = 0,
                    timer: StageTimer | None = None, light_file: str | Path | None = None,
                    time: float | None = None) -> dict:
    """Runtime reconstruction vs path-traced reference for the bundle's held-out lights,
    or for the lights of ``light_file`` (docs/lights.md: e.g. another family than the one the
    bundle was trained on, paper Figure 8).

    A keyframe bundle is validated posed: each held-out light at the keyframe it was drawn
    with (``light_file`` lights at the keyframe nearest ``time``, default the first), the
    reference path-traced on the scene posed at that keyframe.

    count : how many of the lights (default all). Returns a JSON-ready dict with per-n
    mean/max relative RMSE, the reference noise (relative standard error) and, per light,
    the errors.
    """
    from prtcore.reference.lightmap import texel_space_for

    bundle = Path(bundle)
    timer = timer or StageTimer(quiet=True)
    m = read_manifest(bundle)
    data = load_runtime(bundle, m)
    source = Path(light_file) if light_file else bundle / m["validation"]["holdout_lights"]
    lights = load_light_file(source)[:count]
    kf = m.get("keyframes")

    def reconstruct(data_h: RuntimeData, weights: np.ndarray) -> np.ndarray:
        return image_to_texels(texels, blend(data_h, weights))[:, :3]

    if (m.get("strands") or {}).get("basis_files"):  # hair baked with a mesh
        if time is not None:
            from prtcore.core.errors import PrtError
            raise PrtError(f"{bundle}: time {time:g}: the bundle was baked without keyframes")
        from prtcore.io.bundle import strand_runtime

        texels, space, tracer, ref, err = _hair_mesh_references(bundle, m, lights, spp,
                                                                seed, timer)
        strand_data = strand_runtime(bundle, m, data)

        def reconstruct(data_h: RuntimeData, weights: np.ndarray) -> np.ndarray:
            # the atlas texels, then the strand texels: the bake's receiver order
            return np.concatenate([image_to_texels(texels, blend(data_h, weights))[:, :3],
                                   image_to_texels(space, blend(strand_data, weights))[:, :3]])

        posed = [(data, tracer, None)] * len(lights)
    elif "strands" in m:  # a hair bundle: the fibre path tracer over the strand texels
        if time is not None:
            from prtcore.core.errors import PrtError
            raise PrtError(f"{bundle}: time {time:g}: the bundle was baked without keyframes")
        texels, tracer, ref, err = _hair_references(bundle, m, lights, spp, seed, timer)
        posed = [(data, tracer, None)] * len(lights)
    elif kf:
        scene, texels = texel_space_for(bundle, timer=timer)
        from prtcore.keyframes.pose import nearest_keyframe

        k0 = 0 if time is None else nearest_keyframe(kf["times"], time)
        keys = [kf["holdout_keyframe"][h] if light_file is None else k0
                for h in range(len(lights))]
        ref, err, posed = _posed_references(bundle, m, data, scene, texels, lights, keys,
                                            spp, seed, timer)
    else:
        if time is not None:
            from prtcore.core.errors import PrtError
            raise PrtError(f"{bundle}: time {time:g}: the bundle was baked without keyframes")
        scene, texels = texel_space_for(bundle, timer=timer)
        tracer = RayTracer(scene.positions, scene.faces, scene.radius)
        ref, err = two_halves(lambda n, sd: reference_lightmaps(
            scene, texels, [[lt] for lt in lights], n, seed=sd, tracer=tracer, timer=timer),
            spp, seed)
        posed = [(data, tracer, None)] * len(lights)
    ns = sorted({n for n in TABLE_N if n <= data.n_basis} | {data.n_basis})
    # the bound against the reference itself: bundles with one transfer
    basis = None if kf else BasisAtTexels.for_bundle(data, texels)
    if basis is not None and (m.get("strands") or {}).get("basis_files"):
        # both textures' planes at their receivers, atlas texels then strand texels
        basis = BasisAtTexels(data, np.concatenate([
            image_to_texels(texels, data.planes), image_to_texels(space, strand_data.planes)
        ]).astype(np.float64))
    per_light = []
    for h, light in enumerate(lights):
        data_h, tracer_h, key = posed[h]
        x = shade_points(data_h, [light], tracer_h)
        norm = float(np.sqrt((ref[h] ** 2).mean()))
        row = {"light": h, "reference_noise": float(np.sqrt((err[h] ** 2).mean()) / norm)
               if norm > 0 else None, "rmse": {}}
        if key is not None:
            row["keyframe"] = key
        row["rmse_noise_corrected"] = {}
        row["projection_bound_noise_corrected"] = {}
        noise2 = float((err[h] ** 2).mean())
        for n in ns:
            rec = reconstruct(data_h, plane_weights(data_h, x, n))
            row["rmse"][str(n)] = relative_rmse(rec, ref[h]) if norm > 0 else None
            # E‖rec − ref‖² = ‖rec − truth‖² + Σ stderr²: the reference's own variance
            # removed gives an estimate of the error against the noiseless truth.
            ms = float(((rec - ref[h]) ** 2).mean())
            row["rmse_noise_corrected"][str(n)] = (
                float(np.sqrt(max(ms - noise2, 0.0))) / norm if norm > 0 else None)
            bound2 = None if basis is None else basis.residual(x, ref[h], err[h], n)
            row["projection_bound_noise_corrected"][str(n)] = (
                float(np.sqrt(max(bound2, 0.0) / ref[h].size)) / norm
                if norm > 0 and bound2 is not None else None)
        per_light.append(row)
    rows = []
    for n in ns:
        v = [r["rmse"][str(n)] for r in per_light if r["rmse"][str(n)] is not None]
        c = [r["rmse_noise_corrected"][str(n)] for r in per_light
             if r["rmse_noise_corrected"][str(n)] is not None]
        b = [r["projection_bound_noise_corrected"][str(n)] for r in per_light
             if r["projection_bound_noise_corrected"][str(n)] is not None]
        rows.append({"n": n, "rmse_mean": float(np.mean(v)) if v else None,
                     "rmse_max": float(np.max(v)) if v else None,
                     "rmse_noise_corrected_mean": float(np.mean(c)) if c else None,
                     "projection_bound_noise_corrected_mean":
                         float(np.mean(b)) if len(b) == len(c) and b else None})
    noise = [r["reference_noise"] for r in per_light if r["reference_noise"] is not None]
    return {"reference": f"path tracer, {spp} spp", "lights": len(lights), "spp": spp,
            "light_source": "held-out" if light_file is None else str(light_file),
            "seed": seed, "reference_noise_mean": float(np.mean(noise)) if noise else None,
            "rows": rows, "per_light": per_light}


def two_halves(compute, spp: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A path-traced reference of ``spp`` samples as two independent halves, and its noise
    from their difference: compute(n, seed) → (mean, stderr) of n samples per texel.
    Returns the ``spp``-sample mean and its standard error per entry,
    |a − b|·√(n_a n_b)/spp (E[(a − b)²] = v/n_a + v/n_b; the mean's variance is v/spp),
    which does not lean on the estimator's own per-path variance: on the exterior house the
    per-path standard errors undercount the real spread of two runs by 13–50 % (light
    paths spread one sample over several texels). With spp = 1: the estimator's own."""
    na = spp // 2
    if na == 0:
        return compute(spp, seed)
    nb = spp - na
    a, _ = compute(na, seed)
    b, _ = compute(nb, int(np.random.SeedSequence([int(seed), 0x68616c66]).generate_state(1)[0]))
    return (na * a + nb * b) / spp, np.abs(a - b) * (np.sqrt(na * nb) / spp)


class BasisAtTexels:
    """A bundle's planes at the texels, orthonormalised once for every n:
    mean : (T, 3) float64 the mean planes; q : three (T, n_b) float64, per channel an
    orthonormal basis whose first k columns span the first k elements' planes (QR keeps
    the nesting). None for a bundle fitted in gamma space (a non-linear projection) or
    with per-keyframe transfers."""

    def __init__(self, data: RuntimeData, planes: np.ndarray):
        self.mean = np.zeros((len(planes), 3))
        self.q = []
        for c in range(3):
            self.mean[:, c] = planes[:, (data.plane_element == 0)
                                     & (data.plane_channel == c)].sum(axis=1)
            use = np.flatnonzero((data.plane_element > 0) & (
                (data.plane_channel == c) | (data.plane_channel < 0)))
            use = use[np.argsort(data.plane_element[use], kind="stable")]
            self.q.append(np.linalg.qr(planes[:, use])[0] if len(use)
                          else np.zeros((len(planes), 0)))

    @staticmethod
    def for_bundle(data: RuntimeData, texels) -> BasisAtTexels | None:
        if (data.gamma not in (None, 1.0)) or data.transfer.ndim == 4:
            return None
        return BasisAtTexels(data, image_to_texels(texels, data.planes).astype(np.float64))

    def residual(self, x: np.ndarray, ref: np.ndarray, stderr: np.ndarray, n: int) -> float:
        """The projection bound against a path-traced reference, its noise removed: Σ over
        texels and channels of the squared residual of the best coefficients any transfer
        could give the first n elements (the mean plane's weight fixed at ‖x‖, as at
        runtime; least squares per channel, as :func:`prtcore.fit.transfer.projection_bound`),
        less the part of the reference's variance outside the basis, Σ σ²(1 − leverage).
        x : (P, 3) direct vector; ref, stderr : (T, 3); n : elements, mean included."""
        s = float(np.linalg.norm(x))
        out = 0.0
        for c in range(3):
            q = self.q[c][:, :max(n - 1, 0)]
            r = ref[:, c] - s * self.mean[:, c]
            r = r - q @ (q.T @ r)
            leverage = np.einsum("ij,ij->i", q, q)
            out += float(r @ r) - float((stderr[:, c] ** 2 * (1.0 - leverage)).sum())
        return out


def _hair_references(bundle: Path, manifest: dict, lights, spp: int, seed: int,
                     timer: StageTimer):
    """References of a hair bundle: every strand texel's indirect light for each light by
    the path tracer of its fibre (:func:`prtcore.reference.fibres.fibre_reference`, or
    :func:`prtcore.reference.chiang.chiang_reference` for the Chiang fibre,
    ``spp`` paths per texel in two independent halves). Returns the strand space, the
    tracer of its fibre tubes, and ``ref`` (L, T, 3) with per-texel standard errors
    ``err`` (L, T, 3) (|a − b| / 2: its square is an unbiased estimate of the variance)."""
    from prtcore.io.hair import read_hair
    from prtcore.receivers.strands import build_strand_space
    from prtcore.reference.chiang import chiang_reference
    from prtcore.reference.fibres import fibre_reference
    from prtcore.transport.fibre import hair_tracer
    from prtcore.transport.fibre_chiang import bundle_fibre

    with timer.stage("reference"):
        hair = read_hair(bundle / manifest["asset"]["file"])
        space = build_strand_space(hair, int(manifest["strands"]["texels_per_strand"]))
        tracer, mesh = hair_tracer(space)
        every = np.arange(space.count)
        fibre = bundle_fibre(manifest, space)

        def trace(light, seed_h):
            if fibre is not None:  # the Chiang fibre's own path tracer
                return chiang_reference(space, tracer, mesh, 0, [light], every, spp, seed_h,
                                        fibre.params, fibre.sigma_points)
            return fibre_reference(space, tracer, mesh, 0, [light], every, spp,
                                   seed=seed_h)

        ref, err = _per_light(lights, seed, len(every), trace)
    return space, tracer, ref, err


def _per_light(lights, seed: int, n: int, trace) -> tuple[np.ndarray, np.ndarray]:
    """``trace(light, seed + h)`` → two independent halves (a, b), each (n, 1, 3), for
    each light h: the mean ``ref`` (L, n, 3) and standard errors ``err`` (L, n, 3),
    |a − b| / 2 (its square is an unbiased estimate of the variance)."""
    ref, err = np.zeros((len(lights), n, 3)), np.zeros((len(lights), n, 3))
    for h, light in enumerate(lights):
        a, b = trace(light, seed + h)
        ref[h], err[h] = (a[:, 0] + b[:, 0]) / 2, np.abs(a[:, 0] - b[:, 0]) / 2
    return ref, err


def _hair_mesh_references(bundle: Path, manifest: dict, lights, spp: int, seed: int,
                          timer: StageTimer):
    """References of a hair + mesh bundle: the indirect light of every atlas texel, then
    every strand texel, for each light, by the hair + mesh path tracer of its fibre
    (:func:`prtcore.reference.hair_mesh.hair_mesh_reference`, or
    :func:`~prtcore.reference.hair_mesh.chiang_hair_mesh_reference` for the Chiang fibre),
    ``spp`` paths per receiver in two independent halves. Returns the mesh's texel space,
    the strand space, the tracer of both, ``ref`` (L, T_m + T_h, 3) and ``err``."""
    from prtcore.io.hair import read_hair
    from prtcore.receivers.strands import build_strand_space
    from prtcore.reference.hair_mesh import chiang_hair_mesh_reference, hair_mesh_reference
    from prtcore.reference.lightmap import texel_space_for
    from prtcore.transport.fibre import hair_tracer
    from prtcore.transport.fibre_chiang import bundle_fibre

    scene, texels = texel_space_for(bundle, timer=timer)
    with timer.stage("reference"):
        hair = read_hair(bundle / manifest["asset"]["hair"]["file"])
        space = build_strand_space(hair, int(manifest["strands"]["texels_per_strand"]))
        tracer, fibres = hair_tracer(space, scene)
        every = np.arange(texels.count + space.count)
        fibre = bundle_fibre(manifest, space)

        def trace(light, seed_h):
            if fibre is not None:
                return chiang_hair_mesh_reference(scene, texels, space, tracer, fibres,
                                                  [light], every, spp, seed_h,
                                                  fibre.params, fibre.sigma_points)
            return hair_mesh_reference(scene, texels, space, tracer, fibres, [light], every,
                                       spp, seed_h)

        ref, err = _per_light(lights, seed, len(every), trace)
    return texels, space, tracer, ref, err


def _posed_references(bundle: Path, manifest: dict, data, scene, texels, lights, keys,
                      spp: int, seed: int, timer: StageTimer):
    """References of a keyframe bundle: per keyframe, the scene and texels posed there and
    the lights drawn with it path-traced together. Returns (ref, err) as
    :func:`reference_lightmaps` for all lights, and per light (posed runtime data, tracer
    of the posed scene, keyframe)."""
    from prtcore.keyframes.pose import bundle_at_time, pose_texels

    ref = np.zeros((len(lights), texels.count, 3))
    err = np.zeros((len(lights), texels.count, 3))
    posed: list = [None] * len(lights)
    for k in sorted(set(keys)):
        idx = [h for h, key in enumerate(keys) if key == k]
        data_k, scene_k, _ = bundle_at_time(bundle, manifest, data, scene,
                                            manifest["keyframes"]["times"][k])
        tracer = RayTracer(scene_k.positions, scene_k.faces, scene_k.radius)
        r, e = reference_lightmaps(scene_k, pose_texels(texels, scene_k),
                                   [[lights[h]] for h in idx], spp, seed=seed,
                                   tracer=tracer, timer=timer)
        ref[idx], err[idx] = r, e
        for h in idx:
            posed[h] = (data_k, tracer, k)
    return ref, err, posed


def format_validation(v: dict) -> str:
    which = v.get("light_source", "held-out")
    lines = [f"validation against the {v['reference']} — {v['lights']} {which} lights, "
             f"reference noise {100 * (v['reference_noise_mean'] or 0):.2f}%",
             f"{'n':>4s} {'rRMSE':>8s} {'(max)':>8s} {'noise-corrected':>16s}"]
    for r in v["rows"]:
        if r["rmse_mean"] is not None:
            c = r.get("rmse_noise_corrected_mean")
            lines.append(f"{r['n']:>4d} {100 * r['rmse_mean']:>7.2f}% {100 * r['rmse_max']:>7.2f}%"
                         + (f" {100 * c:>15.2f}%" if c is not None else ""))
    return "\n".join(lines)
