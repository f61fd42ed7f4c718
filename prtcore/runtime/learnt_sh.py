"""The learnt SH transfer on the GPU (thesis 4.1.4.1): the network of
:class:`prtcore.fit.learnt_sh.LearntSh` with every weight matrix cut into 4 × 4 blocks
read as ``mat4`` (zero-padded to multiples of 4), its per-output scales as ``vec4``
(``learnt_sh_net.glsl``). The thesis bakes the blocks into the shader source as
constants; here they sit in storage buffers: with the k = 64 and k = 128 networks as
constant arrays, llvmpipe's compiler had not finished after 10 minutes.

* :func:`gpu_evaluate` — :func:`prtcore.fit.learnt_sh.evaluate` in a compute pass, one
  point per invocation (``tests/test_learnt_sh_gl.py`` holds them equal to 1e-4);
* :class:`LearntShRenderer` — the camera pass of a ``learnt_sh`` bundle
  (docs/learnt_sh.md): the mesh rasterised (``sh_vs.glsl``), σ(p, n̂) per fragment,
  ``albedo(uv1) · (T · l)`` per channel, and with a glossy network ``+ ρ_s · TP`` of the
  network's visibility block (``sh_glossy.glsl``, shared with the sh_prt runtime); for an
  SDF scene a full-screen pass that sphere-traces the field per pixel
  (``learnt_sh_sdf_fs.glsl``) and shades the hit the same way.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from prtcore.core.errors import PrtError
from prtcore.core.sdf import GRADIENT_STEP, HIT_EPSILON, MAX_STEPS, sdf_t_max
from prtcore.core.sdf import packed as packed_sdf
from prtcore.fit.learnt_sh import LearntSh
from prtcore.fit.subscenes import LearntShScenes, single
from prtcore.reference.camera import Camera
from prtcore.runtime.gl import RenderResult
from prtcore.runtime.glcontext import check_gl, current, set_uniform
from prtcore.runtime.glsl import shader_source
from prtcore.runtime.sh_gl import DistantPass, glossy_constants, render_distant_to_file

#: invocations per work group (the compute shader's local_size_x)
GROUP = 64
#: the networks' storage-buffer bindings in learnt_sh_net.glsl: weights, biases, layer
#: table, output scales, frames
NET_BINDINGS = (10, 11, 12, 13, 15)
#: the SDF primitives' binding in learnt_sh_sdf.glsl
SDF_BINDING = 14


def _blocks(w: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """W (out, in) and b (out,) zero-padded to multiples of 4: (out4, in4, 4, 4), (out4, 4)."""
    o4, i4 = -(-w.shape[0] // 4), -(-w.shape[1] // 4)
    wp = np.zeros((4 * o4, 4 * i4))
    wp[:w.shape[0], :w.shape[1]] = w
    bp = np.zeros(4 * o4)
    bp[:len(b)] = b
    return wp.reshape(o4, 4, i4, 4).transpose(0, 2, 1, 3), bp.reshape(o4, 4)


def packed(model: LearntSh | LearntShScenes
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The networks as the shader reads them, one per sub-scene cell in cell order: every
    layer's 4 × 4 blocks as column-major mat4 (blocks, 16) float32, the biases (vec4s, 4)
    float32, per network and layer (input vec4s, output vec4s, first block, first bias)
    (cells·L, 4) int32, the output scales (cells·out4, 4) float32, and per network its
    frame (centre, 1 / radius) (cells, 4) float32."""
    scenes = model if isinstance(model, LearntShScenes) else single(model)
    mats, vecs, table, scales, frames = [], [], [], [], []
    for m in scenes.models:
        for w, b in zip(m.net.weights, m.net.biases, strict=True):
            wb, bb = _blocks(np.asarray(w, np.float64), np.asarray(b, np.float64))
            o4, i4 = wb.shape[:2]
            table.append((i4, o4, sum(len(x) for x in mats), sum(len(v) for v in vecs)))
            # GLSL mat4 is column-major: column c holds W[4o + r, 4q + c] for r = 0..3
            mats.append(wb.transpose(0, 1, 3, 2).reshape(o4 * i4, 16))
            vecs.append(bb)
        out = m.net.outputs
        scale = np.zeros(4 * -(-out // 4))
        scale[:out] = np.broadcast_to(np.asarray(m.scale, np.float64), (out,))
        scales.append(scale.reshape(-1, 4))
        frames.append((*m.centre, 1.0 / m.radius))
    return (np.concatenate(mats).astype("<f4"), np.concatenate(vecs).astype("<f4"),
            np.asarray(table, "<i4"), np.concatenate(scales).astype("<f4"),
            np.asarray(frames, "<f4"))


def _defines(model: LearntSh | LearntShScenes) -> dict[str, int]:
    first = model.models[0] if isinstance(model, LearntShScenes) else model
    _, _, table, _, _ = packed(first)
    return {"IN4": int(table[0, 0]), "MAX4": int(max(table[:, 0].max(), table[:, 1].max())),
            "OUT4": int(table[-1, 1]), "LAYERS": len(table),
            "POSITION_FREQUENCIES": first.position_frequencies,
            "NORMAL_FREQUENCIES": first.normal_frequencies}


def shader(model: LearntSh | LearntShScenes) -> str:
    """The compute shader's source for ``model``'s sizes and encoding."""
    return shader_source("learnt_sh_cs.glsl", **_defines(model))


def network_buffers(ctx, model: LearntSh | LearntShScenes) -> list:
    """The networks' storage buffers, bound to :data:`NET_BINDINGS` (the caller releases
    them)."""
    bufs = [ctx.buffer(a.tobytes()) for a in packed(model)]
    for binding, buf in zip(NET_BINDINGS, bufs, strict=True):
        buf.bind_to_storage_buffer(binding)
    return bufs


def set_network_uniforms(prog, model: LearntSh | LearntShScenes) -> None:
    """The activation's and the sub-scene grid's uniforms of ``learnt_sh_net.glsl``."""
    scenes = model if isinstance(model, LearntShScenes) else single(model)
    set_uniform(prog, "slope", scenes.net.slope)
    set_uniform(prog, "tanh_output", int(scenes.net.output == "tanh"))
    set_uniform(prog, "grid_cells", tuple(int(c) for c in scenes.grid.cells))
    set_uniform(prog, "grid_lo", tuple(float(v) for v in scenes.grid.lo))
    set_uniform(prog, "grid_size", tuple(float(v) for v in scenes.grid.hi - scenes.grid.lo))


def gpu_evaluate(ctx, model: LearntSh | LearntShScenes, position: np.ndarray, normal: np.ndarray
                 ) -> np.ndarray:
    """σ at points (n, 3) with unit normals (n, 3) in the moderngl context ``ctx``:
    (n, outputs) float64 (computed in float32)."""
    n = len(position)
    out4 = -(-model.net.outputs // 4)

    def vec4s(a):
        v = np.zeros((max(n, 1), 4), "<f4")
        v[:n, :3] = a
        return ctx.buffer(v.tobytes())

    cs = ctx.compute_shader(shader(model))
    bufs = [vec4s(position), vec4s(normal), ctx.buffer(reserve=max(n, 1) * out4 * 16)]
    try:
        for k, buf in enumerate(bufs):
            buf.bind_to_storage_buffer(k)
        bufs += network_buffers(ctx, model)
        set_uniform(cs, "n_points", n)
        set_network_uniforms(cs, model)
        cs.run(group_x=max(1, -(-n // GROUP)))
        ctx.memory_barrier()
        out = np.frombuffer(bufs[2].read(), "<f4").reshape(-1, 4 * out4)[:n]
        check_gl(ctx, "learnt SH")
        return out[:, :model.net.outputs].astype(np.float64)
    finally:
        for buf in bufs:
            buf.release()
        cs.release()


class LearntShRenderer(DistantPass):
    """The GPU runtime of one ``learnt_sh`` bundle (the manifest's ``learnt_sh`` section):
    one camera pass evaluating the network per fragment."""

    def __init__(self, bundle: str | Path, ctx=None):
        from prtcore.fit.subscenes import read_scenes
        from prtcore.io.bundle import read_manifest
        from prtcore.io.sdf import load_sdf

        manifest = read_manifest(Path(bundle))
        sec = manifest.get("learnt_sh")
        if manifest.get("method") != "learnt_sh" or sec is None:
            raise PrtError(f"{bundle}: not a learnt_sh bundle")
        self.model = read_scenes(Path(bundle), sec["networks"])
        self.sdf = load_sdf(Path(bundle) / sec["sdf"]["file"]) if sec.get("sdf") else None
        if self.sdf is None:
            fragment = shader_source("learnt_sh_fs.glsl", **_defines(self.model))
        else:
            fragment = shader_source("learnt_sh_sdf_fs.glsl", MAX_STEPS=MAX_STEPS,
                                     **_defines(self.model))
        self.bands = self.model.bands
        self.specular = float(sec["specular"]) if self.model.glossy else 0.0
        super().__init__(bundle, "learnt_sh", fragment, ctx, fullscreen=self.sdf is not None,
                         setup=lambda: self._setup(sec))

    def _setup(self, sec: dict) -> None:
        """The field, albedo atlas, network, light and glossy-layer buffers."""
        import moderngl

        from prtcore.io.imageio import read_image

        c = self.ctx
        self._sdf = self._keep(c.buffer(packed_sdf(self.sdf).tobytes() if self.sdf
                                        else np.zeros(12, "<f4").tobytes()))
        albedo = read_image(self.bundle / sec["albedo"])[:, :, :3]
        h, w = albedo.shape[:2]
        self._albedo = self._keep(c.texture((w, h), 3, np.ascontiguousarray(
            albedo, "<f4").tobytes(), dtype="f4"))
        self._albedo.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self._albedo.repeat_x = self._albedo.repeat_y = False
        self._net = [self._keep(b) for b in network_buffers(c, self.model)]
        n = self.bands ** 2
        self._light = self._keep(c.buffer(reserve=16 * n))
        if self.model.glossy:
            kernel, norm = glossy_constants(self.bands, float(sec["exponent"]))
        else:
            kernel = norm = np.zeros(4, "<f4").tobytes()
        self._kernel, self._norm = self._keep(c.buffer(kernel)), self._keep(c.buffer(norm))
        self._product = self._keep(c.buffer(reserve=4 * 3 * n * n))

    @current
    def render(self, light_sh: np.ndarray, camera: Camera) -> RenderResult:
        """One frame under light SH coefficients (L², 3) through ``camera``."""
        self._upload_light(light_sh, self.bands ** 2, self.model.glossy)
        prog = self._prog
        set_uniform(prog, "vertex_storage", 0)
        set_uniform(prog, "bands", self.bands)
        set_uniform(prog, "glossy", int(self.model.glossy))
        set_uniform(prog, "specular", self.specular)
        set_uniform(prog, "albedo_tex", 0)
        set_network_uniforms(prog, self.model)
        if self.sdf is not None:
            self._set_sdf_uniforms(camera)
        self._albedo.use(location=0)
        for binding, b in zip(NET_BINDINGS, self._net, strict=True):
            b.bind_to_storage_buffer(binding)
        self._light.bind_to_storage_buffer(6)
        self._product.bind_to_storage_buffer(7)
        self._kernel.bind_to_storage_buffer(8)
        self._norm.bind_to_storage_buffer(9)
        self._sdf.bind_to_storage_buffer(SDF_BINDING)
        return self._draw(camera, self.pass_name)

    @property
    def pass_name(self) -> str:
        """The timed pass's name: "learnt_sh" (mesh) or "learnt_sh_sdf" (sphere tracing)."""
        return "learnt_sh" if self.sdf is None else "learnt_sh_sdf"

    def _set_sdf_uniforms(self, camera: Camera) -> None:
        """The sphere-tracing pass's uniforms: the field (prtcore.core.sdf), the camera's
        frame as :meth:`prtcore.reference.camera.Camera.primary_rays` builds its rays, and
        the march's limits (:func:`prtcore.core.sdf.sphere_trace`)."""
        prog, sdf = self._prog, self.sdf
        r, u, f = camera.frame()
        for name, v in (("cam_right", r), ("cam_up", u), ("cam_forward", f)):
            set_uniform(prog, name, tuple(float(x) for x in v))
        set_uniform(prog, "tan_half_fov", math.tan(math.radians(camera.fov_y_deg) / 2.0))
        set_uniform(prog, "aspect", camera.aspect)
        set_uniform(prog, "viewport", (float(camera.width), float(camera.height)))
        set_uniform(prog, "t_max", sdf_t_max(sdf, camera.position))
        set_uniform(prog, "hit_eps", HIT_EPSILON * sdf.radius)
        set_uniform(prog, "grad_h", GRADIENT_STEP * sdf.radius)
        set_uniform(prog, "n_prims", len(sdf.primitives))
        set_uniform(prog, "smooth_k", sdf.smooth)
        set_uniform(prog, "sdf_albedo", tuple(float(a) for a in sdf.albedo))


def render_learnt_sh_to_file(bundle: str | Path, light_path: str | Path,
                             camera_path: str | Path, out: str | Path, *,
                             exposure: float = 1.0) -> tuple[RenderResult, str]:
    """``prtcore render`` of a learnt_sh bundle: distant lighting (docs/lights.md) → one
    frame to a PNG or EXR. Returns the frame and the GL renderer's label."""
    return render_distant_to_file(LearntShRenderer, bundle, light_path, camera_path, out,
                                  exposure=exposure)
