#version 430
// Hair camera pass: direct light on the round fibre (radial normal, shadow maps of the
// tubes) plus the indirect light blended from the strand-texture basis at the manifest's
// sampling rule (docs/hair.md) — prtcore.runtime.strands.render_strands on the GPU.
#include "lights.glsl"
#include "blend.glsl"
in vec3 v_pos;
in vec3 v_centre;
flat in vec3 v_tan;
in float v_arc;
flat in float v_strand;
in float v_offset;
in vec3 v_albedo;
uniform int mode;  // bit 0: direct, bit 1: indirect
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
        vec3 o = v_centre + v_offset * n;  // on the circumscribed cylinder, as the bake
        vec3 e = vec3(0.0);
        for (int l = 0; l < n_lights; ++l) e += irradiance(l, o, n, n);
        col += v_albedo / PI * e;
    }
    if ((mode & 2) != 0) col += indirect_at(px / texture_size);
    f_color = vec4(col, 1.0);
    f_aux = vec4(px / texture_size, 1.0, 1.0);
}
