// The viewer's shaders (GLSL ES 3.00): the basis blend with the bundle's row order
// (prtcore/runtime/shaders/blend.glsl), the camera pass with the viewer's modes
// (camera_fs.glsl), the atlas pass (atlas_fs.glsl) and the measurement-point dots. The light
// formulas and shadow test (LIGHTS_GLSL) are runtime.js's.
import { LIGHTS_GLSL } from './runtime.js';

export const HEADER = 'precision highp float;\nprecision highp int;\nprecision highp sampler2DArray;\n';

// The basis blend (prtcore/runtime/shaders/blend.glsl) with the bundle's row order, and the
// display transform.
export const BLEND_GLSL = `
uniform highp sampler2DArray u_basis;
uniform highp sampler2D u_weights;  // (planes, 1) RGBA32F: the RGB weight of every plane
uniform int u_planes;
uniform float u_gamma;              // 0: none; < 0: signed, unclamped (one basis element)
uniform int u_flipV;
uniform int u_output;               // 0: linear radiance (read-back), 1: display
uniform float u_exposure;
uniform int u_tonemap;
vec2 atlas_uv(vec2 uv1) { return vec2(uv1.x, u_flipV == 1 ? 1.0 - uv1.y : uv1.y); }
vec3 indirect_at(vec2 uv1) {
  vec2 t = atlas_uv(uv1);
  vec3 c = vec3(0.0);
  for (int f = 0; f < N_LAYERS; ++f) {
    vec4 p = texture(u_basis, vec3(t, float(f)));
    for (int k = 0; k < 4; ++k) {
      int j = 4 * f + k;
      if (j < u_planes) c += p[k] * texelFetch(u_weights, ivec2(j, 0), 0).rgb;
    }
  }
  if (u_gamma >= 0.0) c = max(c, vec3(0.0));  // negative light clamped (runtime formula)
  if (u_gamma > 0.0) c = pow(c, vec3(u_gamma));
  return c;
}
vec3 srgb(vec3 c) {
  c = clamp(c, 0.0, 1.0);
  return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, c));
}
vec4 display(vec3 c) {
  if (u_output == 0) return vec4(c, 1.0);
  c *= exp2(u_exposure);
  if (u_tonemap == 0) c = c * (2.51 * c + 0.03) / (c * (2.43 * c + 0.59) + 0.14);
  else if (u_tonemap == 1) c = c / (1.0 + c);
  return vec4(srgb(c), 1.0);
}
`;

export const SURFACE_VS = `${HEADER}
uniform mat4 modelMatrix; uniform mat4 viewMatrix; uniform mat4 projectionMatrix;
uniform int u_mode;
in vec3 position; in vec3 normal; in vec2 uv; in vec2 uv1;
out vec3 v_pos; out vec3 v_nrm; out vec2 v_uv0; out vec2 v_uv1;
void main() {
  vec4 wp = modelMatrix * vec4(position, 1.0);
  v_pos = wp.xyz; v_nrm = mat3(modelMatrix) * normal; v_uv0 = uv; v_uv1 = uv1;
  // UV layout: the mesh drawn at TEXCOORD_1, the image's top row at the top
  gl_Position = u_mode == 7 ? vec4(uv1.x * 2.0 - 1.0, 1.0 - uv1.y * 2.0, 0.0, 1.0)
                            : projectionMatrix * viewMatrix * wp;
}`;

