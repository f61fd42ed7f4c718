#version 430
// learnt_sh camera pass, fragment stage (thesis 4.1.4): the network sigma(p, n) per
// fragment (learnt_sh_net.glsl) at the interpolated position and shading normal; colour =
// albedo(uv1) * (T . l) per channel, T the network's first L^2 outputs; glossy networks
// add specular * TP of their visibility block (outputs L^2 .. 2L^2, sh_glossy.glsl).
// prtcore.methods.learnt_sh.shade_view on the CPU (tests/test_learnt_sh_method.py).
#include "learnt_sh_net.glsl"
#include "distant_fs.glsl"
uniform sampler2D albedo_tex;
void main() {
    if (!gl_FrontFacing) {  // inside geometry: no light (as the path tracer)
        f_color = vec4(0.0);
        return;
    }
    vec3 n = shading_normal(v_pos, v_nrm, eye);
    vec4 y[MAX4];
    sigma(v_pos, n, y);
    int nc = bands * bands;
    vec3 col = vec3(0.0);
    for (int i = 0; i < nc; ++i) col += y[i / 4][i % 4] * light[i].rgb;
    col *= texture(albedo_tex, v_uv1).rgb;
    if (glossy != 0) {
        float v[SH_MAX_COEFFS];
        for (int j = 0; j < nc; ++j) v[j] = y[(nc + j) / 4][(nc + j) % 4];
        col += specular * glossy_tp(v, reflect(-normalize(eye - v_pos), n), bands);
    }
    f_color = vec4(col, 1.0);
}
