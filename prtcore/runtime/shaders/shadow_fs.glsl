#version 430
// Shadow maps: distance to the light (directional: depth along its direction), MIN-blended.
in vec3 v_pos;
uniform vec4 light_pos_type;
uniform vec3 light_dir;
out float f_dist;
void main() {
    f_dist = int(light_pos_type.w) == 2 ? dot(v_pos, light_dir)
                                        : length(v_pos - light_pos_type.xyz);
}
