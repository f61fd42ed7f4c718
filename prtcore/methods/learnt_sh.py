"""Learnt SH transfer as a shipping method (thesis ch. 4, ``"method": {"name":
"learnt_sh"}``, docs/learnt_sh.md).

The bake trains σ(p, n̂) → the L² SH coefficients of the shadowed diffuse transfer at
unit albedo (:func:`prtcore.fit.subscenes.fit_scenes`: one network, or one per sub-scene
cell with ``learnt_sh.cells``; with ``learnt_sh.specular`` > 0 also the visibility SH for
a glossy Phong layer; on an ``*.sdf.json`` asset, samples on the field's zero level set)
and writes a bundle of the networks (``learnt_sh_net_{k}.bin`` + the manifest's
``learnt_sh.networks``), the albedo atlas (``albedo.exr``, sampled at TEXCOORD_1), the
coverage, and for SDF scenes the field (``scene.sdf.json``). Engines shade a surface point
p with shading normal n̂ under distant lighting l (L², 3):

    diffuse  c = albedo(uv1) · Σ_i T_i(p, n̂) l_ic
    glossy   + ρ_s Σ_k (M_c V(p, n̂))_k z_k Y_k(r)     (TP, as sh_prt's glossy layer)

on the CPU (:func:`shade_points`, :func:`relight_bundle` for the view-independent
lightmap, :func:`shade_sdf_view` for SDF scenes) and in GLSL
(:mod:`prtcore.runtime.learnt_sh`: the mesh rasterised, or the field sphere-traced).

The bake's metrics (stage "report", :func:`view_metrics`) compare the method with the
texture-PRT baseline (transfer textures of the same scene, shadowed, same bands) over
``views`` cameras on an orbit under a fixed sky with a sun: MAE, PSNR and SSIM of the
display images (thesis Tables 4.1–4.4), for the diffuse material and, with a glossy
layer, the glossy one; also the same textures from independent rays (the ceiling the
reference's own noise sets), the sizes and the CPU time per view. ``prtcore report``
prints them (:func:`format_metrics`); ``--gpu`` adds the GL frame time.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prtcore.core.geometry import shading_normals
from prtcore.core.imagemetrics import compare_images
from prtcore.core.materials import (
    CLAMP_TO_EDGE,
    albedo_at,
    clamp_albedo,
    linear_to_srgb,
    sample_texture,
)
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Scene, Texture
from prtcore.core.sdf import SdfScene, sdf_t_max, sphere_trace
from prtcore.emitters.environment import light_sh, sky_with_sun
from prtcore.fit.learnt_sh import transfer_of, visibility_of
from prtcore.fit.subscenes import (
    LearntShScenes,
    evaluate_scenes,
    fit_scenes,
    read_scenes,
    write_scenes,
)
from prtcore.io.imageio import read_image, write_exr, write_png
from prtcore.io.sdf import asset_sdf, load_sdf
from prtcore.methods.base import BakeInputs, DirectMethod, register
from prtcore.methods.sh_prt import (
    TEXTURE_BYTES,
    bake_sh_prt,
    evaluate_texture,
    glossy_tp,
    reflect,
    texel_samples,
    write_preview_png,
)
from prtcore.receivers.texels import TexelSpace
from prtcore.reference.camera import Camera, orbit_cameras
from prtcore.reference.pathtracer import default_tracer
from prtcore.transport.sh_transfer import visibility_transfer

#: the SDF scene file in a bundle baked from one
SDF_FILE = "scene.sdf.json"
#: how an engine evaluates a learnt_sh bundle (the manifest's runtime.formula)
LEARNT_SH_FORMULA = (
    "outgoing radiance, channel c = albedo_c(uv1) * sum_i T_i * l[i, c] (+ specular * "
    "sum_k (M_c V)_k z_k Y_k(r) with a glossy network): y = network(p, n) "
    "(learnt_sh.networks: the network of p's grid cell, its encoding, layers, scale), "
    "T = y[0:L²], V = y[L²:2L²], l the "
    "light's real SH (prtcore.core.sh), M_c[k, j] = sum_i Gamma_ijk l[i, c], z the Phong "
    "lobe's Funk-Hecke kernel, r the view's mirror direction about the shading normal; "
    "albedo from albedo.exr at TEXCOORD_1 (bilinear)")


@dataclass(frozen=True, eq=False)
class LearntShBake:
    """The method's result.

    model : the trained network; albedo_image : (H, W, 3) float64 clamped albedo atlas
    (dilated); preview : (t, 3) the covered texels under a uniform white sky of radiance
    1; preview_image : (H, W, 4) its dilated atlas, A = coverage; metrics : None or
    :func:`view_metrics`'s figures; strip : None or the first view as display images
    (baseline | learnt | |difference| × 4 per material row) (h', w', 3) float32;
    seconds : training time
    """

    model: LearntShScenes
    albedo_image: np.ndarray
    preview: np.ndarray
    preview_image: np.ndarray
    metrics: dict | None
    strip: np.ndarray | None
    spec: Any
    seconds: float
    #: the SDF scene file's path when the asset is one (``*.sdf.json``), else None
    sdf_file: str | None = None


# ---------------------------------------------------------------------------------------
# Shading (CPU)


def sample_atlas(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of an atlas image (H, W, c) at lightmap ``uv`` (m, 2), edges clamped
    (as the GL sampler): (m, c) float64."""
    return sample_texture(Texture(np.asarray(image, np.float64), CLAMP_TO_EDGE,
                                  CLAMP_TO_EDGE), np.asarray(uv))


