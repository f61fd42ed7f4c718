"""The bake spec (docs/spec.md): strict validation, defaults, and a canonical JSON echo.

Every key is optional; unknown keys are rejected with their JSON path. The result is a
tree of frozen dataclasses; :func:`spec_to_dict` gives back the complete spec with all
defaults filled (echoed in the manifest and hashed for idempotent bakes).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from prtcore.core.errors import SpecError
from prtcore.core.jsonfile import read_json

# ---------------------------------------------------------------------------------------
# Sections


@dataclass(frozen=True)
class AtlasSpec:
    resolution: int = 512
    padding: int = 4


@dataclass(frozen=True)
class PrepareSpec:
    #: "auto": repair only what needs it; "always"; "never".
    repair: str = "auto"
    #: Isotropic remeshing target edge length as a fraction of the bounding-box diagonal,
    #: or None for no remeshing.
    remesh: float | None = None
    #: "auto": keep a valid TEXCOORD_1, else generate; "generate": always generate;
    #: "keep": require a valid TEXCOORD_1.
    uv: str = "auto"


@dataclass(frozen=True)
class PointsSpec:
    #: P, or "auto": the bake chooses P from the data (prtcore/sizing.py)
    count: int | str = "auto"
    #: "auto": "qdeim" when the bake chooses P (count "auto", static), else "surface"
    placement: str = "auto"  # "auto" | "surface" | "hull" | "qdeim"
    supersample: int = 8
    seed: int = 1
    #: blue-noise candidates the points are chosen from ("qdeim", or count "auto")
    #: (0: 8 × count, or 2 × sizing.max_points when count is "auto")
    candidates: int = 0


@dataclass(frozen=True)
class LightFamily:
    """One family of random lights. Distributions are kept as validated plain dicts."""

    type: str = "point"
    weight: float = 1.0
    position: dict = field(default_factory=lambda: {"shell": [1.5, 3.0]})
    aim: dict = field(default_factory=lambda: {"jitter": 0.3})
    intensity: dict = field(default_factory=lambda: {"log_uniform": [1.0, 100.0]})
    color: Any = "white"
    inner_cone_angle: Any = None
    outer_cone_angle: Any = field(default_factory=lambda: {"uniform": [0.3, 0.8]})
    range: float | None = None
    #: Seed this family from the asset's KHR_lights_punctual lights ("jitter around these").
    from_asset: bool = False
    #: type "environment" only: "sky" (an analytic sky whose sun direction is drawn like a
    #: directional light's), "ambient" (uniform radiance: beside a directional family, the
    #: "directional lights plus an ambient term") or an equirect map file turned about +y
    #: by the drawn direction's azimuth (docs/lights.md, emitters/environment_light.py)
    environment: str | None = None


@dataclass(frozen=True)
class LightsSpec:
    #: K, or "auto": start at sizing.lights_start and grow while the verdict needs it
    count: int | str = "auto"
    holdout: int = 16
    seed: int = 2
    families: tuple[LightFamily, ...] = (
        LightFamily(type="spot"),
    )


@dataclass(frozen=True)
class TransportSpec:
    gather_rays: int = 64
    max_bounces: int = 16
    tolerance: float = 1e-3
    seed: int = 3
    #: points per texel whose direct light is averaged (stratified over the texel)
    direct_samples: int = 4
    #: gather hits closer than this many texel footprints get the direct light of the hit
    #: point, not of its texel, in the first bounce (0: off)
    near_field: float = 1.0
    #: random walks per translucent texel through the medium (the subsurface operator)
    subsurface_walks: int = 32
    #: the solve iterates on cells of this many × this many atlas texels, the first bounce
    #: at full resolution (prtcore.transport.coarse); 1: every bounce at full resolution;
    #: "auto": prtcore.transport.coarse.grid_factor
    coarse_grid: int | str = "auto"
    #: scattering events after which a walk is dropped (its light counts as absorbed)
    subsurface_max_scatter: int = 4096


@dataclass(frozen=True)
class FitSpec:
    #: n, or "auto" (the smallest n within 1 % of the best held-out error). Not the default:
    #: n is the runtime's budget (blend cost and storage grow with it), and "auto" runs to
    #: the rank on smooth scenes (n = 45–64 on the Cornell example)
    basis: int | str = 16
    ridge: float | str = "auto"  # float ≥ 0 or "auto"
    channels: str = "mono"  # "mono" | "rgb"
    gamma: float | None = None
    #: radius in texels of the seam-aware filter applied to the lightmaps before the basis
    #: is fitted (0: off); keeps the gather's per-texel noise out of the basis. "auto":
    #: the radius with the least error against the noiseless lightmaps, measured with a
    #: second, independent transport of the held-out lights (prtcore/transport/noise.py)
    denoise: float | str = "auto"
    #: the transfer regressor: "ridge" | "mlp" (ridge + a learnt residual, issue 18)
    transfer: str = "ridge"
    mlp_width: int = 64
    mlp_layers: int = 2
    mlp_steps: int = 2000
    #: seed of the learnt transfer's initial weights and validation split
    seed: int = 0


@dataclass(frozen=True)
class KeyframesSpec:
    animation: int | str | None = None  # index or name; None: static bake
    count: int = 16
    times: tuple[float, ...] | None = None
    transfer: str = "shared"  # "shared" | "per_keyframe"
    seed: int = 4


@dataclass(frozen=True)
class OutputSpec:
    dtype: str = "half"  # "half" | "float"


@dataclass(frozen=True)
class ValidateSpec:
    #: the verdict fails when held-out error > target_ratio × the projection bound
    target_ratio: float = 1.25
    #: ... or when the held-out error (relative to the held-out RMS) exceeds this
    max_error: float = 0.5
    #: > 0: path-trace ``reference_lights`` held-out lights at this many samples per texel
    #: and judge their noise-corrected error instead of the fast transport's
    reference_spp: int = 0
    reference_lights: int = 4


@dataclass(frozen=True)
class SizingSpec:
    """The budget of automatic sizing (``"auto"`` counts; prtcore/sizing.py)."""

    #: largest P tried (P doubles from 256)
    max_points: int = 1024
    #: K of the first transport pass, and the most it may grow to (K doubles)
    lights_start: int = 128
    max_lights: int = 512
    #: growing K stops when the next transport pass would end past this many seconds of
    #: the bake's transport (0: no time limit; the memory limit always holds)
    max_seconds: float = 300.0


@dataclass(frozen=True)
class SubsurfaceSpec:
    """The medium of a translucent material (docs/subsurface.md)."""

    #: multiple-scattering albedo (the colour of a thick slab under diffuse light), linear
    #: RGB; inverted to the single-scattering albedo (Chiang et al. 2016)
    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)
    #: mean free path 1/σ_t per channel, world units
    mean_free_path: tuple[float, float, float] = (0.05, 0.05, 0.05)
    #: Henyey–Greenstein g
    anisotropy: float = 0.0


@dataclass(frozen=True)
class MaterialOverride:
    """``materials.<name>``: what the spec says about one material of the asset."""

    #: the medium inside (null: the material stays as the asset says)
    subsurface: SubsurfaceSpec | None = None
    #: the boundary model of a translucent material: "lambertian" (light enters and leaves
    #: with a cosine distribution; KHR_materials_diffuse_transmission)
    boundary: str = "lambertian"
    #: t, the boundary's diffuse transmission factor
    transmission: float = 0.5


#: boundary models of translucent materials
BOUNDARIES = ("lambertian",)


@dataclass(frozen=True)
class MethodSpec:
    #: the method that fits and writes the bundle (prtcore.methods): "data_driven" |
    #: "sh_prt" | "learnt_sh"
    name: str = "data_driven"


@dataclass(frozen=True)
class ShPrtSpec:
    """Classic SH-PRT / transfer textures (method "sh_prt", docs/sh_prt.md)."""

    storage: str = "texture"  # "texture" | "vertex"
    bands: int = 5
    strata: int = 16
    bounce: bool = True
    seed: int = 5
    #: > 0: a glossy Phong layer (TP, texture storage): ρ_s of every material
    specular: float = 0.0
    #: its Phong exponent n
    exponent: float = 8.0


@dataclass(frozen=True)
class LearntShSpec:
    """Learnt SH transfer, the thesis' network σ(p, n̂) (method "learnt_sh",
    docs/learnt_sh.md)."""

    bands: int = 4
    #: neurons per hidden layer k and hidden layers l (thesis: k 64 or 128, l 4)
    width: int = 128
    layers: int = 4
    #: area-uniform training samples, and rays per sample = strata²
    samples: int = 8000
    strata: int = 16
    #: AdamW steps on minibatches of ``batch``
    steps: int = 1500
    batch: int = 512
    seed: int = 0
    #: > 0: a glossy Phong layer of this ρ_s (the network also learns the visibility SH)
    specular: float = 0.0
    exponent: float = 8.0
    #: the bake's metrics against transfer textures: camera views on an orbit, their size,
    #: and the textures' rays per texel = baseline_strata² (0 views: no metrics)
    views: int = 30
    view_width: int = 96
    view_height: int = 64
    baseline_strata: int = 16
    #: sub-scenes (thesis 4.1.5): a grid of (nx, ny, nz) cells, one network each, trained
    #: on its cell grown by ``overlap`` × the cell's size into the neighbours
    cells: tuple[int, int, int] = (1, 1, 1)
    overlap: float = 0.1


@dataclass(frozen=True)
class ChiangSpec:
    """``hair.chiang``: the Chiang et al. 2016 fibre (``hair.fibre = "chiang"``,
    prtcore/core/bcsdf.py). With ``eumelanin`` null, σ_a comes from the fibre colour (the
    file's or ``hair.albedo``) read as the hair volume's colour."""

    #: eumelanin concentration (0 blond … 8 black), or null: σ_a from the colour
    eumelanin: float | None = None
    #: pheomelanin concentration (red), with eumelanin
    pheomelanin: float = 0.0
    #: longitudinal and azimuthal roughness
    beta_m: float = 0.3
    beta_n: float = 0.3
    #: cuticle tilt, degrees
    alpha_deg: float = 2.0
    #: index of refraction of the fibre
    eta: float = 1.55
    #: what transport carries of each texel's outgoing radiance: "linear" (its average
    #: plus a linear function of direction, through every bounce: 11 % per texel on the
    #: tangle), "quadratic" (plus second-order azimuthal terms: 10 %, 1.5× linear's
    #: solve), "second_order" (the whole second order: ten terms), "isotropic" (the
    #: average alone, the paper's: 38 %, the least memory) or "auto": second_order with
    #: ≥ 256 gather rays or denoised strand texels (hair alone; dense hair with a
    #: mesh), else linear, where the bake's memory estimate allows it, else
    #: isotropic (prtcore.hairbake.chiang_exitance); docs/hair.md
    exitance: str = "auto"
    #: with a mesh: where an atlas texel's gather ray meets a fibre closer than this many
    #: of the texel's footprints, the fibre is shaded at the point met (its direct light
    #: from punctual lights, and its light from the mesh and the other fibres gathered
    #: there), not read as its strand texel's mean (prtcore.transport.fibre_near;
    #: docs/hair.md: 5 took the dark 10k head's scalp from 15.0 to 12.4 % per texel and
    #: the light one from 9.4 to 7.7 %; 20, the default since 2026-12-07, took the light
    #: scalp's bias from −1.8 to −1.2 % and the dark one's from +0.8 to +0.5 % against
    #: the near fibres at 5 and the shaded hits at 20, for 11.9 min at 528 lights); 0:
    #: every hit reads its texel
    near_fibres: float = 20.0
    #: with a mesh: beyond ``near_fibres``, an atlas texel's gather ray that meets a
    #: fibre closer than this many of the texel's footprints still reads its strand
    #: texel for the later bounces, but the fibre's direct light from punctual lights
    #: reaches the first bounce shaded at the point met (prtcore.transport.fibre_near.
    #: shaded_fibre_correction); at most ``near_fibres`` (the default): off. docs/hair.md:
    #: with the near fibres at 5, 20 took the dark 10k head's scalp bias from +2.2 to
    #: +0.8 % (the light one's from −1.2 to −1.8 %); the near fibres at 20 do that and
    #: gather the fibre's indirect light at the point too
    shaded_fibres: float = 0.0
    #: with a mesh: beyond ``near_fibres``, an atlas texel's gather ray that meets a
    #: fibre closer than this many of the texel's footprints is a near hit whose rays
    #: gather the fibre's light from the mesh and the other fibres at the point met, but
    #: whose direct light is read from its strand texel (prtcore.transport.fibre_near;
    #: the shaded hits start beyond it); at most ``near_fibres`` (the default): off
    gathered_fibres: float = 0.0


@dataclass(frozen=True)
class HairSpec:
    """``hair``: how a hair asset (``.hair``, USD BasisCurves) is baked (docs/hair.md)."""

    #: texels along each strand in the strand texture (paper: 10)
    texels_per_strand: int = 10
    #: fibre colour for every strand, linear RGB; null: the file's colours
    albedo: tuple[float, float, float] | None = None
    #: the fibre scattering model ("diffuse": Lambertian fibre, radially averaged)
    fibre: str = "diffuse"
    #: azimuthal harmonics in transport: "first_bounce" | "all_bounces" | "mesh_bounces" |
    #: "turn_bounces" | "adaptive" | "auto" (docs/hair.md; "auto": first_bounce for hair
    #: alone, adaptive for hair baked with a mesh; mesh_bounces without a mesh is
    #: first_bounce; turn_bounces: all_bounces on the texels whose fibre turns less than
    #: 30° along them, mesh_bounces on the others; adaptive: all_bounces where fewer than
    #: SPARSE_FIBRE_SHARE (0.6) of the fibre gather's rays meet another fibre (sparse
    #: hair), turn_bounces otherwise)
    harmonics: str = "auto"
    #: k: every strand texel's indirect light from a local linear fit through its k nearest
    #: texels in space (prtcore.transport.strand_denoise; docs/hair.md); 0 or 1: off;
    #: "auto": 64; for "chiang" with a mesh 128 on dense hair (at least 0.6 of the fibre
    #: gather's rays meet another fibre, traced before the transport), else 0: on sparse
    #: hair the filter bends bias in (prtcore.hairbake.dense_hair; docs/hair.md)
    denoise_neighbours: int | str = "auto"
    #: M_h, the fibre gather's rays per strand texel (transport.gather_rays stays the
    #: atlas's, with a mesh); "auto": transport.gather_rays, or for "chiang" with a mesh
    #: 128 on dense hair where the bake's memory estimate allows it
    #: (prtcore.hairbake.dense_hair; docs/hair.md)
    gather_rays: int | str = "auto"
    #: the hair solve's bounces at most (transport.max_bounces stays the other bakes');
    #: "auto": 64 for "chiang" (its series on a basis of the lights converges slowly on
    #: light hair, and its late bounces are cheap: 16 left the 10k head 0.3–0.4 % short),
    #: transport.max_bounces for the diffuse fibre (docs/hair.md)
    max_bounces: int | str = "auto"
    #: the fibre-direction terms the denoiser's fit takes besides the plane: "none" | "t2"
    #: (the second band of the fibre's direction, five terms) | "t12" (also the first) |
    #: "auto": "t2" for "chiang" (whose texels differ with the fibre's direction through
    #: its lobes), "none" for the diffuse fibre (prtcore.transport.strand_denoise)
    denoise_direction: str = "auto"
    #: the diffuse fibre's direct-light estimator: "facing" (one shadow ray per arc sample
    #: and light from across the projected width, the azimuth in closed form) | "sampled"
    #: (J stratified azimuths per texel, each shaded) (prtcore.transport.fibre_facing)
    direct: str = "facing"
    #: samples per strand texel for the direct light: the diffuse fibre's arc samples
    #: (facing) or surface points (sampled), the Chiang fibre's surface points; "auto":
    #: FACING_SAMPLES (facing), or max(4, transport.direct_samples) (sampled, and the
    #: Chiang fibre with a mesh; alone, times the small-hair scale of
    #: prtcore.hairbake.small_hair, up to 8×)
    direct_samples: int | str = "auto"
    #: how many pieces each strand texel is transported as (the diffuse fibre with a
    #: mesh): S pieces of 1/S the arc, ⌈M/S⌉ fibre-gather rays and ⌈J/S⌉ facing samples
    #: each, averaged back into the texel after the solve; "auto": 2 with a mesh when the
    #: hair is curly (the median texel turns ≥ 30°), else 1 (docs/hair.md, "Transporting
    #: each texel in pieces")
    arc_subdivision: int | str = "auto"
    #: the Chiang fibre's parameters (used with ``fibre = "chiang"``)
    chiang: ChiangSpec = ChiangSpec()


#: fibre models a hair bake can use
FIBRE_MODELS = ("diffuse", "chiang")
#: the diffuse fibre's direct-light estimators (``hair.direct``)
DIRECT_ESTIMATORS = ("facing", "sampled")
#: the most pieces ``hair.arc_subdivision`` cuts a strand texel into
MAX_ARC_SUBDIVISION = 8


@dataclass(frozen=True)
class BakeSpec:
    atlas: AtlasSpec = AtlasSpec()
    prepare: PrepareSpec = PrepareSpec()
    measurement_points: PointsSpec = PointsSpec()
    lights: LightsSpec = LightsSpec()
    transport: TransportSpec = TransportSpec()
    fit: FitSpec = FitSpec()
    keyframes: KeyframesSpec = KeyframesSpec()
    output: OutputSpec = OutputSpec()
    validate: ValidateSpec = ValidateSpec()
    sizing: SizingSpec = SizingSpec()
    method: MethodSpec = MethodSpec()
    sh_prt: ShPrtSpec = ShPrtSpec()
    learnt_sh: LearntShSpec = LearntShSpec()
    hair: HairSpec = HairSpec()
    #: material name → :class:`MaterialOverride`
    materials: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------------
# Validation helpers


def _type_name(v: Any) -> str:
    return type(v).__name__ if v is not None else "null"


def _int(v: Any, key: str, lo: int | None = None, hi: int | None = None) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        if isinstance(v, float) and v.is_integer():
            v = int(v)
        else:
            raise SpecError(key, f"expected an integer, got {_type_name(v)} {v!r}")
    if lo is not None and v < lo:
        raise SpecError(key, f"must be ≥ {lo}, got {v}")
    if hi is not None and v > hi:
        raise SpecError(key, f"must be ≤ {hi}, got {v}")
    return int(v)


def _int_or_auto(v: Any, key: str, lo: int, hi: int) -> int | str:
    return "auto" if v == "auto" else _int(v, key, lo=lo, hi=hi)


def _num(v: Any, key: str, lo: float | None = None, hi: float | None = None,
         lo_open: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise SpecError(key, f"expected a number, got {_type_name(v)} {v!r}")
    v = float(v)
    if not math.isfinite(v):
        raise SpecError(key, f"must be finite, got {v}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise SpecError(key, f"must be {'>' if lo_open else '≥'} {lo}, got {v}")
    if hi is not None and v > hi:
        raise SpecError(key, f"must be ≤ {hi}, got {v}")
    return v


def _choice(v: Any, key: str, choices: tuple[str, ...]) -> str:
    if v not in choices:
        raise SpecError(key, f"must be one of {', '.join(map(repr, choices))}, got {v!r}")
    return v


def _obj(v: Any, key: str, allowed: tuple[str, ...]) -> dict:
    if not isinstance(v, dict):
        raise SpecError(key or "<root>", f"expected an object, got {_type_name(v)}")
    unknown = sorted(set(v) - set(allowed))
    if unknown:
        where = f"{key}.{unknown[0]}" if key else unknown[0]
        raise SpecError(where, f"unknown key (allowed: {', '.join(allowed)})")
    return v


def _vec3(v: Any, key: str) -> list[float]:
    if not isinstance(v, list | tuple) or len(v) != 3:
        raise SpecError(key, f"expected [x, y, z], got {v!r}")
    return [_num(x, f"{key}[{i}]") for i, x in enumerate(v)]


def _range(v: Any, key: str, lo: float | None = None, lo_open: bool = False) -> list[float]:
    if not isinstance(v, list | tuple) or len(v) != 2:
        raise SpecError(key, f"expected [min, max], got {v!r}")
    a, b = (_num(x, f"{key}[{i}]", lo=lo, lo_open=lo_open) for i, x in enumerate(v))
    if b < a:
        raise SpecError(key, f"min {a} is greater than max {b}")
    return [a, b]


def _scalar_dist(v: Any, key: str, lo: float | None = None, lo_open: bool = False,
                 allow_log: bool = True) -> dict:
    """A number, ``{"uniform": [a, b]}``, or ``{"log_uniform": [a, b]}`` (a > 0)."""
    if isinstance(v, int | float) and not isinstance(v, bool):
        return {"constant": _num(v, key, lo=lo, lo_open=lo_open)}
    kinds = ("constant", "uniform", "log_uniform") if allow_log else ("constant", "uniform")
    d = _obj(v, key, kinds)
    if len(d) != 1:
        raise SpecError(key, f"give exactly one of {', '.join(kinds)}")
    (kind, arg), = d.items()
    if kind == "constant":
        return {"constant": _num(arg, f"{key}.constant", lo=lo, lo_open=lo_open)}
    if kind == "log_uniform":
        return {"log_uniform": _range(arg, f"{key}.log_uniform", lo=0.0, lo_open=True)}
    return {"uniform": _range(arg, f"{key}.uniform", lo=lo, lo_open=lo_open)}


def _position(v: Any, key: str) -> dict:
    d = _obj(v, key, ("shell", "box", "fixed"))
    if len(d) != 1:
        raise SpecError(key, "give exactly one of shell, box, fixed")
    (kind, arg), = d.items()
    if kind == "shell":
        return {"shell": _range(arg, f"{key}.shell", lo=0.0)}
    if kind == "fixed":
        return {"fixed": _vec3(arg, f"{key}.fixed")}
    if not isinstance(arg, list | tuple) or len(arg) != 2:
        raise SpecError(f"{key}.box", f"expected [[x0,y0,z0], [x1,y1,z1]], got {arg!r}")
    lo, hi = _vec3(arg[0], f"{key}.box[0]"), _vec3(arg[1], f"{key}.box[1]")
    if any(b < a for a, b in zip(lo, hi, strict=True)):
        raise SpecError(f"{key}.box", "first corner must be ≤ second corner on every axis")
    return {"box": [lo, hi]}


def _aim(v: Any, key: str) -> dict:
    d = _obj(v, key, ("jitter", "target", "direction"))
    out: dict = {}
    if "jitter" in d:
        out["jitter"] = _num(d["jitter"], f"{key}.jitter", lo=0.0)
    if "target" in d:
        out["target"] = _vec3(d["target"], f"{key}.target")
    if "direction" in d:
        out["direction"] = _vec3(d["direction"], f"{key}.direction")
    if "target" in out and "direction" in out:
        raise SpecError(key, "give target or direction, not both")
    return out


def _color(v: Any, key: str) -> Any:
    if v in ("white", "random"):
        return v
    if isinstance(v, list | tuple):
        c = _vec3(v, key)
        if min(c) < 0:
            raise SpecError(key, f"colour components must be ≥ 0, got {c}")
        return c
    raise SpecError(key, f"expected 'white', 'random' or [r, g, b], got {v!r}")


_FAMILY_KEYS = tuple(f.name for f in dataclasses.fields(LightFamily))


def _family(v: Any, key: str) -> LightFamily:
    d = _obj(v, key, _FAMILY_KEYS)
    base = LightFamily()
    t = _choice(d.get("type", base.type), f"{key}.type",
                ("point", "spot", "directional", "environment"))
    kw: dict[str, Any] = {"type": t}
    kw["weight"] = _num(d.get("weight", base.weight), f"{key}.weight", lo=0.0, lo_open=True)
    kw["position"] = _position(d.get("position", base.position), f"{key}.position")
    kw["aim"] = _aim(d.get("aim", base.aim), f"{key}.aim")
    kw["intensity"] = _scalar_dist(d.get("intensity", base.intensity), f"{key}.intensity",
                                   lo=0.0)
    kw["color"] = _color(d.get("color", base.color), f"{key}.color")
    half_pi = math.pi / 2
    if t == "spot":
        outer = _scalar_dist(d.get("outer_cone_angle", base.outer_cone_angle),
                             f"{key}.outer_cone_angle", lo=0.0, lo_open=True, allow_log=False)
        vals = outer.get("uniform", [outer.get("constant")])
        if max(vals) > half_pi:
            raise SpecError(f"{key}.outer_cone_angle", f"must be ≤ π/2, got {max(vals)}")
        kw["outer_cone_angle"] = outer
        if d.get("inner_cone_angle") is not None:
            kw["inner_cone_angle"] = _scalar_dist(d["inner_cone_angle"],
                                                  f"{key}.inner_cone_angle", lo=0.0,
                                                  allow_log=False)
    else:
        for k in ("outer_cone_angle", "inner_cone_angle"):
            if d.get(k) is not None:
                raise SpecError(f"{key}.{k}", f"only spot lights have cone angles, not {t}")
        kw["outer_cone_angle"] = None
    if t == "environment":
        env = d.get("environment", "sky")
        if not isinstance(env, str) or not env:
            raise SpecError(f"{key}.environment",
                            f'expected "sky", "ambient" or a map file, got {env!r}')
        kw["environment"] = env
    elif d.get("environment") is not None:
        raise SpecError(f"{key}.environment", f"only environment lights have one, not {t}")
    if d.get("range") is not None:
        if t in ("directional", "environment"):
            raise SpecError(f"{key}.range", f"{t} lights have no range")
        kw["range"] = _num(d["range"], f"{key}.range", lo=0.0, lo_open=True)
    if "from_asset" in d:
        if not isinstance(d["from_asset"], bool):
            raise SpecError(f"{key}.from_asset", "expected true or false")
        kw["from_asset"] = d["from_asset"]
    return LightFamily(**kw)


def _rgb(v: Any, key: str, lo: float, hi: float | None = None, lo_open: bool = False
         ) -> tuple[float, float, float]:
    """One number for all channels, or [r, g, b]."""
    if isinstance(v, list | tuple):
        if len(v) != 3:
            raise SpecError(key, f"expected a number or [r, g, b], got {v!r}")
        return tuple(_num(x, f"{key}[{i}]", lo=lo, hi=hi, lo_open=lo_open)
                     for i, x in enumerate(v))
    x = _num(v, key, lo=lo, hi=hi, lo_open=lo_open)
    return (x, x, x)


_MATERIAL_KEYS = tuple(f.name for f in dataclasses.fields(MaterialOverride))
_SUBSURFACE_KEYS = tuple(f.name for f in dataclasses.fields(SubsurfaceSpec))


def _material(v: Any, key: str) -> MaterialOverride:
    d = _obj(v, key, _MATERIAL_KEYS)
    base, sub = MaterialOverride(), None
    if d.get("subsurface") is not None:
        ss = _obj(d["subsurface"], f"{key}.subsurface", _SUBSURFACE_KEYS)
        sd = SubsurfaceSpec()
        sub = SubsurfaceSpec(
            albedo=_rgb(ss.get("albedo", sd.albedo), f"{key}.subsurface.albedo", 0.0, 1.0),
            mean_free_path=_rgb(ss.get("mean_free_path", sd.mean_free_path),
                                f"{key}.subsurface.mean_free_path", 0.0, lo_open=True),
            anisotropy=_num(ss.get("anisotropy", sd.anisotropy),
                            f"{key}.subsurface.anisotropy", lo=-0.99, hi=0.99))
    return MaterialOverride(
        subsurface=sub,
        boundary=_choice(d.get("boundary", base.boundary), f"{key}.boundary", BOUNDARIES),
        transmission=_num(d.get("transmission", base.transmission), f"{key}.transmission",
                          lo=0.0, hi=1.0))


def _chiang(v: Any) -> ChiangSpec:
    c = _section(ChiangSpec, v, "hair.chiang")
    d = ChiangSpec()
    eu = c.get("eumelanin", d.eumelanin)
    return ChiangSpec(
        eumelanin=None if eu is None else _num(eu, "hair.chiang.eumelanin", lo=0.0, hi=50.0),
        pheomelanin=_num(c.get("pheomelanin", d.pheomelanin), "hair.chiang.pheomelanin",
                         lo=0.0, hi=50.0),
        beta_m=_num(c.get("beta_m", d.beta_m), "hair.chiang.beta_m", lo=0.1, hi=1.0),
        beta_n=_num(c.get("beta_n", d.beta_n), "hair.chiang.beta_n", lo=0.1, hi=1.0),
        alpha_deg=_num(c.get("alpha_deg", d.alpha_deg), "hair.chiang.alpha_deg", lo=-10.0,
                       hi=10.0),
        eta=_num(c.get("eta", d.eta), "hair.chiang.eta", lo=1.0, hi=3.0),
        exitance=_choice(c.get("exitance", d.exitance), "hair.chiang.exitance",
                         ("auto", "isotropic", "linear", "quadratic", "second_order")),
        near_fibres=_num(c.get("near_fibres", d.near_fibres), "hair.chiang.near_fibres",
                         lo=0.0, hi=64.0),
        shaded_fibres=_num(c.get("shaded_fibres", d.shaded_fibres),
                           "hair.chiang.shaded_fibres", lo=0.0, hi=1024.0),
        gathered_fibres=_num(c.get("gathered_fibres", d.gathered_fibres),
                             "hair.chiang.gathered_fibres", lo=0.0, hi=1024.0))


def _section(cls: type, v: Any, key: str) -> dict:
    return _obj(v, key, tuple(f.name for f in dataclasses.fields(cls)))


def parse_spec(data: Any, file: str | None = None) -> BakeSpec:
    """Validate a decoded JSON spec and fill defaults.

    Raises :class:`SpecError` naming the JSON path of the first problem.
    """
    try:
        return _parse(data)
    except SpecError as e:
        if file and e.file is None:
            raise SpecError(e.key, e.what, file=file) from None
        raise


def _parse(data: Any) -> BakeSpec:
    if data is None:
        data = {}
    root = _obj(data, "", tuple(f.name for f in dataclasses.fields(BakeSpec)))

    a = _section(AtlasSpec, root.get("atlas", {}), "atlas")
    atlas = AtlasSpec(
        resolution=_int(a.get("resolution", 512), "atlas.resolution", lo=8, hi=16384),
        padding=_int(a.get("padding", 4), "atlas.padding", lo=0, hi=64),
    )

    p = _section(PrepareSpec, root.get("prepare", {}), "prepare")
    remesh = p.get("remesh")
    prepare = PrepareSpec(
        repair=_choice(p.get("repair", "auto"), "prepare.repair", ("auto", "always", "never")),
        remesh=None if remesh is None else _num(remesh, "prepare.remesh", lo=1e-4, hi=0.5),
        uv=_choice(p.get("uv", "auto"), "prepare.uv", ("auto", "keep", "generate")),
    )

    m = _section(PointsSpec, root.get("measurement_points", {}), "measurement_points")
    points = PointsSpec(
        count=_int_or_auto(m.get("count", "auto"), "measurement_points.count", lo=1,
                           hi=1 << 20),
        placement=_choice(m.get("placement", "auto"), "measurement_points.placement",
                          ("auto", "surface", "hull", "qdeim")),
        supersample=_int(m.get("supersample", 8), "measurement_points.supersample",
                         lo=1, hi=256),
        seed=_int(m.get("seed", 1), "measurement_points.seed", lo=0),
        candidates=_int(m.get("candidates", 0), "measurement_points.candidates", lo=0,
                        hi=1 << 20),
    )

    lt = _section(LightsSpec, root.get("lights", {}), "lights")
    fams = lt.get("families")
    if fams is None:
        families = LightsSpec().families
    else:
        if not isinstance(fams, list) or not fams:
            raise SpecError("lights.families", "expected a non-empty list of light families")
        families = tuple(_family(f, f"lights.families[{i}]") for i, f in enumerate(fams))
    lights = LightsSpec(
        count=_int_or_auto(lt.get("count", "auto"), "lights.count", lo=1, hi=1 << 16),
        holdout=_int(lt.get("holdout", 16), "lights.holdout", lo=0, hi=1 << 16),
        seed=_int(lt.get("seed", 2), "lights.seed", lo=0),
        families=families,
    )

    t = _section(TransportSpec, root.get("transport", {}), "transport")
    transport = TransportSpec(
        gather_rays=_int(t.get("gather_rays", 64), "transport.gather_rays", lo=1, hi=4096),
        max_bounces=_int(t.get("max_bounces", 16), "transport.max_bounces", lo=0, hi=1000),
        tolerance=_num(t.get("tolerance", 1e-3), "transport.tolerance", lo=0.0, hi=1.0,
                       lo_open=True),
        seed=_int(t.get("seed", 3), "transport.seed", lo=0),
        direct_samples=_int(t.get("direct_samples", 4), "transport.direct_samples", lo=1,
                            hi=64),
        near_field=_num(t.get("near_field", 1.0), "transport.near_field", lo=0.0, hi=16.0),
        subsurface_walks=_int(t.get("subsurface_walks", TransportSpec.subsurface_walks),
                              "transport.subsurface_walks", lo=1, hi=4096),
        coarse_grid=_int_or_auto(t.get("coarse_grid", TransportSpec.coarse_grid),
                                 "transport.coarse_grid", lo=1, hi=16),
        subsurface_max_scatter=_int(t.get("subsurface_max_scatter",
                                          TransportSpec.subsurface_max_scatter),
                                    "transport.subsurface_max_scatter", lo=1, hi=1 << 20),
    )

    f = _section(FitSpec, root.get("fit", {}), "fit")
    basis = _int_or_auto(f.get("basis", 16), "fit.basis", lo=1, hi=4096)
    ridge = f.get("ridge", "auto")
    ridge = "auto" if ridge == "auto" else _num(ridge, "fit.ridge", lo=0.0)
    gamma = f.get("gamma")
    fit = FitSpec(
        basis=basis,
        ridge=ridge,
        channels=_choice(f.get("channels", "mono"), "fit.channels", ("mono", "rgb")),
        # gamma < 1 expands the dynamic range (|v|^(1/g) overflows float64 for radiance
        # ~1e6 at g = 0.05, and the float32 model long before): refused, see fit.py
        gamma=None if gamma is None else _num(gamma, "fit.gamma", lo=1.0, hi=10.0),
        denoise="auto" if f.get("denoise", "auto") == "auto" else _num(
            f["denoise"], "fit.denoise", lo=0.0, hi=8.0),
        transfer=_choice(f.get("transfer", "ridge"), "fit.transfer", ("ridge", "mlp")),
        mlp_width=_int(f.get("mlp_width", 64), "fit.mlp_width", lo=1, hi=256),
        mlp_layers=_int(f.get("mlp_layers", 2), "fit.mlp_layers", lo=1, hi=8),
        mlp_steps=_int(f.get("mlp_steps", 2000), "fit.mlp_steps", lo=0, hi=100000),
        seed=_int(f.get("seed", 0), "fit.seed", lo=0),
    )

    k = _section(KeyframesSpec, root.get("keyframes", {}), "keyframes")
    anim = k.get("animation")
    if anim is not None and not isinstance(anim, str):
        anim = _int(anim, "keyframes.animation", lo=0)
    times = k.get("times")
    if times is not None:
        if not isinstance(times, list) or not times:
            raise SpecError("keyframes.times", "expected a non-empty list of times in seconds")
        times = tuple(_num(x, f"keyframes.times[{i}]", lo=0.0) for i, x in enumerate(times))
    keyframes = KeyframesSpec(
        animation=anim,
        count=_int(k.get("count", 16), "keyframes.count", lo=1, hi=4096),
        times=times,
        transfer=_choice(k.get("transfer", "shared"), "keyframes.transfer",
                         ("shared", "per_keyframe")),
        seed=_int(k.get("seed", 4), "keyframes.seed", lo=0),
    )
    if fit.transfer == "mlp" and keyframes.transfer == "per_keyframe":
        raise SpecError("fit.transfer", "'mlp' learns one shared transfer; "
                        "keyframes.transfer 'per_keyframe' needs 'ridge'")

    o = _section(OutputSpec, root.get("output", {}), "output")
    output = OutputSpec(dtype=_choice(o.get("dtype", "half"), "output.dtype", ("half", "float")))

    v = _section(ValidateSpec, root.get("validate", {}), "validate")
    d = ValidateSpec()
    validate = ValidateSpec(
        target_ratio=_num(v.get("target_ratio", d.target_ratio), "validate.target_ratio",
                          lo=1.0, hi=1e6),
        max_error=_num(v.get("max_error", d.max_error), "validate.max_error", lo=0.0,
                       lo_open=True),
        reference_spp=_int(v.get("reference_spp", d.reference_spp), "validate.reference_spp",
                           lo=0, hi=1 << 20),
        reference_lights=_int(v.get("reference_lights", d.reference_lights),
                              "validate.reference_lights", lo=1, hi=1 << 16),
    )

    z = _section(SizingSpec, root.get("sizing", {}), "sizing")
    zd = SizingSpec()
    sizing = SizingSpec(
        max_points=_int(z.get("max_points", zd.max_points), "sizing.max_points", lo=1,
                        hi=1 << 20),
        lights_start=_int(z.get("lights_start", zd.lights_start), "sizing.lights_start", lo=2,
                          hi=1 << 16),
        max_lights=_int(z.get("max_lights", zd.max_lights), "sizing.max_lights", lo=2,
                        hi=1 << 16),
        max_seconds=_num(z.get("max_seconds", zd.max_seconds), "sizing.max_seconds", lo=0.0),
    )
    if sizing.max_lights < sizing.lights_start:
        raise SpecError("sizing.max_lights", f"{sizing.max_lights} is below "
                        f"sizing.lights_start ({sizing.lights_start})")

    mt = _section(MethodSpec, root.get("method", {}), "method")
    method = MethodSpec(name=_choice(mt.get("name", "data_driven"), "method.name",
                                     ("data_driven", "sh_prt", "learnt_sh")))
    sp = _section(ShPrtSpec, root.get("sh_prt", {}), "sh_prt")
    sd = ShPrtSpec()
    bounce = sp.get("bounce", sd.bounce)
    if not isinstance(bounce, bool):
        raise SpecError("sh_prt.bounce", f"expected true or false, got {bounce!r}")
    sh_prt = ShPrtSpec(
        storage=_choice(sp.get("storage", sd.storage), "sh_prt.storage",
                        ("texture", "vertex")),
        bands=_int(sp.get("bands", sd.bands), "sh_prt.bands", lo=1, hi=16),
        strata=_int(sp.get("strata", sd.strata), "sh_prt.strata", lo=1, hi=128),
        bounce=bounce,
        seed=_int(sp.get("seed", sd.seed), "sh_prt.seed", lo=0),
        specular=_num(sp.get("specular", sd.specular), "sh_prt.specular", lo=0.0, hi=1.0),
        exponent=_num(sp.get("exponent", sd.exponent), "sh_prt.exponent", lo=0.0, hi=1e4),
    )
    if sh_prt.specular > 0 and sh_prt.storage != "texture":
        raise SpecError("sh_prt.specular", "the glossy layer (TP) needs texture storage")
    if method.name in ("sh_prt", "learnt_sh") and keyframes.animation is not None:
        raise SpecError("method.name", f"{method.name} bakes static assets only (keyframes."
                        "animation is set)")
    ls = _section(LearntShSpec, root.get("learnt_sh", {}), "learnt_sh")
    ld = LearntShSpec()

    def lint(key: str, lo: int, hi: int) -> int:
        return _int(ls.get(key, getattr(ld, key)), f"learnt_sh.{key}", lo=lo, hi=hi)

    learnt_sh = LearntShSpec(
        bands=lint("bands", 1, 8), width=lint("width", 1, 1024), layers=lint("layers", 1, 16),
        samples=lint("samples", 16, 1 << 24), strata=lint("strata", 1, 128),
        steps=lint("steps", 0, 1 << 24), batch=lint("batch", 1, 1 << 20),
        seed=lint("seed", 0, 1 << 62),
        specular=_num(ls.get("specular", ld.specular), "learnt_sh.specular", lo=0.0, hi=1.0),
        exponent=_num(ls.get("exponent", ld.exponent), "learnt_sh.exponent", lo=0.0, hi=1e4),
        views=lint("views", 0, 1024), view_width=lint("view_width", 8, 4096),
        view_height=lint("view_height", 8, 4096),
        baseline_strata=lint("baseline_strata", 1, 128),
        cells=_cells(ls.get("cells", list(ld.cells))),
        overlap=_num(ls.get("overlap", ld.overlap), "learnt_sh.overlap", lo=0.0, hi=1.0))

    hs = _section(HairSpec, root.get("hair", {}), "hair")
    albedo = hs.get("albedo")
    if albedo is not None:
        if not isinstance(albedo, list) or len(albedo) != 3:
            raise SpecError("hair.albedo", "expected null or [r, g, b]")
        albedo = tuple(_num(x, f"hair.albedo[{i}]", lo=0.0, hi=1.0)
                       for i, x in enumerate(albedo))
    hair = HairSpec(
        texels_per_strand=_int(hs.get("texels_per_strand", 10), "hair.texels_per_strand",
                               lo=1, hi=4096),
        albedo=albedo,
        fibre=_choice(hs.get("fibre", "diffuse"), "hair.fibre", FIBRE_MODELS),
        harmonics=_choice(hs.get("harmonics", "auto"), "hair.harmonics",
                          ("auto", "first_bounce", "all_bounces", "mesh_bounces",
                           "turn_bounces", "adaptive")),
        denoise_neighbours=_int_or_auto(hs.get("denoise_neighbours", "auto"),
                                        "hair.denoise_neighbours", lo=0, hi=1024),
        gather_rays=_int_or_auto(hs.get("gather_rays", "auto"), "hair.gather_rays", lo=1,
                                 hi=4096),
        max_bounces=_int_or_auto(hs.get("max_bounces", "auto"), "hair.max_bounces", lo=0,
                                 hi=1000),
        denoise_direction=_choice(hs.get("denoise_direction", "auto"),
                                  "hair.denoise_direction", ("auto", "none", "t2", "t12")),
        direct=_choice(hs.get("direct", "facing"), "hair.direct", DIRECT_ESTIMATORS),
        direct_samples=_int_or_auto(hs.get("direct_samples", "auto"), "hair.direct_samples",
                                    lo=1, hi=256),
        arc_subdivision=_int_or_auto(hs.get("arc_subdivision", "auto"),
                                     "hair.arc_subdivision", lo=1, hi=MAX_ARC_SUBDIVISION),
        chiang=_chiang(hs.get("chiang", {})),
    )
    if hair.fibre == "chiang" and hair.arc_subdivision not in ("auto", 1):
        raise SpecError("hair.arc_subdivision", "pieces of texels are transported for the "
                        "diffuse fibre only; the 'chiang' fibre's texels are transported "
                        "whole (leave it 'auto' or 1)")
    if hair.fibre == "chiang" and hair.direct != "facing":
        raise SpecError("hair.direct", "the direct-light estimator belongs to the diffuse "
                        "fibre; the 'chiang' fibre samples its own (hair.direct_samples)")
    if hair.fibre == "chiang" and hair.harmonics != "auto":
        raise SpecError("hair.harmonics", "the azimuthal harmonics belong to the diffuse "
                        "fibre; the 'chiang' fibre averages over every direction (leave "
                        "it 'auto')")

    mats = root.get("materials", {})
    if not isinstance(mats, dict):
        raise SpecError("materials", f"expected an object of material names, got "
                        f"{_type_name(mats)}")
    materials = {str(name): _material(mv, f"materials.{name}") for name, mv in mats.items()}

    return BakeSpec(atlas=atlas, prepare=prepare, measurement_points=points, lights=lights,
                    transport=transport, fit=fit, keyframes=keyframes, output=output,
                    validate=validate, method=method, sh_prt=sh_prt, learnt_sh=learnt_sh,
                    hair=hair,
                    materials=materials, sizing=sizing)


def _cells(v: Any) -> tuple[int, int, int]:
    """``learnt_sh.cells``: [nx, ny, nz], each 1–16."""
    if not isinstance(v, list) or len(v) != 3:
        raise SpecError("learnt_sh.cells", f"expected [nx, ny, nz], got {v!r}")
    return tuple(_int(c, f"learnt_sh.cells[{i}]", lo=1, hi=16)
                 for i, c in enumerate(v))  # type: ignore[return-value]


def load_spec(path: str | Path | None) -> BakeSpec:
    """Read and validate a spec file; ``None`` gives the defaults."""
    if path is None:
        return parse_spec({})
    data = read_json(path, lambda what: SpecError("<file>", what, file=str(path)))
    return parse_spec(data, file=str(path))


def spec_to_dict(spec: BakeSpec) -> dict:
    """The complete spec with defaults, as plain JSON-compatible data."""
    def conv(x: Any) -> Any:
        if dataclasses.is_dataclass(x):
            return {f.name: conv(getattr(x, f.name)) for f in dataclasses.fields(x)}
        if isinstance(x, tuple | list):
            return [conv(v) for v in x]
        if isinstance(x, dict):
            return {k: conv(v) for k, v in x.items()}
        return x
    return conv(spec)


def canonical_spec_json(spec: BakeSpec) -> str:
    """The complete spec (defaults filled) as canonical JSON: sorted keys, no spaces. The
    one form that is hashed, stored by the service and compared for idempotent bakes."""
    return json.dumps(spec_to_dict(spec), sort_keys=True, separators=(",", ":"))


def spec_hash(spec: BakeSpec) -> str:
    """sha256 of :func:`canonical_spec_json`."""
    return hashlib.sha256(canonical_spec_json(spec).encode()).hexdigest()
