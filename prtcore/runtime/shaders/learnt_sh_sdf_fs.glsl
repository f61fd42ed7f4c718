#version 430
// learnt_sh full-screen pass of an SDF scene (thesis 4.1.4): a ray per pixel centre
// sphere-traced through the field (learnt_sh_sdf.glsl; hit below hit_eps, at most
// MAX_STEPS steps, out past t_max), the network at the hit with the field's normal,
// colour = albedo * (T . l) [+ specular * TP of the visibility outputs]; background
// A = 0. prtcore.methods.learnt_sh.shade_sdf_view on the CPU.
#include "learnt_sh_net.glsl"
#include "learnt_sh_sdf.glsl"
#include "distant_fs.glsl"
uniform vec3 cam_right;
uniform vec3 cam_up;
uniform vec3 cam_forward;
uniform float tan_half_fov;
uniform float aspect;
uniform vec2 viewport;
uniform float t_max;
uniform float hit_eps;
uniform vec3 sdf_albedo;
void main() {
    float i = gl_FragCoord.x / viewport.x * 2.0 - 1.0;
    float j = gl_FragCoord.y / viewport.y * 2.0 - 1.0;  // row 0 of the image is the top
    vec3 dir = normalize(cam_forward + i * tan_half_fov * aspect * cam_right
                         + j * tan_half_fov * cam_up);
    float t = 0.0;
    bool hit = false;
    for (int s = 0; s < MAX_STEPS; ++s) {
        float d = sdf(eye + t * dir);
        if (d < hit_eps) { hit = true; break; }
        t += d;
        if (t > t_max) break;
    }
    if (!hit) {
        f_color = vec4(0.0);
        return;
    }
    vec3 p = eye + t * dir;
    vec3 n = sdf_normal(p);
    vec4 y[MAX4];
    sigma(p, n, y);
    int nc = bands * bands;
    vec3 col = vec3(0.0);
    for (int k = 0; k < nc; ++k) col += y[k / 4][k % 4] * light[k].rgb;
    col *= sdf_albedo;
    if (glossy != 0) {
        float v[SH_MAX_COEFFS];
        for (int k = 0; k < nc; ++k) v[k] = y[(nc + k) / 4][(nc + k) % 4];
        col += specular * glossy_tp(v, reflect(dir, n), bands);
    }
    f_color = vec4(col, 1.0);
}