def albedo_atlas(scene: Scene, texels: TexelSpace) -> tuple[np.ndarray, np.ndarray]:
    """The clamped albedo (as transport clamps it) at the covered texels (t, 3) and as the
    bundle's dilated atlas (H, W, 3) float64."""
    rho, _ = clamp_albedo(albedo_at(scene, texels.triangle, texels.barycentric))
    return rho, texels.to_image(rho)[:, :, :3].astype(np.float64)


def shade_points(model: LearntShScenes, albedo: np.ndarray, position: np.ndarray,
                 normal: np.ndarray, light: np.ndarray, *, eye: np.ndarray | None = None,
                 specular: float = 0.0, exponent: float = 8.0) -> np.ndarray:
    """Outgoing radiance (m, 3) float64 at surface points (m, 3) with unit shading normals
    (m, 3) and albedo (m, 3), under light SH (L², 3): ``albedo · (T · l)``, plus with
    ``specular`` > 0 (a glossy network; ``eye`` (3,) the viewer) the Phong layer by the
    triple product (:func:`prtcore.methods.sh_prt.glossy_tp`)."""
    y = evaluate_scenes(model, position, normal)
    out = np.asarray(albedo, np.float64) * (transfer_of(model, y) @ light)
    if specular > 0:
        view = np.asarray(eye, np.float64) - position
        view /= np.linalg.norm(view, axis=1, keepdims=True)
        out += glossy_tp(visibility_of(model, y), light, reflect(view, normal), exponent,
                         np.full((len(out), 3), specular))
    return out


@dataclass(frozen=True, eq=False)
class ViewHits:
    """The front surface each pixel centre of a camera sees.

    pixels : (m,) int64 row-major pixel indices (top row first); uv1 (m, 2); position,
    normal (shading) (m, 3) float64
    """

    pixels: np.ndarray
    uv1: np.ndarray
    position: np.ndarray
    normal: np.ndarray


def view_hits(scene: Scene, tracer: RayTracer, camera: Camera) -> ViewHits:
    """Ray cast through ``camera``'s pixel centres (front faces only)."""
    hits = tracer.intersect(*camera.primary_rays())
    sel = np.flatnonzero(hits.hit & hits.front)
    tri, bary = hits.triangle[sel], hits.barycentric[sel]
    uv1 = np.einsum("mk,mkj->mj", bary, np.asarray(scene.uv1)[scene.faces[tri]])
    return ViewHits(sel, uv1, tracer.surface_point(tri, bary),
                    shading_normals(scene, tri, bary, tracer.face_normals[tri]))


def shade_view(model: LearntShScenes, albedo_image: np.ndarray, hits: ViewHits, camera: Camera,
               light: np.ndarray, *, specular: float = 0.0, exponent: float = 8.0
               ) -> np.ndarray:
    """The CPU equivalent of the GL camera pass: (h, w, 4) float64, A = 1 where a pixel
    centre sees a front face (``hits``)."""
    img = np.zeros((camera.height * camera.width, 4))
    img[hits.pixels, :3] = shade_points(
        model, sample_atlas(albedo_image, hits.uv1), hits.position, hits.normal, light,
        eye=camera.position, specular=specular, exponent=exponent)
    img[hits.pixels, 3] = 1.0
    return img.reshape(camera.height, camera.width, 4)


