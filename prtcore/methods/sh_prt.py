"""Classic SH-PRT (Sloan et al. 2002) and transfer textures (the poster, thesis ch. 3).

Both store diffuse transfer vectors (:mod:`prtcore.transport.sh_transfer`) for distant
lighting in spherical harmonics; they differ in where:

* ``vertex`` — one transfer vector per mesh vertex; the runtime evaluates ``T · l`` per
  vertex (the vertex-shader variant) and the rasteriser interpolates the colour
  barycentrically, so quality follows tessellation;
* ``texture`` — one per lightmap texel, in RGBA EXRs (four SH coefficients of one colour
  channel per file) dilated into the atlas padding; the runtime evaluates ``T · l`` per
  fragment from bilinearly filtered textures, so a two-triangle floor still gets its
  shadow.

Transfer is shadowed (T⁰) and, with ``bounce``, one-bounce inter-reflected (T⁰ + T¹): the
poster's T₁ computed from the stored T₀ (interpolated from the vertices, or looked up in
the dilated texture at the bounce's hit point).

:func:`bake_sh_prt` is the library entry point; :class:`ShPrtMethod` the registered
method (``"method": {"name": "sh_prt"}``, section ``sh_prt`` of the spec) that writes a
bundle; :mod:`prtcore.io.transfer_textures` the file format; :func:`memory_table` the
poster's Table 1 for one asset. Glossy Phong: :func:`glossy_tp` (the poster's TP: stored
visibility × light by the triple product) and :func:`glossy_tpfl` (TPFL: stored L·V for a
fixed light), with :func:`evaluate_vertex` / :func:`evaluate_texture` the CPU equivalents
of the GL variants (:mod:`prtcore.runtime.sh_gl`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prtcore.core import sh
from prtcore.core.materials import CLAMP_TO_EDGE, sample_texture
from prtcore.core.progress import StageTimer
from prtcore.core.raytrace import RayTracer
from prtcore.core.scene import Scene, Texture
from prtcore.io.bundle import raw_file
from prtcore.io.imageio import read_image, write_exr, write_png
from prtcore.io.transfer_textures import (
    VISIBILITY,
    read_transfer_textures,
    write_transfer_textures,
)
from prtcore.methods.base import BakeInputs, DirectMethod, register
from prtcore.receivers.texels import TexelSpace
from prtcore.transport.sh_transfer import (
    ShTransfer,
    SurfaceSamples,
    shadowed_transfer,
    texel_lookup,
    vertex_lookup,
    vertex_samples,
    visibility_transfer,
)

#: bytes per stored coefficient: float32 per vertex (a vertex attribute), half per texel
VERTEX_BYTES = 4
TEXTURE_BYTES = 2


@dataclass(frozen=True, eq=False)
class ShPrtResult:
    """One SH-PRT bake.

    storage : "vertex" | "texture"; transfer : per vertex (V, 3, L²) or per covered texel
    (t, 3, L²) float64 (:class:`ShTransfer`); image : texture storage only, the dilated
    atlas (H, W, 3, L²) float32 with coverage (H, W) float32; seconds : bake time.
    """

    storage: str
    transfer: ShTransfer
    image: np.ndarray | None
    coverage: np.ndarray | None
    seconds: float

    @property
    def bands(self) -> int:
        return self.transfer.bands

    @property
    def storage_bytes(self) -> int:
        """Bytes of the stored transfer: V·3·L²·4 (float32 vertex attributes) or
        W·H·3·L²·2 (half-float textures, the whole atlas)."""
        if self.storage == "vertex":
            return int(self.transfer.coeffs.shape[0] * self.transfer.coeffs[0].size
                       * VERTEX_BYTES)
        h, w = self.image.shape[:2]
        return int(h * w * self.transfer.coeffs[0].size * TEXTURE_BYTES)


def texel_samples(texels: TexelSpace) -> SurfaceSamples:
    """The covered texels as transfer samples."""
    return SurfaceSamples(texels.position, texels.normal, texels.geometric_normal,
                          texels.albedo)


def _texture_image(texels: TexelSpace, transfer: ShTransfer) -> tuple[np.ndarray, np.ndarray]:
    img = texels.to_image(transfer.coeffs.reshape(texels.count, -1))
    n = transfer.bands ** 2
    return img[..., :-1].reshape(texels.height, texels.width, 3, n), img[..., -1]


def bake_sh_prt(scene: Scene, tracer: RayTracer, storage: str, bands: int, strata: int,
                seed: int, *, bounce: bool = True, texels: TexelSpace | None = None
                ) -> ShPrtResult:
    """Shadowed (and with ``bounce`` one-bounce inter-reflected) diffuse transfer stored
    per ``storage`` ("vertex" or "texture"; texture needs ``texels``), ``strata²`` rays per
    sample, every random choice from ``seed``."""
    t0 = time.perf_counter()
    if storage == "vertex":
        samples = vertex_samples(scene)
        transfer = shadowed_transfer(scene, tracer, samples, bands, strata, seed)
        if bounce:
            transfer = shadowed_transfer(scene, tracer, samples, bands, strata, seed,
                                         bounce_lookup=vertex_lookup(scene, transfer))
        return ShPrtResult("vertex", transfer, None, None, time.perf_counter() - t0)
    if storage != "texture":
        raise ValueError(f"SH-PRT storage must be 'vertex' or 'texture', got {storage!r}")
    if texels is None:
        raise ValueError("texture storage needs the texel space")
    samples = texel_samples(texels)
    transfer = shadowed_transfer(scene, tracer, samples, bands, strata, seed)
    if bounce:
        image, _ = _texture_image(texels, transfer)
        transfer = shadowed_transfer(scene, tracer, samples, bands, strata, seed,
                                     bounce_lookup=texel_lookup(scene, image))
    image, coverage = _texture_image(texels, transfer)
    return ShPrtResult("texture", transfer, image, coverage, time.perf_counter() - t0)


# ---------------------------------------------------------------------------------------
# Files


def evaluate_texture(image: np.ndarray, uv: np.ndarray, light: np.ndarray) -> np.ndarray:
    """The fragment-shader variant on the CPU: bilinear transfer at lightmap ``uv`` (m, 2)
    (TEXCOORD_1, origin top-left, clamped at the edges) dotted with light SH (L², 3).
    Returns (m, 3) float64 outgoing radiance."""
    # shade the texels, then filter: linear, so the same as filtering the transfer
    lit = np.einsum("hwcl,lc->hwc", image.astype(np.float64), np.asarray(light, np.float64))
    return sample_texture(Texture(lit, CLAMP_TO_EDGE, CLAMP_TO_EDGE), np.asarray(uv))


def evaluate_vertex(scene: Scene, transfer: ShTransfer, triangle: np.ndarray,
                    barycentric: np.ndarray, light: np.ndarray) -> np.ndarray:
    """The vertex-shader variant on the CPU: ``T · l`` per vertex, interpolated
    barycentrically at surface points (triangle (m,), barycentric (m, 3)). (m, 3) float64."""
    per_vertex = transfer.radiance(light)
    return np.einsum("mk,mkc->mc", barycentric, per_vertex[scene.faces[triangle]])


def memory_table(vertices: int, texture_sizes: tuple[int, ...], bands_list: tuple[int, ...]
                 ) -> list[dict]:
    """The poster's Table 1 for one asset: bytes of per-vertex storage (float32, 3 colour
    channels) and of transfer textures (half float, whole atlas, 3 channels) per band
    count. Rows: {"storage", "size", "bands", "coefficients", "bytes"}."""
    rows = []
    for b in bands_list:
        n = sh.n_coeffs(b)
        rows.append({"storage": "vertex", "size": vertices, "bands": b, "coefficients": n,
                     "bytes": vertices * 3 * n * VERTEX_BYTES})
        for s in texture_sizes:
            rows.append({"storage": "texture", "size": s, "bands": b, "coefficients": n,
                         "bytes": s * s * 3 * n * TEXTURE_BYTES})
    return rows


# ---------------------------------------------------------------------------------------
# Glossy Phong at runtime (the poster's TP and TPFL)


def reflect(view: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Mirror directions (n, 3) of unit ``view`` directions (toward the viewer) about unit
    ``normal`` (n, 3)."""
    return 2.0 * np.einsum("ij,ij->i", view, normal)[:, None] * normal - view


