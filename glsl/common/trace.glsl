// One intersection interface, two bodies chosen by a define at build time:
//   TRACE_RAY_QUERY  - VK_KHR_ray_query against a TLAS (binding 0) whose instances are
//                      the object and the view's second level (instance custom index =
//                      first triangle index of the level)
//   TRACE_SOFTWARE   - stack traversal of two flattened obvhs BVH2s, the object's
//                      (bindings 0, 1) and the second level's (bindings 2, 3), read
//                      through their device addresses (binding 4)
//   TRACE_SOFTWARE_WIDE - the same with compressed wide BVHs (obvhs CWBVH, eight
//                      children a node, src/trace/software_bvh.rs)
// Both answer trace_query (a closest hit, the first light, shadow tests: TQ_* below) and
// trace (the closest hit over both levels), triangles numbered in one index space.
// Passes put their own bindings from TRACE_BINDING_COUNT on.
#ifndef TRACE_GLSL
#define TRACE_GLSL

#if defined(TRACE_SOFTWARE_WIDE)
#define TRACE_SOFTWARE
#define TRACE_WIDE
#endif

#define NO_HIT 0xffffffffu

struct Hit {
    float t;      // distance along the (unnormalised) direction; tmax when missed
    uint prim;    // original triangle index, NO_HIT when missed
    vec2 bary;    // weights of the triangle's 2nd and 3rd corner
    uint inst;    // instance index (one instance today: 0)
};

// No hit yet, with tmax as the distance a hit must beat.
Hit hit_none(float tmax) {
    Hit h;
    h.t = tmax; h.prim = NO_HIT; h.bary = vec2(0.0); h.inst = 0u;
    return h;
}

// What one trace_query traces: at most two traversals (one per level, or one ray query
// over both), run by one loop, so a shader compiles one traversal per call site
// (lavapipe inlines every call: with a traversal per level and query the path tracer's
// LLVM compile took minutes longer).
const uint TQ_CLOSEST = 0u;        // h: the closest hit over both levels (trace)
const uint TQ_LIGHT_CLOSEST = 1u;  // light: the first light on the ray, occluders ignored;
                                   // h: the closest hit over both levels
const uint TQ_LIGHTS = 2u;         // h and light: the first light, occluders ignored
const uint TQ_LIGHT_VISIBLE = 3u;  // a light sample's shadow test: blocked where the
                                   // closest hit within tmax is not a light triangle at
                                   // t_light or farther; light: the first light
const uint TQ_LIGHT_SEEN = 4u;     // light: the first light, occluders ignored (up to tmax);
                                   // blocked: none, or the object hides it
const uint TQ_BLOCKED = 5u;        // blocked: anything, object or light, within tmax

struct TraceResult {
    Hit h;
    Hit light;
    bool blocked;
};

// A closest-hit query's hint (TQ_CLOSEST only): an object triangle (level 0; corners in
// original order, as the BVH's leaves hold them) the ray is likely to hit first, or
// prim NO_HIT. The software traversal tests it before the BVH, so it starts with that
// hit as its bound and skips what lies behind; the answer is the same (the closest hit,
// ties to the lower index, whatever the order). The ray query ignores it.
struct TraceHint { vec3 a; vec3 b; vec3 c; uint prim; };

TraceHint trace_no_hint() {
    TraceHint t;
    t.a = t.b = t.c = vec3(0.0);
    t.prim = NO_HIT;
    return t;
}

#if defined(TRACE_RAY_QUERY)
#extension GL_EXT_ray_query : require
#define TRACE_BINDING_COUNT 1
layout(set = 0, binding = 0) uniform accelerationStructureEXT trace_tlas;

// One ray query over the instances whose mask meets `mask`: the closest hit, or with
// `any` the first found.
Hit trace_masked(vec3 o, vec3 d, float tmin, float tmax, uint mask, bool any) {
    Hit h = hit_none(tmax);
    rayQueryEXT rq;
    uint flags = gl_RayFlagsOpaqueEXT | (any ? gl_RayFlagsTerminateOnFirstHitEXT : 0u);
    rayQueryInitializeEXT(rq, trace_tlas, flags, mask, o, tmin, d, tmax);
    while (rayQueryProceedEXT(rq)) {}
    if (rayQueryGetIntersectionTypeEXT(rq, true) == gl_RayQueryCommittedIntersectionTriangleEXT) {
        h.t = rayQueryGetIntersectionTEXT(rq, true);
        h.prim = uint(rayQueryGetIntersectionPrimitiveIndexEXT(rq, true))
            + uint(rayQueryGetIntersectionInstanceCustomIndexEXT(rq, true));
        h.bary = rayQueryGetIntersectionBarycentricsEXT(rq, true);
        h.inst = uint(rayQueryGetIntersectionInstanceIdEXT(rq, true));
    }
    return h;
}