def shade_sdf_view(model: LearntShScenes, sdf: SdfScene, camera: Camera, light: np.ndarray, *,
                   specular: float = 0.0, exponent: float = 8.0) -> np.ndarray:
    """The CPU equivalent of the GL pass of an SDF bundle: each pixel centre's ray
    sphere-traced through the field (:func:`prtcore.core.sdf.sphere_trace`), the network
    at the hit with the field's normal, the scene's albedo: (h, w, 4) float64, A = 1 on
    hits."""
    origins, dirs = camera.primary_rays()
    hit, t = sphere_trace(sdf, origins, dirs, sdf_t_max(sdf, camera.position))
    p = origins[hit] + t[hit, None] * dirs[hit]
    img = np.zeros((len(dirs), 4))
    img[hit, :3] = shade_points(model, np.broadcast_to(np.asarray(sdf.albedo), p.shape), p,
                                sdf.normal(p), light, eye=camera.position,
                                specular=specular, exponent=exponent)
    img[hit, 3] = 1.0
    return img.reshape(camera.height, camera.width, 4)


# ---------------------------------------------------------------------------------------
# Metrics against transfer textures


def metrics_lighting(bands: int, seed: int) -> tuple[np.ndarray, dict]:
    """The metrics' light: a sky with a sun (:func:`prtcore.emitters.environment.
    sky_with_sun`, seeded) in SH (L², 3), and its description."""
    env, sun = sky_with_sun(np.random.default_rng(seed))
    light = env.sh_coefficients(bands) + light_sh(sun, bands)
    return light, {"kind": "sky_with_sun", "seed": seed,
                   "sun_direction": [float(v) for v in sun.direction],
                   "sun_lux": float(sun.intensity)}


def display(rgb: np.ndarray, exposure: float) -> np.ndarray:
    """Linear radiance → display image in [0, 1]: × exposure, clipped, sRGB-encoded."""
    return linear_to_srgb(np.clip(np.asarray(rgb) * exposure, 0.0, 1.0)).astype(np.float64)


