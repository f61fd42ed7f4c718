"""Headless OpenGL runtime (moderngl, EGL): the engine side of a bundle (DESIGN 3.3 render).

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
   ``u_c = M_c x'_c + s·b_c`` per channel, then the RGB weight of every basis plane
   (:func:`prtcore.runtime.cpu.plane_weights`);
4. **camera pass** — direct light with shadow-map shadows plus the indirect term: the
   basis planes, packed four per RGBA layer of a texture array, are blended in the
   fragment shader, one 4×3 coefficient matrix per layer (paper 5.2), then gamma undone.

Shadow test: a point p with normal n (geometric normal in the camera pass, the stored
shading normal at measurement points) is looked up at ``p + n·k_n·τ`` where τ is the
world size of one shadow-map texel at p (``2d/res`` at distance d for a 90° view,
``2·1.01·R/res`` for directional), and is lit when its distance is at most the stored one
plus ``k_c·τ``. Both biases are thus in shadow texels, scaled to the scene (DESIGN 4),
never a fixed world epsilon. Each pass is timed with GL timer queries (GL_TIME_ELAPSED).

Images: float RGBA, row 0 at the top; A = 1 where the pixel centre sees the front of a
surface. Back faces (inside geometry, as in the path tracer) and background are black.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from prtcore.core.errors import PrtError
from prtcore.core.scene import Light
from prtcore.emitters.base import emitter_for
from prtcore.reference.camera import Camera, look_at, orthographic, perspective

#: Lights drawn at once (each gets a row of the shadow atlas).
MAX_LIGHTS = 16
#: Shadow-map side per view (a point light has six views).
SHADOW_RESOLUTION = 1024
#: Normal offset of a shadow lookup, in shadow texels at the point.
SHADOW_NORMAL_OFFSET = 1.5
#: Constant depth bias of a shadow lookup, in shadow texels at the point.
SHADOW_DEPTH_BIAS = 1.0
#: Render modes: which terms the camera pass adds.
MODES = {"full": 3, "direct": 1, "indirect": 2}
#: Work-group size of the coefficient pass.
_COEFF_GROUP = 256
_FLOATS_PER_LIGHT = 4 * 4 + 6 * 16

GL_LIGHTS = r"""
struct Light {
    vec4 pos_type;   // xyz position, w type: 0 point, 1 spot, 2 directional
    vec4 dir_range;  // xyz unit direction light travels, w range (0: none)
    vec4 color;      // rgb colour * intensity, w unused
    vec4 params;     // x spot scale, y spot offset, z atlas row, w texel size (directional)
    mat4 views[6];   // clip_from_world of each shadow view
};
layout(std430, binding = 0) readonly buffer Lights { Light lights[]; };
uniform int n_lights;
uniform int use_shadows;
uniform sampler2D shadow_atlas;
uniform int shadow_res;
uniform float bias_normal;
uniform float bias_const;
const float PI = 3.14159265358979323846;

int cube_face(vec3 v) {
    vec3 a = abs(v);
    if (a.x >= a.y && a.x >= a.z) return v.x > 0.0 ? 0 : 1;
    if (a.y >= a.z) return v.y > 0.0 ? 2 : 3;
    return v.z > 0.0 ? 4 : 5;
}

float visibility(int l, vec3 p, vec3 ng) {
    Light L = lights[l];
    int type = int(L.pos_type.w);
    vec3 to_light = type == 2 ? -L.dir_range.xyz : normalize(L.pos_type.xyz - p);
    float side = dot(ng, to_light) >= 0.0 ? 1.0 : -1.0;
    float texel = type == 2 ? L.params.w
                            : 2.0 * length(L.pos_type.xyz - p) / float(shadow_res);
    vec3 q = p + ng * (side * bias_normal * texel);
    int face = 0;
    float dq;
    if (type == 2) {
        dq = dot(q, L.dir_range.xyz);
    } else {
        vec3 v = q - L.pos_type.xyz;
        dq = length(v);
        face = cube_face(v);
    }
    vec4 clip = L.views[face] * vec4(q, 1.0);
    vec2 ndc = clip.xy / clip.w;
    ivec2 t = clamp(ivec2(floor((ndc * 0.5 + 0.5) * float(shadow_res))), ivec2(0),
                    ivec2(shadow_res - 1));
    t += ivec2(face * shadow_res, int(L.params.z) * shadow_res);
    float stored = texelFetch(shadow_atlas, t, 0).r;
    return dq <= stored + bias_const * texel ? 1.0 : 0.0;
}