// prtcore/runtime/shaders/camera_fs.glsl plus the viewer's modes.
export const SURFACE_FS = `${HEADER}${LIGHTS_GLSL}${BLEND_GLSL}
uniform vec3 u_eye;
uniform vec3 u_baseColor;
uniform int u_hasMap;
uniform int u_mapChannel;
uniform mat3 u_mapTransform;
uniform sampler2D u_map;
uniform int u_mode;          // MODES of viewer.js
uniform float u_elementScale;
uniform vec2 u_atlasSize;
uniform highp sampler2D u_reference;  // path-traced indirect lightmap (mode 8)
uniform float u_referenceScale;       // 1 / (mean reference radiance * full scale)
in vec3 v_pos; in vec3 v_nrm; in vec2 v_uv0; in vec2 v_uv1;
out vec4 f_color;
void main() {
  if (u_mode == 8) {  // per-texel error heat map: blue 0, green, red at full scale
    vec3 ref = texture(u_reference, atlas_uv(v_uv1)).rgb;
    float e = length(indirect_at(v_uv1) - ref) / sqrt(3.0) * u_referenceScale;
    if (u_output == 0) { f_color = vec4(vec3(e), 1.0); return; }
    float t = clamp(e, 0.0, 1.0);
    f_color = vec4(srgb(vec3(smoothstep(0.5, 1.0, t), 1.0 - abs(2.0 * t - 1.0), 1.0 - smoothstep(0.0, 0.5, t))), 1.0);
    return;
  }
  if (u_mode == 7) { f_color = display(indirect_at(v_uv1)); return; }
  if (u_mode == 6) {  // texel density: one checker square per lightmap texel
    ivec2 t = ivec2(floor(atlas_uv(v_uv1) * u_atlasSize));
    f_color = vec4(vec3(((t.x + t.y) & 1) == 0 ? 0.85 : 0.35), 1.0);
    return;
  }
  if (!gl_FrontFacing) { f_color = vec4(0.0, 0.0, 0.0, 1.0); return; }  // inside geometry
  vec3 ng = normalize(cross(dFdx(v_pos), dFdy(v_pos)));
  if (dot(ng, u_eye - v_pos) < 0.0) ng = -ng;
  vec3 n = normalize(v_nrm);
  if (!(dot(n, ng) > 0.0)) n = ng;  // prtcore.core.geometry.shading_normals
  vec3 albedo = u_baseColor;
  if (u_hasMap != 0) {
    vec2 uv = u_mapChannel == 1 ? v_uv1 : v_uv0;
    albedo *= texture(u_map, (u_mapTransform * vec3(uv, 1.0)).xy).rgb;
  }
  albedo = clamp(albedo, 0.0, 0.99);
  if (u_mode == 3) { f_color = u_output == 0 ? vec4(albedo, 1.0) : vec4(srgb(albedo), 1.0); return; }
  if (u_mode == 4) {  // one basis element, signed: positive as is, negative in blue
    vec3 v = indirect_at(v_uv1) * u_elementScale;
    float neg = max(-(v.r + v.g + v.b) / 3.0, 0.0);
    f_color = u_output == 0 ? vec4(indirect_at(v_uv1), 1.0)
                            : vec4(srgb(max(v, 0.0) + vec3(0.0, 0.0, neg)), 1.0);
    return;
  }
  vec3 col = vec3(0.0);
  if (u_mode != 2) col += albedo / PI * irradiance(v_pos, n, ng);
  if (u_mode != 1) col += indirect_at(v_uv1);
  f_color = display(col);
}`;

// The indirect lightmap at atlas size (prtcore/runtime/shaders/atlas_fs.glsl): texel (x, y),
// y from the top row, at TEXCOORD_1 ((x+0.5)/W, (y+0.5)/H); A = coverage.
// One triangle covering the viewport.
export const ATLAS_VS = `${HEADER}in vec3 position; void main() { gl_Position = vec4(position, 1.0); }`;

export const ATLAS_FS = `${HEADER}${BLEND_GLSL}
uniform sampler2D u_coverage;
uniform vec2 u_atlasSize;
out vec4 f_color;
void main() {
  vec2 t = vec2(floor(gl_FragCoord.x), u_atlasSize.y - 1.0 - floor(gl_FragCoord.y));
  vec2 uv1 = (t + 0.5) / u_atlasSize;
  f_color = vec4(indirect_at(uv1), texture(u_coverage, atlas_uv(uv1)).r);
}`;

