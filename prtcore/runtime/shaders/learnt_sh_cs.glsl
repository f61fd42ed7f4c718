#version 430
// The learnt SH transfer sigma(p, n) at points (thesis 4.1.4.1): every weight matrix cut
// into 4x4 blocks read as mat4 (block (o, q) maps input vec4 q to output vec4 o), biases
// as vec4; prtcore.fit.learnt_sh.evaluate on the GPU (tests/test_learnt_sh_gl.py). One
// invocation per point. IN4 (input vec4s), MAX4 (widest layer in vec4s), LAYERS and the
// encoding's frequencies are #defined by prtcore.runtime.learnt_sh.
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer Pos { vec4 pos[]; };
layout(std430, binding = 1) readonly buffer Nrm { vec4 nrm[]; };
layout(std430, binding = 2) writeonly buffer Coeffs { vec4 coeffs[]; };  // OUT4 per point
layout(std430, binding = 3) readonly buffer Weights { mat4 w[]; };
layout(std430, binding = 4) readonly buffer Biases { vec4 bias[]; };
layout(std430, binding = 5) readonly buffer Layers { ivec4 layer[]; };  // in4, out4, w0, b0
uniform int n_points;
uniform vec3 centre;
uniform float inv_radius;
uniform float out_scale;
uniform float slope;
uniform int tanh_output;
void encode(vec3 v, int freqs, inout float enc[IN4 * 4], inout int at) {
    for (int c = 0; c < 3; ++c) enc[at++] = v[c];
    for (int k = 0; k < freqs; ++k)
        for (int c = 0; c < 3; ++c) enc[at++] = sin(exp2(float(k)) * 3.14159265358979 * v[c]);
    for (int k = 0; k < freqs; ++k)
        for (int c = 0; c < 3; ++c) enc[at++] = cos(exp2(float(k)) * 3.14159265358979 * v[c]);
}
void main() {
    int i = int(gl_GlobalInvocationID.x);
    if (i >= n_points) return;
    float enc[IN4 * 4];
    for (int q = 0; q < IN4 * 4; ++q) enc[q] = 0.0;
    int at = 0;
    encode((pos[i].xyz - centre) * inv_radius, POSITION_FREQUENCIES, enc, at);
    encode(nrm[i].xyz, NORMAL_FREQUENCIES, enc, at);
    vec4 h[MAX4], g[MAX4];
    for (int q = 0; q < IN4; ++q) h[q] = vec4(enc[4 * q], enc[4 * q + 1], enc[4 * q + 2], enc[4 * q + 3]);
    for (int j = 0; j < LAYERS; ++j) {
        ivec4 L = layer[j];
        for (int o = 0; o < L.y; ++o) {
            vec4 a = bias[L.w + o];
            for (int q = 0; q < L.x; ++q) a += w[L.z + o * L.x + q] * h[q];
            if (j < LAYERS - 1) a = mix(slope * a, a, step(0.0, a));
            else if (tanh_output != 0) a = tanh(a);
            g[o] = a;
        }
        for (int o = 0; o < L.y; ++o) h[o] = g[o];
    }
    for (int o = 0; o < layer[LAYERS - 1].y; ++o) coeffs[layer[LAYERS - 1].y * i + o] = out_scale * h[o];
}
