// The fragment stage's inputs of the distant-lighting camera passes (sh_prt, learnt_sh):
// sh_vs.glsl's outputs, the glossy layer's uniforms (sh_glossy.glsl), the light's SH
// (binding 6: vec4 i = r, g, b of coefficient i, padded) and the colour output.
#include "sh_glossy.glsl"
in vec3 v_color;
in vec2 v_uv1;
in vec3 v_pos;
in vec3 v_nrm;
uniform int glossy;
uniform float specular;
uniform int bands;
uniform vec3 eye;
layout(std430, binding = 6) readonly buffer LightSH { vec4 light[]; };
layout(location = 0) out vec4 f_color;
