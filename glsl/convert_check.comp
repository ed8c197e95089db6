#version 460
// glsl/common/convert.glsl against GLSL's own conversions, and glsl/common/octahedral.glsl's
// decode, on the device that runs it (tests only: tests/shader_convert.rs). Binding 0: the
// floats; binding 1: per float x f2u(x), uint(x), and the bits of f2i(x) and int(x);
// binding 2: per float oct_decode(x) (xyz; a normal where x is a code, an integer below
// 2^24).
#include "interface.glsl"
#include "common/convert.glsl"
#include "common/octahedral.glsl"

layout(local_size_x = 64) in;

layout(std430, set = 0, binding = 0) readonly buffer Inputs { float xs[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Outputs { uvec4 outs[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Normals { vec4 normals[]; };

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= uint(xs.length())) return;
    float x = xs[i];
    outs[i] = uvec4(f2u(x), uint(x), uint(f2i(vec3(x)).x), uint(int(x)));
    normals[i] = vec4(oct_decode(x), 0.0);
}