// KHR_lights_punctual irradiance (prtcore.emitters.punctual.unshadowed_irradiance) times visibility
vec3 irradiance(int l, vec3 p, vec3 n, vec3 ng) {
    Light L = lights[l];
    int type = int(L.pos_type.w);
    float att;
    if (type == 2) {
        att = max(dot(n, -L.dir_range.xyz), 0.0);
    } else {
        vec3 d = L.pos_type.xyz - p;
        float r2 = dot(d, d);
        if (!(r2 > 0.0)) return vec3(0.0);
        float r = sqrt(r2);
        vec3 w = d / r;
        att = max(dot(n, w), 0.0);
        if (L.dir_range.w > 0.0) {
            float x = clamp(1.0 - pow(r / L.dir_range.w, 4.0), 0.0, 1.0);
            att *= x * x;
        }
        if (type == 1) {
            float a = clamp(dot(-w, L.dir_range.xyz) * L.params.x + L.params.y, 0.0, 1.0);
            att *= a * a;
        }
        att /= r2;
    }
    if (att > 0.0 && use_shadows != 0) att *= visibility(l, p, ng);
    return att * L.color.rgb;
}
"""

SHADOW_VS = r"""
#version 430
in vec3 in_pos;
uniform mat4 clip_from_world;
out vec3 v_pos;
void main() {
    v_pos = in_pos;
    gl_Position = clip_from_world * vec4(in_pos, 1.0);
}
"""

SHADOW_FS = r"""
#version 430
in vec3 v_pos;
uniform vec4 light_pos_type;
uniform vec3 light_dir;
out float f_dist;
void main() {
    f_dist = int(light_pos_type.w) == 2 ? dot(v_pos, light_dir)
                                        : length(v_pos - light_pos_type.xyz);
}
"""

CAMERA_VS = r"""
#version 430
in vec3 in_pos;
in vec3 in_nrm;
in vec2 in_uv0;
in vec2 in_uv1;
uniform mat4 clip_from_world;
out vec3 v_pos;
out vec3 v_nrm;
out vec2 v_uv0;
out vec2 v_uv1;
void main() {
    v_pos = in_pos;
    v_nrm = in_nrm;
    v_uv0 = in_uv0;
    v_uv1 = in_uv1;
    gl_Position = clip_from_world * vec4(in_pos, 1.0);
}
"""

BLEND = r"""
layout(std430, binding = 4) readonly buffer Weights { vec4 w[]; };
uniform sampler2DArray basis;
uniform int n_layers;
uniform float gamma;  // 0: none