def phong_from_radiance_sh(lv: np.ndarray, reflected: np.ndarray, exponent: float,
                           specular: np.ndarray) -> np.ndarray:
    """Glossy outgoing radiance ``ρ_s ∫ (LV)(ω) (n+1)/(2π) cos^n∠(ω, r) dω`` from the SH of
    the shadowed incident radiance ``lv`` (n, 3, L²): Funk–Hecke with the Phong lobe's
    zonal coefficients, evaluated at the mirror directions ``reflected`` (n, 3);
    ``specular`` ρ_s (n, 3). Returns (n, 3) float64."""
    bands = math.isqrt(lv.shape[2])
    y = sh.basis(reflected, bands) * sh.zonal_kernel(sh.phong_zonal(exponent, bands))
    return np.asarray(specular, np.float64) * np.einsum("pcl,pl->pc", lv, y)


def glossy_tp(visibility: np.ndarray, light: np.ndarray, reflected: np.ndarray,
              exponent: float, specular: np.ndarray) -> np.ndarray:
    """TP: the light's SH (L², 3) times the stored visibility SH (n, L²) by the triple
    product (:func:`prtcore.core.sh.product_matrix`, once per light and channel), then the
    Phong lobe at the mirror directions. Returns (n, 3) float64."""
    light = np.asarray(light, np.float64)
    mats = np.stack([sh.product_matrix(light[:, c]) for c in range(3)])  # (3, k, j)
    lv = np.einsum("ckj,pj->pck", mats, visibility)
    return phong_from_radiance_sh(lv, reflected, exponent, specular)


