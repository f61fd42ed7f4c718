#version 430
// Camera pass: direct light with shadow-map shadows plus the indirect blend at TEXCOORD_1.
#include "lights.glsl"
#include "blend.glsl"
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
