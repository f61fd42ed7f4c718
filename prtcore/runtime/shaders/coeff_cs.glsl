#version 430
// Coefficients: s = |x'|, u_c = M_c x'_c + s b_c (+ s r(x'/s)_c with a learnt transfer,
// learnt.glsl), the RGB weight of every basis plane; prtcore.runtime.cpu.plane_weights on
// the GPU. GROUP (the work-group size) and N_U (3 n_b, at least 1) are #defined by
// prtcore.runtime.gl, and LEARNT for a bundle with fit.transfer "mlp".
layout(local_size_x = GROUP) in;
layout(std430, binding = 3) readonly buffer X { vec4 x[]; };
layout(std430, binding = 6) readonly buffer M { float m[]; };       // [c][i][p]
layout(std430, binding = 7) readonly buffer B { float b[]; };       // [c][i]
layout(std430, binding = 8) readonly buffer Planes { ivec2 plane[]; };  // element, channel
layout(std430, binding = 4) writeonly buffer Weights { vec4 w[]; };
uniform int n_points;
uniform int n_b;
uniform int use;
uniform int n_planes;
shared float partial[GROUP];
shared float u[N_U];
#ifdef LEARNT
#include "learnt.glsl"
#endif
void main() {
    int t = int(gl_LocalInvocationID.x);
    float acc = 0.0;
    for (int p = t; p < n_points; p += GROUP) acc += dot(x[p].xyz, x[p].xyz);
    partial[t] = acc;
    memoryBarrierShared();
    barrier();
    for (int s = GROUP / 2; s > 0; s >>= 1) {
        if (t < s) partial[t] += partial[t + s];
        memoryBarrierShared();
        barrier();
    }
    float s = sqrt(partial[0]);
#ifdef LEARNT
    learnt_residual(t, s, n_points);
#endif
    for (int k = t; k < 3 * n_b; k += GROUP) {
        int c = k / n_b, i = k - c * n_b;
        float v = 0.0;
        if (i < use) {
            int row = (c * n_b + i) * n_points;
            for (int p = 0; p < n_points; ++p) v += m[row + p] * x[p][c];
            v += s * b[c * n_b + i];
#ifdef LEARNT
            v += s * r_learnt[k];
#endif
        }
        u[k] = v;
    }
    memoryBarrierShared();
    barrier();
    for (int j = t; j < n_planes; j += GROUP) {
        int el = plane[j].x, ch = plane[j].y;
        vec3 wj = vec3(0.0);
        if (el == 0) wj[ch] = s;
        else if (el <= use) {
            if (ch < 0) wj = vec3(u[el - 1], u[n_b + el - 1], u[2 * n_b + el - 1]);
            else wj[ch] = u[ch * n_b + el - 1];
        }
        w[j] = vec4(wj, 0.0);
    }
}