// paper 5.2: one 4x3 coefficient matrix per RGBA texture of 4 basis planes
vec3 indirect_at(vec2 uv) {
    vec3 c = vec3(0.0);
    for (int f = 0; f < n_layers; ++f) {
        mat4x3 W = mat4x3(w[4 * f].xyz, w[4 * f + 1].xyz, w[4 * f + 2].xyz, w[4 * f + 3].xyz);
        c += W * texture(basis, vec3(uv, float(f)));
    }
    if (gamma > 0.0) c = pow(max(c, vec3(0.0)), vec3(gamma));
    return c;
}
"""

CAMERA_FS = "#version 430\n" + GL_LIGHTS + BLEND + r"""
in vec3 v_pos;
in vec3 v_nrm;
in vec2 v_uv0;
in vec2 v_uv1;
uniform vec3 eye;
uniform vec4 base_color;
uniform int has_texture;
uniform int texture_uv;
uniform mat3 uv_transform;
uniform sampler2D albedo_texture;
uniform int mode;  // bit 0: direct, bit 1: indirect
layout(location = 0) out vec4 f_color;
layout(location = 1) out vec4 f_aux;
void main() {
    if (!gl_FrontFacing) {  // inside geometry: no light (as the path tracer)
        f_color = vec4(0.0);
        f_aux = vec4(v_uv1, 0.0, 1.0);
        return;
    }
    vec3 ng = normalize(cross(dFdx(v_pos), dFdy(v_pos)));
    if (dot(ng, eye - v_pos) < 0.0) ng = -ng;
    vec3 n = normalize(v_nrm);
    if (!(dot(n, ng) > 0.0)) n = ng;  // as prtcore.core.geometry.shading_normals
    vec3 col = vec3(0.0);
    if ((mode & 1) != 0) {
        vec3 albedo = base_color.rgb;
        if (has_texture != 0) {
            vec2 uv = texture_uv == 1 ? v_uv1 : v_uv0;
            albedo *= texture(albedo_texture, (uv_transform * vec3(uv, 1.0)).xy).rgb;
        }
        albedo = clamp(albedo, 0.0, 0.99);
        vec3 e = vec3(0.0);
        for (int l = 0; l < n_lights; ++l) e += irradiance(l, v_pos, n, ng);
        col += albedo / PI * e;
    }
    if ((mode & 2) != 0) col += indirect_at(v_uv1);
    f_color = vec4(col, 1.0);
    f_aux = vec4(v_uv1, 1.0, 1.0);
}
"""

POINTS_CS = "#version 430\nlayout(local_size_x = 64) in;\n" + GL_LIGHTS + r"""
layout(std430, binding = 1) readonly buffer Clusters { vec4 cl[]; };  // pos, normal, albedo
layout(std430, binding = 2) readonly buffer Starts { int start[]; };  // P + 1
layout(std430, binding = 3) writeonly buffer X { vec4 x[]; };         // x' per point
layout(std430, binding = 5) writeonly buffer CE { vec4 ce[]; };       // E per supersample
uniform int n_points;
uniform float gamma;
void main() {
    int p = int(gl_GlobalInvocationID.x);
    if (p >= n_points) return;
    int a = start[p], b = start[p + 1];
    vec3 sum = vec3(0.0);
    for (int k = a; k < b; ++k) {
        vec3 pos = cl[3 * k].xyz, n = cl[3 * k + 1].xyz, albedo = cl[3 * k + 2].xyz;
        vec3 e = vec3(0.0);
        for (int l = 0; l < n_lights; ++l) e += irradiance(l, pos, n, n);
        ce[k] = vec4(e, 0.0);
        sum += albedo / PI * e;
    }
    vec3 v = sum / float(max(b - a, 1));
    if (gamma > 0.0) v = sign(v) * pow(abs(v), vec3(1.0 / gamma));
    x[p] = vec4(v, 0.0);
}
"""

COEFF_CS = r"""
#version 430
layout(local_size_x = %(group)d) in;
layout(std430, binding = 3) readonly buffer X { vec4 x[]; };
layout(std430, binding = 6) readonly buffer M { float m[]; };       // [c][i][p]
layout(std430, binding = 7) readonly buffer B { float b[]; };       // [c][i]
layout(std430, binding = 8) readonly buffer Planes { ivec2 plane[]; };  // element, channel
layout(std430, binding = 4) writeonly buffer Weights { vec4 w[]; };
uniform int n_points;
uniform int n_b;
uniform int use;
uniform int n_planes;
shared float partial[%(group)d];
shared float u[%(nu)d];
void main() {
    int t = int(gl_LocalInvocationID.x);
    float acc = 0.0;
    for (int p = t; p < n_points; p += %(group)d) acc += dot(x[p].xyz, x[p].xyz);
    partial[t] = acc;
    memoryBarrierShared();
    barrier();
    for (int s = %(group)d / 2; s > 0; s >>= 1) {
        if (t < s) partial[t] += partial[t + s];
        memoryBarrierShared();
        barrier();
    }
    float s = sqrt(partial[0]);
    for (int k = t; k < 3 * n_b; k += %(group)d) {
        int c = k / n_b, i = k - c * n_b;
        float v = 0.0;
        if (i < use) {
            int row = (c * n_b + i) * n_points;
            for (int p = 0; p < n_points; ++p) v += m[row + p] * x[p][c];
            v += s * b[c * n_b + i];
        }
        u[k] = v;
    }
    memoryBarrierShared();
    barrier();
    for (int j = t; j < n_planes; j += %(group)d) {
        int el = plane[j].x, ch = plane[j].y;
        vec3 wj = vec3(0.0);
        if (el == 0) wj[ch] = s;
        else if (el <= use) {
            if (ch < 0) wj = vec3(u[el - 1], u[n_b + el - 1], u[2 * n_b + el - 1]);
            else wj[ch] = u[ch * n_b + el - 1];
        }
        w[j] = vec4(wj, 0.0);
    }
}
"""

ATLAS_VS = r"""
#version 430
void main() {
    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
"""

ATLAS_FS = "#version 430\n" + BLEND + r"""
uniform sampler2D coverage;
out vec4 f_color;
void main() {
    ivec2 size = textureSize(coverage, 0);
    // FBO row r (from the bottom) becomes image row H-1-r after the read-back flip
    ivec2 t = ivec2(int(gl_FragCoord.x), size.y - 1 - int(gl_FragCoord.y));
    vec2 uv = (vec2(t) + 0.5) / vec2(size);
    f_color = vec4(indirect_at(uv), texelFetch(coverage, t, 0).r);
}
"""


def create_context(require: int = 430):
    """A standalone headless OpenGL context through EGL (Mesa llvmpipe or a GPU driver)."""
    import moderngl

    try:
        return moderngl.create_context(standalone=True, backend="egl", require=require)
    except Exception as e:  # moderngl raises plain Exceptions for a missing EGL/driver
        raise PrtError(f"render: cannot create an OpenGL {require // 100}.{require % 100 // 10} "
                       f"context through EGL: {e}".replace("\n", " ")) from None


def renderer_label(ctx) -> str:
    """The GL renderer string, marked "(software)" for Mesa's CPU rasterisers."""
    name = str(ctx.info["GL_RENDERER"])
    soft = any(k in name.lower() for k in ("llvmpipe", "softpipe", "swrast", "lavapipe"))
    return f"{name} (software)" if soft else name


def check_gl(ctx, where: str) -> None:
    """Raise if the context has a GL error pending (moderngl reads glGetError)."""
    err = ctx.error
    if err != "GL_NO_ERROR":
        raise PrtError(f"render: {where}: OpenGL error {err}")


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


def _mat(m: np.ndarray) -> bytes:
    """Column-major float32 bytes of a (4, 4) matrix (GLSL's layout)."""
    return np.ascontiguousarray(np.asarray(m, np.float64).T, dtype="<f4").tobytes()


def _set(prog, name: str, value) -> None:
    """Set a uniform if the compiler kept it (unused uniforms are optimised away)."""
    try:
        u = prog[name]
    except KeyError:
        return
    if isinstance(value, bytes):
        u.write(value)
    else:
        u.value = value


def make_current(ctx) -> None:
    """Make ``ctx`` the thread's current context and leave it current.

    Several contexts may live in one process (a test session's and one the CLI creates);
    creating one makes it current, and glcontext's ``with ctx:`` leaves *no* context
    current on exit, so GL methods call this on entry instead of using ``with``.
    """
    ctx.__enter__()


def _current(method):
    """Run a GL method with the renderer's context current (see :func:`make_current`)."""
    import functools

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        make_current(self.ctx)
        return method(self, *args, **kwargs)

    return wrapper


#: Cube-face axes and up vectors of the six views of a point or spot light.
_FACES = [((1, 0, 0), (0, -1, 0)), ((-1, 0, 0), (0, -1, 0)), ((0, 1, 0), (0, 0, 1)),
          ((0, -1, 0), (0, 0, -1)), ((0, 0, 1), (0, -1, 0)), ((0, 0, -1), (0, -1, 0))]


class BundleRenderer:
    """The GPU runtime of one bundle in one OpenGL context.

    bundle : bundle directory (DESIGN 3.4); ctx : a moderngl context (created through EGL
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
        self.ctx = ctx if ctx is not None else create_context()
        self._own_ctx = ctx is None
        self._released = False
        self.shadow_resolution = int(shadow_resolution)
        self._objects: list = []
        self._mgl = moderngl
        try:
            make_current(self.ctx)
            check_gl(self.ctx, "before setup")
            self._setup()
            check_gl(self.ctx, "setup")
        except BaseException:
            self._lights_buf = self._shadow_fbo = self._shadow_tex = None
            self._fbos, self._queries = {}, {}
            self.release()
            raise

    # -- setup -------------------------------------------------------------------------
    def _keep(self, obj):
        self._objects.append(obj)
        return obj

    def _setup(self) -> None:
        moderngl = self._mgl
        ctx, d, sc = self.ctx, self.data, self.scene
        self.center = np.asarray(sc.center, np.float64)
        self.radius = float(max(sc.radius, 1e-30))
        uv0 = sc.uv0 if sc.uv0 is not None else np.zeros((len(sc.positions), 2))
        verts = np.concatenate([sc.positions, sc.normals, uv0, sc.uv1], axis=1)
        self._vbo = self._keep(ctx.buffer(np.ascontiguousarray(verts, dtype="<f4").tobytes()))
        self._shadow_prog = self._keep(ctx.program(vertex_shader=SHADOW_VS,
                                                   fragment_shader=SHADOW_FS))
        self._camera_prog = self._keep(ctx.program(vertex_shader=CAMERA_VS,
                                                   fragment_shader=CAMERA_FS))
        ibo = self._keep(ctx.buffer(np.ascontiguousarray(sc.faces, dtype="<u4").tobytes()))
        self._shadow_vao = self._keep(ctx.vertex_array(
            self._shadow_prog, [(self._vbo, "3f 7x4", "in_pos")], index_buffer=ibo,
            index_element_size=4))
        # one draw per material (its factor and texture as uniforms)
        self._draws = []
        textures = {}
        for m in np.unique(sc.face_material):
            faces = sc.faces[sc.face_material == m]
            mat = sc.materials[int(m)]
            buf = self._keep(ctx.buffer(np.ascontiguousarray(faces, dtype="<u4").tobytes()))
            vao = self._keep(ctx.vertex_array(
                self._camera_prog, [(self._vbo, "3f 3f 2f 2f", "in_pos", "in_nrm", "in_uv0",
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
        # basis planes: 4 per RGBA layer, row 0 = the EXR's top row = TEXCOORD_1 v ≈ 0
        h, w, q = d.planes.shape
        layers = -(-q // 4)
        planes = np.zeros((layers, h, w, 4), np.float32)
        for f in range(layers):
            part = d.planes[:, :, 4 * f:4 * f + 4]
            planes[f, :, :, :part.shape[2]] = part
        self._basis = self._keep(ctx.texture_array((w, h, layers), 4, planes.tobytes(),
                                                   dtype="f4"))
        self._basis.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self._basis.repeat_x = self._basis.repeat_y = False
        self._coverage = self._keep(ctx.texture((w, h), 1, np.ascontiguousarray(
            d.coverage, dtype="<f4").tobytes(), dtype="f4"))
        self._coverage.filter = (moderngl.NEAREST, moderngl.NEAREST)
        # measurement points: supersamples grouped by owner
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
        M, b = d.transfer, d.offset
        if M.ndim == 4:  # keyframe sets: the first keyframe (as the CPU runtime's default)
            M, b = M[0], b[0]
        self._n_b = int(M.shape[1])
        self._m = self._keep(ctx.buffer(np.ascontiguousarray(M, "<f4").tobytes() or b"\0" * 4))
        self._b = self._keep(ctx.buffer(np.ascontiguousarray(b, "<f4").tobytes() or b"\0" * 4))
        pl = np.stack([d.plane_element, d.plane_channel.astype(np.int32)], 1).astype("<i4")
        self._planes = self._keep(ctx.buffer(pl.tobytes()))
        self._weights = self._keep(ctx.buffer(reserve=4 * layers * 16))
        self._points_cs = self._keep(ctx.compute_shader(POINTS_CS))
        self._coeff_cs = self._keep(ctx.compute_shader(COEFF_CS % {
            "group": _COEFF_GROUP, "nu": max(1, 3 * self._n_b)}))
        self._atlas_prog = self._keep(ctx.program(vertex_shader=ATLAS_VS,
                                                  fragment_shader=ATLAS_FS))
        self._atlas_vao = self._keep(ctx.vertex_array(self._atlas_prog, []))
        self._lights_buf = None
        self._shadow_tex = None
        self._shadow_fbo = None
        self._shadow_rows = 0
        self._queries = {}
        self._ran: set[str] = set()
        self._wall: dict[str, float] = {}
        self._fbos: dict[tuple, tuple] = {}

    def _unbind(self) -> None:
        """Bind framebuffer 0 before framebuffers are released: moderngl re-binds its
        current framebuffer after creating one, and a deleted one then fails with
        GL_INVALID_OPERATION (a shared context outlives this renderer)."""
        self.ctx.detect_framebuffer(0).use()

    def release(self) -> None:
        """Free every GL object (and the context when this renderer created it)."""
        if self._released:
            return
        self._release_objects()
        self._released = True
        if self._own_ctx:
            self.ctx.release()

    @_current
    def _release_objects(self) -> None:
        self._unbind()
        for obj in reversed(self._objects):
            obj.release()
        self._objects.clear()
        for fbo_objs in self._fbos.values():
            for o in fbo_objs:
                o.release()
        self._fbos.clear()
        for o in (self._lights_buf, self._shadow_fbo, self._shadow_tex):
            if o is not None:
                o.release()
        self._lights_buf = self._shadow_fbo = self._shadow_tex = None
        self._queries.clear()

    def __enter__(self) -> BundleRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    @property
    def n_basis(self) -> int:
        return self.data.n_basis

    # -- passes ------------------------------------------------------------------------
    @contextmanager
    def _timed(self, name: str) -> Iterator[None]:
        """Time a pass twice: a GL timer query (GPU clock) and the wall clock between a
        glFinish before and one after (what a CPU rasteriser actually spends; Mesa's
        llvmpipe runs compute dispatches outside its timer queries, which then read ~0)."""
        if name not in self._queries:  # moderngl queries are reused, never released
            self._queries[name] = self.ctx.query(time=True)
        q = self._queries[name]
        self.ctx.finish()
        t0 = time.perf_counter()
        with q:
            yield
        self.ctx.finish()
        self._wall[name] = (time.perf_counter() - t0) * 1e3
        self._ran.add(name)

    def _light_views(self, light: Light) -> tuple[list[np.ndarray], float]:
        """Clip-from-world matrices of a light's shadow views, and the world texel size
        for directional lights (0 otherwise)."""
        R, c, res = self.radius, self.center, self.shadow_resolution
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
                for a, u in _FACES], 0.0

    def _upload_lights(self, lights: Sequence[Light]) -> None:
        if len(lights) > MAX_LIGHTS:
            raise PrtError(f"render: {len(lights)} lights; at most {MAX_LIGHTS} at once")
        buf = np.zeros((max(1, len(lights)), _FLOATS_PER_LIGHT), np.float32)
        self._views = []
        for i, lt in enumerate(lights):
            t = emitter_for(lt).gl_code
            views, texel = self._light_views(lt)
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
        if self._lights_buf is None or self._lights_buf.size < len(data):
            if self._lights_buf is not None:
                self._lights_buf.release()
            self._lights_buf = self.ctx.buffer(reserve=MAX_LIGHTS * _FLOATS_PER_LIGHT * 4)
        self._lights_buf.write(data)
        self._n_lights = len(lights)

    def _shadow_target(self, rows: int) -> None:
        res = self.shadow_resolution
        limit = int(self.ctx.info["GL_MAX_TEXTURE_SIZE"])
        if 6 * res > limit or rows * res > limit:
            raise PrtError(f"render: shadow atlas {6 * res}×{rows * res} exceeds "
                           f"GL_MAX_TEXTURE_SIZE {limit}; lower the shadow resolution")
        if self._shadow_fbo is not None and self._shadow_rows >= rows:
            return
        self._unbind()
        for o in (self._shadow_fbo, self._shadow_tex):
            if o is not None:
                o.release()
        self._shadow_tex = self.ctx.texture((6 * res, rows * res), 1, dtype="f4")
        self._shadow_tex.filter = (self._mgl.NEAREST, self._mgl.NEAREST)
        self._shadow_fbo = self.ctx.framebuffer(color_attachments=[self._shadow_tex])
        self._shadow_rows = rows

    @_current
    def shadow_pass(self, lights: Sequence[Light]) -> None:
        """Upload the lights and render their shadow maps."""
        ctx, mgl = self.ctx, self._mgl
        self._upload_lights(lights)
        self._shadow_target(max(1, len(lights)))
        res = self.shadow_resolution
        prog = self._shadow_prog
        with self._timed("shadow_maps"):
            self._shadow_fbo.use()
            self._shadow_fbo.viewport = (0, 0, *self._shadow_fbo.size)
            self._shadow_fbo.clear(red=3.0e38)
            ctx.disable(mgl.DEPTH_TEST | mgl.CULL_FACE)
            ctx.enable(mgl.BLEND)
            ctx.blend_equation = mgl.MIN
            for i, lt in enumerate(lights):
                d = np.asarray(lt.direction, np.float64)
                _set(prog, "light_pos_type", (*map(float, lt.position),
                                              float(emitter_for(lt).gl_code)))
                _set(prog, "light_dir", tuple(float(v) for v in d / np.linalg.norm(d)))
                for k, view in enumerate(self._views[i]):
                    self._shadow_fbo.viewport = (k * res, i * res, res, res)
                    _set(prog, "clip_from_world", _mat(view))
                    self._shadow_vao.render(mgl.TRIANGLES)
            ctx.blend_equation = mgl.FUNC_ADD
            ctx.disable(mgl.BLEND)

    def _bind_lighting(self, prog, use_shadows: bool = True) -> None:
        self._lights_buf.bind_to_storage_buffer(0)
        self._shadow_tex.use(location=0)
        _set(prog, "shadow_atlas", 0)
        _set(prog, "n_lights", self._n_lights)
        _set(prog, "use_shadows", int(use_shadows))
        _set(prog, "shadow_res", self.shadow_resolution)
        _set(prog, "bias_normal", SHADOW_NORMAL_OFFSET)
        _set(prog, "bias_const", SHADOW_DEPTH_BIAS)

    @_current
    def points_pass(self, use_shadows: bool = True) -> None:
        """Fake G-buffer: shade the supersamples, average clusters → x' (after shadows)."""
        cs = self._points_cs
        self._bind_lighting(cs, use_shadows)
        self._clusters.bind_to_storage_buffer(1)
        self._starts.bind_to_storage_buffer(2)
        self._x.bind_to_storage_buffer(3)
        self._ce.bind_to_storage_buffer(5)
        _set(cs, "n_points", self.data.point_count)
        _set(cs, "gamma", float(self.data.gamma or 0.0))
        with self._timed("points"):
            cs.run(group_x=max(1, -(-self.data.point_count // 64)))
        self.ctx.memory_barrier()

    def _use(self, n: int | None) -> int:
        if n is not None and not 1 <= n <= self.n_basis:
            raise PrtError(f"render: --basis {n}: the bundle has {self.n_basis} basis "
                           f"elements (mean included); use 1..{self.n_basis}")
        return self._n_b if n is None else max(0, min(n - 1, self._n_b))

    @_current
    def coefficients_pass(self, n: int | None = None) -> int:
        """u = M·x' per channel and the plane weights; returns the RGBA layers in use."""
        use = self._use(n)
        cs = self._coeff_cs
        self._x.bind_to_storage_buffer(3)
        self._m.bind_to_storage_buffer(6)
        self._b.bind_to_storage_buffer(7)
        self._planes.bind_to_storage_buffer(8)
        self._weights.bind_to_storage_buffer(4)
        q = len(self.data.plane_element)
        _set(cs, "n_points", self.data.point_count)
        _set(cs, "n_b", self._n_b)
        _set(cs, "use", use)
        _set(cs, "n_planes", q)
        with self._timed("coefficients"):
            cs.run(group_x=1)
        self.ctx.memory_barrier()
        planes_used = int(np.count_nonzero(self.data.plane_element <= use))
        return -(-planes_used // 4)

    def _bind_blend(self, prog, layers: int) -> None:
        self._weights.bind_to_storage_buffer(4)
        self._basis.use(location=1)
        _set(prog, "basis", 1)
        _set(prog, "n_layers", layers)
        _set(prog, "gamma", float(self.data.gamma or 0.0))

    def _target(self, width: int, height: int, attachments: int):
        key = (width, height, attachments)
        if key not in self._fbos:
            texs = [self.ctx.texture((width, height), 4, dtype="f4")
                    for _ in range(attachments)]
            depth = self.ctx.depth_renderbuffer((width, height))
            fbo = self.ctx.framebuffer(color_attachments=texs, depth_attachment=depth)
            self._fbos[key] = (fbo, depth, *texs)
        return self._fbos[key][0]

    @_current
    def camera_pass(self, camera: Camera, mode: str, layers: int) -> None:
        ctx, mgl, prog = self.ctx, self._mgl, self._camera_prog
        if mode not in MODES:
            raise PrtError(f"render: mode {mode!r}: expected one of {', '.join(MODES)}")
        fbo = self._target(camera.width, camera.height, 2)
        dist = float(np.linalg.norm(camera.position - self.center))
        near = max(1e-4 * self.radius, 0.5 * (dist - 1.01 * self.radius)) \
            if dist > 1.01 * self.radius else 1e-4 * self.radius
        far = dist + 1.01 * self.radius
        clip = camera.clip_from_view(near, far) @ camera.view_from_world()
        self._bind_lighting(prog)
        self._bind_blend(prog, layers)
        _set(prog, "clip_from_world", _mat(clip))
        _set(prog, "eye", tuple(float(v) for v in camera.position))
        _set(prog, "mode", MODES[mode])
        _set(prog, "albedo_texture", 2)
        with self._timed("camera"):
            fbo.use()
            fbo.viewport = (0, 0, *fbo.size)
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            ctx.enable(mgl.DEPTH_TEST)
            ctx.disable(mgl.CULL_FACE | mgl.BLEND)
            for vao, mat, tex in self._draws:
                _set(prog, "base_color", tuple(float(v) for v in mat.base_color_factor))
                _set(prog, "has_texture", int(tex is not None))
                _set(prog, "texture_uv", int(mat.texcoord == 1))
                _set(prog, "uv_transform", _mat3(mat.uv_transform))
                if tex is not None:
                    tex.use(location=2)
                vao.render(mgl.TRIANGLES)
            ctx.disable(mgl.DEPTH_TEST)

    # -- frames ------------------------------------------------------------------------
    @_current
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

    @_current
    def plane_weights(self, lights: Sequence[Light], n: int | None = None) -> np.ndarray:
        """GPU coefficients: the RGB weight of every basis plane, (q, 3) float64."""
        self.shadow_pass(lights)
        self.points_pass()
        self.coefficients_pass(n)
        q = len(self.data.plane_element)
        w = np.frombuffer(self._weights.read(), "<f4").reshape(-1, 4)[:q, :3]
        check_gl(self.ctx, "coefficients")
        return w.astype(np.float64)

    def _timings(self) -> tuple[dict[str, float | None], dict[str, float]]:
        gpu: dict[str, float | None] = {}
        for k in self._ran:
            ns = self._queries[k].elapsed
            # a 32-bit result of all ones: no valid measurement (seen on a first frame)
            gpu[k] = None if ns < 0 or ns >= 0xFFFFFFFF else ns / 1e6
        return gpu, {k: self._wall[k] for k in self._ran}

    @_current
    def render(self, lights: Sequence[Light], camera: Camera, n: int | None = None,
               mode: str = "full") -> RenderResult:
        """One frame through ``camera``: mode "full" (direct + indirect), "direct" (the
        same pass without the indirect term) or "indirect" (indirect only)."""
        self._use(n)  # refuse a bad n before any GL work
        if mode not in MODES:
            raise PrtError(f"render: mode {mode!r}: expected one of {', '.join(MODES)}")
        self._queries_reset()
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
        gpu, wall = self._timings()
        return RenderResult(image=img, uv1=np.ascontiguousarray(aux[:, :, :2]),
                            milliseconds=gpu, wall_milliseconds=wall)

    @_current
    def relight_atlas(self, lights: Sequence[Light], n: int | None = None) -> RenderResult:
        """The indirect lightmap at atlas size on the GPU (the fragment-shader blend at
        texel centres): image (h, w, 4), A = coverage — what ``prtcore relight`` writes."""
        self._queries_reset()
        self.shadow_pass(lights)
        self.points_pass()
        layers = self.coefficients_pass(n)
        h, w = self.data.coverage.shape
        fbo = self._target(w, h, 1)
        prog = self._atlas_prog
        self._bind_blend(prog, layers)
        self._coverage.use(location=3)
        _set(prog, "coverage", 3)
        with self._timed("atlas_blend"):
            fbo.use()
            fbo.viewport = (0, 0, *fbo.size)
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            self.ctx.disable(self._mgl.DEPTH_TEST | self._mgl.CULL_FACE | self._mgl.BLEND)
            self._atlas_vao.render(self._mgl.TRIANGLES, vertices=3)
        img = np.frombuffer(fbo.read(components=4, dtype="f4", attachment=0), "<f4")
        check_gl(self.ctx, "relight atlas")
        gpu, wall = self._timings()
        return RenderResult(image=img.reshape(h, w, 4)[::-1].copy(),
                            uv1=np.zeros((h, w, 2), np.float32), milliseconds=gpu,
                            wall_milliseconds=wall)

    def _queries_reset(self) -> None:
        self._ran.clear()


def _mat3(m: np.ndarray) -> bytes:
    return np.ascontiguousarray(np.asarray(m, np.float64).T, dtype="<f4").tobytes()


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
