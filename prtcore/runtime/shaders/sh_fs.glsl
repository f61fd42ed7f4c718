#version 430
// SH-PRT camera pass, fragment stage. Texture storage (the fragment-shader variant,
// transfer textures): colour = T(uv1) · l per channel, T filtered bilinearly; layer
// c·files + k holds coefficients 4k..4k+3 of channel c in R, G, B, A. Vertex storage: the
// interpolated vertex colour. Glossy layer (TP, texture storage): the visibility SH V(uv1)
// times the light by the triple product (M_c = Σ_i Γ_ijk l_ic, from the CPU per frame),
// then the Phong lobe's kernel at the mirror direction (prtcore.methods.sh_prt.glossy_tp).
#include "distant_fs.glsl"
uniform sampler2DArray visibility_tex;
uniform int vertex_storage;
uniform int files;
uniform sampler2DArray transfer_tex;  // light[] padded to 4·files
void main() {
    if (!gl_FrontFacing) {  // inside geometry: no light (as the path tracer)
        f_color = vec4(0.0);
        return;
    }
    vec3 col = v_color;
    if (vertex_storage == 0) {
        col = vec3(0.0);
        for (int k = 0; k < files; ++k) {
            vec4 l0 = light[4 * k], l1 = light[4 * k + 1], l2 = light[4 * k + 2],
                 l3 = light[4 * k + 3];
            col.r += dot(texture(transfer_tex, vec3(v_uv1, float(k))), vec4(l0.r, l1.r, l2.r, l3.r));
            col.g += dot(texture(transfer_tex, vec3(v_uv1, float(files + k))),
                         vec4(l0.g, l1.g, l2.g, l3.g));
            col.b += dot(texture(transfer_tex, vec3(v_uv1, float(2 * files + k))),
                         vec4(l0.b, l1.b, l2.b, l3.b));
        }
    }
    if (glossy != 0) {
        vec3 r = mirror_direction(v_pos, v_nrm, eye);
        int nc = bands * bands;
        float v[SH_MAX_COEFFS];
        for (int k = 0; k < files; ++k) {
            vec4 t = texture(visibility_tex, vec3(v_uv1, float(k)));
            for (int j = 0; j < 4; ++j) if (4 * k + j < nc) v[4 * k + j] = t[j];
        }
        col += specular * glossy_tp(v, r, bands);
    }
    f_color = vec4(col, 1.0);
}
