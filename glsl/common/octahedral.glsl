// Octahedral normals: a unit normal coded as one float, the integer u * OCT_LEVELS + v
// (Tri's w; scene::curved::encode_normal, decode_normal its CPU mirror); and a direction
// in one word (rec_pack, rec_unpack). Needs interface.glsl (OCT_LEVELS, OCT_STEPS).
#ifndef OCTAHEDRAL_GLSL
#define OCTAHEDRAL_GLSL
#include "convert.glsl"

// The octahedron's lower half folded out to the square's corners, or back (its own
// inverse): point p of the square [-1, 1]^2 across its inner diamond.
vec2 oct_fold(vec2 p) {
    return (1.0 - abs(p.yx)) * vec2(p.x >= 0.0 ? 1.0 : -1.0, p.y >= 0.0 ? 1.0 : -1.0);
}

// Point e of the square [-1, 1]^2 as its point on the unit octahedron (|x| + |y| + |z|
// = 1; not unit length).
vec3 oct_point(vec2 e) {
    float z = 1.0 - abs(e.x) - abs(e.y);
    if (z < 0.0) e = oct_fold(e);
    return vec3(e, z);
}

vec3 oct_decode(float code) {
    uint k = f2u(code);   // codes reach 2^24 - 1
    vec2 e = vec2(float(k / OCT_LEVELS), float(k % OCT_LEVELS)) / float(OCT_STEPS) * 2.0 - 1.0;
    return normalize(oct_point(e));
}
// Direction w (any nonzero length) in one word: its octahedral projection (the unit
// octahedron's face point, the lower half folded out) at 16 bits an axis, at most 6.3e-5
// rad of rounding (the analytic light's recorded ring vertices: analytic_light.glsl
// rec_w; test `directions_in_one_word_round_trip`).
uint rec_pack(vec3 w) {
    vec3 a = abs(w);
    vec2 p = w.xy / (a.x + a.y + a.z);
    if (w.z < 0.0) p = oct_fold(p);
    uint qx = min(f2u((p.x + 1.0) * 32767.5 + 0.5), 65535u);
    uint qy = min(f2u((p.y + 1.0) * 32767.5 + 0.5), 65535u);
    return qx | (qy << 16);
}

// The direction of a rec_pack word (not unit length; its users normalise).
vec3 rec_unpack(uint code) {
    return oct_point(vec2(float(code & 0xffffu), float(code >> 16)) * (1.0 / 32767.5) - 1.0);
}
#endif