def view_metrics(scene: Scene, tracer: RayTracer, texels: TexelSpace, model: LearntShScenes,
                 albedo_image: np.ndarray, *, views: int, width: int, height: int,
                 strata: int, seed: int, specular: float, exponent: float
                 ) -> tuple[dict, np.ndarray]:
    """The learnt transfer against transfer textures (shadowed, no bounce, the same bands,
    ``strata²`` rays per texel, at the bake's atlas) over ``views`` orbit cameras
    (:func:`prtcore.reference.camera.orbit_cameras`) under :func:`metrics_lighting`:
    display images with one exposure (0.9 over the baseline's 99.5th percentile over all
    views), MAE/PSNR/SSIM per view averaged, for "diffuse" and (glossy networks)
    "glossy" = diffuse + the Phong layer. "baseline_reseeded" is the same textures from
    independent rays (seed + 1) compared the same way: the reference's own noise.
    Returns (figures as JSON data, the first view's strip (h', w', 3) float32)."""
    bands = model.bands
    light, lighting = metrics_lighting(bands, seed)
    t0 = time.perf_counter()
    bases = [bake_sh_prt(scene, tracer, "texture", bands, strata, s, bounce=False,
                         texels=texels) for s in (seed, seed + 1)]
    vis = []
    if specular > 0:
        for s in (seed, seed + 1):
            v = visibility_transfer(tracer, texel_samples(texels), bands, strata, s)
            vis.append(texels.to_image(v)[:, :, :-1])
    baseline_seconds = time.perf_counter() - t0
    materials = ("diffuse", "glossy") if specular > 0 else ("diffuse",)
    linear: dict[str, list] = {f"{w}/{m}": [] for w in ("baseline", "reseeded", "learnt")
                               for m in materials}
    cameras = orbit_cameras(scene.center, scene.radius, views, width, height)
    cpu_seconds = 0.0
    for cam in cameras:
        hits = view_hits(scene, tracer, cam)
        for who, k in (("baseline", 0), ("reseeded", 1)):
            diffuse = evaluate_texture(bases[k].image, hits.uv1, light)
            imgs = {"diffuse": diffuse}
            if specular > 0:
                view = cam.position - hits.position
                view /= np.linalg.norm(view, axis=1, keepdims=True)
                imgs["glossy"] = diffuse + glossy_tp(
                    sample_atlas(vis[k], hits.uv1), light, reflect(view, hits.normal),
                    exponent, np.full((len(diffuse), 3), specular))
            for m in materials:
                full = np.zeros((height * width, 3))
                full[hits.pixels] = imgs[m]
                linear[f"{who}/{m}"].append(full.reshape(height, width, 3))
        for m in materials:
            t1 = time.perf_counter()
            img = shade_view(model, albedo_image, hits, cam, light,
                             specular=specular if m == "glossy" else 0.0, exponent=exponent)
            cpu_seconds += time.perf_counter() - t1
            linear[f"learnt/{m}"].append(img[:, :, :3])
    rows, strip = [], []
    for m in materials:
        exposure = 0.9 / max(float(np.percentile(np.stack(linear[f"baseline/{m}"]), 99.5)),
                             1e-12)
        ref = [display(im, exposure) for im in linear[f"baseline/{m}"]]
        cells = "" if model.grid.count == 1 else f"×{model.grid.count}"
        for who, name in (("learnt", f"learnt k{model.net.widths[0]}_l"
                                     f"{len(model.net.widths)}{cells}"),
                          ("reseeded", "baseline_reseeded")):
            per = [compare_images(display(im, exposure), r)
                   for im, r in zip(linear[f"{who}/{m}"], ref, strict=True)]
            rows.append({"material": m, "method": name, "exposure": exposure,
                         **{k: float(np.mean([p[k] for p in per]))
                            for k in ("mae", "psnr", "ssim")},
                         "psnr_min": float(np.min([p["psnr"] for p in per]))})
        shown = display(linear[f"learnt/{m}"][0], exposure)
        strip.append(np.concatenate([ref[0], shown, np.clip(4 * np.abs(shown - ref[0]), 0, 1)],
                                    axis=1))
    h, w = albedo_image.shape[:2]
    figures = {
        "views": views, "width": width, "height": height, "lighting": lighting,
        "baseline": {"kind": "transfer textures, shadowed, no bounce", "bands": bands,
                     "rays_per_texel": strata * strata, "atlas": [w, h],
                     "seconds": baseline_seconds},
        "rows": rows,
        "weights_bytes": int(4 * sum(a.size for m in model.models
                                     for a in (*m.net.weights, *m.net.biases))),
        "texture_bytes": int(h * w * 3 * bands * bands * TEXTURE_BYTES
                             + (h * w * bands * bands * TEXTURE_BYTES if specular > 0
                                else 0)),
        "cpu_ms_per_view": 1e3 * cpu_seconds / max(views * len(materials), 1),
    }
    return figures, np.concatenate(strip, axis=0).astype(np.float32)


def format_metrics(metrics: dict, gpu: dict | None = None) -> str:
    """The metrics table ``prtcore report`` prints for a learnt_sh bundle."""
    lines = [f"learnt SH vs transfer textures ({metrics['baseline']['rays_per_texel']} rays "
             f"per texel, atlas {metrics['baseline']['atlas'][0]}×"
             f"{metrics['baseline']['atlas'][1]}), {metrics['views']} orbit views "
             f"{metrics['width']}×{metrics['height']}, sky with sun (seed "
             f"{metrics['lighting']['seed']})",
             f"{'material':<9s} {'method':<18s} {'MAE':>7s} {'PSNR dB':>8s} "
             f"{'min dB':>7s} {'SSIM':>6s}"]
    for r in metrics["rows"]:
        lines.append(f"{r['material']:<9s} {r['method']:<18s} {r['mae']:>7.4f} "
                     f"{r['psnr']:>8.2f} {r['psnr_min']:>7.2f} {r['ssim']:>6.3f}")
    lines.append(f"weights {metrics['weights_bytes']} B (float32) vs transfer textures "
                 f"{metrics['texture_bytes']} B (half): "
                 f"{metrics['weights_bytes'] / metrics['texture_bytes']:.3f}×")
    lines.append(f"frame time: CPU (numpy) {metrics['cpu_ms_per_view']:.1f} ms per view")
    if gpu:
        lines.append(f"frame time: GL {gpu['median_ms']:.2f} ms median wall clock of "
                     f"{gpu['frames']} frames at {gpu['width']}×{gpu['height']} "
                     f"({gpu.get('pass', 'learnt_sh')} pass) on {gpu['renderer']}")
    else:
        lines.append("frame time: GL not measured (`prtcore report --gpu`)")
    lines.append("(baseline_reseeded: the same textures from independent rays — the "
                 "ceiling the reference's own noise sets)")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------
