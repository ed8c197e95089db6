#version 460
//! variants: rq=TRACE_RAY_QUERY sw=TRACE_SOFTWARE sw8=TRACE_SOFTWARE_WIDE
// Traces a list of rays and writes the closest hit of each (tests and benchmarks), each
// ray with a hint of its own where the push constant asks for it.
#include "common/trace.glsl"
#include "interface.glsl"
#include "common/scramble.glsl"

layout(local_size_x = 64) in;

struct RayIn { vec4 o_tmin; vec4 d_tmax; };
layout(std430, set = 0, binding = HT_RAYS) readonly buffer Rays { RayIn rays[]; };
layout(std430, set = 0, binding = HT_HITS) writeonly buffer Hits { vec4 hits[]; };
// With pc.hinted: each ray's closest-hit hint (corners; original index as bits in a.w,
// NO_HIT none), which must not change the hit (tests).
layout(std430, set = 0, binding = HT_HINTS) readonly buffer Hints { Tri hints[]; };

// With pc.hinted 2: each ray's camera-ray bundle (trace_bundle_init's arguments), built
// before its query, which must not change the hit either; BundleUse says what became of
// it (0: none built, 1: built, the object traversed, 2: the hit taken from it).
layout(std430, set = 0, binding = HT_BUNDLES) readonly buffer Bundles { BundleBlock bundles[]; };
layout(std430, set = 0, binding = HT_BUNDLE_USE) writeonly buffer BundleUse { uint bundle_use[]; };

// With pc.hinted 3: each ray is an occlusion test (TQ_BLOCKED) with a shadow bundle of
// its own built first (trace_shadow_init), which must not change the answer.
layout(std430, set = 0, binding = HT_SHADOWS) readonly buffer Shadows { ShadowBlock shadows[]; };

layout(push_constant) uniform Push { HitsPush pc; };

void main() {
    uint g = scramble_group(gl_WorkGroupID.x, pc.groups, pc.mult);
    uint i = g * 64u + gl_LocalInvocationID.x;
    if (i >= pc.count) return;
    RayIn r = rays[i];
    if (pc.hinted == 3u) {
        ShadowBlock b = shadows[i];
        if (b.origin_lo.w != 0.0) {
            trace_shadow_init(b.origin_lo.xyz, b.origin_hi.xyz, b.light_lo.xyz, b.light_hi.xyz);
        }
        bool blocked = trace_query(TQ_BLOCKED, r.o_tmin.xyz, r.d_tmax.xyz, r.o_tmin.w, r.d_tmax.w,
                                   0.0).blocked;
        bundle_use[i] = !trace_shadow_built() ? 0u : trace_shadow_answered ? 2u : 1u;
        hits[i] = vec4(blocked ? 1.0 : 0.0, 0.0, 0.0, 0.0);
        return;
    }
    TraceHint hint = trace_no_hint();
    if (pc.hinted != 0u) {
        hint.a = hints[i].a.xyz;
        hint.b = hints[i].b.xyz;
        hint.c = hints[i].c.xyz;
        hint.prim = floatBitsToUint(hints[i].a.w);
    }
    if (pc.hinted == 2u) {
        BundleBlock b = bundles[i];
        trace_bundle_init(b.eye.xyz, b.right.xyz, b.up.xyz, b.fwd.xyz, b.eye.w, b.fwd.w,
                          b.footprint, b.plane_p.xyz, b.plane_n.xyz);
    }
    Hit h = trace_query_hinted(TQ_CLOSEST, r.o_tmin.xyz, r.d_tmax.xyz, r.o_tmin.w, r.d_tmax.w,
                               0.0, hint).h;
    if (pc.hinted == 2u) {
        bundle_use[i] = trace_bundle_size() == 0u ? 0u : trace_bundle_answered ? 2u : 1u;
    }
    hits[i] = vec4(h.prim == NO_HIT ? -1.0 : h.t, uintBitsToFloat(h.prim), h.bary);
}
