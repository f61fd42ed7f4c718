// The Chiang et al. 2016 hair BCSDF, prtcore.core.bcsdf.scattering on the GPU (float32),
// for the direct light of a Chiang fibre's bundle (strand_fs.glsl). Needs PI (lights.glsl).
uniform vec4 chiang_v;       // longitudinal variances v0..v3 (ChiangParams.variances)
uniform float chiang_s;      // azimuthal logistic scale (ChiangParams.logistic_scale)
uniform float chiang_alpha;  // cuticle tilt, radians
uniform float chiang_eta;    // index of refraction

// log I0(x) (scipy's i0e in bcsdf._mp): the power series, each term from the last
// (pbrt-v3's ten terms are 2 % low near x = 12), or the asymptotic series above 12
float chiang_log_i0(float x) {
    if (x > 12.0) {
        float r = 1.0 / x;
        return x - 0.5 * log(2.0 * PI * x)
               + log(1.0 + r * (0.125 + r * (0.0703125 + r * 0.0732421875)));
    }
    float q = 0.25 * x * x, term = 1.0, val = 1.0;
    for (int k = 1; k < 40; ++k) {
        term *= q / float(k * k);
        val += term;
    }
    return log(val);
}

// the longitudinal lobe M_p (bcsdf._mp)
float chiang_mp(float cos_i, float cos_o, float sin_i, float sin_o, float v) {
    float a = cos_i * cos_o / v, b = sin_i * sin_o / v;
    return exp(chiang_log_i0(a) - b - 1.0 / v - log(v) - log(1.0 - exp(-2.0 / v)));
}

float chiang_logistic(float x, float s) {  // trimmed to [−π, π] (bcsdf._trimmed_logistic)
    float e = exp(-abs(x) / s);
    float norm = 1.0 / (1.0 + exp(-PI / s)) - 1.0 / (1.0 + exp(PI / s));
    return e / (s * (1.0 + e) * (1.0 + e)) / norm;
}

float chiang_fresnel(float cos_i, float eta) {  // bcsdf._fresnel
    cos_i = clamp(cos_i, -1.0, 1.0);
    float sin_t2 = (1.0 - cos_i * cos_i) / (eta * eta);
    if (sin_t2 >= 1.0) return 1.0;
    float cos_t = sqrt(max(1.0 - sin_t2, 0.0)), ci = abs(cos_i);
    float r_par = (eta * ci - cos_t) / (eta * ci + cos_t);
    float r_perp = (ci - eta * cos_t) / (ci + eta * cos_t);
    return 0.5 * (r_par * r_par + r_perp * r_perp);
}

// S(wo, wi) per channel for a fibre of unit tangent t at offset h, absorption sigma
// (per unit radius); wo toward the viewer, wi toward the light
vec3 chiang_scattering(vec3 t, vec3 wo, vec3 wi, float h, vec3 sigma) {
    float sin_o = clamp(dot(wo, t), -1.0, 1.0), sin_i = clamp(dot(wi, t), -1.0, 1.0);
    float cos_o = sqrt(1.0 - sin_o * sin_o), cos_i = sqrt(1.0 - sin_i * sin_i);
    vec3 u = wo - sin_o * t;  // the frame's u along wo across the fibre: φo = 0
    u = dot(u, u) > 1e-12 ? normalize(u) : normalize(cross(t, abs(t.x) < 0.9 ?
                                                        vec3(1, 0, 0) : vec3(0, 1, 0)));
    float phi = atan(dot(wi, cross(t, u)), dot(wi, u)) - atan(dot(wo, cross(t, u)),
                                                              dot(wo, u));
    // attenuation (bcsdf.attenuation)
    float eta = chiang_eta;
    float sin_t = sin_o / eta, cos_t = sqrt(max(1.0 - sin_t * sin_t, 0.0));
    float etap = sqrt(max(eta * eta - sin_o * sin_o, 0.0)) / max(cos_o, 1e-12);
    float sin_gt = clamp(h / etap, -1.0, 1.0), cos_gt = sqrt(1.0 - sin_gt * sin_gt);
    float hc = clamp(h, -1.0, 1.0);  // atan, not asin: Mesa's asin is 1e-3 off near ±1
    float gamma_o = atan(hc, sqrt(1.0 - hc * hc)), gamma_t = atan(sin_gt, cos_gt);
    vec3 tr = exp(-sigma * (2.0 * cos_gt / max(cos_t, 1e-12)));
    float f = chiang_fresnel(cos_o * cos(gamma_o), eta);
    vec3 a[4];
    a[0] = vec3(f);
    a[1] = (1.0 - f) * (1.0 - f) * tr;
    a[2] = a[1] * tr * f;
    a[3] = a[2] * f * tr / max(1.0 - tr * f, vec3(1e-12));
    // θo tilted by the cuticle: −2α (R), +α (TT), +4α (TRT) (bcsdf._tilted)
    float s1 = sin(chiang_alpha), c1 = cos(chiang_alpha);
    float s2 = sin(2.0 * chiang_alpha), c2 = cos(2.0 * chiang_alpha);
    float s4 = sin(4.0 * chiang_alpha), c4 = cos(4.0 * chiang_alpha);
    vec2 rot[3] = vec2[3](vec2(sin_o * c2 - cos_o * s2, cos_o * c2 + sin_o * s2),
                          vec2(sin_o * c1 + cos_o * s1, cos_o * c1 - sin_o * s1),
                          vec2(sin_o * c4 + cos_o * s4, cos_o * c4 - sin_o * s4));
    vec3 out_s = vec3(0.0);
    for (int p = 0; p < 3; ++p) {
        float dphi = phi - (2.0 * float(p) * gamma_t - 2.0 * gamma_o + float(p) * PI);
        dphi = mod(dphi + PI, 2.0 * PI) - PI;
        out_s += chiang_mp(cos_i, abs(rot[p].y), sin_i, rot[p].x, chiang_v[p])
                 * chiang_logistic(dphi, chiang_s) * a[p];
    }
    out_s += chiang_mp(cos_i, cos_o, sin_i, sin_o, chiang_v[3]) / (2.0 * PI) * a[3];
    return out_s;
}

// the offset h a camera at eye sees at the point of radial normal n (bcsdf.impact_offset)
float chiang_offset(vec3 t, vec3 n, vec3 wo) {
    vec3 w = wo - dot(wo, t) * t;
    float lw = length(w);
    return lw > 1e-12 ? clamp(dot(cross(n, w), t) / lw, -1.0, 1.0) : 0.0;
}