export const POINTS_VS = `${HEADER}
uniform mat4 modelViewMatrix; uniform mat4 projectionMatrix;
in vec3 position; in vec3 color; out vec3 v_color;
void main() { v_color = color; gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0); gl_PointSize = 5.0; }`;
export const POINTS_FS = `${HEADER}${BLEND_GLSL}
in vec3 v_color; out vec4 f_color;
void main() { vec2 d = gl_PointCoord - 0.5; if (dot(d, d) > 0.25) discard; f_color = display(v_color); }`;

// Hair bundles: the strand texture's sampling rule (the manifest's strands.sample,
// prtcore/receivers/strands.py StrandSpace.layout): strand s at arc fraction a is read at
// px = (s % r)·n + clamp(a·n, 0.5, n − 0.5), py = s / r + 0.5 (from the top row), bilinear;
// the row's centre line and the clamp keep it within the strand's own texels.
export const STRAND_GLSL = `
uniform int u_texelsPerStrand;  // n
uniform int u_strandsPerRow;    // r
uniform vec2 u_atlasSize;
// the strand-texture coordinate as a TEXCOORD_1-like uv (v = 0 at the top row)
vec2 strand_uv(int s, float a) {
  float n = float(u_texelsPerStrand);
  int row = s / u_strandsPerRow;
  float px = float(s - row * u_strandsPerRow) * n + clamp(a * n, 0.5, n - 0.5);
  return vec2(px, float(row) + 0.5) / u_atlasSize;
}
`;

// The Chiang fibre's BCSDF: the GL runtime's own shader (prtcore/runtime/shaders/chiang.glsl,
// served as static/shaders/chiang.glsl by prtcore/viewer/page.py), not a copy.
export const CHIANG_GLSL = await (await fetch(new URL('./shaders/chiang.glsl',
                                                      import.meta.url))).text();

// The direct light on a fibre seen as a line at p (tangent t, eye e): the diffuse cylinder's
// side facing the eye, albedo/π · E with the radial normal towards the eye
// (prtcore/runtime/strands.py takes the normal of the tube's hit point; a one-pixel line
// sees the fibre's middle); for the Chiang fibre (u_fibreModel 1, s the fibre's σ_a) the
// BCSDF toward the eye averaged over the offset h (a line's pixel covers the fibre's
// width: 8 Gauss–Legendre nodes), times E⊥ V from the side facing the light.
export const STRAND_DIRECT_GLSL = `
uniform int u_fibreModel;
const float GL_X[8] = float[8](-0.9602898565, -0.7966664774, -0.5255324099, -0.1834346425,
                               0.1834346425, 0.5255324099, 0.7966664774, 0.9602898565);
const float GL_W[8] = float[8](0.1012285363, 0.2223810345, 0.3137066459, 0.3626837834,
                               0.3626837834, 0.3137066459, 0.2223810345, 0.1012285363);
vec3 strand_direct(vec3 p, vec3 t, vec3 e, vec3 s) {
  vec3 n = e - dot(e, t) * t;
  n = dot(n, n) > 0.0 ? normalize(n) : vec3(0.0);
  if (u_fibreModel != 1) return s / PI * irradiance(p, n, n);
  vec3 wo = normalize(e), wl = u_lightType == 2 ? -u_lightDir : normalize(u_lightPos - p);
  vec3 side = wl - dot(wl, t) * t;
  side = dot(side, side) > 1e-12 ? normalize(side) : n;
  vec3 bsdf = vec3(0.0);
  for (int k = 0; k < 8; ++k) bsdf += GL_W[k] * chiang_scattering(t, wo, wl, GL_X[k], s);
  return 0.5 * bsdf * irradiance(p, wl, side);
}
`;

// Strands drawn as lines (THREE.LineSegments of strands.js strandGeometry).
export const STRAND_VS = `${HEADER}
uniform mat4 modelMatrix; uniform mat4 viewMatrix; uniform mat4 projectionMatrix;
in vec3 position; in vec3 s_tangent; in vec3 s_albedo; in float s_strand; in float s_arc;
out vec3 v_pos; out vec3 v_tan; out vec3 v_albedo; flat out int v_strand; out float v_arc;
void main() {
  vec4 wp = modelMatrix * vec4(position, 1.0);
  v_pos = wp.xyz; v_tan = mat3(modelMatrix) * s_tangent; v_albedo = s_albedo;
  v_strand = int(s_strand + 0.5); v_arc = s_arc;
  gl_Position = projectionMatrix * viewMatrix * wp;
}`;

