"""Headless OpenGL runtime (moderngl, EGL): the engine side of a bundle (`prtcore render`).

Per frame, all on the GPU (paper 4.3, 5.1, 5.2):

1. **shadow maps** — one per light: six 90° views (point and spot lights) or one
   orthographic view over the scene's bounding sphere (directional), rendered into one
   R32F atlas storing the distance to the light (directional: depth along the light's
   direction); MIN blending keeps the nearest surface exactly, with no depth-buffer
   precision involved;
2. **fake G-buffer** — a compute shader shades every measurement-point supersample
   (``albedo/π · E``, the KHR_lights_punctual formulas of :mod:`prtcore.emitters.punctual`, shadows
   from the shadow maps) and averages each cluster → x (P, 3), gamma applied;
3. **coefficients** — a compute shader (one work group): ``s = ‖x'‖``,
   ``u_c = M_c x'_c + s·b_c`` per channel (plus ``s·r(x'/s)``, the learnt residual of a
   ``fit.transfer: "mlp"`` bundle, one neuron per invocation: ``learnt.glsl``), then the
   RGB weight of every basis plane (:func:`prtcore.runtime.cpu.plane_weights`);
4. **camera pass** — direct light with shadow-map shadows plus the indirect term: the
   basis planes, packed four per RGBA layer of a texture array, are blended in the
   fragment shader, one 4×3 coefficient matrix per layer (paper 5.2), then gamma undone.

Shadow test: a point p with normal n (geometric normal in the camera pass, the stored
shading normal at measurement points) is looked up at ``p + n·k_n·τ`` where τ is the
world size of one shadow-map texel at p (``2d/res`` at distance d for a 90° view,
``2·1.01·R/res`` for directional), and is lit when its distance is at most the stored one
plus ``k_c·τ``. Both biases are thus in shadow texels, scaled to the scene (core/tolerances.py),
never a fixed world epsilon. Each pass is timed with GL timer queries (GL_TIME_ELAPSED).

Images: float RGBA, row 0 at the top; A = 1 where the pixel centre sees the front of a
surface. Back faces (inside geometry, as in the path tracer) and background are black.

Modules: the passes here (:class:`BundleRenderer`), the shadow maps in
:mod:`prtcore.runtime.shadows`, the GL plumbing (context, uniforms, pass timing) in
:mod:`prtcore.runtime.glcontext`, the GLSL as package data in ``prtcore/runtime/shaders/``
(read by :mod:`prtcore.runtime.glsl`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from prtcore.core.errors import PrtError
from prtcore.core.mlp import Mlp
from prtcore.core.scene import Light
from prtcore.reference.camera import Camera
from prtcore.runtime.glcontext import (
    PassTimer,
    check_gl,
    create_context,
    current,
    make_current,
    matrix_bytes,
    renderer_label,
    scene_clip_from_world,
    set_uniform,
    unbind_framebuffer,
)
from prtcore.runtime.glsl import shader_source
from prtcore.runtime.shadows import SHADOW_RESOLUTION, ShadowMaps

#: Render modes: which terms the camera pass adds.
MODES = {"full": 3, "direct": 1, "indirect": 2}
#: Work-group size of the coefficient pass.
COEFF_GROUP = 256
#: The interleaved vertex of the scene buffer: position, normal, TEXCOORD_0, TEXCOORD_1.
VERTEX_FORMAT = "3f 3f 2f 2f"
#: The same buffer seen by the shadow pass: the position only.
SHADOW_VERTEX_FORMAT = "3f 7x4"


@dataclass(frozen=True)
class RenderResult:
    """One frame.

    image : (h, w, 4) float32 linear RGB outgoing radiance, A = 1 on front-facing surfaces
    uv1 : (h, w, 2) float32 interpolated TEXCOORD_1 at each pixel centre (0 on background)
    milliseconds : GPU time of each pass by GL timer query (shadow_maps, points,
        coefficients, camera or atlas_blend); None where the query gave no valid result
    wall_milliseconds : the same passes timed by the wall clock between glFinish calls
    """

    image: np.ndarray
    uv1: np.ndarray
    milliseconds: dict[str, float | None] = field(default_factory=dict)
    wall_milliseconds: dict[str, float] = field(default_factory=dict)


class GLRenderer:
    """What every renderer of a bundle does with its GL objects: keeps them
    (:meth:`_keep`), caches its framebuffers (:meth:`_target`), frees them all (and the
    context when it created it) in :meth:`release` or on leaving a ``with`` block. A
    subclass calls :meth:`_open` with its setup, which may set ``_shadows`` (a
    :class:`~prtcore.runtime.shadows.ShadowMaps`)."""

    def _open(self, ctx, setup) -> None:
        """Take ``ctx`` (or create an EGL context when None) and run ``setup()`` with it
        current; on any failure free what was made and re-raise."""
        self.ctx = ctx if ctx is not None else create_context()
        self._own_ctx = ctx is None
        self._released = False
        self._objects: list = []
        self._fbos: dict[tuple, tuple] = {}
        self._shadows: ShadowMaps | None = None
        self._timer = PassTimer(self.ctx)
        try:
            make_current(self.ctx)
            check_gl(self.ctx, "before setup")
            setup()
            check_gl(self.ctx, "setup")
        except BaseException:
            self.release()
            raise

    def _keep(self, obj):
        self._objects.append(obj)
        return obj

    def _unbind(self) -> None:
        """Bind framebuffer 0 before framebuffers are released (see
        :func:`prtcore.runtime.glcontext.unbind_framebuffer`; a shared context outlives
        this renderer)."""
        unbind_framebuffer(self.ctx)

    def release(self) -> None:
        """Free every GL object (and the context when this renderer created it)."""
        if self._released:
            return
        self._release_objects()
        self._released = True
        if self._own_ctx:
            self.ctx.release()

    @current
    def _release_objects(self) -> None:
        self._unbind()
        for obj in reversed(self._objects):
            obj.release()
        self._objects.clear()
        for fbo_objs in self._fbos.values():
            for o in fbo_objs:
                o.release()
        self._fbos.clear()
        if self._shadows is not None:
            self._shadows.release()
            self._shadows = None
        self._timer.release()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def _target(self, width: int, height: int, attachments: int):
        """A framebuffer of ``attachments`` float RGBA textures and a depth buffer, made
        once per size."""
        key = (width, height, attachments)
        if key not in self._fbos:
            texs = [self.ctx.texture((width, height), 4, dtype="f4")
                    for _ in range(attachments)]
            depth = self.ctx.depth_renderbuffer((width, height))
            fbo = self.ctx.framebuffer(color_attachments=texs, depth_attachment=depth)
            self._fbos[key] = (fbo, depth, *texs)
        return self._fbos[key][0]


def draw_depth_tested(ctx, fbo, draw, clear: bool = True) -> None:
    """Clear ``fbo`` (colour 0, depth 1; not with ``clear`` False: over what an earlier
    pass drew) and run ``draw()`` into it with the depth test on, no culling, no blending —
    how every camera pass draws."""
    import moderngl

    fbo.use()
    fbo.viewport = (0, 0, *fbo.size)
    if clear:
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
    ctx.enable(moderngl.DEPTH_TEST)
    ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
    draw()
    ctx.disable(moderngl.DEPTH_TEST)


class BundleRenderer(GLRenderer):
    """The GPU runtime of one bundle in one OpenGL context.

    bundle : bundle directory (docs/bundle.md); ctx : a moderngl context (created through EGL
    when None; pass one to share it, e.g. a test session's); shadow_resolution : side of
    each shadow view; time : keyframe bundles, seconds into the animation (the nearest
    keyframe's vertices, points and transfer; default the first keyframe). Call
    :meth:`release` (or use as a context manager) to free the GL objects.
    """

    def __init__(self, bundle: str | Path, ctx=None, shadow_resolution: int = SHADOW_RESOLUTION,
                 time: float | None = None):
        import moderngl

        from prtcore.io.bundle import load_runtime, read_manifest
        from prtcore.io.gltf.loader import load_asset

        if not 16 <= int(shadow_resolution) <= 8192:
            raise PrtError(f"render: shadow resolution {shadow_resolution}: expected 16..8192")
        self.bundle = Path(bundle)
        self.manifest = read_manifest(self.bundle)
        self.data = load_runtime(self.bundle, self.manifest)
        self.scene = load_asset(self.bundle / self.manifest["asset"]["file"])
        self.keyframe = None
        if self.manifest.get("keyframes") or time is not None:
            from prtcore.keyframes.pose import (
                bundle_at_time,  # vertices and points posed on the CPU
            )

            self.data, self.scene, self.keyframe = bundle_at_time(
                self.bundle, self.manifest, self.data, self.scene, time)
        if self.scene.uv1 is None:
            raise PrtError(f"{self.bundle}: asset.glb has no TEXCOORD_1")
        self.shadow_resolution = int(shadow_resolution)
        self._mgl = moderngl
        self._open(ctx, self._setup)

    # -- setup -------------------------------------------------------------------------
    def _setup(self) -> None:
        sc = self.scene
        self.center = np.asarray(sc.center, np.float64)
        self.radius = float(max(sc.radius, 1e-30))
        uv0 = sc.uv0 if sc.uv0 is not None else np.zeros((len(sc.positions), 2))
        verts = np.concatenate([sc.positions, sc.normals, uv0, sc.uv1], axis=1)
        self._vbo = self._keep(self.ctx.buffer(np.ascontiguousarray(verts, dtype="<f4")
                                               .tobytes()))
        self._shadows = ShadowMaps(self.ctx, self._vbo, SHADOW_VERTEX_FORMAT, sc.faces,
                                   self.center, self.radius, self.shadow_resolution)
        self._setup_draws()
        self._setup_basis()
        self._setup_points()
        self._setup_coefficients()

    def _setup_draws(self) -> None:
        """The camera program and one draw per material (its factor and texture as
        uniforms)."""
        moderngl, ctx, sc = self._mgl, self.ctx, self.scene
        self._camera_prog = self._keep(ctx.program(
            vertex_shader=shader_source("camera_vs.glsl"),
            fragment_shader=shader_source("camera_fs.glsl")))
        self._draws = []
        textures = {}
        for m in np.unique(sc.face_material):
            faces = sc.faces[sc.face_material == m]
            mat = sc.materials[int(m)]
            buf = self._keep(ctx.buffer(np.ascontiguousarray(faces, dtype="<u4").tobytes()))
            vao = self._keep(ctx.vertex_array(
                self._camera_prog, [(self._vbo, VERTEX_FORMAT, "in_pos", "in_nrm", "in_uv0",
                                     "in_uv1")], index_buffer=buf, index_element_size=4))
            tex = None
            if mat.texture >= 0:
                if mat.texture not in textures:
                    t = sc.textures[mat.texture]
                    h, w = t.pixels.shape[:2]
                    gt = self._keep(ctx.texture((w, h), 4, np.ascontiguousarray(
                        t.pixels, dtype="<f4").tobytes(), dtype="f4"))
                    gt.filter = (moderngl.LINEAR, moderngl.LINEAR)
                    gt.repeat_x = t.wrap_s != 33071  # MIRRORED_REPEAT drawn as REPEAT
                    gt.repeat_y = t.wrap_t != 33071
                    textures[mat.texture] = gt
                tex = textures[mat.texture]
            self._draws.append((vao, mat, tex))

    def _setup_basis(self) -> None:
        """Basis planes, 4 per RGBA layer of a texture array (row 0 = the EXR's top row =
        TEXCOORD_1 v ≈ 0), the coverage, and the atlas program that blends them."""
        moderngl, ctx, d = self._mgl, self.ctx, self.data
        h, w, q = d.planes.shape
        self._basis = self._keep(basis_texture(ctx, d.planes))
        layers = -(-q // 4)
        self._coverage = self._keep(ctx.texture((w, h), 1, np.ascontiguousarray(
            d.coverage, dtype="<f4").tobytes(), dtype="f4"))
        self._coverage.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._weights = self._keep(ctx.buffer(reserve=4 * layers * 16))
        self._atlas_prog = self._keep(ctx.program(
            vertex_shader=shader_source("atlas_vs.glsl"),
            fragment_shader=shader_source("atlas_fs.glsl")))
        self._atlas_vao = self._keep(ctx.vertex_array(self._atlas_prog, []))

    def _setup_points(self) -> None:
        """Measurement points: supersamples grouped by owner, and the points pass."""
        ctx, d = self.ctx, self.data
        order = np.argsort(d.cluster_owner, kind="stable")
        owner = d.cluster_owner[order]
        self._cluster_order = order
        starts = np.searchsorted(owner, np.arange(d.point_count + 1)).astype("<i4")
        cl = np.zeros((len(order), 3, 4), np.float32)
        cl[:, 0, :3] = d.cluster_position[order]
        cl[:, 1, :3] = d.cluster_normal[order]
        cl[:, 2, :3] = d.cluster_albedo[order]
        self._clusters = self._keep(ctx.buffer(cl.tobytes()))
        self._starts = self._keep(ctx.buffer(starts.tobytes()))
        self._x = self._keep(ctx.buffer(reserve=max(1, d.point_count) * 16))
        self._ce = self._keep(ctx.buffer(reserve=max(1, len(order)) * 16))
        self._points_cs = self._keep(ctx.compute_shader(shader_source("points_cs.glsl")))

    def _setup_coefficients(self) -> None:
        """The transfer (the first keyframe's for keyframe sets, as the CPU runtime's
        default), the plane layout and the coefficients pass."""
        ctx, d = self.ctx, self.data
        M, b = d.transfer, d.offset
        if M.ndim == 4:
            M, b = M[0], b[0]
        self._n_b = int(M.shape[1])
        self._m = self._keep(ctx.buffer(np.ascontiguousarray(M, "<f4").tobytes() or b"\0" * 4))
        self._b = self._keep(ctx.buffer(np.ascontiguousarray(b, "<f4").tobytes() or b"\0" * 4))
        pl = np.stack([d.plane_element, d.plane_channel.astype(np.int32)], 1).astype("<i4")
        self._planes = self._keep(ctx.buffer(pl.tobytes()))
        defines = {"GROUP": COEFF_GROUP, "N_U": max(1, 3 * self._n_b)}
        self._learnt = None
        if d.learnt is not None:  # fit.transfer "mlp": learnt.glsl in the same pass
            weights, layers = learnt_buffers(d.learnt)
            self._learnt = (self._keep(ctx.buffer(weights.tobytes())),
                            self._keep(ctx.buffer(layers.tobytes())))
            defines.update(LEARNT=1, LEARNT_LAYERS=len(d.learnt.weights),
                           LEARNT_WIDTH=max((1, *d.learnt.widths)))
        self._coeff_cs = self._keep(ctx.compute_shader(shader_source("coeff_cs.glsl",
                                                                     **defines)))

    @property
    def n_basis(self) -> int:
        return self.data.n_basis

    # -- passes ------------------------------------------------------------------------
    @current
    def shadow_pass(self, lights: Sequence[Light]) -> None:
        """Upload the lights and render their shadow maps."""
        self._shadows.render(lights, self._timer)

    @current
    def points_pass(self, use_shadows: bool = True) -> None:
        """Fake G-buffer: shade the supersamples, average clusters → x' (after shadows)."""
        cs = self._points_cs
        self._shadows.bind(cs, use_shadows)
        self._clusters.bind_to_storage_buffer(1)
        self._starts.bind_to_storage_buffer(2)
        self._x.bind_to_storage_buffer(3)
        self._ce.bind_to_storage_buffer(5)
        set_uniform(cs, "n_points", self.data.point_count)
        set_uniform(cs, "gamma", float(self.data.gamma or 0.0))
        with self._timer.timed("points"):
            cs.run(group_x=max(1, -(-self.data.point_count // 64)))
        self.ctx.memory_barrier()

    def _use(self, n: int | None) -> int:
        if n is not None and not 1 <= n <= self.n_basis:
            raise PrtError(f"render: --basis {n}: the bundle has {self.n_basis} basis "
                           f"elements (mean included); use 1..{self.n_basis}")
        return self._n_b if n is None else max(0, min(n - 1, self._n_b))

    @current
    def coefficients_pass(self, n: int | None = None) -> int:
        """u = M·x' per channel and the plane weights; returns the RGBA layers in use."""
        use = self._use(n)
        cs = self._coeff_cs
        self._x.bind_to_storage_buffer(3)
        self._m.bind_to_storage_buffer(6)
        self._b.bind_to_storage_buffer(7)
        self._planes.bind_to_storage_buffer(8)
        self._weights.bind_to_storage_buffer(4)
        if self._learnt is not None:
            self._learnt[0].bind_to_storage_buffer(9)
            self._learnt[1].bind_to_storage_buffer(10)
            set_uniform(cs, "learnt_slope", float(self.data.learnt.slope))
        q = len(self.data.plane_element)
        set_uniform(cs, "n_points", self.data.point_count)
        set_uniform(cs, "n_b", self._n_b)
        set_uniform(cs, "use", use)
        set_uniform(cs, "n_planes", q)
        with self._timer.timed("coefficients"):
            cs.run(group_x=1)
        self.ctx.memory_barrier()
        planes_used = int(np.count_nonzero(self.data.plane_element <= use))
        return -(-planes_used // 4)

    def _bind_blend(self, prog, layers: int) -> None:
        self._weights.bind_to_storage_buffer(4)
        self._basis.use(location=1)
        set_uniform(prog, "basis", 1)
        set_uniform(prog, "n_layers", layers)
        set_uniform(prog, "gamma", float(self.data.gamma or 0.0))

    @current
    def camera_pass(self, camera: Camera, mode: str, layers: int) -> None:
        ctx, mgl, prog = self.ctx, self._mgl, self._camera_prog
        if mode not in MODES:
            raise PrtError(f"render: mode {mode!r}: expected one of {', '.join(MODES)}")
        fbo = self._target(camera.width, camera.height, 2)
        clip = scene_clip_from_world(camera, self.center, self.radius)
        self._shadows.bind(prog)
        self._bind_blend(prog, layers)
        set_uniform(prog, "clip_from_world", matrix_bytes(clip))
        set_uniform(prog, "eye", tuple(float(v) for v in camera.position))
        set_uniform(prog, "mode", MODES[mode])
        set_uniform(prog, "albedo_texture", 2)
        def draw() -> None:
            for vao, mat, tex in self._draws:
                set_uniform(prog, "base_color", tuple(float(v) for v in mat.base_color_factor))
                set_uniform(prog, "has_texture", int(tex is not None))
                set_uniform(prog, "texture_uv", int(mat.texcoord == 1))
                set_uniform(prog, "uv_transform", matrix_bytes(mat.uv_transform))
                if tex is not None:
                    tex.use(location=2)
                vao.render(mgl.TRIANGLES)

        with self._timer.timed("camera"):
            draw_depth_tested(ctx, fbo, draw)

    @current
    def atlas_pass(self, layers: int) -> None:
        """The basis blend (blend.glsl) at every texel centre of the atlas with the plane
        weights in the weights buffer (:meth:`coefficients_pass` or :meth:`upload_weights`)."""
        h, w = self.data.coverage.shape
        fbo = self._target(w, h, 1)
        prog = self._atlas_prog
        self._bind_blend(prog, layers)
        self._coverage.use(location=3)
        set_uniform(prog, "coverage", 3)
        with self._timer.timed("atlas_blend"):
            fbo.use()
            fbo.viewport = (0, 0, *fbo.size)
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            self.ctx.disable(self._mgl.DEPTH_TEST | self._mgl.CULL_FACE | self._mgl.BLEND)
            self._atlas_vao.render(self._mgl.TRIANGLES, vertices=3)

    @current
    def upload_weights(self, weights: np.ndarray) -> int:
        """Write plane weights (q, 3) (:func:`prtcore.runtime.cpu.plane_weights`' layout)
        into the weights buffer the blend reads, in place of :meth:`coefficients_pass`;
        returns the RGBA layers they span."""
        w = np.asarray(weights, np.float64)
        q = len(self.data.plane_element)
        if w.shape != (q, 3):
            raise PrtError(f"render: plane weights of shape {w.shape}; expected ({q}, 3)")
        buf = np.zeros((self._weights.size // 16, 4), "<f4")
        buf[:q, :3] = w
        self._weights.write(buf.tobytes())
        return -(-q // 4)

    # -- frames ------------------------------------------------------------------------
    @current
    def shade_points(self, lights: Sequence[Light], use_shadows: bool = True
                     ) -> tuple[np.ndarray, np.ndarray]:
        """GPU fake G-buffer: x' (P, 3) (gamma applied when the bundle has gamma) and the
        irradiance at each supersample (s, 3) in the bundle's cluster order, float64."""
        self.shadow_pass(lights)
        self.points_pass(use_shadows)
        x = np.frombuffer(self._x.read(), "<f4").reshape(-1, 4)[:self.data.point_count, :3]
        ce = np.frombuffer(self._ce.read(), "<f4").reshape(-1, 4)[:len(self._cluster_order),
                                                                 :3]
        e = np.empty_like(ce, dtype=np.float64)
        e[self._cluster_order] = ce
        check_gl(self.ctx, "shade points")
        return x.astype(np.float64), e

    @current
    def plane_weights(self, lights: Sequence[Light], n: int | None = None) -> np.ndarray:
        """GPU coefficients: the RGB weight of every basis plane, (q, 3) float64."""
        self.shadow_pass(lights)
        self.points_pass()
        self.coefficients_pass(n)
        q = len(self.data.plane_element)
        w = np.frombuffer(self._weights.read(), "<f4").reshape(-1, 4)[:q, :3]
        check_gl(self.ctx, "coefficients")
        return w.astype(np.float64)

    @current
    def render(self, lights: Sequence[Light], camera: Camera, n: int | None = None,
               mode: str = "full") -> RenderResult:
        """One frame through ``camera``: mode "full" (direct + indirect), "direct" (the
        same pass without the indirect term) or "indirect" (indirect only)."""
        self._use(n)  # refuse a bad n before any GL work
        if mode not in MODES:
            raise PrtError(f"render: mode {mode!r}: expected one of {', '.join(MODES)}")
        self._timer.reset()
        self.shadow_pass(lights)
        self.points_pass()
        layers = self.coefficients_pass(n)
        self.camera_pass(camera, mode, layers)
        fbo = self._target(camera.width, camera.height, 2)
        h, w = camera.height, camera.width
        img = np.frombuffer(fbo.read(components=4, dtype="f4", attachment=0), "<f4")
        aux = np.frombuffer(fbo.read(components=4, dtype="f4", attachment=1), "<f4")
        img = img.reshape(h, w, 4)[::-1].copy()
        aux = aux.reshape(h, w, 4)[::-1]
        check_gl(self.ctx, "render")
        gpu, wall = self._timer.results()
        return RenderResult(image=img, uv1=np.ascontiguousarray(aux[:, :, :2]),
                            milliseconds=gpu, wall_milliseconds=wall)

    @current
    def relight_atlas(self, lights: Sequence[Light], n: int | None = None) -> RenderResult:
        """The indirect lightmap at atlas size on the GPU (the fragment-shader blend at
        texel centres): image (h, w, 4), A = coverage — what ``prtcore relight`` writes."""
        self._timer.reset()
        self.shadow_pass(lights)
        self.points_pass()
        layers = self.coefficients_pass(n)
        return self._read_atlas(layers, "relight atlas")

    @current
    def blend_atlas(self, weights: np.ndarray) -> RenderResult:
        """The GPU blend (blend.glsl) of the basis planes with given plane weights (q, 3) at
        every texel centre: what :func:`prtcore.runtime.cpu.blend` computes on the CPU.
        image (h, w, 4), A = coverage."""
        self._timer.reset()
        return self._read_atlas(self.upload_weights(weights), "blend atlas")

    def _read_atlas(self, layers: int, where: str) -> RenderResult:
        self.atlas_pass(layers)
        h, w = self.data.coverage.shape
        fbo = self._target(w, h, 1)
        img = np.frombuffer(fbo.read(components=4, dtype="f4", attachment=0), "<f4")
        check_gl(self.ctx, where)
        gpu, wall = self._timer.results()
        return RenderResult(image=img.reshape(h, w, 4)[::-1].copy(),
                            uv1=np.zeros((h, w, 2), np.float32), milliseconds=gpu,
                            wall_milliseconds=wall)


def basis_texture(ctx, planes: np.ndarray):
    """The basis planes (h, w, q) as a float RGBA texture array of ⌈q/4⌉ layers, four
    planes per layer (row 0 = the EXR's top row), bilinear, clamped — what blend.glsl's
    ``basis`` samples."""
    import moderngl

    h, w, q = planes.shape
    layers = -(-q // 4)
    packed = np.zeros((layers, h, w, 4), np.float32)
    for f in range(layers):
        part = planes[:, :, 4 * f:4 * f + 4]
        packed[f, :, :, :part.shape[2]] = part
    tex = ctx.texture_array((w, h, layers), 4, packed.tobytes(), dtype="f4")
    tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
    tex.repeat_x = tex.repeat_y = False
    return tex


def learnt_buffers(net: Mlp) -> tuple[np.ndarray, np.ndarray]:
    """The learnt transfer as learnt.glsl reads it: every layer's weights (row-major) then
    its biases in one float32 array, and per layer (inputs, outputs, weight offset, bias
    offset) as (L, 4) int32."""
    parts, table, at = [], [], 0
    for w, c in zip(net.weights, net.biases, strict=True):
        table.append((w.shape[1], w.shape[0], at, at + w.size))
        parts += [np.asarray(w, "<f4").ravel(), np.asarray(c, "<f4")]
        at += w.size + c.size
    return np.concatenate(parts), np.asarray(table, "<i4")


# ---------------------------------------------------------------------------------------
# Output


def tone_map(image: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear RGB(A) (h, w, c) → (h, w, 3) uint8 sRGB: scale by ``exposure``, clip to
    [0, 1], sRGB-encode (no filmic curve: what is bright clips)."""
    from prtcore.core.materials import linear_to_srgb

    rgb = np.clip(np.asarray(image, np.float64)[:, :, :3] * exposure, 0.0, 1.0)
    return np.round(linear_to_srgb(rgb) * 255.0).astype(np.uint8)


def write_render(path: str | Path, image: np.ndarray, exposure: float = 1.0) -> None:
    """``.exr``: linear RGBA float; ``.png``: tone-mapped sRGB (see :func:`tone_map`)."""
    from prtcore.io.imageio import write_exr, write_png

    suffix = Path(path).suffix.lower()
    if suffix == ".exr":
        write_exr(path, image, dtype="float")
    elif suffix == ".png":
        write_png(path, tone_map(image, exposure))
    else:
        raise PrtError(f"{path}: output must end in .png or .exr")


def render_to_file(bundle: str | Path, light_path: str | Path, camera_path: str | Path,
                   out: str | Path, *, n: int | None = None, mode: str = "full",
                   exposure: float = 1.0, shadow_resolution: int = SHADOW_RESOLUTION,
                   time: float | None = None) -> tuple[RenderResult, str]:
    """``prtcore render``: one frame of the bundle to a PNG or EXR. Returns the frame and
    the GL renderer's label. (A single frame's timings include shader compilation.)"""
    from prtcore.emitters.lightfile import load_light_file
    from prtcore.reference.camera import load_camera

    if Path(out).suffix.lower() not in (".png", ".exr"):
        raise PrtError(f"{out}: output must end in .png or .exr")
    lights = load_light_file(light_path)
    camera = load_camera(camera_path)
    with BundleRenderer(bundle, shadow_resolution=shadow_resolution, time=time) as r:
        res = r.render(lights, camera, n=n, mode=mode)
        label = renderer_label(r.ctx)
    write_render(out, res.image, exposure)
    return res, label


def gpu_runtime_table(renderer: BundleRenderer, lights: Sequence[Light], ns: Sequence[int],
                      camera: Camera | None = None, repeat: int = 5) -> dict:
    """Median milliseconds per pass for each basis count n, after one warm-up frame.

    Per n: ``points`` (fake G-buffer), ``coefficients`` (u = M·x), ``atlas_blend`` (the
    basis blend over the whole atlas) and, with a camera, ``shadow_maps`` and ``camera``
    (the camera pass at the camera's size, direct + indirect). Returns {"renderer":
    label, "rows": [{"n": n, pass: GL timer query ms (None if no valid result), ...,
    "wall": {pass: wall-clock ms between glFinish calls}}]}.
    """
    rows = []
    for n in ns:
        gpu: dict[str, list[float]] = {}
        wall: dict[str, list[float]] = {}
        for i in range(repeat + 1):
            a = renderer.relight_atlas(lights, n)
            g, w = dict(a.milliseconds), dict(a.wall_milliseconds)
            g.pop("shadow_maps", None)
            w.pop("shadow_maps", None)
            if camera is not None:
                c = renderer.render(lights, camera, n=n)
                for k in ("shadow_maps", "camera"):
                    g[k], w[k] = c.milliseconds[k], c.wall_milliseconds[k]
            if i == 0:  # warm-up: shader compilation, allocation
                continue
            for k, v in g.items():
                gpu.setdefault(k, [])
                if v is not None:
                    gpu[k].append(v)
            for k, v in w.items():
                wall.setdefault(k, []).append(v)
        row: dict = {"n": int(n)}
        row.update({k: float(np.median(v)) if v else None for k, v in gpu.items()})
        row["wall"] = {k: float(np.median(v)) for k, v in wall.items()}
        rows.append(row)
    return {"renderer": renderer_label(renderer.ctx), "rows": rows}
