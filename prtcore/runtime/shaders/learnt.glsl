// The learnt transfer's residual r(x'/s) of fit.transfer "mlp": prtcore.core.mlp.forward
// on the GPU, one neuron per invocation of the coefficients work group (tests/test_render.py
// checks it against prtcore.runtime.cpu.plane_weights). Included by coeff_cs.glsl when
// prtcore.runtime.gl #defines LEARNT, with LEARNT_LAYERS (layers, output included) and
// LEARNT_WIDTH (the widest hidden layer).
layout(std430, binding = 9) readonly buffer LearntWeights { float lw[]; };  // W_j row-major, c_j
layout(std430, binding = 10) readonly buffer LearntLayers { ivec4 layer[]; };  // in, out, W_j, c_j
uniform float learnt_slope;
shared float hidden_a[LEARNT_WIDTH];
shared float hidden_b[LEARNT_WIDTH];
shared float r_learnt[N_U];

// r_learnt[c * n_b + i] for the unit direct vector x'/s, whose input index is c * n_points + p
void learnt_residual(int t, float s, int n_points) {
    float inv = s > 0.0 ? 1.0 / s : 0.0;
    for (int j = 0; j < LEARNT_LAYERS; ++j) {
        ivec4 L = layer[j];
        for (int o = t; o < L.y; o += GROUP) {
            int row = L.z + o * L.x;
            float v = 0.0;
            if (j == 0) {
                for (int c = 0; c < 3; ++c)
                    for (int p = 0; p < n_points; ++p) v += lw[row + c * n_points + p] * x[p][c];
                v *= inv;
            } else if (j % 2 == 1) {
                for (int q = 0; q < L.x; ++q) v += lw[row + q] * hidden_a[q];
            } else {
                for (int q = 0; q < L.x; ++q) v += lw[row + q] * hidden_b[q];
            }
            v += lw[L.w + o];
            if (j == LEARNT_LAYERS - 1) r_learnt[o] = s > 0.0 ? v : 0.0;
            else if (j % 2 == 0) hidden_a[o] = v >= 0.0 ? v : learnt_slope * v;
            else hidden_b[o] = v >= 0.0 ? v : learnt_slope * v;
        }
        memoryBarrierShared();
        barrier();
    }
}
