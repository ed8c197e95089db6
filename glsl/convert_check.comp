#version 460
// glsl/common/convert.glsl against GLSL's own conversions, and glsl/common/octahedral.glsl's
// decode, on the device that runs it (tests only: tests/shader_convert.rs). Binding 0: the
// floats; binding 1: per float x f2u(x), uint(x), and the bits of f2i(x) and int(x);
// binding 2: per float oct_decode(x) (xyz; a normal where x is a code, an integer below
// 2^24) and, in w, how far a direction made from x (rec_direction) moves through
// rec_pack and rec_unpack: the distance between the two unit vectors.
#include "interface.glsl"
#include "common/convert.glsl"
#include "common/octahedral.glsl"

layout(local_size_x = 64) in;

layout(std430, set = 0, binding = 0) readonly buffer Inputs { float xs[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Outputs { uvec4 outs[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Normals { vec4 normals[]; };

// A direction from float x, all round the sphere as x varies, of length 0.01 to 100
// (rec_pack takes any length): tests/shader_convert.rs `directions_in_one_word_round_trip`.
vec3 rec_direction(float x) {
    float t = fract(x * 0.618034) * 3.14159265, p = fract(x * 0.137) * 6.2831853;
    float len = exp2(fract(x * 0.291) * 13.3 - 6.65);
    return len * vec3(sin(t) * cos(p), sin(t) * sin(p), cos(t));
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= uint(xs.length())) return;
    float x = xs[i];
    outs[i] = uvec4(f2u(x), uint(x), uint(f2i(vec3(x)).x), uint(int(x)));
    vec3 d = rec_direction(x);
    float moved = length(normalize(rec_unpack(rec_pack(d))) - normalize(d));
    normals[i] = vec4(oct_decode(x), moved);
}
