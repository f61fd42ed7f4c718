"""The bake-spec reference (docs/spec.md), generated from the spec's own definitions.

Every key of :class:`~prtcore.core.spec.BakeSpec` has an entry in :data:`DOCS`; the
defaults come from the dataclasses themselves, so the reference cannot drift from the
code (``tests/test_spec.py`` checks both: every key documented, the file up to date).
Regenerate with ``.venv/bin/python -m prtcore.core.spec_reference > docs/spec.md``.
"""

from __future__ import annotations

import dataclasses
import json

from prtcore.core.spec import (
    BakeSpec,
    ChiangSpec,
    LightFamily,
    MaterialOverride,
    SubsurfaceSpec,
)

#: "section.key" → what it means, its unit or choices, its range
DOCS: dict[str, str] = {
    "atlas.resolution": "lightmap width = height in texels, 8–16384 (limit: "
                        "`PRT_LIMIT_MAX_ATLAS_RESOLUTION`, default 4096)",
    "atlas.padding": "texels kept free around UV charts, 0–64",
    "prepare.repair": "`auto` (repair only what needs it) · `always` · `never`",
    "prepare.remesh": "isotropic remeshing target edge length as a fraction of the "
                      "bounding-box diagonal (1e-4–0.5), or null for none",
    "prepare.uv": "`auto` (keep a valid TEXCOORD_1, else generate) · `generate` · `keep` "
                  "(refuse when TEXCOORD_1 is missing or invalid)",
    "measurement_points.count": "P, measurement points, 1–1048576, or `auto`: the bake "
                                "tries P = 256, 512, … up to `sizing.max_points` and "
                                "ships the smallest that meets the verdict's target "
                                "(hair bakes: 256 on the hull, fitted again on 512 and "
                                "1024 while the verdict fails on the transfer's ratio, "
                                "with no second transport; docs/hair.md)",
    "measurement_points.placement": "`auto` (`qdeim` when the bake chooses P: count "
                                    "`auto` on a static bake; else `surface`) · "
                                    "`surface` (blue noise on the asset) · `hull` (on "
                                    "its convex hull) · `qdeim` (chosen for the transfer "
                                    "from blue-noise candidates by pivoted QR on their "
                                    "direct light, Drmač & Gugercin 2016)",
    "measurement_points.candidates": "blue-noise candidates the points are chosen from "
                                     "(`qdeim`, or count `auto`; 0: 8 × count, or 2 × "
                                     "`sizing.max_points` when count is `auto`)",
    "measurement_points.supersample": "samples averaged per measurement point, 1–256",
    "measurement_points.seed": "seed of the placement",
    "lights.count": "K, training lighting configurations, 1–65536, or `auto`: start at "
                    "`sizing.lights_start` and double (tracing only the new lights) while "
                    "the verdict's target is not met, within `sizing`'s budget (hair "
                    "bakes: 128, 256 with a mesh, 512 with the Chiang fibre, baked once "
                    "more with twice that when the verdict fails on the transfer's ratio "
                    "and the memory estimate allows; docs/hair.md)",
    "lights.holdout": "held-out validation configurations, 0–65536",
    "lights.seed": "seed of the light draws (training and held-out streams are "
                   "independent)",
    "lights.families": "list of light families (below); one is drawn per configuration "
                       "by weight",
    "transport.gather_rays": "M, cosine gather rays per texel, 1–4096",
    "transport.max_bounces": "indirect bounces at most, 0–1000",
    "transport.tolerance": "relative change that ends the bounce iteration, (0, 1]",
    "transport.seed": "seed of the gather and direct sampling",
    "transport.direct_samples": "points per texel whose direct light is averaged, 1–64",
    "transport.near_field": "gather hits closer than this many texel footprints take the "
                            "direct light of the hit point in the first bounce (0: off), "
                            "0–16",
    "fit.basis": "n, basis elements including the mean (1–4096), or `auto` (the smallest "
                 "n whose held-out error is within 1 % of the best)",
    "transport.coarse_grid": "the solve iterates on cells of s × s atlas texels, the "
                             "first bounce and two closing steps at full resolution "
                             "(prtcore/transport/coarse.py), 1–16 (1: every bounce at full "
                             "resolution), or `auto` (atlas side / 128, at most 8)",
    "transport.subsurface_walks": "random walks per translucent texel through its medium "
                                  "(docs/subsurface.md), 1–4096",
    "transport.subsurface_max_scatter": "scattering events after which a walk is dropped "
                                        "(its light counts as absorbed), 1–1048576",
    "hair.texels_per_strand": "texels along each strand of a hair asset's strand texture "
                              "(docs/hair.md), 1–4096",
    "hair.albedo": "null (the hair file's colours), or [r, g, b] in [0, 1]: one fibre "
                   "colour for every strand",
    "hair.fibre": "`diffuse` (Lambertian fibre, radially averaged) · `chiang` (the "
                  "Chiang et al. 2016 hair BCSDF, parameters in `hair.chiang`; point, "
                  "spot, directional and environment lights)",
    "hair.chiang": "the Chiang fibre's parameters (`hair.chiang` below)",
    "chiang.eumelanin": "eumelanin concentration (0 blond … 8 black), 0–50, or null: "
                        "σ_a from the fibre colour read as the hair volume's colour",
    "chiang.pheomelanin": "pheomelanin concentration (red), 0–50, with eumelanin",
    "chiang.beta_m": "longitudinal roughness, 0.1–1",
    "chiang.beta_n": "azimuthal roughness, 0.1–1",
    "chiang.alpha_deg": "cuticle tilt in degrees, −10–10",
    "chiang.eta": "index of refraction of the fibre, 1–3",
    "chiang.exitance": "`auto` (`second_order` with `hair.gather_rays` ≥ 256 or "
                       "where the strand texels are denoised (hair alone, or dense "
                       "hair with a mesh), "
                       "else `linear`, where the bake's memory estimate is within "
                       "`max_bake_bytes`, else the next one down, and the run says so) · "
                       "`linear` (transport carries each texel's direction-averaged "
                       "outgoing radiance plus a linear function of direction, through "
                       "every bounce: 11 % per texel on the tangle, docs/hair.md) · "
                       "`quadratic` (plus cos² θ (cos 2φ, sin 2φ): 10 %, 1.5× the solve) "
                       "· `second_order` (plus sin² θ − 1/4 and sin θ cos θ (cos φ, "
                       "sin φ), kept as one quadratic form in world axes: ten terms) "
                       "· `isotropic` (the average alone, the paper's: 38 %, the "
                       "cheapest); with a `--mesh` too",
    "chiang.near_fibres": "with a `--mesh`: an atlas texel's gather ray that meets a fibre "
                          "closer than this many of the texel's footprints is shaded at "
                          "the point it meets (its direct light from punctual lights, "
                          "the hits on a 32nd of a strand texel sharing a shadow ray a "
                          "light; its light from the mesh and the other fibres with 2 "
                          "rays), not read as the strand texel's mean; 0–64, 0 off. 20 "
                          "(the default) reads the 10k head's scalp at 11.0 % / +0.5 % "
                          "per texel with dark hair and 6.9 % / −1.2 % with light hair "
                          "(5 with the shaded hits at 20: 11.3 % / +0.8 % and 6.9 % / "
                          "−1.8 %), for 1.35 s a light there: 11.9 min at 528 lights "
                          "(docs/hair.md)",
    "chiang.shaded_fibres": "with a `--mesh`: beyond `near_fibres`, an atlas texel's "
                            "gather ray that meets a fibre closer than this many of the "
                            "texel's footprints keeps its strand texel's read for the "
                            "later bounces, but its first bounce takes the fibre's "
                            "direct light from punctual lights shaded at the point met "
                            "(as `near_fibres` shades it), not the texel's mean; 0–1024, "
                            "at most `near_fibres` (the default) off. With the near "
                            "fibres at 5, 20 took the 10k head's dark scalp bias from "
                            "+2.2 to +0.8 % and the light one's from −1.2 to −1.8 %; "
                            "the near fibres at 20 shade those hits and gather their "
                            "light at the point too (docs/hair.md)",
    "chiang.gathered_fibres": "with a `--mesh`: beyond `near_fibres`, an atlas texel's "
                              "gather ray that meets a fibre closer than this many of the "
                              "texel's footprints gathers the fibre's light from the mesh "
                              "and the other fibres at the point met (2 rays, as "
                              "`near_fibres`), and reads its direct light from the strand "
                              "texel; 0–1024, at most `near_fibres` (the default) off; "
                              "the shaded hits start beyond it (docs/hair.md)",
    "hair.harmonics": "`auto` (`first_bounce` for hair alone, `adaptive` for hair "
                      "baked with a mesh) · `first_bounce` (the direct light's first "
                      "azimuthal harmonic in the first bounce) · `all_bounces` (every "
                      "texel's mean, cos and sin through every bounce: 9× the operator, a "
                      "slower solve) · `mesh_bounces` (with a mesh: the fibres' harmonics "
                      "carry the direct light and the mesh's through every bounce, not "
                      "other fibres'; without one it is `first_bounce`) · "
                      "`turn_bounces` (`all_bounces` on the texels whose fibre turns "
                      "less than 30° along them, `mesh_bounces` on the others) · "
                      "`adaptive` (`all_bounces` for sparse hair, where fewer than 60 % "
                      "of the rays from the fibres meet another fibre, `turn_bounces` "
                      "otherwise; the report's `transport.fibre.harmonic_receivers` "
                      "says which texels took other fibres' light)",
    "hair.denoise_neighbours": "`auto` (64; for `chiang` alone 16 from 512 fibre-gather "
                               "rays a texel, docs/hair.md \"Small hair spends the "
                               "hairball's rays\"; "
                               "for `chiang` with a mesh 128 where at least "
                               "0.6 of the fibre gather's rays meet another fibre, traced "
                               "on 4096 texels before the transport, else 0: docs/hair.md, "
                               "\"Dense hair with a mesh: second order, denoised\"), or k "
                               "in 0–1024: every strand texel's indirect irradiance "
                               "taken from a local linear fit through its k nearest texels "
                               "in space (Epanechnikov weights, adaptive radius; "
                               "docs/hair.md); 0 or 1: off",
    "hair.gather_rays": "`auto` (`transport.gather_rays`; for `chiang` alone that × s, "
                        "s the largest power of two up to 8 with s·T ≤ 100 000 strand "
                        "texels: small hair spends the 10k hairball's rays; for `chiang` "
                        "with a mesh 128 "
                        "on dense hair, where the memory estimate allows it: docs/hair.md, "
                        "\"Dense hair with a mesh: second order, denoised\"), or M_h in "
                        "1–4096: the fibre gather's rays per strand texel; "
                        "`transport.gather_rays` stays the atlas's",
    "hair.max_bounces": "`auto` (64 for `chiang`: its solve on a basis of the lights "
                        "converges slowly on light hair and its late bounces are cheap; "
                        "`transport.max_bounces` for the diffuse fibre), or 0–1000: the "
                        "hair solve's bounces at most (docs/hair.md, \"Where the solve "
                        "stops\")",
    "hair.denoise_direction": "`auto` (`t2` for `chiang`, `none` for the diffuse fibre), "
                              "`none`, `t2` or `t12`: the terms of the fibre's direction "
                              "t that the denoiser's local fit takes besides the plane: "
                              "`t2` the five of t tᵀ − I/3 (a radially averaged fibre's "
                              "response turns with its direction through them), `t12` "
                              "also t (docs/hair.md, \"Denoising the Chiang fibre\")",
    "hair.arc_subdivision": "`auto` (2 for the diffuse fibre with a mesh when the hair is curly: "
                            "the median texel's fibre turns 30° or more along it; 1 "
                            "otherwise), or "
                            "S in 1–8: each strand texel is transported as S pieces of "
                            "1/S its arc (⌈M/S⌉ fibre-gather rays and ⌈J/S⌉ facing "
                            "samples each, so about the same rays), averaged back into "
                            "the texel after the solve; the strand texture's layout is "
                            "unchanged. Under dense curls a whole texel's average read "
                            "where another fibre or the scalp sees it is a few per cent "
                            "bright (docs/hair.md); refused above 1 with the `chiang` "
                            "fibre and with hair alone",
    "hair.direct": "the diffuse fibre's direct light: `facing` (one shadow ray per arc "
                   "sample and light, from a point across the fibre's projected width; "
                   "the azimuth integrated in closed form) · `sampled` (J stratified "
                   "azimuths per texel, each shaded); refused with the `chiang` fibre, "
                   "which samples its own; docs/hair.md",
    "hair.direct_samples": "`auto` (2 arc samples for `facing`, max(4, "
                           "`transport.direct_samples`) points for `sampled` and for "
                           "`chiang`, times s for `chiang` alone, s as for "
                           "`hair.gather_rays`), or 1–256; "
                           "`facing` with 1 traces half the shadow rays (the 10k "
                           "hairball's dataset 35 s instead of 46 s, 7.9 % instead of "
                           "6.4 % against the path tracer; docs/hair.md)",
    "fit.ridge": "λ ≥ 0 in normalised units, or `auto` (leave-one-out)",
    "fit.channels": "`mono` (one basis for R, G, B) · `rgb` (one per channel)",
    "fit.gamma": "null, or g in [1, 10]: fit values as |v|^(1/g)",
    "fit.denoise": "`auto`, or a radius in texels (0–8) of the seam-aware filter applied "
                   "to the training and held-out lightmaps alike before the basis is "
                   "fitted (0: off). `auto` traces the first 8 held-out lights a second "
                   "time with an independent seed and ships the radius of 0, 0.75, 1.5, "
                   "2.5 with the least estimated error against the noiseless lightmaps (manifest "
                   "`transport_noise`); keyframe bakes take 1.5, and so do hair + mesh bakes "
                   "(their atlas rows only; hair alone: 0)",
    "fit.transfer": "`ridge` (linear, paper 4.3) · `mlp` (the ridge plus a learnt "
                    "residual network trained on its leave-one-out errors; "
                    "docs/bundle.md)",
    "fit.mlp_width": "`mlp`: neurons per hidden layer, 1–256",
    "fit.mlp_layers": "`mlp`: hidden layers (leaky ReLU), 1–8",
    "fit.mlp_steps": "`mlp`: AdamW steps at most (the count is chosen on a seeded "
                     "validation fifth of the training lights), 0–100000",
    "fit.seed": "`mlp`: seed of the initial weights and the validation split",
    "keyframes.animation": "animation index or name to bake keyframes of; null: static",
    "keyframes.count": "keyframes drawn (stratified) when `times` is not given, 1–4096",
    "keyframes.times": "explicit keyframe times in seconds",
    "keyframes.transfer": "`shared` (one transfer for all keyframes) · `per_keyframe`",
    "keyframes.seed": "seed of the keyframe draws",
    "output.dtype": "basis EXR pixels: `half` · `float`",
    "validate.target_ratio": "the verdict fails when the held-out error at the shipped n is "
                             "above this multiple of the projection bound, ≥ 1",
    "validate.max_error": "... or when the held-out error, relative to the RMS of all "
                          "held-out indirect lightmaps, is above this, > 0",
    "validate.reference_spp": "0: judge against the held-out lights' fast transport; > 0: "
                              "path-trace `reference_lights` of them at this many samples "
                              "per texel and judge their noise-corrected error",
    "validate.reference_lights": "held-out lights path-traced when `reference_spp` > 0",
    "sizing.max_points": "largest P tried when `measurement_points.count` is `auto`",
    "sizing.lights_start": "K of the first transport pass when `lights.count` is `auto`, ≥ 2",
    "sizing.max_lights": "largest K automatic sizing may grow to, ≥ `lights_start`",
    "sizing.max_seconds": "growing K stops when the next pass would end past this many "
                          "seconds of transport (0: no time limit; the memory limit holds)",
    "method.name": "`data_driven` (Belcour et al. 2022) · `sh_prt` (classic SH-PRT or "
                   "transfer textures, section `sh_prt`; docs/sh_prt.md) · `learnt_sh` "
                   "(the thesis' network σ(p, n̂) → SH transfer, section `learnt_sh`; "
                   "docs/learnt_sh.md)",
    "learnt_sh.bands": "L, SH bands of the learnt transfer (L² network outputs), 1–8",
    "learnt_sh.width": "k, neurons per hidden layer (thesis: 64 or 128)",
    "learnt_sh.layers": "l, hidden layers, leaky ReLU (thesis: 4)",
    "learnt_sh.samples": "area-uniform training samples on the surface",
    "learnt_sh.strata": "rays per training sample = strata² (more rays: less noisy "
                        "targets)",
    "learnt_sh.steps": "AdamW steps",
    "learnt_sh.batch": "minibatch size",
    "learnt_sh.seed": "seed of the samples, rays, initial weights and minibatches (same "
                      "seed, same weights)",
    "learnt_sh.specular": "ρ_s of a glossy Phong layer (0: diffuse only); > 0 makes the "
                          "network also learn the visibility SH for the triple product",
    "learnt_sh.exponent": "Phong exponent n of the glossy layer",
    "learnt_sh.views": "camera views on an orbit for the bake's metrics against transfer "
                       "textures (0: none)",
    "learnt_sh.view_width": "width of each metrics view in pixels",
    "learnt_sh.view_height": "height of each metrics view in pixels",
    "learnt_sh.baseline_strata": "the baseline transfer textures' rays per texel = this²",
    "learnt_sh.cells": "sub-scenes (thesis 4.1.5): [nx, ny, nz] grid cells over the "
                       "samples' bounds, one network each (1–16 per axis)",
    "learnt_sh.overlap": "δ: each cell's network is trained on its cell grown by this "
                         "share of the cell's size into the neighbours, 0–1",
    "sh_prt.storage": "`texture` (transfer textures: per lightmap texel, RGBA EXRs) · "
                      "`vertex` (per vertex, Sloan et al. 2002)",
    "sh_prt.bands": "L, SH bands (L² coefficients per colour channel), 1–16; 5 = the "
                    "poster's 25 coefficients",
    "sh_prt.strata": "rays per sample = strata² (stratified cosine directions), 1–128",
    "sh_prt.bounce": "add one inter-reflection bounce computed from the stored shadowed "
                     "transfer (T⁰ + T¹)",
    "sh_prt.seed": "seed of the transfer rays",
    "sh_prt.specular": "ρ_s of a glossy Phong layer on every material, 0–1 (0: diffuse "
                       "only); > 0 stores visibility textures for the triple product (TP, "
                       "texture storage only), drawn by `prtcore render`",
    "sh_prt.exponent": "Phong exponent n of the glossy layer, 0–10000 (the lobe "
                       "(n+1)/(2π)·cosⁿ about the mirror direction, band-limited to "
                       "`bands`)",
    "material.subsurface": "the medium inside the material's closed mesh (below); null: "
                           "as the asset says (KHR_materials_volume, "
                           "KHR_materials_diffuse_transmission, KHR_materials_volume_scatter)",
    "material.boundary": "`lambertian`: light enters and leaves with a cosine distribution; "
                         "the boundary reflects and transmits the same albedo "
                         "½((1 − t)·base colour + t·base colour) on both sides",
    "material.transmission": "t, the boundary's diffuse transmission factor, 0–1",
    "subsurface.albedo": "multiple-scattering albedo (the colour of a thick slab under "
                         "diffuse light), a number or [r, g, b] in [0, 1]; the "
                         "single-scattering albedo is Chiang et al. 2016's inversion",
    "subsurface.mean_free_path": "1/σ_t, world units, a number or [r, g, b], > 0",
    "subsurface.anisotropy": "Henyey–Greenstein g, −0.99–0.99",
    "family.type": "`point` · `spot` · `directional` (KHR_lights_punctual) · "
                   "`environment` (distant radiance, prtcore/emitters/environment_light.py)",
    "family.weight": "relative probability of this family",
    "family.position": "`{\"shell\": [a, b]}` (radii in units of the asset's bounding "
                       "radius) · `{\"box\": [[x,y,z], [x,y,z]]}` (world) · "
                       "`{\"fixed\": [x,y,z]}`",
    "family.aim": "`{\"jitter\": j}` toward the asset's centre, `{\"target\": [x,y,z]}`, "
                  "or `{\"direction\": [x,y,z]}` (spot, directional)",
    "family.intensity": "`{\"uniform\": [a, b]}` · `{\"log_uniform\": [a, b]}` · "
                        "`{\"constant\": v}` — cd (point, spot) or lux (directional)",
    "family.color": "`white` · `random` · `[r, g, b]` linear",
    "family.inner_cone_angle": "spot inner cone (radians, a distribution as above), "
                               "default 0",
    "family.outer_cone_angle": "spot outer cone (radians, a distribution as above)",
    "family.range": "KHR range in metres, or null (infinite)",
    "family.from_asset": "jitter around the asset's own KHR_lights_punctual lights of "
                         "this type",
    "family.environment": "type environment only (default \"sky\"): \"sky\" — an analytic "
                          "sky whose sun direction is drawn like a directional light's —, "
                          "\"ambient\" — uniform radiance, an ambient term beside a "
                          "directional family —, or an equirect map file turned about +y "
                          "by the drawn direction's azimuth; direct light = hemisphere "
                          "integral (docs/lights.md)",
}


