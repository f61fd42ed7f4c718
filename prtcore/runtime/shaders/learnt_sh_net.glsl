// The learnt SH network sigma(p, n) (thesis 4.1.4.1), shared by the compute pass and the
// fragment pass: every weight matrix cut into 4x4 blocks read as mat4 (block (o, q) maps
// input vec4 q to output vec4 o), biases as vec4, one scale per output, one network per
// sub-scene cell; prtcore.fit.subscenes.evaluate_scenes on the GPU
// (tests/test_learnt_sh_gl.py). IN4 (input vec4s), MAX4 (widest layer in vec4s), OUT4
// (output vec4s), LAYERS (per network) and the encoding's frequencies are #defined by
// prtcore.runtime.learnt_sh.
layout(std430, binding = 10) readonly buffer NetWeights { mat4 w[]; };
layout(std430, binding = 11) readonly buffer NetBiases { vec4 bias[]; };
// LAYERS rows per network: in4, out4, first block, first bias
layout(std430, binding = 12) readonly buffer NetLayers { ivec4 layer[]; };
layout(std430, binding = 13) readonly buffer NetScale { vec4 out_scale[]; };  // OUT4 per network
layout(std430, binding = 15) readonly buffer NetFrame { vec4 frame[]; };  // centre, 1 / radius
uniform float slope;
uniform int tanh_output;
// sub-scenes (prtcore.fit.subscenes.Grid): one network per cell of the grid over
// grid_lo .. grid_lo + grid_size
uniform ivec3 grid_cells;
uniform vec3 grid_lo;
uniform vec3 grid_size;
int cell_of(vec3 p) {
    ivec3 c = clamp(ivec3(floor((p - grid_lo) / grid_size * vec3(grid_cells))), ivec3(0),
                    grid_cells - 1);
    return c.x + grid_cells.x * (c.y + grid_cells.y * c.z);
}
void encode(vec3 v, int freqs, inout float enc[IN4 * 4], inout int at) {
    for (int c = 0; c < 3; ++c) enc[at++] = v[c];
    for (int k = 0; k < freqs; ++k)
        for (int c = 0; c < 3; ++c) enc[at++] = sin(exp2(float(k)) * 3.14159265358979 * v[c]);
    for (int k = 0; k < freqs; ++k)
        for (int c = 0; c < 3; ++c) enc[at++] = cos(exp2(float(k)) * 3.14159265358979 * v[c]);
}
// sigma at point p (world) with unit normal n, by the network of p's cell: outputs in
// y[0 .. OUT4)
void sigma(vec3 p, vec3 n, out vec4 y[MAX4]) {
    int net = cell_of(p);
    vec4 f = frame[net];
    float enc[IN4 * 4];
    for (int q = 0; q < IN4 * 4; ++q) enc[q] = 0.0;
    int at = 0;
    encode((p - f.xyz) * f.w, POSITION_FREQUENCIES, enc, at);
    encode(n, NORMAL_FREQUENCIES, enc, at);
    vec4 g[MAX4];
    for (int q = 0; q < IN4; ++q) y[q] = vec4(enc[4 * q], enc[4 * q + 1], enc[4 * q + 2], enc[4 * q + 3]);
    for (int j = 0; j < LAYERS; ++j) {
        ivec4 L = layer[net * LAYERS + j];
        for (int o = 0; o < L.y; ++o) {
            vec4 a = bias[L.w + o];
            for (int q = 0; q < L.x; ++q) a += w[L.z + o * L.x + q] * y[q];
            if (j < LAYERS - 1) a = mix(slope * a, a, step(0.0, a));
            else if (tanh_output != 0) a = tanh(a);
            g[o] = a;
        }
        for (int o = 0; o < L.y; ++o) y[o] = g[o];
    }
    for (int o = 0; o < OUT4; ++o) y[o] *= out_scale[net * OUT4 + o];
}
