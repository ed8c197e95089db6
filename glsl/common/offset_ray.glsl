// Ray origins that never self-intersect: Waechter & Binder, "A Fast and Robust Method
// for Avoiding Self-Intersection", Ray Tracing Gems ch. 6. The point is moved along the
// geometric normal by a fixed number of ulps (scale-independent, so it works 10 m from
// the origin), and by a small absolute distance near the origin where ulps are tiny.
#ifndef OFFSET_RAY_GLSL
#define OFFSET_RAY_GLSL
#include "convert.glsl"
const float OFFSET_ORIGIN = 1.0 / 32.0;
const float OFFSET_FLOAT_SCALE = 1.0 / 65536.0;
const float OFFSET_INT_SCALE = 256.0;

vec3 offset_ray(vec3 p, vec3 n) {
    ivec3 of_i = f2i(OFFSET_INT_SCALE * n);   // ivec3(), vectorized (convert.glsl)
    vec3 p_i = vec3(
        intBitsToFloat(floatBitsToInt(p.x) + ((p.x < 0.0) ? -of_i.x : of_i.x)),
        intBitsToFloat(floatBitsToInt(p.y) + ((p.y < 0.0) ? -of_i.y : of_i.y)),
        intBitsToFloat(floatBitsToInt(p.z) + ((p.z < 0.0) ? -of_i.z : of_i.z)));
    return vec3(
        abs(p.x) < OFFSET_ORIGIN ? p.x + OFFSET_FLOAT_SCALE * n.x : p_i.x,
        abs(p.y) < OFFSET_ORIGIN ? p.y + OFFSET_FLOAT_SCALE * n.y : p_i.y,
        abs(p.z) < OFFSET_ORIGIN ? p.z + OFFSET_FLOAT_SCALE * n.z : p_i.z);
}

// An orthonormal basis around n (Duff et al. 2017, "Building an Orthonormal Basis,
// Revisited"): no branch on a threshold, no loss of precision near the poles.
void onb(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}

// Direction w given in the basis (t, b, n) (n its z axis) in world space; and world
// direction v in that basis.
vec3 from_frame(vec3 w, vec3 t, vec3 b, vec3 n) { return w.x * t + w.y * b + w.z * n; }
vec3 to_frame(vec3 v, vec3 t, vec3 b, vec3 n) { return vec3(dot(v, t), dot(v, b), dot(v, n)); }
#endif
