// Real orthonormal SH basis at a unit direction, as prtcore.core.sh.basis (no Condon–Shortley
// phase, index l(l+1)+m, polar axis +z): the three-term recurrence on P_l^m / sin^m θ and
// (x + iy)^m. sh_norm[l * SH_MAX_BANDS + m] = K_l^m, uploaded from prtcore.core.sh.
#define SH_MAX_BANDS 8
#define SH_MAX_COEFFS 64
layout(std430, binding = 9) readonly buffer ShNorm { float sh_norm[]; };

void sh_basis(vec3 d, int bands, out float y[SH_MAX_COEFFS]) {
    float c_m = 1.0, s_m = 0.0, p_mm = 1.0;
    for (int m = 0; m < bands; ++m) {
        if (m > 0) {
            float c2 = c_m * d.x - s_m * d.y;
            s_m = c_m * d.y + s_m * d.x;
            c_m = c2;
            p_mm *= float(2 * m - 1);
        }
        float p_prev = 0.0, p_cur = p_mm;
        for (int l = m; l < bands; ++l) {
            if (l == m + 1) {
                p_prev = p_cur;
                p_cur = d.z * float(2 * m + 1) * p_mm;
            } else if (l > m + 1) {
                float p_next = (float(2 * l - 1) * d.z * p_cur - float(l + m - 1) * p_prev)
                               / float(l - m);
                p_prev = p_cur;
                p_cur = p_next;
            }
            int centre = l * (l + 1);
            float k = sh_norm[l * SH_MAX_BANDS + m];
            if (m == 0) {
                y[centre] = k * p_cur;
            } else {
                float sc = 1.41421356237 * k * p_cur;
                y[centre + m] = sc * c_m;
                y[centre - m] = sc * s_m;
            }
        }
    }
}
