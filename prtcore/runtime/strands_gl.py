"""Drawing a hair bundle with the GL renderer (``prtcore render`` on a strand-texture bundle).

The strands are drawn as the bake's fibre tubes (:func:`prtcore.core.fibres.fibre_tubes`,
3 sides, the mean projected width of the fibre): the same geometry the bake traces and the
CPU drawing (:mod:`prtcore.runtime.strands`) ray traces, so both cover the same pixels
(a ribbon or a line would not). Per frame:

1. **shadow maps** of the tubes (:class:`prtcore.runtime.shadows.ShadowMaps`, as meshes);
2. **coefficients** on the CPU, from the bundle alone: the measurement points shaded for
   the frame's lights (:func:`prtcore.runtime.cpu.shade_points` without shadow rays — the
   points lie on the convex hull of the tubes with the hull's normals, so a light a point
   faces is outside the hull and no fibre can shadow it; docs/hair.md) and the plane
   weights (:func:`prtcore.runtime.cpu.plane_weights`) — P is a few hundred;
3. **camera pass** (``strand_vs.glsl``, ``strand_fs.glsl``): at each fragment the round
   fibre's radial normal (from the axis point of its ring, the segment's tangent as a flat
   attribute), direct light ``ρ/π · E`` at the point on the circumscribed cylinder with
   shadow-map visibility (``lights.glsl``) — for a Chiang fibre's bundle the BCSDF
   (``chiang.glsl``, :func:`prtcore.core.bcsdf.scattering` in float32) toward the eye at
   the offset the fragment sees, times E⊥ V from the side facing the light, as the CPU
   drawing —, plus the indirect light — the basis planes
   blended in the fragment shader (``blend.glsl``) at the manifest's sampling rule
   (strand index and arc fraction interpolated along the tube; docs/hair.md).

Differences from the CPU drawing: shadows come from shadow maps (a shadow texel is wider
than a fibre: a fibre's shadow is resolved on average, not per fibre, and the biases of
:mod:`prtcore.runtime.shadows` lose contact shadows within about a texel); the indirect
term is the same blend at the same place (bilinear weights at the GPU's precision).
``benchmarks/hair_render_gl.py`` measures the two against each other.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from prtcore.core.errors import PrtError
from prtcore.core.fibres import DEFAULT_SIDES, fibre_tubes, outside_offset
from prtcore.core.materials import clamp_albedo
from prtcore.core.scene import Light
from prtcore.reference.camera import Camera
from prtcore.runtime.gl import (
    MODES,
    GLRenderer,
    RenderResult,
    basis_texture,
    draw_depth_tested,
)
from prtcore.runtime.glcontext import (
    check_gl,
    current,
    matrix_bytes,
    renderer_label,
    scene_clip_from_world,
    set_uniform,
)
from prtcore.runtime.glsl import shader_source
from prtcore.runtime.shadows import SHADOW_RESOLUTION, ShadowMaps

#: The interleaved vertex of the tube buffer: position, axis point, tangent, arc fraction,
#: strand, offset, albedo (strand_vs.glsl's inputs).
STRAND_VERTEX_FORMAT = "3f 3f 3f 1f 1f 1f 3f"
STRAND_ATTRIBUTES = ("in_pos", "in_centre", "in_tan", "in_arc", "in_strand", "in_offset",
                     "in_albedo")
#: The same buffer seen by the shadow pass: the position only.
STRAND_SHADOW_FORMAT = "3f 12x4"
#: Strand indices travel as float32: exact below 2^24.
MAX_GL_STRANDS = 1 << 24


def tube_vertices(hair, sides: int = DEFAULT_SIDES, sigma: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The tube mesh of ``hair`` as the camera pass reads it: vertices (v, 15) float32 in
    :data:`STRAND_VERTEX_FORMAT` and faces (f, 3) uint32. A vertex of ring p carries point
    p's axis point, arc fraction, strand, outside offset and clamped albedo (or, for the
    Chiang fibre, ``sigma`` (p, 3): its absorption per unit radius), and the unit
    direction of the segment ending at p (the start ring of a strand: the one leaving it;
    never read — a tube triangle's provoking, last, vertex is on its segment's end ring)."""
    mesh = fibre_tubes(hair, sides, pieces=1)  # a vertex per point and side
    strand = np.repeat(np.arange(hair.strand_count), np.diff(hair.offsets))
    p = hair.points
    seg = np.zeros_like(p)
    seg[1:] = p[1:] - p[:-1]
    first = hair.offsets[:-1]
    seg[first] = p[np.minimum(first + 1, len(p) - 1)] - p[first]
    ln = np.linalg.norm(seg, axis=1, keepdims=True)
    tan = np.divide(seg, ln, out=np.tile([0.0, 1.0, 0.0], (len(p), 1)), where=ln > 0)
    frac = hair.arc_length / np.maximum(hair.strand_length[strand], 1e-300)
    rho = clamp_albedo(hair.color)[0] if sigma is None else np.asarray(sigma, np.float64)
    per_point = np.concatenate([p, tan, frac[:, None], strand[:, None].astype(np.float64),
                                outside_offset(hair, sides)[:, None], rho], axis=1)
    verts = np.concatenate([mesh.positions, np.repeat(per_point, sides, axis=0)], axis=1)
    return (np.ascontiguousarray(verts, dtype="<f4"),
            np.ascontiguousarray(mesh.faces, dtype="<u4"))


