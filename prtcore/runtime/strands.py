"""Drawing a hair bundle (``prtcore render`` on a strand-texture bundle), on the CPU.

The GL renderer (:mod:`prtcore.runtime.gl`) draws meshes; hair bundles are drawn here by
ray tracing the fibre tubes from the camera (:mod:`prtcore.reference.camera`'s primary
rays): at each hit, direct light ``ρ/π · E(x, n)`` with the cylinder's radial normal and
shadow rays, plus the indirect light read from the relit strand texture
(:func:`prtcore.runtime.cpu.relight`) by the manifest's sampling rule
(:func:`sample_strands`: bilinear, the arc position clamped between the strand's first and
last texel centres, the row's centre line — never mixing strands). The paper's runtime
reconstructs the texture the same way; only the rasterisation differs. A Chiang fibre's
bundle (``manifest["fibre"]["chiang"]``) is shaded with the BCSDF instead:
``Σ_l S(ωo, ωl, h) E⊥_l V_l`` toward the camera at the offset h the pixel sees
(:func:`prtcore.core.bcsdf.impact_offset`), V from the side of the fibre facing the light
(:func:`prtcore.reference.chiang.fibre_nee`).

A hair + mesh bundle (docs/hair.md) is drawn the same way with the mesh in the tracer: a
pixel that sees the mesh gets ``ρ/π · E`` at the hit (shading normal, albedo at the hit,
shadow rays through the mesh and the tubes) plus the lightmap's planes sampled bilinearly
at the hit's TEXCOORD_1 (edges clamped) and blended likewise.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from prtcore.core.bcsdf import impact_offset
from prtcore.core.fibres import outside_offset, segment_hits
from prtcore.core.geometry import shading_normals
from prtcore.core.materials import CLAMP_TO_EDGE, albedo_at, clamp_albedo, sample_texture
from prtcore.core.scene import Light, Texture
from prtcore.emitters.punctual import irradiance
from prtcore.io.bundle import is_hair_mesh, load_runtime, read_manifest, strand_runtime
from prtcore.io.gltf.loader import load_asset
from prtcore.io.hair import read_hair
from prtcore.receivers.strands import (
    axis_frame,
    azimuth_frame,
    build_strand_space,
    interp_points,
)
from prtcore.reference.camera import Camera
from prtcore.reference.chiang import fibre_nee
from prtcore.runtime.cpu import blend_at, plane_weights, shade_points
from prtcore.transport.fibre import hair_tracer
from prtcore.transport.fibre_chiang import bundle_fibre


def sample_strands(image: np.ndarray, layout: dict, strand: np.ndarray,
                   arc_fraction: np.ndarray) -> np.ndarray:
    """The manifest's sampling rule (docs/hair.md): bilinear samples (n, c) of the strand
    texture ``image`` (H, W, c), row 0 at the top, for strands (n,) at arc fractions (n,)
    in [0, 1]."""
    n, r = int(layout["texels_per_strand"]), int(layout["strands_per_row"])
    px = (strand % r) * n + np.clip(arc_fraction * n, 0.5, n - 0.5)
    py = strand // r + 0.5
    x0 = np.floor(px - 0.5).astype(np.int64)
    f = (px - 0.5 - x0)[:, None]
    y = np.floor(py - 0.5).astype(np.int64)  # py sits on the row's centre line
    x1 = np.minimum(x0 + 1, image.shape[1] - 1)
    return (1 - f) * image[y, x0] + f * image[y, x1]


def render_strands(bundle: str | Path, lights: Sequence[Light], camera: Camera,
                   n: int | None = None, mode: str = "full") -> np.ndarray:
    """One frame of a hair bundle (or a hair + mesh bundle): (h, w, 4) float32 linear
    RGBA, A = 1 where a fibre (or the mesh) is seen. mode "full" | "direct" |
    "indirect"."""
    bundle = Path(bundle)
    manifest = read_manifest(bundle)
    layout = manifest["strands"]
    both = is_hair_mesh(manifest)
    scene = load_asset(bundle / manifest["asset"]["file"]) if both else None
    hair = read_hair(bundle / (manifest["asset"]["hair"]["file"] if both else
                               manifest["asset"]["file"]))
    space = build_strand_space(hair, int(layout["texels_per_strand"]))
    # the GL renderer's tubes (one prism per segment), so both drawings see one surface
    tracer, mesh = hair_tracer(space, scene, pieces=1)
    first = scene.triangle_count if both else 0
    o, d = camera.primary_rays()
    hits = tracer.intersect(o, d)
    hit = np.flatnonzero(hits.hit & (hits.triangle >= first))
    seg, t = segment_hits(mesh, hits.triangle[hit] - first, hits.barycentric[hit])
    p0 = hair.segment_start[seg]
    arc = hair.arc_length[p0] + t * (hair.arc_length[p0 + 1] - hair.arc_length[p0])
    strand = hair.strand_of_segment[seg]
    out = np.zeros((len(o), 3))
    if mode in ("full", "indirect"):  # the planes sampled, then blended (per fragment)
        data = load_runtime(bundle, manifest)
        strands = strand_runtime(bundle, manifest, data) if both else data
        weights = plane_weights(data, shade_points(data, lights, tracer), n)
        frac = arc / np.maximum(hair.strand_length[strand], 1e-300)
        out[hit] += blend_at(sample_strands(strands.planes.astype(np.float64), layout,
                                            strand, frac), weights, data.gamma)
    if mode in ("full", "direct"):
        point = o[hit] + hits.t[hit][:, None] * d[hit]
        axis, normal, _ = azimuth_frame(hair, strand, arc, point)
        extra = interp_points(hair, np.concatenate([outside_offset(hair)[:, None],
                                                    hair.color], axis=1), strand, arc)
        fibre = bundle_fibre(manifest, space)
        if fibre is not None:  # the BCSDF toward the camera at the offset seen
            tangent = axis_frame(hair, strand, arc)[1]
            wo = -d[hit]
            out[hit] += fibre_nee(lights, tracer, fibre.params, np.ones((len(hit), 3)), axis,
                                  tangent, extra[:, 0], wo,
                                  interp_points(hair, fibre.sigma_points, strand, arc),
                                  impact_offset(tangent, normal, wo), None).sum(axis=1)
        else:
            origin = axis + extra[:, :1] * normal
            rho, _ = clamp_albedo(extra[:, 1:])
            e = sum(irradiance(li, origin, normal, tracer) for li in lights)
            out[hit] += rho / np.pi * e
    seen = hits.hit & (hits.triangle >= first)
    if both:  # the mesh's pixels: its relit lightmap and its direct light
        mh = np.flatnonzero(hits.hit & hits.front & (hits.triangle < first))
        tri, bary = hits.triangle[mh], hits.barycentric[mh]
        if mode in ("full", "indirect"):
            uv = np.einsum("nk,nkj->nj", bary, scene.uv1[scene.faces[tri]])
            planes = sample_texture(Texture(data.planes.astype(np.float64), CLAMP_TO_EDGE,
                                            CLAMP_TO_EDGE), uv)
            out[mh] += blend_at(planes, weights, data.gamma)
        if mode in ("full", "direct"):
            p = tracer.surface_point(tri, bary)
            ns = shading_normals(scene, tri, bary, tracer.face_normals[tri])
            rho, _ = clamp_albedo(albedo_at(scene, tri, bary))
            out[mh] += rho / np.pi * sum(irradiance(li, p, ns, tracer) for li in lights)
        seen[mh] = True
    img = np.zeros((camera.height, camera.width, 4), dtype=np.float32)
    img[..., :3] = out.reshape(camera.height, camera.width, 3)
    img[..., 3] = seen.reshape(camera.height, camera.width)
    return img
