#version 460
//! variants: rq=TRACE_RAY_QUERY sw=TRACE_SOFTWARE sw8=TRACE_SOFTWARE_WIDE
// Traces a list of rays and writes the closest hit of each (tests and benchmarks).
#include "common/trace.glsl"
#include "interface.glsl"
#include "common/scramble.glsl"

layout(local_size_x = 64) in;

struct RayIn { vec4 o_tmin; vec4 d_tmax; };
layout(std430, set = 0, binding = HT_RAYS) readonly buffer Rays { RayIn rays[]; };
layout(std430, set = 0, binding = HT_HITS) writeonly buffer Hits { vec4 hits[]; };

layout(push_constant) uniform Push { HitsPush pc; };

void main() {
    uint g = scramble_group(gl_WorkGroupID.x, pc.groups, pc.mult);
    uint i = g * 64u + gl_LocalInvocationID.x;
    if (i >= pc.count) return;
    RayIn r = rays[i];
    Hit h = trace(r.o_tmin.xyz, r.d_tmax.xyz, r.o_tmin.w, r.d_tmax.w);
    hits[i] = vec4(h.prim == NO_HIT ? -1.0 : h.t, uintBitsToFloat(h.prim), h.bary);
}
