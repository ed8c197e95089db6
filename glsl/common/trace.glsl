// One intersection interface, two bodies chosen by a define at build time:
//   TRACE_RAY_QUERY  - VK_KHR_ray_query against a TLAS (binding 0) whose instances are
//                      the object and the view's second level (instance custom index =
//                      first triangle index of the level)
//   TRACE_SOFTWARE   - stack traversal of two flattened obvhs BVH2s, the object's
//                      (bindings 0, 1) and the second level's (bindings 2, 3)
//   TRACE_SOFTWARE_WIDE - the same with compressed wide BVHs (obvhs CWBVH, eight
//                      children a node, src/trace/software_bvh.rs)
// Both return the closest hit over both levels, triangles numbered in one index space.
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

#if defined(TRACE_RAY_QUERY)
#extension GL_EXT_ray_query : require
#define TRACE_BINDING_COUNT 1
layout(set = 0, binding = 0) uniform accelerationStructureEXT trace_tlas;

// The closest hit among the instances whose mask meets `mask`.
Hit trace_masked(vec3 o, vec3 d, float tmin, float tmax, uint mask) {
    Hit h = hit_none(tmax);
    rayQueryEXT rq;
    rayQueryInitializeEXT(rq, trace_tlas, gl_RayFlagsOpaqueEXT, mask, o, tmin, d, tmax);
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

Hit trace(vec3 o, vec3 d, float tmin, float tmax) { return trace_masked(o, d, tmin, tmax, 0xffu); }

// The closest hit among the view's lights alone (the second level; instance mask 0x02,
// src/trace/mod.rs), occluders ignored.
Hit trace_lights(vec3 o, vec3 d) { return trace_masked(o, d, 0.0, 3.0e38, 0x02u); }

// Whether any triangle of the instances whose mask meets `mask` lies on the ray within
// [0, tmax]: the query ends at its first hit.
bool trace_any_masked(vec3 o, vec3 d, float tmax, uint mask) {
    rayQueryEXT rq;
    rayQueryInitializeEXT(rq, trace_tlas, gl_RayFlagsOpaqueEXT | gl_RayFlagsTerminateOnFirstHitEXT,
                          mask, o, 0.0, d, tmax);
    while (rayQueryProceedEXT(rq)) {}
    return rayQueryGetIntersectionTypeEXT(rq, true) == gl_RayQueryCommittedIntersectionTriangleEXT;
}

// trace_light_visible (below), with the ray query: the lights' closest hit, then an
// occlusion query against the object (mask 0x01) up to it.
bool trace_light_visible(vec3 o, vec3 d, float tmax, float t_light) {
    Hit l = trace_masked(o, d, 0.0, tmax, 0x02u);
    if (l.prim != NO_HIT && l.t < t_light) return false;
    return !trace_any_masked(o, d, l.prim != NO_HIT ? l.t : tmax, 0x01u);
}

// Whether any triangle, object or light, lies on the ray within [0, tmax].
bool trace_blocked(vec3 o, vec3 d, float tmax) { return trace_any_masked(o, d, tmax, 0xffu); }

#elif defined(TRACE_SOFTWARE)
#define TRACE_BINDING_COUNT 4
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
layout(std430, set = 0, binding = 0) readonly buffer TraceNodes { TRACE_NODE trace_nodes[]; };
layout(std430, set = 0, binding = 1) readonly buffer TraceTris { BvhTri trace_tris[]; };
layout(std430, set = 0, binding = 2) readonly buffer TraceNodes2 { TRACE_NODE trace_nodes2[]; };
layout(std430, set = 0, binding = 3) readonly buffer TraceTris2 { BvhTri trace_tris2[]; };

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


#define TRACE_NODES trace_nodes
#define TRACE_TRIS trace_tris
#define TRACE_LEAF trace_leaf_0
#define TRACE_BVH trace_bvh_0
#define TRACE_INST 0u
#include "trace_bvh.glsl"
#undef TRACE_NODES
#undef TRACE_TRIS
#undef TRACE_LEAF
#undef TRACE_BVH
#undef TRACE_INST
#define TRACE_NODES trace_nodes2
#define TRACE_TRIS trace_tris2
#define TRACE_LEAF trace_leaf_1
#define TRACE_BVH trace_bvh_1
#define TRACE_INST 1u
#include "trace_bvh.glsl"

// The traversal's view of ray (o, d): reciprocal direction for the slab tests (zero
// components nudged: 0 * inf would give NaN) and the watertight test's shear.
void trace_prepare(vec3 o, vec3 d, out vec3 inv_d, out TraceRay tr) {
    vec3 dd = mix(d, sign(d) * 1e-30 + vec3(equal(d, vec3(0.0))) * 1e-30, lessThan(abs(d), vec3(1e-30)));
    inv_d = 1.0 / dd;
    tr = trace_setup(o, d);
}

Hit trace(vec3 o, vec3 d, float tmin, float tmax) {
    Hit h = hit_none(tmax);
    vec3 inv_d;
    TraceRay tr;
    trace_prepare(o, d, inv_d, tr);
    trace_bvh_0(o, inv_d, tr, tmin, h, false);
    trace_bvh_1(o, inv_d, tr, tmin, h, false);
    return h;
}

// The closest hit among the view's lights alone (the second level), occluders ignored.
Hit trace_lights(vec3 o, vec3 d) {
    Hit h = hit_none(3.0e38);
    vec3 inv_d;
    TraceRay tr;
    trace_prepare(o, d, inv_d, tr);
    trace_bvh_1(o, inv_d, tr, 0.0, h, false);
    return h;
}

// Whether the closest hit of trace(o, d, 0, tmax) would be nothing, or a light triangle
// at t_light or farther: a light sample's shadow test, exactly as that closest hit
// decides it, without finding the closest occluder. The lights' closest hit first (the
// small second level); then the object traversal stops at its first hit up to there
// (inclusive: an object triangle wins a tie, its index is lower), or up to tmax
// (exclusive, as trace's) without one.
bool trace_light_visible(vec3 o, vec3 d, float tmax, float t_light) {
    vec3 inv_d;
    TraceRay tr;
    trace_prepare(o, d, inv_d, tr);
    Hit l = hit_none(tmax);
    trace_bvh_1(o, inv_d, tr, 0.0, l, false);
    if (l.prim != NO_HIT && l.t < t_light) return false;
    // A hit is taken when t < h.t: the next float up makes the bound inclusive.
    Hit h = hit_none(l.prim != NO_HIT ? uintBitsToFloat(floatBitsToUint(l.t) + 1u) : tmax);
    trace_bvh_0(o, inv_d, tr, 0.0, h, true);
    return h.prim == NO_HIT;
}

// Whether trace(o, d, 0, tmax) would hit anything (object or light): stops at the first
// hit found.
bool trace_blocked(vec3 o, vec3 d, float tmax) {
    vec3 inv_d;
    TraceRay tr;
    trace_prepare(o, d, inv_d, tr);
    Hit h = hit_none(tmax);
    trace_bvh_0(o, inv_d, tr, 0.0, h, true);
    if (h.prim == NO_HIT) trace_bvh_1(o, inv_d, tr, 0.0, h, true);
    return h.prim != NO_HIT;
}
#else
#error "define TRACE_RAY_QUERY or TRACE_SOFTWARE"
#endif

#endif
