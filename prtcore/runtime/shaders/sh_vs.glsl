#version 430
// SH-PRT camera pass, vertex stage. Vertex storage (the vertex-shader variant, Sloan 2002):
// colour = T_v · l per channel here, interpolated by the rasteriser. Texture storage:
// only passes TEXCOORD_1 on (the fragment stage evaluates T · l).
in vec3 in_pos;
in vec3 in_nrm;
in vec2 in_uv1;
uniform mat4 clip_from_world;
uniform int vertex_storage;
uniform int n_coeffs;
layout(std430, binding = 5) readonly buffer VertexTransfer { float transfer[]; };  // [v][c][i]
layout(std430, binding = 6) readonly buffer LightSH { vec4 light[]; };  // [i]: r, g, b, 0
out vec3 v_color;
out vec2 v_uv1;
out vec3 v_pos;
out vec3 v_nrm;
void main() {
    vec3 col = vec3(0.0);
    if (vertex_storage != 0) {
        int base = gl_VertexID * 3 * n_coeffs;
        for (int i = 0; i < n_coeffs; ++i) {
            col += vec3(transfer[base + i], transfer[base + n_coeffs + i],
                        transfer[base + 2 * n_coeffs + i]) * light[i].rgb;
        }
    }
    v_color = col;
    v_uv1 = in_uv1;
    v_pos = in_pos;
    v_nrm = in_nrm;
    gl_Position = clip_from_world * vec4(in_pos, 1.0);
}