// The query `kind` (TQ_*) of ray o + t d, t in [tmin, tmax]. The view's lights are the
// instances of mask 0x02 (src/trace/mod.rs), the object's 0x01. A shadow test: the
// lights' closest hit first, then a query of the object that ends at its first hit up
// to there.
TraceResult trace_query_hinted(uint kind, vec3 o, vec3 d, float tmin, float tmax, float t_light,
                              TraceHint hint) {
    TraceResult res;
    res.blocked = false;
    res.light = hit_none(3.0e38);
    bool one = kind == TQ_CLOSEST || kind == TQ_BLOCKED;
    uint mask = one ? 0xffu : 0x02u;
    bool any = kind == TQ_BLOCKED;
    float bound = tmax;
    Hit h;
    for (uint step = 0u; step < 2u; step++) {
        h = trace_masked(o, d, tmin, bound, mask, any);
        if (one || step == 1u) break;
        res.light = h;
        if (kind == TQ_LIGHTS) break;
        if (kind == TQ_LIGHT_CLOSEST) {
            mask = 0xffu;   // then the closest hit over both, as TQ_CLOSEST
            continue;
        }
        if (kind == TQ_LIGHT_SEEN ? h.prim == NO_HIT : h.prim != NO_HIT && h.t < t_light) {
            res.blocked = true;
            break;
        }
        mask = 0x01u;
        any = true;
        bound = h.prim != NO_HIT ? h.t : tmax;
    }
    if (any) res.blocked = res.blocked || h.prim != NO_HIT;
    res.h = h;
    return res;
}