def glossy_tpfl(fixed: np.ndarray, reflected: np.ndarray, exponent: float,
                specular: np.ndarray) -> np.ndarray:
    """TPFL: the stored SH of ``L·V`` for the fixed light (n, 3, L²) and the Phong lobe at
    the mirror directions (no triple product at runtime). Returns (n, 3) float64."""
    return phong_from_radiance_sh(fixed, reflected, exponent, specular)


# ---------------------------------------------------------------------------------------
# The method (``"method": {"name": "sh_prt"}`` in the bake spec)

#: how an engine evaluates an sh_prt bundle (the manifest's runtime.formula)
SH_PRT_FORMULA = (
    "outgoing radiance, channel c = sum_i T[c, i] * l[i, c]: T the stored transfer vector "
    "(per vertex, interpolated barycentrically; or per fragment from the transfer textures "
    "sampled bilinearly at TEXCOORD_1, texture k of channel c holding coefficients "
    "4k..4k+3 in R, G, B, A), l the light's real SH coefficients (prtcore.core.sh: "
    "orthonormal, no Condon-Shortley phase, index l(l+1)+m) of the distant radiance")


def _uniform_sky(bands: int) -> np.ndarray:
    """(L², 3) SH of a uniform white sky of radiance 1 (only the DC term, √(4π))."""
    light = np.zeros((bands * bands, 3))
    light[0] = math.sqrt(4.0 * math.pi)
    return light


def sky_lightmap(scene: Scene, texels: TexelSpace, result: ShPrtResult) -> np.ndarray:
    """(t, 3) outgoing radiance at the covered texels under a uniform white sky of radiance
    1 (albedo × ambient occlusion, plus the bounce): the bake's preview image."""
    light = _uniform_sky(result.bands)
    if result.storage == "texture":
        return result.transfer.radiance(light)
    return evaluate_vertex(scene, result.transfer, texels.triangle, texels.barycentric, light)


def write_preview_png(path: Path, preview_image: np.ndarray) -> None:
    """report.png of a preview atlas (H, W, ≥3): clipped to [0, 1], gamma 2.2, 8 bits."""
    rgb = np.clip(preview_image[:, :, :3], 0.0, 1.0)
    write_png(path, (rgb ** (1 / 2.2) * 255 + 0.5).astype(np.uint8))


@dataclass(frozen=True, eq=False)
class ShPrtBake:
    """The method's result: the SH-PRT bake, its preview lightmap (t, 3) at the covered
    texels and the same as a dilated atlas image (H, W, 4), A = coverage."""

    bake: ShPrtResult
    preview: np.ndarray
    preview_image: np.ndarray
    spec: object
    #: the glossy layer's visibility SH as an atlas (H, W, 1, L²) (``sh_prt.specular`` > 0)
    visibility: np.ndarray | None = None


