// The analytic SDF of an SDF scene (prtcore.core.sdf): primitives folded by the smooth
// union of radius smooth_k, their gradient by central differences of step grad_h, and
// sphere tracing; three vec4 per primitive as prtcore.core.sdf.packed writes them.
layout(std430, binding = 14) readonly buffer SdfPrimitives { vec4 prim[]; };
uniform int n_prims;
uniform float smooth_k;
uniform float grad_h;
float prim_distance(int i, vec3 p) {
    vec4 a = prim[3 * i], b = prim[3 * i + 1];
    int kind = int(prim[3 * i + 2].x);
    if (kind == 0) return length(p - a.xyz) - a.w;  // sphere
    if (kind == 1) {  // ellipsoid (Quilez's bound)
        float k0 = length((p - a.xyz) / b.xyz), k1 = length((p - a.xyz) / (b.xyz * b.xyz));
        return k0 * (k0 - 1.0) / max(k1, 1e-30);
    }
    if (kind == 2) {  // box, edges rounded by a.w
        vec3 q = abs(p - a.xyz) - (b.xyz - a.w);
        return length(max(q, 0.0)) + min(max(q.x, max(q.y, q.z)), 0.0) - a.w;
    }
    if (kind == 3) {  // capsule a.xyz - b.xyz, radius a.w
        vec3 pa = p - a.xyz, ba = b.xyz - a.xyz;
        float h = clamp(dot(pa, ba) / dot(ba, ba), 0.0, 1.0);
        return length(pa - h * ba) - a.w;
    }
    // torus: major a.w, minor b.x, ring normal along axis b.y
    vec3 q = p - a.xyz;
    int ax = int(b.y);
    vec2 plane = ax == 0 ? q.yz : (ax == 1 ? q.xz : q.xy);
    return length(vec2(length(plane) - a.w, q[ax])) - b.x;
}
float sdf(vec3 p) {
    float d = prim_distance(0, p);
    for (int i = 1; i < n_prims; ++i) {
        float e = prim_distance(i, p);
        if (smooth_k > 0.0) {
            float h = max(smooth_k - abs(d - e), 0.0) / smooth_k;
            d = min(d, e) - h * h * smooth_k * 0.25;
        } else {
            d = min(d, e);
        }
    }
    return d;
}
vec3 sdf_normal(vec3 p) {
    vec3 g;
    for (int k = 0; k < 3; ++k) {
        vec3 e = vec3(0.0);
        e[k] = grad_h;
        g[k] = (sdf(p + e) - sdf(p - e)) / (2.0 * grad_h);
    }
    return normalize(g);
}
