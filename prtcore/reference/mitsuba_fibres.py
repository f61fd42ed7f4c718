"""An independent check of light in hair by Mitsuba 3 (a dev dependency, imported here only):
the diffuse-fibre model on Mitsuba's own round ``linearcurve`` geometry, ``diffuse`` BSDF
and ``path`` integrator (``scalar_rgb``: the LLVM variants do not run on this machine's
LLVM).

Mitsuba has no bake. A strand texel's value — outgoing radiance averaged over azimuth and
the texel's arc interval — is estimated by rays that start just outside the fibre
(1.02 × its radius, at a uniform arc position and azimuth of the texel) and point at its
axis: for a Lambertian fibre the radiance the path integrator returns along such a ray is
the outgoing radiance ρ/π·E at the hit, whatever the direction. ``max_depth = 2`` gives the
direct part (camera → fibre → light); the indirect part is the full estimate minus the
direct one, both drawn with the same sampler seed per ray so that their first vertices
coincide. Estimates come as two independent halves (noise removal as in
:func:`prtcore.reference.fibres.noise_corrected_error`).

The Chiang fibre (``chiang=``) goes through Mitsuba's own ``hair`` BSDF. That BSDF reads
the fibre's direction from the shading frame, which ``linearcurve`` leaves arbitrary
(``dp_du = 0``), so the polylines become ``bsplinecurve``s with every point tripled: a
cubic B-spline that is the polyline itself. Its texel is the radiance averaged over view
directions, so the query rays come from directions with density cos θ / π² at a uniform
offset across the fibre (:func:`_chiang_queries`).

A mesh baked with the hair (``scene=``, a head) joins Mitsuba's scene as an OBJ with the
scene's vertex normals (Mitsuba interpolates them, as prtcore's shading normals) and a
``diffuse`` BSDF of its one material's base colour.

Shared with prtcore: the hair (polylines and radii), the mesh's triangles and vertex
normals, the lights' meaning (point: intensity as radiant intensity, directional:
illuminance as irradiance), the texels' arc intervals. Not shared: fibre geometry (round
curves with round joints, not triangulated tubes), ray tracing, sampling, ray offsets.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from prtcore.core.bcsdf import ChiangParams
from prtcore.core.geometry import face_normals
from prtcore.core.scene import Light, Scene
from prtcore.receivers.strands import StrandSpace, axis_frame, interp_points
from prtcore.receivers.texels import TexelSpace, sample_texel_regions, texel_regions

#: where the query rays start, in fibre radii from the axis
START_RADII = 1.02
#: where a mesh texel's query rays start above its surface (metres)
MESH_START = 1e-5


def _write_curves(space: StrandSpace, path: Path, repeat: int = 1) -> None:
    """Mitsuba's curve text format: ``x y z radius`` per control point, curves separated
    by an empty line; each point ``repeat`` times (3: a cubic B-spline through them that
    is the polyline itself, segment by segment)."""
    h = space.hair
    with open(path, "w") as f:
        for s in range(h.strand_count):
            a, b = h.offsets[s], h.offsets[s + 1]
            for p, t in zip(h.points[a:b], h.thickness[a:b], strict=True):
                line = f"{float(p[0])!r} {float(p[1])!r} {float(p[2])!r} {float(t) / 2!r}\n"
                f.write(line * repeat)
            f.write("\n")


def _write_obj(scene: Scene, path: Path) -> None:
    """The scene's triangles as an OBJ with its vertex normals (``f a//a b//b c//c``)."""
    with open(path, "w") as f:
        f.writelines(f"v {p[0]!r} {p[1]!r} {p[2]!r}\n" for p in scene.positions.tolist())
        f.writelines(f"vn {n[0]!r} {n[1]!r} {n[2]!r}\n" for n in scene.normals.tolist())
        f.writelines(f"f {a}//{a} {b}//{b} {c}//{c}\n" for a, b, c in (scene.faces + 1).tolist())


def _mesh_shape(scene: Scene, path: Path) -> dict:
    """Mitsuba's shape of ``scene`` (one base colour, untextured: a diffuse BSDF)."""
    used = np.unique(scene.face_material)
    colours = {tuple(scene.materials[m].base_color_factor[:3]) for m in used}
    if len(colours) != 1 or any(scene.materials[m].texture >= 0 for m in used):
        raise ValueError("mitsuba_fibres: the mesh must have one untextured colour")
    _write_obj(scene, path)
    return {"type": "obj", "filename": str(path), "face_normals": False,
            "bsdf": {"type": "diffuse", "reflectance": {
                "type": "rgb", "value": np.clip(colours.pop(), 0, 0.99).tolist()}}}


