#version 460
// glsl/common/polygon_edge.glsl's edges on the device that runs it (tests only:
// tests/shader_convert.rs `polygon_edges_match_float64`). Binding 0: pairs of vectors (a,
// then b, each a vec4 whose w is unused); binding 1: per pair edge_z(a, b), the same edge
// from GLSL's atan (the form edge_z replaced: atan(s, a . b) (a x b).z / s / (2 pi), s =
// |a x b|).
#include "common/polygon_edge.glsl"

layout(local_size_x = 64) in;

layout(std430, set = 0, binding = 0) readonly buffer Pairs { vec4 pairs[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Edges { vec2 edges[]; };

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= uint(pairs.length()) / 2u) return;
    vec3 a = pairs[2u * i].xyz, b = pairs[2u * i + 1u].xyz;
    vec3 c = cross(a, b);
    float s = length(c);
    float by_atan = s > 0.0 ? atan(s, dot(a, b)) * c.z / s * (0.5 / 3.14159265358979) : 0.0;
    edges[i] = vec2(edge_z(a, b), by_atan);
}
