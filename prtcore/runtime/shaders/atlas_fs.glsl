#version 430
// The indirect lightmap at atlas size: the blend at every texel centre, A = coverage.
#include "blend.glsl"
uniform sampler2D coverage;
out vec4 f_color;
void main() {
    ivec2 size = textureSize(coverage, 0);
    // FBO row r (from the bottom) becomes image row H-1-r after the read-back flip
    ivec2 t = ivec2(int(gl_FragCoord.x), size.y - 1 - int(gl_FragCoord.y));
    vec2 uv = (vec2(t) + 0.5) / vec2(size);
    f_color = vec4(indirect_at(uv), texelFetch(coverage, t, 0).r);
}
