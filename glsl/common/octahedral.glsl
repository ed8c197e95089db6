// Octahedral normals: a unit normal coded as one float, the integer u * OCT_LEVELS + v
// (Tri's w; scene::curved::encode_normal, decode_normal its CPU mirror). Needs
// interface.glsl (OCT_LEVELS, OCT_STEPS).
#ifndef OCTAHEDRAL_GLSL
#define OCTAHEDRAL_GLSL
#include "convert.glsl"

vec3 oct_decode(float code) {
    uint k = f2u(code);   // codes reach 2^24 - 1
    vec2 e = vec2(float(k / OCT_LEVELS), float(k % OCT_LEVELS)) / float(OCT_STEPS) * 2.0 - 1.0;
    float z = 1.0 - abs(e.x) - abs(e.y);
    if (z < 0.0) {
        e = vec2((1.0 - abs(e.y)) * (e.x >= 0.0 ? 1.0 : -1.0),
                 (1.0 - abs(e.x)) * (e.y >= 0.0 ? 1.0 : -1.0));
    }
    return normalize(vec3(e, z));
}
#endif
