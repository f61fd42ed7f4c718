#version 430
// Fake G-buffer: shade every measurement-point supersample (albedo/pi * E, shadows from
// the shadow maps), average each cluster -> x' (gamma applied); prtcore.runtime.cpu.shade_points.
layout(local_size_x = 64) in;
#include "lights.glsl"
layout(std430, binding = 1) readonly buffer Clusters { vec4 cl[]; };  // pos, normal, albedo
layout(std430, binding = 2) readonly buffer Starts { int start[]; };  // P + 1
layout(std430, binding = 3) writeonly buffer X { vec4 x[]; };         // x' per point
layout(std430, binding = 5) writeonly buffer CE { vec4 ce[]; };       // E per supersample
uniform int n_points;
uniform float gamma;
void main() {
    int p = int(gl_GlobalInvocationID.x);
    if (p >= n_points) return;
    int a = start[p], b = start[p + 1];
    vec3 sum = vec3(0.0);
    for (int k = a; k < b; ++k) {
        vec3 pos = cl[3 * k].xyz, n = cl[3 * k + 1].xyz, albedo = cl[3 * k + 2].xyz;
        vec3 e = vec3(0.0);
        for (int l = 0; l < n_lights; ++l) e += irradiance(l, pos, n, n);
        ce[k] = vec4(e, 0.0);
        sum += albedo / PI * e;
    }
    vec3 v = sum / float(max(b - a, 1));
    if (gamma > 0.0) v = sign(v) * pow(abs(v), vec3(1.0 / gamma));
    x[p] = vec4(v, 0.0);
}
