// The basis blend: colour = max(sum_j plane_j * w_j, 0), gamma undone; prtcore.runtime.cpu.blend
// on the GPU (tests/test_render.py checks the two equal). Included by camera_fs.glsl and
// atlas_fs.glsl.
layout(std430, binding = 4) readonly buffer Weights { vec4 w[]; };
uniform sampler2DArray basis;
uniform int n_layers;
uniform float gamma;  // 0: none

// paper 5.2: one 4x3 coefficient matrix per RGBA texture of 4 basis planes
vec3 indirect_at(vec2 uv) {
    vec3 c = vec3(0.0);
    for (int f = 0; f < n_layers; ++f) {
        mat4x3 W = mat4x3(w[4 * f].xyz, w[4 * f + 1].xyz, w[4 * f + 2].xyz, w[4 * f + 3].xyz);
        c += W * texture(basis, vec3(uv, float(f)));
    }
    c = max(c, vec3(0.0));  // negative light clamped (the runtime formula's policy)
    if (gamma > 0.0) c = pow(c, vec3(gamma));
    return c;
}
