// The light table (one Light per row of the shadow atlas, written by
// prtcore.runtime.shadows), the KHR_lights_punctual irradiance of
// prtcore.emitters.punctual and the shadow-map visibility.
// Included by camera_fs.glsl and points_cs.glsl.
struct Light {
    vec4 pos_type;   // xyz position, w type: 0 point, 1 spot, 2 directional
    vec4 dir_range;  // xyz unit direction light travels, w range (0: none)
    vec4 color;      // rgb colour * intensity, w unused
    vec4 params;     // x spot scale, y spot offset, z atlas row, w texel size (directional)
    mat4 views[6];   // clip_from_world of each shadow view
};
layout(std430, binding = 0) readonly buffer Lights { Light lights[]; };
uniform int n_lights;
uniform int use_shadows;
uniform sampler2D shadow_atlas;
uniform int shadow_res;
uniform float bias_normal;
uniform float bias_const;
const float PI = 3.14159265358979323846;

int cube_face(vec3 v) {
    vec3 a = abs(v);
    if (a.x >= a.y && a.x >= a.z) return v.x > 0.0 ? 0 : 1;
    if (a.y >= a.z) return v.y > 0.0 ? 2 : 3;
    return v.z > 0.0 ? 4 : 5;
}

float visibility(int l, vec3 p, vec3 ng) {
    Light L = lights[l];
    int type = int(L.pos_type.w);
    vec3 to_light = type == 2 ? -L.dir_range.xyz : normalize(L.pos_type.xyz - p);
    float side = dot(ng, to_light) >= 0.0 ? 1.0 : -1.0;
    float texel = type == 2 ? L.params.w
                            : 2.0 * length(L.pos_type.xyz - p) / float(shadow_res);
    vec3 q = p + ng * (side * bias_normal * texel);
    int face = 0;
    float dq;
    if (type == 2) {
        dq = dot(q, L.dir_range.xyz);
    } else {
        vec3 v = q - L.pos_type.xyz;
        dq = length(v);
        face = cube_face(v);
    }
    vec4 clip = L.views[face] * vec4(q, 1.0);
    vec2 ndc = clip.xy / clip.w;
    ivec2 t = clamp(ivec2(floor((ndc * 0.5 + 0.5) * float(shadow_res))), ivec2(0),
                    ivec2(shadow_res - 1));
    t += ivec2(face * shadow_res, int(L.params.z) * shadow_res);
    float stored = texelFetch(shadow_atlas, t, 0).r;
    return dq <= stored + bias_const * texel ? 1.0 : 0.0;
}

// KHR_lights_punctual irradiance (prtcore.emitters.punctual.unshadowed_irradiance) times visibility
vec3 irradiance(int l, vec3 p, vec3 n, vec3 ng) {
    Light L = lights[l];
    int type = int(L.pos_type.w);
    float att;
    if (type == 2) {
        att = max(dot(n, -L.dir_range.xyz), 0.0);
    } else {
        vec3 d = L.pos_type.xyz - p;
        float r2 = dot(d, d);
        if (!(r2 > 0.0)) return vec3(0.0);
        float r = sqrt(r2);
        vec3 w = d / r;
        att = max(dot(n, w), 0.0);
        if (L.dir_range.w > 0.0) {
            float x = clamp(1.0 - pow(r / L.dir_range.w, 4.0), 0.0, 1.0);
            att *= x * x;
        }
        if (type == 1) {
            float a = clamp(dot(-w, L.dir_range.xyz) * L.params.x + L.params.y, 0.0, 1.0);
            att *= a * a;
        }
        att /= r2;
    }
    if (att > 0.0 && use_shadows != 0) att *= visibility(l, p, ng);
    return att * L.color.rgb;
}
