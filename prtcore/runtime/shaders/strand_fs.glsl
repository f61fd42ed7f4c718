#version 430
// Hair camera pass: direct light on the round fibre (radial normal, shadow maps of the
// tubes) plus the indirect light blended from the strand-texture basis at the manifest's
// sampling rule (docs/hair.md) — prtcore.runtime.strands.render_strands on the GPU.
#include "lights.glsl"
#include "blend.glsl"
#include "chiang.glsl"
in vec3 v_pos;
in vec3 v_centre;
flat in vec3 v_tan;
in float v_arc;
flat in float v_strand;
in float v_offset;
in vec3 v_albedo;  // the clamped albedo; with the Chiang fibre its σ_a per unit radius
uniform int mode;  // bit 0: direct, bit 1: indirect
uniform int fibre_model;  // 0 diffuse, 1 Chiang (chiang.glsl)
uniform vec3 eye;
uniform int texels_per_strand;
uniform int strands_per_row;
uniform vec2 texture_size;  // (width, height) of the strand texture
layout(location = 0) out vec4 f_color;
layout(location = 1) out vec4 f_aux;
void main() {
    // the radial direction from the axis to the point seen (azimuth_frame)
    vec3 r = v_pos - v_centre;
    r -= dot(r, v_tan) * v_tan;
    float lr = length(r);
    vec3 n = lr > 0.0 ? r / lr : normalize(cross(dFdx(v_pos), dFdy(v_pos)));
    int s = int(v_strand + 0.5);
    float tn = float(texels_per_strand);
    vec2 px = vec2(float(s % strands_per_row) * tn + clamp(v_arc * tn, 0.5, tn - 0.5),
                   float(s / strands_per_row) + 0.5);
    vec3 col = vec3(0.0);
    if ((mode & 1) != 0) {
        if (fibre_model == 1) {  // the BCSDF toward the eye, V from the side facing the light
            vec3 wo = normalize(eye - v_pos);
            float h = chiang_offset(v_tan, n, wo);
            for (int l = 0; l < n_lights; ++l) {
                Light L = lights[l];
                vec3 wl = int(L.pos_type.w) == 2 ? -L.dir_range.xyz
                                                  : normalize(L.pos_type.xyz - v_centre);
                vec3 side = wl - dot(wl, v_tan) * v_tan;
                side = dot(side, side) > 1e-12 ? normalize(side) : n;
                vec3 o = v_centre + v_offset * side;
                col += chiang_scattering(v_tan, wo, wl, h, v_albedo)
                       * irradiance(l, o, wl, side);
            }
        } else {
            vec3 o = v_centre + v_offset * n;  // on the circumscribed cylinder, as the bake
            vec3 e = vec3(0.0);
            for (int l = 0; l < n_lights; ++l) e += irradiance(l, o, n, n);
            col += v_albedo / PI * e;
        }
    }
    if ((mode & 2) != 0) col += indirect_at(px / texture_size);
    f_color = vec4(col, 1.0);
    f_aux = vec4(px / texture_size, 1.0, 1.0);
}