@register
class ShPrtMethod(DirectMethod):
    """Classic SH-PRT (per vertex) or transfer textures (per texel): no light dataset, no
    fit; the transfer is ray traced directly (stage "fit")."""

    name = "sh_prt"

    def fit(self, inputs: BakeInputs, timer: StageTimer) -> ShPrtBake:
        spec = inputs.spec.sh_prt
        scene, texels = inputs.intake.scene, inputs.intake.texels
        tracer = RayTracer(scene.positions, scene.faces, scene.radius)
        with timer.stage("fit"):
            bake = bake_sh_prt(scene, tracer, spec.storage, spec.bands, spec.strata,
                               spec.seed, bounce=spec.bounce, texels=texels)
            visibility = None
            if spec.specular > 0:  # the glossy layer's T₀ for the triple product
                vis = visibility_transfer(tracer, texel_samples(texels), spec.bands,
                                          spec.strata, spec.seed)
                visibility = texels.to_image(vis)[:, :, :-1][:, :, None, :]
        with timer.stage("report"):
            preview = sky_lightmap(scene, texels, bake)
        return ShPrtBake(bake, preview, texels.to_image(preview), spec, visibility)

    def write(self, directory: Path, inputs: BakeInputs, result: ShPrtBake
              ) -> tuple[dict, dict]:
        bake, texels = result.bake, inputs.intake.texels
        dtype = inputs.spec.output.dtype
        section = {"storage": bake.storage, "bands": bake.bands,
                   "coefficients": bake.bands ** 2, "kind": bake.transfer.kind,
                   "rays_per_sample": bake.transfer.samples, "seed": result.spec.seed,
                   "storage_bytes": bake.storage_bytes,
                   "convention": "prtcore.core.sh (docs/sh_prt.md)"}
        if bake.storage == "texture":
            section["files"] = write_transfer_textures(directory, bake.image, dtype)
            section["layout"] = ("sh_transfer_{R,G,B}_{k}.exr: R, G, B, A = coefficients "
                                 "4k..4k+3 of that colour channel, dilated")
            section["dtype"] = dtype
            if result.visibility is not None:
                section["glossy"] = {
                    "model": "TP: specular · Σ_k (M_c V)_k z_k Y_k(r), M_c = Σ_i Γ_ijk l_ic, V "
                             "the visibility SH, z the Phong lobe's Funk–Hecke kernel, r the "
                             "mirror direction of the view about the shading normal",
                    "specular": result.spec.specular, "exponent": result.spec.exponent,
                    "files": write_transfer_textures(directory, result.visibility, dtype,
                                                     VISIBILITY)}
        else:
            section["vertex_transfer"] = raw_file(directory / "sh_vertex_transfer.bin",
                                                  bake.transfer.coeffs.astype(np.float32))
            section["layout"] = "vertex_transfer[v, c, i]: vertex v of asset.glb, channel c"
        write_exr(directory / "coverage.exr", result.preview_image[:, :, -1:], dtype="half",
                  channel_names=("Y",))
        memory = memory_table(len(inputs.intake.scene.positions), (texels.width,),
                              (bake.bands,))
        sections = {"sh_prt": section, "runtime": {"formula": SH_PRT_FORMULA},
                    "memory": memory}
        report = {"sh_prt": section, "memory": memory, "bake_seconds": bake.seconds}
        return sections, report

    def summary(self, result: ShPrtBake, seconds: dict[str, float],
                with_verdict: bool = True) -> str:
        b = result.bake
        lines = [f"sh_prt: {b.storage} storage, {b.bands} bands ({b.bands ** 2} "
                 f"coefficients × 3 channels), {b.transfer.kind}, {b.transfer.samples} rays "
                 f"per sample, {b.storage_bytes / 1024:.1f} KiB, {b.seconds:.1f} s"]
        if with_verdict:
            lines.append(self.verdict(result)["line"])
        return "\n".join(lines)

    def verdict(self, result: ShPrtBake) -> dict[str, Any]:
        return {"status": "unknown", "line": "verdict: not judged — sh_prt has no held-out "
                "fit; `prtcore compare` measures it against the path tracer",
                "causes": []}

    def plot(self, result: ShPrtBake, path: Path) -> None:
        """report.png: the preview (uniform white sky of radiance 1) over the atlas."""
        write_preview_png(path, result.preview_image)


def relight_bundle(bundle: Path, manifest: dict, lighting) -> np.ndarray:
    """The lightmap of an sh_prt bundle under distant lighting (an object with
    ``sh_coefficients(bands)``, e.g. :class:`prtcore.emitters.environment.DistantLighting`):
    (H, W, 4) float32 RGBA, A = coverage. Texture storage: ``T · l`` per texel; vertex
    storage: ``T · l`` per vertex interpolated at the texels (what the vertex-shader
    variant shows on the atlas)."""
    from prtcore.io.bundle import load_raw
    from prtcore.io.gltf.loader import load_asset
    from prtcore.receivers.texels import build_texel_space

    section, atlas = manifest["sh_prt"], manifest["atlas"]
    light = lighting.sh_coefficients(section["bands"])
    coverage = read_image(bundle / atlas["coverage"])[:, :, :1]
    if section["storage"] == "texture":
        image = read_transfer_textures(bundle, section["bands"])
        rgb = np.einsum("hwcl,lc->hwc", image.astype(np.float64), light)
    else:
        scene = load_asset(bundle / manifest["asset"]["file"])
        texels = build_texel_space(scene, atlas["width"], atlas["height"],
                                   padding=atlas["padding"])
        coeffs = load_raw(bundle, section["vertex_transfer"]).astype(np.float64)
        t = ShTransfer(coeffs, section["kind"], section["bands"], 0)
        values = evaluate_vertex(scene, t, texels.triangle, texels.barycentric, light)
        rgb = texels.to_image(values)[:, :, :3]
    return np.concatenate([rgb, coverage], axis=2).astype(np.float32)