def _emitter(light: Light) -> dict:
    rgb = {"type": "rgb", "value": (np.asarray(light.color) * light.intensity).tolist()}
    if light.type == "point":
        return {"type": "point", "position": np.asarray(light.position).tolist(),
                "intensity": rgb}
    if light.type == "directional":
        return {"type": "directional", "direction": np.asarray(light.direction).tolist(),
                "irradiance": rgb}
    raise ValueError(f"mitsuba_fibre_indirect: {light.type!r} lights are not mapped")


def mitsuba_fibre_indirect(space: StrandSpace, lights: Sequence[Light], texels: np.ndarray,
                           samples: int, seed: int, max_depth: int = 64,
                           chiang: ChiangParams | None = None, scene: Scene | None = None
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Indirect outgoing radiance of ``texels`` (n,) for each light, as two independent
    halves of ``samples`` // 2 rays each: (a, b), each (n, K, 3) float64. The hair must
    have one colour (one Mitsuba BSDF).

    chiang : the Chiang fibre instead (Mitsuba's ``hair`` BSDF with this fibre's σ_a, in
        fibre radii as ours, roughness, tilt and IOR), whose texel is the radiance
        averaged over view directions with the fibre's projected width: each query ray
        comes from a direction with density cos θ / π² (a cosine direction about a
        uniformly random radial normal) and meets the fibre at a uniform offset h across
        it, so the mean of what the path integrator returns is the texel's value.
    scene : a mesh baked with the hair (one untextured colour), which shadows the fibres
        and reflects light onto them."""
    hair = space.hair
    texels = np.asarray(texels, dtype=np.int64)
    rng = np.random.default_rng(seed)
    half = samples // 2
    n = len(texels)
    strand = np.repeat(space.strand[texels], 2 * half)
    lo = np.repeat(space.arc[texels, 0], 2 * half)
    hi = np.repeat(space.arc[texels, 1], 2 * half)
    arc = lo + rng.random(len(strand)) * (hi - lo)
    axis, tangent, u = axis_frame(hair, strand, arc)
    phi = 2 * np.pi * rng.random(len(strand))
    normal = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * np.cross(tangent, u)
    radius = interp_points(hair, hair.thickness[:, None] / 2, strand, arc)[:, 0]
    if chiang is None:  # toward the axis along the normal: a Lambertian fibre's radiance
        origin, direction = axis + (START_RADII * radius)[:, None] * normal, -normal
    else:
        origin, direction = _chiang_queries(axis, tangent, normal, radius, rng)
    return _trace(space, lights, origin, direction, n, seed, max_depth, chiang, scene)


def mitsuba_mesh_indirect(space: StrandSpace, scene: Scene, texels: TexelSpace,
                          lights: Sequence[Light], rows: np.ndarray, samples: int,
                          seed: int, max_depth: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Indirect outgoing radiance of the mesh's atlas texels ``rows`` (n,) under the hair,
    as :func:`mitsuba_fibre_indirect` gives it for strand texels: two halves (a, b), each
    (n, K, 3) float64. Each query ray starts at a point uniform over the texel's part of
    its triangle (:func:`~prtcore.receivers.texels.sample_texel_regions`, as the path
    tracer's texels), 10 µm above it, and points down its face normal: for a Lambertian
    surface what the integrator returns is the outgoing radiance ρ/π·E there."""
    rows = np.asarray(rows, dtype=np.int64)
    rng = np.random.default_rng(seed)
    half = samples // 2
    n = len(rows)
    local = np.repeat(np.arange(n), 2 * half)
    bary = sample_texel_regions(texel_regions(scene, texels, rows), local, rng)
    triangle = texels.triangle[rows[local]]
    corners = scene.positions[scene.faces[triangle]].astype(np.float64)  # (m, 3, 3)
    point = np.einsum("mi,mij->mj", bary, corners)
    face = face_normals(scene, triangle)
    return _trace(space, lights, point + MESH_START * face, -face, n, seed, max_depth,
                  None, scene)


def _trace(space: StrandSpace, lights: Sequence[Light], origin: np.ndarray,
           direction: np.ndarray, n: int, seed: int, max_depth: int,
           chiang: ChiangParams | None, scene: Scene | None
           ) -> tuple[np.ndarray, np.ndarray]:
    """Mitsuba's indirect radiance along the query rays of ``n`` receivers (m = n · 2 ·
    half rays, receiver by receiver, each's first half then its second): its ``path``
    integrator's estimate minus the ``max_depth = 2`` one with the same sampler seed,
    against the hair (and ``scene``'s mesh) under each light in turn. Returns the two
    halves' means (a, b), each (n, K, 3) float64."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    color = space.hair.color[0]
    if chiang is None and not np.allclose(space.hair.color, color):
        raise ValueError("mitsuba_fibre_indirect: the hair must have one colour")
    out = np.zeros((len(origin), len(lights), 3))
    with tempfile.TemporaryDirectory() as tmp:
        curves = Path(tmp) / "hair.txt"
        # Mitsuba's hair BSDF reads the fibre's direction from the shading frame, which
        # its linearcurve leaves arbitrary (dp_du = 0): the polyline as a B-spline instead
        shape = "linearcurve" if chiang is None else "bsplinecurve"
        _write_curves(space, curves, 1 if chiang is None else 3)
        if chiang is None:
            bsdf = {"type": "diffuse", "reflectance": {
                "type": "rgb", "value": np.clip(color, 0, 0.99).tolist()}}
        else:
            bsdf = {"type": "hair", "sigma_a": {"type": "rgb",
                                                "value": list(chiang.sigma_a)},
                    "longitudinal_roughness": chiang.beta_m,
                    "azimuthal_roughness": chiang.beta_n,
                    "scale_tilt": float(np.degrees(chiang.alpha)),
                    "int_ior": chiang.eta, "ext_ior": 1.0}
        shapes = {"hair": {"type": shape, "filename": str(curves), "bsdf": bsdf}}
        if scene is not None:
            shapes["mesh"] = _mesh_shape(scene, Path(tmp) / "mesh.obj")
        full_i = mi.load_dict({"type": "path", "max_depth": max_depth})
        direct_i = mi.load_dict({"type": "path", "max_depth": 2})
        sampler = mi.load_dict({"type": "independent"})
        for k, light in enumerate(lights):
            world = mi.load_dict({"type": "scene", **shapes, "light": _emitter(light)})
            for i in range(len(origin)):
                ray = mi.Ray3f(mi.Point3f(*origin[i]), mi.Vector3f(*direction[i]))
                sampler.seed(int(seed) * 1_000_003 + i)
                full, _, _ = full_i.sample(world, sampler, ray)
                sampler.seed(int(seed) * 1_000_003 + i)
                direct, _, _ = direct_i.sample(world, sampler, ray)
                out[i, k] = np.array(full) - np.array(direct)
    out = out.reshape(n, 2, -1, len(lights), 3)
    return out[:, 0].mean(axis=1), out[:, 1].mean(axis=1)


def _chiang_queries(axis: np.ndarray, tangent: np.ndarray, normal: np.ndarray,
                    radius: np.ndarray, rng: np.random.Generator
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Query rays for the Chiang texel: a view direction ω with density cos θ / π² (cosine
    about the radial ``normal``), an offset h uniform in [−1, 1] across the fibre; the ray
    starts outside the fibre (START_RADII radii from the axis, across it) and travels −ω.
    Returns origins and directions, (m, 3) float64 each."""
    m = len(axis)
    cos_t = np.sqrt(rng.random(m))
    sin_t = np.sqrt(1 - cos_t ** 2)
    a = 2 * np.pi * rng.random(m)
    b1 = np.cross(tangent, normal)
    view = (sin_t * np.cos(a))[:, None] * tangent + (sin_t * np.sin(a))[:, None] * b1 \
        + cos_t[:, None] * normal
    across = view - np.einsum("ij,ij->i", view, tangent)[:, None] * tangent
    w = np.linalg.norm(across, axis=1)
    side = np.cross(tangent, across / np.maximum(w, 1e-12)[:, None])
    h = 2 * rng.random(m) - 1
    dist = START_RADII * radius / np.maximum(w, 1e-6)
    origin = axis + (h * radius)[:, None] * side + dist[:, None] * view
    return origin, -view
