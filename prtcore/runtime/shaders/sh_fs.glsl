#version 430
// SH-PRT camera pass, fragment stage. Texture storage (the fragment-shader variant,
// transfer textures): colour = T(uv1) · l per channel, T filtered bilinearly; layer
// c·files + k holds coefficients 4k..4k+3 of channel c in R, G, B, A. Vertex storage: the
// interpolated vertex colour.
in vec3 v_color;
in vec2 v_uv1;
uniform int vertex_storage;
uniform int files;
uniform sampler2DArray transfer_tex;
layout(std430, binding = 6) readonly buffer LightSH { vec4 light[]; };  // padded to 4·files
layout(location = 0) out vec4 f_color;
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
    f_color = vec4(col, 1.0);
}
