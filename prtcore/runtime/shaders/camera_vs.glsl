#version 430
// Camera pass: world-space position, normal and both UV sets to the fragment shader.
in vec3 in_pos;
in vec3 in_nrm;
in vec2 in_uv0;
in vec2 in_uv1;
uniform mat4 clip_from_world;
out vec3 v_pos;
out vec3 v_nrm;
out vec2 v_uv0;
out vec2 v_uv1;
void main() {
    v_pos = in_pos;
    v_nrm = in_nrm;
    v_uv0 = in_uv0;
    v_uv1 = in_uv1;
    gl_Position = clip_from_world * vec4(in_pos, 1.0);
}