// The fibre seen at a line's pixel: direct light by strand_direct, shadowed by the line
// shadow maps; indirect from the blended strand texture by the sampling rule.
export const STRAND_FS = `${HEADER}${LIGHTS_GLSL}${BLEND_GLSL}${STRAND_GLSL}${CHIANG_GLSL}
${STRAND_DIRECT_GLSL}
uniform vec3 u_eye;
uniform int u_mode;          // MODES of viewer.js (no UV layout or heat map for hair)
uniform float u_elementScale;
in vec3 v_pos; in vec3 v_tan; in vec3 v_albedo; flat in int v_strand; in float v_arc;
out vec4 f_color;
void main() {
  vec2 uv = strand_uv(v_strand, v_arc);
  if (u_mode == 6) {  // texel density: alternate strand texels
    ivec2 t = ivec2(floor(uv * u_atlasSize));
    f_color = vec4(vec3(((t.x + t.y) & 1) == 0 ? 0.85 : 0.35), 1.0);
    return;
  }
  if (u_mode == 3) { f_color = u_output == 0 ? vec4(v_albedo, 1.0) : vec4(srgb(v_albedo), 1.0); return; }
  if (u_mode == 4) {
    vec3 v = indirect_at(uv) * u_elementScale;
    float neg = max(-(v.r + v.g + v.b) / 3.0, 0.0);
    f_color = u_output == 0 ? vec4(indirect_at(uv), 1.0)
                            : vec4(srgb(max(v, 0.0) + vec3(0.0, 0.0, neg)), 1.0);
    return;
  }
  vec3 col = vec3(0.0);
  if (u_mode != 2) col += strand_direct(v_pos, normalize(v_tan), u_eye - v_pos, v_albedo);
  if (u_mode != 1) col += indirect_at(uv);
  f_color = display(col);
}`;

// Test hook: every strand vertex's indirect (by its strand-texture coordinate), or with
// u_probe 1 its direct light as a line pixel there shades it (strand_direct, unshadowed),
// into one pixel of a float target, row by row from the bottom (as the cluster pass).
export const STRAND_PROBE_VS = `${HEADER}
uniform mat4 modelMatrix;
uniform vec2 u_size;
in vec3 position; in vec3 s_tangent; in vec3 s_albedo; in float s_strand; in float s_arc;
flat out int v_strand; out float v_arc; out vec3 v_pos; out vec3 v_tan; out vec3 v_albedo;
void main() {
  v_strand = int(s_strand + 0.5); v_arc = s_arc;
  v_pos = (modelMatrix * vec4(position, 1.0)).xyz; v_tan = mat3(modelMatrix) * s_tangent;
  v_albedo = s_albedo;
  int row = gl_VertexID / int(u_size.x);
  vec2 px = vec2(float(gl_VertexID - row * int(u_size.x)), float(row)) + 0.5;
  gl_Position = vec4(px / u_size * 2.0 - 1.0, 0.0, 1.0);
  gl_PointSize = 1.0;
}`;
export const STRAND_PROBE_FS = `${HEADER}${LIGHTS_GLSL}${BLEND_GLSL}${STRAND_GLSL}${CHIANG_GLSL}
${STRAND_DIRECT_GLSL}
uniform vec3 u_eye;
uniform int u_probe;
flat in int v_strand; in float v_arc; in vec3 v_pos; in vec3 v_tan; in vec3 v_albedo;
out vec4 f_color;
void main() {
  f_color = vec4(u_probe == 1 ? strand_direct(v_pos, normalize(v_tan), u_eye - v_pos, v_albedo)
                              : indirect_at(strand_uv(v_strand, v_arc)), 1.0);
}`;
