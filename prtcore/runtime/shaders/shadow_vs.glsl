#version 430
// Shadow maps: world position to the light view's clip space.
in vec3 in_pos;
uniform mat4 clip_from_world;
out vec3 v_pos;
void main() {
    v_pos = in_pos;
    gl_Position = clip_from_world * vec4(in_pos, 1.0);
}