def _default(v) -> str:
    if dataclasses.is_dataclass(v):
        v = dataclasses.asdict(v)
    if isinstance(v, tuple):
        v = [dataclasses.asdict(x) if dataclasses.is_dataclass(x) else x for x in v]
    return "`" + json.dumps(v) + "`"


def keys() -> list[str]:
    """Every documented key: "section.key" of BakeSpec, "family.key" of a light family."""
    out = []
    for sec in _sections():
        out += [f"{sec.name}.{f.name}" for f in dataclasses.fields(sec.default)]
    out += [f"family.{f.name}" for f in dataclasses.fields(LightFamily)]
    out += [f"material.{f.name}" for f in dataclasses.fields(MaterialOverride)]
    out += [f"subsurface.{f.name}" for f in dataclasses.fields(SubsurfaceSpec)]
    out += [f"chiang.{f.name}" for f in dataclasses.fields(ChiangSpec)]
    return out


def _sections() -> list:
    """The sections of BakeSpec with fixed keys (``materials`` is keyed by name)."""
    return [s for s in dataclasses.fields(BakeSpec) if s.name != "materials"]


def reference() -> str:
    """docs/spec.md as text."""
    spec, fam = BakeSpec(), LightFamily()
    lines = ["# The bake spec", "",
             "JSON; every key optional; unknown keys are refused with their path. "
             "Generated from `prtcore/core/spec.py` by `prtcore/core/spec_reference.py`.", ""]
    for sec in _sections():
        lines += [f"## `{sec.name}`", "", "| key | default | meaning |", "|---|---|---|"]
        for f in dataclasses.fields(sec.default):
            d = _default(getattr(getattr(spec, sec.name), f.name))
            lines.append(f"| `{f.name}` | {d} | {DOCS[f'{sec.name}.{f.name}']} |")
        lines.append("")
    lines += ["## A light family (`lights.families[i]`)", "",
              "| key | default | meaning |", "|---|---|---|"]
    for f in dataclasses.fields(LightFamily):
        lines.append(f"| `{f.name}` | {_default(getattr(fam, f.name))} | "
                     f"{DOCS['family.' + f.name]} |")
    lines += ["", "## `materials`", "",
              "An object keyed by material name (a name the asset does not have is "
              "refused); each value overrides that material (docs/subsurface.md):", "",
              "| key | default | meaning |", "|---|---|---|"]
    for cls, prefix in ((MaterialOverride, "material"), (SubsurfaceSpec, "subsurface")):
        if prefix == "subsurface":
            lines += ["", "### `materials.<name>.subsurface`", "",
                      "| key | default | meaning |", "|---|---|---|"]
        obj = cls()
        for f in dataclasses.fields(cls):
            lines.append(f"| `{f.name}` | {_default(getattr(obj, f.name))} | "
                         f"{DOCS[prefix + '.' + f.name]} |")
    lines += ["", "## `hair.chiang`", "",
              "The Chiang fibre's parameters (`hair.fibre = \"chiang\"`, docs/hair.md):", "",
              "| key | default | meaning |", "|---|---|---|"]
    obj = ChiangSpec()
    for f in dataclasses.fields(ChiangSpec):
        lines.append(f"| `{f.name}` | {_default(getattr(obj, f.name))} | "
                     f"{DOCS['chiang.' + f.name]} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(reference(), end="")