class StrandRenderer(GLRenderer):
    """The GPU drawing of one hair bundle in one OpenGL context (see the module
    docstring). bundle : bundle directory with a ``strands`` layout; ctx : a moderngl
    context (EGL when None); shadow_resolution : side of each shadow view. Call
    :meth:`release` (or use as a context manager)."""

    def __init__(self, bundle: str | Path, ctx=None,
                 shadow_resolution: int = SHADOW_RESOLUTION):
        import moderngl

        from prtcore.io.bundle import is_hair_mesh, load_runtime, read_manifest, strand_runtime
        from prtcore.io.hair import read_hair

        if not 16 <= int(shadow_resolution) <= 8192:
            raise PrtError(f"render: shadow resolution {shadow_resolution}: expected 16..8192")
        self.bundle = Path(bundle)
        self.manifest = read_manifest(self.bundle)
        if "strands" not in self.manifest:
            raise PrtError(f"{self.bundle}: not a hair bundle (no strands layout)")
        self.layout = self.manifest["strands"]
        self.data = load_runtime(self.bundle, self.manifest)
        asset = self.manifest["asset"]
        if is_hair_mesh(self.manifest):  # hair + mesh: the strand texture's planes
            self.data = strand_runtime(self.bundle, self.manifest, self.data)
            asset = asset["hair"]
        self.hair = read_hair(self.bundle / asset["file"])
        if self.hair.strand_count > MAX_GL_STRANDS:
            raise PrtError(f"{self.bundle}: {self.hair.strand_count} strands; the GL "
                           f"renderer draws at most {MAX_GL_STRANDS}")
        from prtcore.receivers.strands import build_strand_space
        from prtcore.transport.fibre_chiang import bundle_fibre

        # the Chiang fibre of the bundle, or None (diffuse)
        self.fibre = bundle_fibre(self.manifest, build_strand_space(
            self.hair, int(self.layout["texels_per_strand"])))
        self._mgl = moderngl
        self._open(ctx, lambda: self._setup(int(shadow_resolution)))

    def _setup(self, shadow_resolution: int) -> None:
        ctx = self.ctx
        verts, faces = tube_vertices(
            self.hair, sigma=None if self.fibre is None else self.fibre.sigma_points)
        lo, hi = verts[:, :3].min(axis=0), verts[:, :3].max(axis=0)
        self.center = ((lo + hi) / 2).astype(np.float64)
        self.radius = float(max(np.linalg.norm(hi - lo) / 2, 1e-30))
        vbo = self._keep(ctx.buffer(verts.tobytes()))
        ibo = self._keep(ctx.buffer(faces.tobytes()))
        self._shadows = ShadowMaps(ctx, vbo, STRAND_SHADOW_FORMAT, faces, self.center,
                                   self.radius, shadow_resolution)
        self._prog = self._keep(ctx.program(
            vertex_shader=shader_source("strand_vs.glsl"),
            fragment_shader=shader_source("strand_fs.glsl")))
        self._vao = self._keep(ctx.vertex_array(
            self._prog, [(vbo, STRAND_VERTEX_FORMAT, *STRAND_ATTRIBUTES)], index_buffer=ibo,
            index_element_size=4))
        self._basis = self._keep(basis_texture(ctx, self.data.planes))
        q = self.data.planes.shape[2]
        self._layers = -(-q // 4)
        self._weights = self._keep(ctx.buffer(reserve=4 * self._layers * 16))

    def plane_weights(self, lights: Sequence[Light], n: int | None = None) -> np.ndarray:
        """The RGB weight of every basis plane, (q, 3) float64: the CPU runtime's
        coefficients of the unshadowed measurement points (see the module docstring)."""
        from prtcore.runtime.cpu import plane_weights, shade_points

        n_basis = self.data.n_basis
        if n is not None and not 1 <= n <= n_basis:
            raise PrtError(f"render: --basis {n}: the bundle has {n_basis} basis elements "
                           f"(mean included); use 1..{n_basis}")
        return plane_weights(self.data, shade_points(self.data, lights, None), n)

    @current
    def render(self, lights: Sequence[Light], camera: Camera, n: int | None = None,
               mode: str = "full") -> RenderResult:
        """One frame: ``image`` (h, w, 4) float32 linear RGB, A = 1 where a fibre is seen;
        ``uv1`` the strand-texture coordinate each pixel samples. mode "full" | "direct" |
        "indirect"."""
        if mode not in MODES:
            raise PrtError(f"render: mode {mode!r}: expected one of {', '.join(MODES)}")
        weights = self.plane_weights(lights, n)
        ctx = self.ctx
        self._timer.reset()
        self._shadows.render(lights, self._timer)
        fbo = self._target(camera.width, camera.height, 2)
        self.camera_pass(fbo, camera, mode, weights)
        h, w = camera.height, camera.width
        img = np.frombuffer(fbo.read(components=4, dtype="f4", attachment=0), "<f4")
        aux = np.frombuffer(fbo.read(components=4, dtype="f4", attachment=1), "<f4")
        check_gl(ctx, "render strands")
        gpu, wall = self._timer.results()
        return RenderResult(image=img.reshape(h, w, 4)[::-1].copy(),
                            uv1=np.ascontiguousarray(aux.reshape(h, w, 4)[::-1, :, :2]),
                            milliseconds=gpu, wall_milliseconds=wall)

    @current
    def camera_pass(self, fbo, camera: Camera, mode: str, weights: np.ndarray,
                    clear: bool = True) -> None:
        """Draw the tubes into ``fbo`` (two float RGBA attachments and a depth buffer)
        with the plane ``weights`` (q, 3) and the shadow maps already rendered; ``clear``
        False draws over what is there, depth-tested (a mesh drawn first)."""
        ctx, prog = self.ctx, self._prog
        buf = np.zeros((self._weights.size // 16, 4), "<f4")
        buf[:len(weights), :3] = weights
        self._weights.write(buf.tobytes())
        self._shadows.bind(prog)
        self._weights.bind_to_storage_buffer(4)
        self._basis.use(location=1)
        set_uniform(prog, "basis", 1)
        set_uniform(prog, "n_layers", self._layers)
        set_uniform(prog, "gamma", float(self.data.gamma or 0.0))
        set_uniform(prog, "clip_from_world", matrix_bytes(
            scene_clip_from_world(camera, self.center, self.radius)))
        set_uniform(prog, "mode", MODES[mode])
        set_uniform(prog, "texels_per_strand", int(self.layout["texels_per_strand"]))
        set_uniform(prog, "strands_per_row", int(self.layout["strands_per_row"]))
        set_uniform(prog, "texture_size", (float(self.layout["width"]),
                                           float(self.layout["height"])))
        set_uniform(prog, "eye", tuple(float(x) for x in camera.position))
        set_uniform(prog, "fibre_model", 0 if self.fibre is None else 1)
        if self.fibre is not None:
            p = self.fibre.params
            set_uniform(prog, "chiang_v", tuple(float(x) for x in p.variances))
            set_uniform(prog, "chiang_s", float(p.logistic_scale))
            set_uniform(prog, "chiang_alpha", float(p.alpha))
            set_uniform(prog, "chiang_eta", float(p.eta))

        def draw() -> None:
            self._vao.render(self._mgl.TRIANGLES)

        with self._timer.timed("camera"):
            draw_depth_tested(ctx, fbo, draw, clear=clear)


def render_strands_gl(bundle: str | Path, lights: Sequence[Light], camera: Camera,
                      n: int | None = None, mode: str = "full",
                      shadow_resolution: int = SHADOW_RESOLUTION, renderer=None
                      ) -> tuple[RenderResult, str]:
    """One frame of a hair bundle on the GPU, and the GL renderer's label. ``renderer``:
    the class drawing it (default :class:`StrandRenderer`; a hair + mesh bundle's is
    :class:`prtcore.runtime.hair_mesh_gl.HairMeshRenderer`)."""
    with (renderer or StrandRenderer)(bundle, shadow_resolution=shadow_resolution) as r:
        res = r.render(lights, camera, n=n, mode=mode)
        label = renderer_label(r.ctx)
    return res, label
