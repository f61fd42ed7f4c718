#version 430
// Hair camera pass: the fibre tubes' vertices with what the fragment needs to shade the
// round fibre they stand for (prtcore.runtime.strands_gl).
in vec3 in_pos;      // tube vertex
in vec3 in_centre;   // the fibre's axis point of the vertex's ring
in vec3 in_tan;      // unit direction of the segment ending at the ring (provoking vertex)
in float in_arc;     // arc fraction from the root, [0, 1]
in float in_strand;  // strand index (exact in float32 below 2^24)
in float in_offset;  // radius from which the fibre's light leaves (outside_offset)
in vec3 in_albedo;   // clamped fibre albedo
uniform mat4 clip_from_world;
out vec3 v_pos;
out vec3 v_centre;
flat out vec3 v_tan;
out float v_arc;
flat out float v_strand;
out float v_offset;
out vec3 v_albedo;
void main() {
    v_pos = in_pos;
    v_centre = in_centre;
    v_tan = in_tan;
    v_arc = in_arc;
    v_strand = in_strand;
    v_offset = in_offset;
    v_albedo = in_albedo;
    gl_Position = clip_from_world * vec4(in_pos, 1.0);
}