#elif defined(TRACE_SOFTWARE)
#define TRACE_BINDING_COUNT 5
// Triangles in BVH leaf order; v0.w holds the original triangle index.
struct BvhTri { vec4 v0; vec4 v1; vec4 v2; };
#if defined(TRACE_WIDE)
// WideNode (a compressed wide BVH node) and TRACE_WIDE_STACK come from the interface;
// its binding numbers count from TRACE_BINDING_COUNT, defined above.
#include "interface.glsl"
#define TRACE_NODE WideNode
#else
// Child-pair node: both children's boxes live in the parent, so one 64-byte load
// tests two boxes. w of *_min: child node index (inner) or first triangle (leaf);
// w of *_max: triangle count, 0 for an inner child.
struct BvhNode { vec4 l_min; vec4 l_max; vec4 r_min; vec4 r_max; };
#define TRACE_NODE BvhNode
#define TRACE_STACK 64
#endif
// Bindings 0-3 hold the object's nodes and triangles and the second level's (bound so
// that the pass's reads of them are declared), binding 4 their device addresses, in that
// order (src/trace/mod.rs); the traversal reads the levels through the addresses: lavapipe
// (Mesa 25.0) loads a storage buffer at a per-lane offset one lane and one word at a time,
// each behind a bounds branch, a buffer reference as one masked gather per word
// (docs/architecture.md, "Trace backends").
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_control_flow_attributes : require
#extension GL_EXT_buffer_reference_uvec2 : require
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer TraceNodeRef { TRACE_NODE n[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer TraceTriRef { BvhTri t[]; };
layout(std430, set = 0, binding = 4) readonly buffer TraceLevels { uvec2 trace_level_addr[4]; };

// Slab test; the far distance is widened by 3 ulps-worth (Ize 2013) so rounding never
// drops a box that the ray grazes.
bool trace_box(vec3 bmin, vec3 bmax, vec3 o, vec3 inv_d, float tmin, float tmax, out float tnear) {
    vec3 t0 = (bmin - o) * inv_d;
    vec3 t1 = (bmax - o) * inv_d;
    vec3 lo = min(t0, t1);
    vec3 hi = max(t0, t1);
    tnear = max(max(lo.x, lo.y), max(lo.z, tmin));
    float tfar = min(min(hi.x, hi.y), min(hi.z, tmax)) * 1.0000004;
    return tnear <= tfar;
}

#if defined(TRACE_WIDE)
// The hit mask of four child slots of a wide node: their meta bytes, grid minima and
// maxima (one byte per slot and axis), decoded as min + q * cell in f32 (conservative by
// construction, src/trace/software_bvh.rs) and tested with the widened slab test, so no
// ray is lost to quantization or rounding. Inner children (meta 0b001_11sss) set bit
// 24 + (s ^ octant), which orders their visit; a leaf sets its triangles' bits (unary
// count at its offset); an empty slot (meta 0) sets none. Every slot is tested and its
// bits or-ed in with a select: lanes run both sides of a branch on lavapipe.
uint trace_wide_half(uint metas, uvec3 qlos, uvec3 qhis, vec3 nmin, vec3 cell,
                vec3 o, vec3 inv_d, float tmin, float tmax, uint oct_inv) {
    uint hitmask = 0u;
    for (uint k = 0u; k < 4u; ++k) {
        uint sh = k * 8u;
        uint meta = (metas >> sh) & 0xffu;
        vec3 bmin = nmin + vec3((qlos >> sh) & 0xffu) * cell;
        vec3 bmax = nmin + vec3((qhis >> sh) & 0xffu) * cell;
        float tn;
        bool hit = trace_box(bmin, bmax, o, inv_d, tmin, tmax, tn);
        bool inner = (meta & 0x18u) == 0x18u;
        uint at = inner ? ((meta ^ oct_inv) & 0x1fu) : (meta & 0x1fu);
        hitmask |= hit ? ((meta >> 5u) & 7u) << at : 0u;
    }
    return hitmask;
}
#endif

// Watertight ray/triangle test (Woop, Benthin, Wald 2013): the ray is sheared to +z
// and the edge functions are evaluated in 2D, so a ray through a shared edge or vertex
// hits at least one of the triangles (no leaks). `precise` keeps the compiler from
// fusing multiply-adds, so the results match the CPU reference (src/trace/watertight.rs).
struct TraceRay { vec3 o; uint kx; uint ky; uint kz; vec3 s; };

TraceRay trace_setup(vec3 o, vec3 d) {
    TraceRay r;
    r.o = o;
    vec3 a = abs(d);
    r.kz = a.x > a.y ? (a.x > a.z ? 0u : 2u) : (a.y > a.z ? 1u : 2u);
    r.kx = (r.kz + 1u) % 3u;
    r.ky = (r.kx + 1u) % 3u;
    if (d[r.kz] < 0.0) { uint t = r.kx; r.kx = r.ky; r.ky = t; }
    precise float sz = 1.0 / d[r.kz];
    precise float sx = d[r.kx] * sz;
    precise float sy = d[r.ky] * sz;
    r.s = vec3(sx, sy, sz);
    return r;
}


#include "trace_bvh.glsl"

// The traversal's view of ray (o, d): reciprocal direction for the slab tests (zero
// components nudged: 0 * inf would give NaN) and the watertight test's shear.
void trace_prepare(vec3 o, vec3 d, out vec3 inv_d, out TraceRay tr) {
    vec3 dd = mix(d, sign(d) * 1e-30 + vec3(equal(d, vec3(0.0))) * 1e-30, lessThan(abs(d), vec3(1e-30)));
    inv_d = 1.0 / dd;
    tr = trace_setup(o, d);
}

// The query `kind` (TQ_*) of ray o + t d, t in [tmin, tmax]: one traversal written once,
// run for the object (level 0) and the view's lights (level 1) in the order the query
// needs. The closest hit: the object, then the lights nearer than the object's hit
// (TQ_LIGHT_CLOSEST: the lights first, then the object nearer than the light's hit; at
// equal distance the lower triangle index wins either way, so both orders give the same
// hit). A shadow test: the lights' closest hit first (the small second level); then
// the object traversal stops at its first hit up to there (inclusive: an object triangle
// wins a tie, its index is lower), or up to tmax (exclusive, as the closest hit's)
// without one: the answer the closest hit would give, without finding the closest
// occluder.
TraceResult trace_query_hinted(uint kind, vec3 o, vec3 d, float tmin, float tmax, float t_light,
                              TraceHint hint) {
    vec3 inv_d;
    TraceRay tr;
    trace_prepare(o, d, inv_d, tr);
    TraceResult res;
    res.blocked = false;
    res.light = hit_none(3.0e38);
    uint level = kind == TQ_CLOSEST || kind == TQ_BLOCKED ? 0u : 1u;
    bool any = kind == TQ_BLOCKED;
    Hit h = hit_none(tmax);
    if (kind == TQ_CLOSEST && hint.prim != NO_HIT) {
        trace_tri_test(hint.a, hint.b, hint.c, hint.prim, 0u, tr, tmin, h);
    }
    for (uint step = 0u; step < 2u; step++) {
        trace_bvh(level, o, inv_d, tr, tmin, h, any);
        if (step == 1u) break;
        if (kind == TQ_CLOSEST) {
            level = 1u;
        } else if (kind == TQ_BLOCKED) {
            if (h.prim != NO_HIT) break;
            level = 1u;
        } else if (kind == TQ_LIGHT_CLOSEST) {
            res.light = h;
            level = 0u;   // bounded by the light found (h)
        } else if (kind == TQ_LIGHTS) {
            res.light = h;
            break;
        } else {   // TQ_LIGHT_VISIBLE, TQ_LIGHT_SEEN
            res.light = h;
            if (kind == TQ_LIGHT_SEEN ? h.prim == NO_HIT : h.prim != NO_HIT && h.t < t_light) {
                res.blocked = true;
                break;
            }
            // A hit is taken when t < h.t: the next float up makes the bound inclusive.
            h = hit_none(h.prim != NO_HIT ? uintBitsToFloat(floatBitsToUint(h.t) + 1u) : tmax);
            level = 0u;
            any = true;
        }
    }
    if (any) res.blocked = res.blocked || h.prim != NO_HIT;
    res.h = h;
    return res;
}
#else
#error "define TRACE_RAY_QUERY or TRACE_SOFTWARE"
#endif

// trace_query_hinted without a hint.
TraceResult trace_query(uint kind, vec3 o, vec3 d, float tmin, float tmax, float t_light) {
    return trace_query_hinted(kind, o, d, tmin, tmax, t_light, trace_no_hint());
}

// The closest hit over both levels.
Hit trace(vec3 o, vec3 d, float tmin, float tmax) {
    return trace_query(TQ_CLOSEST, o, d, tmin, tmax, 0.0).h;
}

#endif
