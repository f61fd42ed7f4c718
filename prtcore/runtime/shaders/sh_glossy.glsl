// The glossy Phong layer by the triple product (the poster's TP), shared by the sh_prt and
// learnt_sh fragment passes: the stored visibility SH V times the light (M_c = sum_i
// Gamma_ijk l_ic, product matrices from the CPU once per frame), then the Phong lobe's
// Funk-Hecke kernel at the mirror direction (prtcore.methods.sh_prt.glossy_tp).
#include "sh_basis.glsl"
layout(std430, binding = 7) readonly buffer Product { float product[]; };  // [c][k][j]
layout(std430, binding = 8) readonly buffer Kernel { float kernel[]; };  // [k]

// The shading normal of a fragment: the interpolated normal, replaced by the geometric
// one (facing the eye) where it faces away (as prtcore.core.geometry.shading_normals).
vec3 shading_normal(vec3 pos, vec3 nrm, vec3 eye) {
    vec3 ng = normalize(cross(dFdx(pos), dFdy(pos)));
    if (dot(ng, eye - pos) < 0.0) ng = -ng;
    vec3 n = normalize(nrm);
    if (!(dot(n, ng) > 0.0)) n = ng;
    return n;
}

// The mirror direction of the view about the fragment's shading normal.
vec3 mirror_direction(vec3 pos, vec3 nrm, vec3 eye) {
    return reflect(-normalize(eye - pos), shading_normal(pos, nrm, eye));
}

// Glossy outgoing radiance (before rho_s) for visibility SH v at mirror direction r.
vec3 glossy_tp(float v[SH_MAX_COEFFS], vec3 r, int bands) {
    int nc = bands * bands;
    float y[SH_MAX_COEFFS];
    sh_basis(r, bands, y);
    vec3 spec = vec3(0.0);
    for (int c = 0; c < 3; ++c) {
        for (int k = 0; k < nc; ++k) {
            float lv = 0.0;
            for (int j = 0; j < nc; ++j) lv += product[(c * nc + k) * nc + j] * v[j];
            spec[c] += lv * kernel[k] * y[k];
        }
    }
    return spec;
}