# The method


def _uniform_sky(bands: int) -> np.ndarray:
    """(L², 3) SH of a uniform white sky of radiance 1 (only the DC term, √(4π))."""
    light = np.zeros((bands * bands, 3))
    light[0] = math.sqrt(4.0 * math.pi)
    return light


@register
class LearntShMethod(DirectMethod):
    """The thesis' learnt transfer: no light dataset; the network is trained from
    ray-traced transfer at surface samples (stage "fit"), measured against transfer
    textures (stage "report")."""

    name = "learnt_sh"

    def fit(self, inputs: BakeInputs, timer: StageTimer) -> LearntShBake:
        spec = inputs.spec.learnt_sh
        scene, texels = inputs.intake.scene, inputs.intake.texels
        tracer = default_tracer(scene)
        sdf = asset_sdf(inputs.intake.source)
        sdf_file = inputs.intake.source if sdf is not None else None
        with timer.stage("fit"):
            t0 = time.perf_counter()
            model = fit_scenes(scene, tracer, cells=spec.cells, overlap=spec.overlap,
                               samples=spec.samples, bands=spec.bands, strata=spec.strata,
                               width=spec.width, layers=spec.layers, steps=spec.steps,
                               batch=spec.batch, seed=spec.seed, glossy=spec.specular > 0,
                               sdf=sdf)
            seconds = time.perf_counter() - t0
        with timer.stage("report"):
            rho, albedo_image = albedo_atlas(scene, texels)
            preview = rho * (transfer_of(model, evaluate_scenes(model, texels.position,
                                                                texels.normal))
                             @ _uniform_sky(model.bands))
            metrics = strip = None
            if spec.views > 0:
                metrics, strip = view_metrics(
                    scene, tracer, texels, model, albedo_image, views=spec.views,
                    width=spec.view_width, height=spec.view_height,
                    strata=spec.baseline_strata, seed=spec.seed, specular=spec.specular,
                    exponent=spec.exponent)
        return LearntShBake(model, albedo_image, preview, texels.to_image(preview), metrics,
                            strip, spec, seconds, sdf_file)

    def write(self, directory: Path, inputs: BakeInputs, result: LearntShBake
              ) -> tuple[dict, dict]:
        spec, model = result.spec, result.model
        dtype = inputs.spec.output.dtype
        write_exr(directory / "albedo.exr", result.albedo_image, dtype=dtype,
                  channel_names=("R", "G", "B"))
        write_exr(directory / "coverage.exr", result.preview_image[:, :, -1:], dtype="half",
                  channel_names=("Y",))
        networks = write_scenes(directory, model)
        section = {"bands": model.bands, "coefficients": model.bands ** 2,
                   "networks": networks, "albedo": "albedo.exr",
                   "specular": spec.specular if model.glossy else 0.0,
                   "exponent": spec.exponent, "width": spec.width, "layers": spec.layers,
                   "training": model.diagnostics,
                   "weights_bytes": sum((directory / d["file"]).stat().st_size
                                        for d in networks["networks"]),
                   "convention": "prtcore.core.sh (docs/sh_prt.md); docs/learnt_sh.md"}
        if result.sdf_file is not None:  # the field the GL pass sphere-traces
            sdf = load_sdf(result.sdf_file)
            (directory / SDF_FILE).write_bytes(Path(result.sdf_file).read_bytes())
            section["sdf"] = {"file": SDF_FILE, "primitives": len(sdf.primitives),
                              "smooth": sdf.smooth, "albedo": list(sdf.albedo),
                              "format": "docs/learnt_sh.md, SDF scenes"}
        sections = {"learnt_sh": section, "runtime": {"formula": LEARNT_SH_FORMULA}}
        report = {"learnt_sh": section, "metrics": result.metrics,
                  "training_seconds": result.seconds}
        return sections, report

    def summary(self, result: LearntShBake, seconds: dict[str, float],
                with_verdict: bool = True) -> str:
        m, d = result.model, result.model.diagnostics
        lines = [f"learnt_sh: k = {m.net.widths[0]}, l = {len(m.net.widths)}, {m.bands} bands"
                 f"{'' if m.grid.count == 1 else f', {m.grid.count} sub-scenes'}"
                 f"{' + visibility (glossy)' if m.glossy else ''}; {d['samples']} samples × "
                 f"{d['strata']}² rays, {d['steps']} steps; held-out MSE "
                 f"{d['holdout_mse']:.3g} (untrained {d['holdout_mse_zero']:.3g}); "
                 f"{result.seconds:.1f} s"]
        if result.metrics:
            lines.append(format_metrics(result.metrics))
        if with_verdict:
            lines.append(self.verdict(result)["line"])
        return "\n".join(lines)

    def verdict(self, result: LearntShBake) -> dict[str, Any]:
        return {"status": "unknown", "line": "verdict: not judged — learnt_sh has no "
                "held-out light fit; its figures against transfer textures are in "
                "`prtcore report`", "causes": []}

    def plot(self, result: LearntShBake, path: Path) -> None:
        """report.png: the first metrics view (baseline | learnt | |difference| × 4, one
        row per material), or without metrics the preview over the atlas."""
        if result.strip is not None:
            write_png(path, np.round(result.strip * 255).astype(np.uint8))
        else:
            write_preview_png(path, result.preview_image)


