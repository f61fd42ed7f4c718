#version 430
// The learnt SH transfer sigma(p, n) at points (learnt_sh_net.glsl), one invocation per
// point: prtcore.runtime.learnt_sh.gpu_evaluate.
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer Pos { vec4 pos[]; };
layout(std430, binding = 1) readonly buffer Nrm { vec4 nrm[]; };
layout(std430, binding = 2) writeonly buffer Coeffs { vec4 coeffs[]; };  // OUT4 per point
#include "learnt_sh_net.glsl"
uniform int n_points;
void main() {
    int i = int(gl_GlobalInvocationID.x);
    if (i >= n_points) return;
    vec4 y[MAX4];
    sigma(pos[i].xyz, nrm[i].xyz, y);
    for (int o = 0; o < OUT4; ++o) coeffs[OUT4 * i + o] = y[o];
}
