"""Shadow maps of the GL runtime: the light table and one shadow view set per light.

One per light: six 90° views (point and spot lights) or one orthographic view over the
scene's bounding sphere (lights at infinity), rendered into one R32F atlas (a row per
light, a column per view) storing the distance to the light (at infinity: depth along the
light's direction); MIN blending keeps the nearest surface exactly, with no depth-buffer
precision involved. ``lights.glsl`` reads the table and the atlas (:meth:`ShadowMaps.bind`);
the shadow test and its biases are described in :mod:`prtcore.runtime.gl`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from prtcore.core.errors import PrtError
from prtcore.core.scene import Light
from prtcore.emitters.base import emitter_for
from prtcore.reference.camera import look_at, orthographic, perspective
from prtcore.runtime.glcontext import PassTimer, matrix_bytes, set_uniform, unbind_framebuffer
from prtcore.runtime.glsl import shader_source

#: Lights drawn at once (each gets a row of the shadow atlas).
MAX_LIGHTS = 16
#: Shadow-map side per view (a point light has six views).
SHADOW_RESOLUTION = 1024
#: Normal offset of a shadow lookup, in shadow texels at the point.
SHADOW_NORMAL_OFFSET = 1.5
#: Constant depth bias of a shadow lookup, in shadow texels at the point.
SHADOW_DEPTH_BIAS = 1.0
#: Floats per light in the light table (``struct Light`` of lights.glsl).
FLOATS_PER_LIGHT = 4 * 4 + 6 * 16
#: Cube-face axes and up vectors of the six views of a point or spot light.
FACES = [((1, 0, 0), (0, -1, 0)), ((-1, 0, 0), (0, -1, 0)), ((0, 1, 0), (0, 0, 1)),
         ((0, -1, 0), (0, 0, -1)), ((0, 0, 1), (0, -1, 0)), ((0, 0, -1), (0, -1, 0))]


class ShadowMaps:
    """The light table and shadow atlas of one scene in one context.

    ctx : the moderngl context; vbo : the scene's vertex buffer, ``vertex_format`` its
    moderngl format with the position first and the rest skipped (e.g. ``"3f 7x4"``);
    faces : (F, 3) vertex indices; center, radius : the scene's bounding sphere;
    resolution : the side of each view. Call :meth:`release` to free the GL objects.
    """

    def __init__(self, ctx, vbo, vertex_format: str, faces: np.ndarray, center: np.ndarray,
                 radius: float, resolution: int):
        import moderngl

        self.ctx = ctx
        self._mgl = moderngl
        self.center = np.asarray(center, np.float64)
        self.radius = float(radius)
        self.resolution = int(resolution)
        self._objects: list = []
        self.lights_buf = self.fbo = self.texture = None
        self._rows = 0
        self._views: list[list[np.ndarray]] = []
        self.count = 0
        self._prog = self._keep(ctx.program(vertex_shader=shader_source("shadow_vs.glsl"),
                                            fragment_shader=shader_source("shadow_fs.glsl")))
        ibo = self._keep(ctx.buffer(np.ascontiguousarray(faces, dtype="<u4").tobytes()))
        self._vao = self._keep(ctx.vertex_array(
            self._prog, [(vbo, vertex_format, "in_pos")], index_buffer=ibo,
            index_element_size=4))

    def _keep(self, obj):
        self._objects.append(obj)
        return obj

    def light_views(self, light: Light) -> tuple[list[np.ndarray], float]:
        """Clip-from-world matrices of a light's shadow views, and the world texel size
        for directional lights (0 otherwise)."""
        R, c, res = self.radius, self.center, self.resolution
        if not emitter_for(light).positioned:  # at infinity: one orthographic view
            d = np.asarray(light.direction, np.float64)
            d = d / np.linalg.norm(d)
            up = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
            half = 1.01 * R
            view = look_at(c - 2.0 * R * d, c, up)
            return [orthographic(half, half, 0.5 * R, 3.5 * R) @ view], 2.0 * half / res
        pos = np.asarray(light.position, np.float64)
        dist = float(np.linalg.norm(pos - c))
        near, far = 1e-4 * (R + dist), dist + 1.5 * R
        proj = perspective(math.pi / 2, 1.0, near, far)
        return [proj @ look_at(pos, pos + np.asarray(a, float), np.asarray(u, float))
                for a, u in FACES], 0.0

    def upload(self, lights: Sequence[Light]) -> None:
        """Fill the light table (``struct Light`` of lights.glsl) for ``lights``."""
        if len(lights) > MAX_LIGHTS:
            raise PrtError(f"render: {len(lights)} lights; at most {MAX_LIGHTS} at once")
        buf = np.zeros((max(1, len(lights)), FLOATS_PER_LIGHT), np.float32)
        self._views = []
        for i, lt in enumerate(lights):
            t = emitter_for(lt).gl_code
            if t < 0:
                raise PrtError(f"render: {lt.type} lights are not drawn by the GL renderer "
                               "(relight them on the CPU: prtcore relight)")
            views, texel = self.light_views(lt)
            self._views.append(views)
            d = np.asarray(lt.direction, np.float64)
            d = d / np.linalg.norm(d)
            buf[i, 0:4] = [*np.asarray(lt.position, float), t]
            buf[i, 4:8] = [*d, 0.0 if lt.range is None else lt.range]
            buf[i, 8:11] = np.asarray(lt.color, float) * lt.intensity
            if emitter_for(lt).coned:
                ci, co = math.cos(lt.inner_cone_angle), math.cos(lt.outer_cone_angle)
                scale = 1.0 / max(1e-3, ci - co)
                buf[i, 12:14] = [scale, -co * scale]
            buf[i, 14:16] = [i, texel]
            for k, v in enumerate(views):
                buf[i, 16 + 16 * k:32 + 16 * k] = np.asarray(v, np.float64).T.ravel()
        data = buf.tobytes()
        if self.lights_buf is None or self.lights_buf.size < len(data):
            if self.lights_buf is not None:
                self.lights_buf.release()
            self.lights_buf = self.ctx.buffer(reserve=MAX_LIGHTS * FLOATS_PER_LIGHT * 4)
        self.lights_buf.write(data)
        self.count = len(lights)

    def _target(self, rows: int) -> None:
        res = self.resolution
        limit = int(self.ctx.info["GL_MAX_TEXTURE_SIZE"])
        if 6 * res > limit or rows * res > limit:
            raise PrtError(f"render: shadow atlas {6 * res}×{rows * res} exceeds "
                           f"GL_MAX_TEXTURE_SIZE {limit}; lower the shadow resolution")
        if self.fbo is not None and self._rows >= rows:
            return
        unbind_framebuffer(self.ctx)
        for o in (self.fbo, self.texture):
            if o is not None:
                o.release()
        self.texture = self.ctx.texture((6 * res, rows * res), 1, dtype="f4")
        self.texture.filter = (self._mgl.NEAREST, self._mgl.NEAREST)
        self.fbo = self.ctx.framebuffer(color_attachments=[self.texture])
        self._rows = rows

    def render(self, lights: Sequence[Light], timer: PassTimer) -> None:
        """Upload the lights and render their shadow maps (timed as "shadow_maps")."""
        ctx, mgl = self.ctx, self._mgl
        self.upload(lights)
        self._target(max(1, len(lights)))
        res = self.resolution
        prog = self._prog
        with timer.timed("shadow_maps"):
            self.fbo.use()
            self.fbo.viewport = (0, 0, *self.fbo.size)
            self.fbo.clear(red=3.0e38)
            ctx.disable(mgl.DEPTH_TEST | mgl.CULL_FACE)
            ctx.enable(mgl.BLEND)
            ctx.blend_equation = mgl.MIN
            for i, lt in enumerate(lights):
                d = np.asarray(lt.direction, np.float64)
                set_uniform(prog, "light_pos_type", (*map(float, lt.position),
                                                     float(emitter_for(lt).gl_code)))
                set_uniform(prog, "light_dir", tuple(float(v) for v in d / np.linalg.norm(d)))
                for k, view in enumerate(self._views[i]):
                    self.fbo.viewport = (k * res, i * res, res, res)
                    set_uniform(prog, "clip_from_world", matrix_bytes(view))
                    self._vao.render(mgl.TRIANGLES)
            ctx.blend_equation = mgl.FUNC_ADD
            ctx.disable(mgl.BLEND)

    def bind(self, prog, use_shadows: bool = True) -> None:
        """Bind the light table and the atlas for a program that includes lights.glsl."""
        self.lights_buf.bind_to_storage_buffer(0)
        self.texture.use(location=0)
        set_uniform(prog, "shadow_atlas", 0)
        set_uniform(prog, "n_lights", self.count)
        set_uniform(prog, "use_shadows", int(use_shadows))
        set_uniform(prog, "shadow_res", self.resolution)
        set_uniform(prog, "bias_normal", SHADOW_NORMAL_OFFSET)
        set_uniform(prog, "bias_const", SHADOW_DEPTH_BIAS)

    def release(self) -> None:
        """Free the GL objects (framebuffer 0 must be bound, :func:`unbind_framebuffer`)."""
        for obj in reversed(self._objects):
            obj.release()
        self._objects.clear()
        for o in (self.lights_buf, self.fbo, self.texture):
            if o is not None:
                o.release()
        self.lights_buf = self.fbo = self.texture = None