def load_model(bundle: Path, manifest: dict) -> tuple[LearntShScenes, np.ndarray]:
    """The network and the albedo atlas (H, W, 3) float64 of a learnt_sh bundle."""
    sec = manifest["learnt_sh"]
    return (read_scenes(bundle, sec["networks"]),
            read_image(bundle / sec["albedo"])[:, :, :3].astype(np.float64))


def relight_bundle(bundle: Path, manifest: dict, lighting) -> np.ndarray:
    """The lightmap of a learnt_sh bundle under distant lighting (an object with
    ``sh_coefficients(bands)``): the network at every covered texel's position and
    shading normal, ``albedo · (T · l)``, dilated: (H, W, 4) float32 RGBA, A = coverage.
    The glossy layer depends on the view and is left out (as for sh_prt)."""
    from prtcore.io.gltf.loader import load_asset
    from prtcore.receivers.texels import build_texel_space

    model, albedo = load_model(bundle, manifest)
    atlas = manifest["atlas"]
    scene = load_asset(bundle / manifest["asset"]["file"])
    texels = build_texel_space(scene, atlas["width"], atlas["height"],
                               padding=atlas["padding"])
    x, y = texels.xy[:, 0], texels.xy[:, 1]
    light = lighting.sh_coefficients(model.bands)
    values = shade_points(model, albedo[y, x], texels.position, texels.normal, light)
    rgb = texels.to_image(values)[:, :, :3]
    coverage = read_image(bundle / atlas["coverage"])[:, :, :1]
    return np.concatenate([rgb, coverage], axis=2).astype(np.float32)


def gpu_frame_time(bundle: Path, metrics: dict, frames: int = 5) -> dict:
    """The GL runtime's frame time (:class:`prtcore.runtime.learnt_sh.LearntShRenderer`):
    ``frames`` frames of the metrics' first orbit view under their lighting after one
    warm-up frame (shader compilation); the median wall-clock milliseconds of the pass."""
    from prtcore.runtime.glcontext import renderer_label
    from prtcore.runtime.learnt_sh import LearntShRenderer

    with LearntShRenderer(bundle) as r:
        light, _ = metrics_lighting(r.bands, int(metrics["lighting"]["seed"]))
        cam = orbit_cameras(r.scene.center, r.scene.radius, 1, int(metrics["width"]),
                            int(metrics["height"]))[0]
        r.render(light, cam)
        wall = [r.render(light, cam).wall_milliseconds[r.pass_name] for _ in range(frames)]
        label, name = renderer_label(r.ctx), r.pass_name
    return {"median_ms": float(np.median(wall)), "frames": frames, "renderer": label,
            "width": cam.width, "height": cam.height, "pass": name}
