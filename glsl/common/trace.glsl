// One intersection interface, two bodies chosen by a define at build time:
//   TRACE_RAY_QUERY  - VK_KHR_ray_query against a TLAS (binding 0) whose instances are
//                      the object and the view's second level (instance custom index =
//                      first triangle index of the level)
//   TRACE_SOFTWARE   - stack traversal of two flattened obvhs BVH2s, the object's
//                      (bindings 0, 1) and the second level's (bindings 2, 3), read
//                      as texel buffers
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
    float det;    // inside the software traversal: bary's common divisor, divided out
                  // once when the query returns (one division a hit, not two a
                  // triangle test); 1 outside it
};

// No hit yet, with tmax as the distance a hit must beat.
Hit hit_none(float tmax) {
    Hit h;
    h.t = tmax; h.prim = NO_HIT; h.bary = vec2(0.0); h.inst = 0u; h.det = 1.0;
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
const uint TQ_OBJECT = 6u;         // h: the closest hit on the object alone, where the
                                   // caller knows the ray meets no light (as TQ_CLOSEST
                                   // then; lights.glsl misses_lights); light: none
const uint TQ_CLOSEST_ESCAPE = 7u; // as TQ_CLOSEST where the ray meets the object; where
                                   // it does not, the software traversal leaves the
                                   // lights untraversed and says so in `blocked`: the
                                   // caller's TQ_LIGHTS query of the same ray later finds
                                   // the hit TQ_CLOSEST would have (the lights' closest,
                                   // from the same bounds). The ray query answers as
                                   // TQ_CLOSEST.
const uint TQ_LIGHT_CLOSEST_ESCAPE = 8u; // as TQ_LIGHT_CLOSEST where the ray meets the
                                   // object (the object first, then the lights
                                   // unbounded: the same light and hit); where it does
                                   // not, as TQ_CLOSEST_ESCAPE (`blocked`, lights
                                   // untraversed: with no object hit the first light is
                                   // also the closest hit, the caller's TQ_LIGHTS query
                                   // finds both). The ray query answers as
                                   // TQ_LIGHT_CLOSEST.

struct TraceResult {
    Hit h;
    Hit light;
    bool blocked;
};

// A closest-hit query's hint (TQ_CLOSEST): an object triangle (level 0; corners in
// original order, as the BVH's leaves hold them) the ray is likely to hit first, or
// prim NO_HIT. The software traversal tests it before the BVH, so it starts with that
// hit as its bound and skips what lies behind; the answer is the same (the closest hit,
// ties to the lower index, whatever the order). A shadow test's (TQ_LIGHT_VISIBLE): the
// sampled light triangle (level 1, corners in original order) where no other light
// triangle can hide it from the ray's origin, which then stands for the lights'
// traversal. The ray query ignores it.
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
// Whether the traversal takes hints and bundles (trace_query_hinted's hint,
// trace_bundle_init, trace_shadow_init): the ray query traverses in hardware, without.
const bool TRACE_TAKES_HINTS = false;
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

// A pixel's camera-ray bundle (the software traversal's; see there): the ray query
// traverses in hardware and takes none.
uint trace_bundle_size() { return 0u; }
bool trace_bundle_answered = false;
void trace_bundle_init(vec3 eye, vec3 right, vec3 up, vec3 fwd, float lens, float zf, vec4 q,
                       vec3 plane_p, vec3 plane_n) {}
// Nor a shadow bundle.
bool trace_bundle_footprint(out vec3 lo, out vec3 hi) { lo = hi = vec3(0.0); return false; }
bool trace_shadow_built() { return false; }
bool trace_shadow_answered = false;
void trace_shadow_init(vec3 olo, vec3 ohi, vec3 llo, vec3 lhi) {}

// The query `kind` (TQ_*) of ray o + t d, t in [tmin, tmax]. The view's lights are the
// instances of mask 0x02 (src/trace/mod.rs), the object's 0x01. A shadow test: the
// lights' closest hit first, then a query of the object that ends at its first hit up
// to there.
TraceResult trace_query_hinted(uint kind, vec3 o, vec3 d, float tmin, float tmax, float t_light,
                              TraceHint hint) {
    TraceResult res;
    res.blocked = false;
    res.light = hit_none(3.0e38);
    bool one = kind == TQ_CLOSEST || kind == TQ_CLOSEST_ESCAPE || kind == TQ_BLOCKED
        || kind == TQ_OBJECT;
    uint mask = kind == TQ_OBJECT ? 0x01u : one ? 0xffu : 0x02u;
    bool any = kind == TQ_BLOCKED;
    float bound = tmax;
    Hit h;
    for (uint step = 0u; step < 2u; step++) {
        h = trace_masked(o, d, tmin, bound, mask, any);
        if (one || step == 1u) break;
        res.light = h;
        if (kind == TQ_LIGHTS) break;
        if (kind == TQ_LIGHT_CLOSEST || kind == TQ_LIGHT_CLOSEST_ESCAPE) {
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
#define TRACE_BINDING_COUNT 4
const bool TRACE_TAKES_HINTS = true;
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
// Bindings 0-3: the object's nodes and triangles and the second level's, in that order
// (src/trace/mod.rs), read as texel buffers of 16-byte texels (usamplerBuffer,
// R32G32B32A32_UINT views): lavapipe (Mesa 25.0) fetches a texel with one 16-byte load a
// lane, without a branch, where a load through a device address is one masked gather
// per 8-byte word (on CPUs without fast gathers, such as AMD Zen 3, a branch, a scalar
// load and an insert per lane and word), and a storage buffer at a per-lane offset one
// lane and one word at a time behind a bounds branch: 0.83 of the path tracing's time
// with Mitsuba's sampling on a Zen 3 machine, 0.94 on the paper job's crops
// (docs/benchmarks/rendering.md, "The BVH read as texel buffers").
#extension GL_EXT_control_flow_attributes : require
layout(set = 0, binding = 0) uniform usamplerBuffer trace_nodes0;
layout(set = 0, binding = 1) uniform usamplerBuffer trace_tris0;
layout(set = 0, binding = 2) uniform usamplerBuffer trace_nodes1;
layout(set = 0, binding = 3) uniform usamplerBuffer trace_tris1;
// The wide traversal's stack entries are 64-bit words; the device needs shaderInt64
// (checked by trace::resolve).
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require

// Slab test; the far distance is widened by 3 ulps-worth (Ize 2013) so rounding never
// drops a box that the ray grazes. The minima and maxima are selects, not min() and
// max(): no value here is NaN (inv_d is finite, trace_prepare), and lavapipe compiles a
// select of a comparison to one vminps or vmaxps where GLSL's min and max also carry
// NaN handling (a compare and a blend each); the same values either way.
bool trace_box(vec3 bmin, vec3 bmax, vec3 o, vec3 inv_d, float tmin, float tmax, out float tnear) {
    vec3 t0 = (bmin - o) * inv_d;
    vec3 t1 = (bmax - o) * inv_d;
    bvec3 lt = lessThan(t0, t1);
    vec3 lo = mix(t1, t0, lt);
    vec3 hi = mix(t0, t1, lt);
    float n0 = lo.x > lo.y ? lo.x : lo.y;
    float n1 = lo.z > tmin ? lo.z : tmin;
    tnear = n0 > n1 ? n0 : n1;
    float f0 = hi.x < hi.y ? hi.x : hi.y;
    float f1 = hi.z < tmax ? hi.z : tmax;
    float tfar = (f0 < f1 ? f0 : f1) * 1.0000004;
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

// A pixel's camera rays as one bundle (trace_bundle_init): every ray leaves the lens's
// aperture (a disc of radius `lens` about the eye, in the plane of the right and up
// axes) through the pixel's footprint on the plane of focus (depth zf along the forward
// axis). Such a bundle lies, up to the plane of focus, inside four planes from the
// lens's bounding square to the footprint's bounding box, and beyond it inside four
// more (it narrows to the footprint, then widens again). One traversal per pixel
// collects the object's triangles whose leaf boxes meet the bundle up to a depth zfar
// (at most TRACE_BUNDLE_MAX of them; more: no bundle); a camera ray of the pixel then
// tests those alone, and where the closest of them lies no deeper than zfar it is the
// ray's closest hit on the object (a nearer triangle would meet the bundle nearer than
// zfar, so its leaf would have been collected): the same hit as the traversal's, ties
// included (trace_tri_test). Rays whose hit among them lies deeper, or none, traverse
// the object bounded by it. zfar: the deepest point where a ray of the bundle meets the
// plane of the pixel centre's triangle. Every test is widened by TRACE_BUNDLE_SLACK so
// that rounding only ever keeps a box.
#define TRACE_BUNDLE_MAX 16u
#define TRACE_SHADOW_MAX 16u              // the shadow bundle's (trace_shadow_init)
const float TRACE_BUNDLE_SLACK = 1e-3;   // scene units (mm)
// Both bundles' triangle lists in one store (level-0 triangles, BVH leaf order): list
// TRACE_LIST_CAMERA first (at most TRACE_BUNDLE_MAX), TRACE_LIST_SHADOW after it (at most
// TRACE_SHADOW_MAX); trace_list_n: how many in each (each invocation starts with none;
// the camera's 0: no bundle).
const uint TRACE_LIST_CAMERA = 0u;
const uint TRACE_LIST_SHADOW = 1u;
uint trace_list_tri[TRACE_BUNDLE_MAX + TRACE_SHADOW_MAX];
uint trace_list_n[2] = uint[2](0u, 0u);
vec4 trace_bundle_plane[8];               // n.p + w >= 0: 0-3 up to the plane of focus, 4-7 beyond
vec4 trace_bundle_axis;                   // xyz: unit forward; w: -dot(forward, eye): depth = dot(xyz, p) + w
float trace_bundle_zf;
float trace_bundle_zfar;

// Whether the last camera-ray query took its object hit from the bundle (tests).
bool trace_bundle_answered = false;

uint trace_bundle_size() { return trace_list_n[TRACE_LIST_CAMERA]; }

// Whether box [bmin, bmax] may meet the bundle no deeper than zfar (conservative).
bool trace_bundle_box(vec3 bmin, vec3 bmax) {
    vec3 c = 0.5 * (bmin + bmax);
    vec3 e = 0.5 * (bmax - bmin);
    float zc = dot(trace_bundle_axis.xyz, c) + trace_bundle_axis.w;
    float ze = dot(abs(trace_bundle_axis.xyz), e);
    float s = TRACE_BUNDLE_SLACK;
    bool near = zc + ze >= -s && zc - ze <= min(trace_bundle_zf, trace_bundle_zfar) + s;
    bool far = zc + ze >= trace_bundle_zf - s && zc - ze <= trace_bundle_zfar + s;
    [[unroll]] for (uint k = 0u; k < 4u; k++) {
        vec4 pn = trace_bundle_plane[k];
        vec4 pf = trace_bundle_plane[k + 4u];
        near = near && dot(pn.xyz, c) + dot(abs(pn.xyz), e) + pn.w >= -s;
        far = far && dot(pf.xyz, c) + dot(abs(pf.xyz), e) + pf.w >= -s;
    }
    return near || far;
}

// Where list `list` starts in the store.
uint trace_list_base(uint list) { return list == TRACE_LIST_CAMERA ? 0u : TRACE_BUNDLE_MAX; }

// Adds `count` consecutive level-0 triangles from `first` to list `list`; false once it
// would overflow (the bundle is then dropped).
bool trace_list_add(uint list, uint first, uint count) {
    uint cap = list == TRACE_LIST_CAMERA ? TRACE_BUNDLE_MAX : TRACE_SHADOW_MAX;
    uint n = trace_list_n[list];
    if (n + count > cap) return false;
    for (uint k = 0u; k < count; k++) trace_list_tri[trace_list_base(list) + n + k] = first + k;
    trace_list_n[list] = n + count;
    return true;
}

// A pixel's shadow rays as one bundle (trace_shadow_init): rays from an origin box (where
// the pixel's camera rays meet the plane of its centre ray's triangle, offset off the
// surface) whose segments end in a light box (the lights' bounds). Every such segment
// lies in the convex hull of the two boxes: one traversal per pixel collects the
// object's triangles whose leaf boxes meet that hull (at most TRACE_SHADOW_MAX; more:
// none), and an occlusion test of the object (a shadow ray's, the query's step with
// `any`) whose origin lies in the origin box and whose segment ends in the light box
// tests those alone: a triangle that blocks the segment meets the hull, so it was
// collected, and the answer is the traversal's. The hull test is widened by
// TRACE_BUNDLE_SLACK, as the camera rays' bundle.
bool trace_shadow_on = false;             // built (the list may be empty: nothing blocks)
vec3 trace_shadow_olo, trace_shadow_ohi;  // the origin box
vec3 trace_shadow_llo, trace_shadow_lhi;  // the light box
// Whether the last occlusion query of the object took its answer from the shadow
// bundle (tests).
bool trace_shadow_answered = false;

bool trace_shadow_built() { return trace_shadow_on; }

// Whether box [bmin, bmax] may meet the hull of the origin and light boxes (conservative).
// The hull is the union over s in [0, 1] of the boxes (1 - s) O + s L, so a box meets it
// where one s puts that box over it on every axis: per axis and bound, a s <= c, an
// interval of s; their intersection with [0, 1] not empty.
bool trace_shadow_box(vec3 bmin, vec3 bmax) {
    float e = TRACE_BUNDLE_SLACK;
    vec3 o0 = trace_shadow_olo - e, o1 = trace_shadow_ohi + e;
    vec3 l0 = trace_shadow_llo - e, l1 = trace_shadow_lhi + e;
    float lo = 0.0, hi = 1.0;
    bool ok = true;
    // (1 - s) o0 + s l0 <= bmax + e and (1 - s) o1 + s l1 >= bmin - e.
    [[unroll]] for (uint k = 0u; k < 2u; k++) {
        vec3 a = k == 0u ? l0 - o0 : o1 - l1;
        vec3 c = k == 0u ? bmax + e - o0 : o1 - bmin + e;
        [[unroll]] for (uint i = 0u; i < 3u; i++) {
            float q = c[i] / a[i];
            // min and max as selects (see trace_box): the same bounds.
            hi = a[i] > 0.0 && q < hi ? q : hi;
            lo = a[i] < 0.0 && q > lo ? q : lo;
            ok = ok && (a[i] != 0.0 || c[i] >= 0.0);
        }
    }
    return ok && lo <= hi;
}

// Whether box [bmin, bmax] may meet list `list`'s bundle (trace_bundle_collect).
bool trace_list_box(uint list, vec3 bmin, vec3 bmax) {
    return list == TRACE_LIST_CAMERA ? trace_bundle_box(bmin, bmax) : trace_shadow_box(bmin, bmax);
}

// Whether the object's occlusion test of ray o + t d, t up to tmax, may take its answer
// from the shadow bundle: built, o in the origin box and the segment's end in the light
// box.
bool trace_shadow_covers(vec3 o, vec3 d, float tmax) {
    vec3 e = o + tmax * d;
    return trace_shadow_on
        && all(greaterThanEqual(o, trace_shadow_olo)) && all(lessThanEqual(o, trace_shadow_ohi))
        && all(greaterThanEqual(e, trace_shadow_llo)) && all(lessThanEqual(e, trace_shadow_lhi));
}

#include "trace_bvh.glsl"

// Tests list `list`'s triangles against ray tr, taking each hit into h (trace_tri_test).
void trace_list_test(uint list, TraceRay tr, float tmin, inout Hit h) {
    for (uint k = 0u; k < trace_list_n[list]; k++) {
        BvhTri t = trace_tri(0u, trace_list_tri[trace_list_base(list) + k]);
        trace_tri_test(t.v0.xyz, t.v1.xyz, t.v2.xyz, floatBitsToUint(t.v0.w), 0u, tr, tmin, h);
    }
}

// Sets the pixel's shadow bundle (above) from its origin box and light box (min and max
// corners); none where more than TRACE_SHADOW_MAX triangles meet their hull.
void trace_shadow_init(vec3 olo, vec3 ohi, vec3 llo, vec3 lhi) {
    trace_list_n[TRACE_LIST_SHADOW] = 0u;
    trace_shadow_olo = olo;
    trace_shadow_ohi = ohi;
    trace_shadow_llo = llo;
    trace_shadow_lhi = lhi;
    trace_shadow_on = trace_bundle_collect(TRACE_LIST_SHADOW);
}

// The bounding box of the points where the last trace_bundle_init's rays meet the plane
// it was given (the pixel's camera rays' footprint on it); false where it made no bundle
// because a ray of it could meet that plane behind the lens or along it.
vec3 trace_foot_lo, trace_foot_hi;
bool trace_foot_ok = false;
bool trace_bundle_footprint(out vec3 lo, out vec3 hi) {
    lo = trace_foot_lo;
    hi = trace_foot_hi;
    return trace_foot_ok;
}

// Sets the pixel's bundle (above): eye, unit right, up and forward axes, the aperture's
// radius `lens` (0: a pinhole) and the depth of the plane of focus zf (any positive
// depth for a pinhole), the footprint's bounding box on it in the right and up
// coordinates (q: x0, x1, y0, y1), and the plane of the pixel centre's triangle (a point
// and a normal of any length). No bundle (trace_bundle_size() 0) where a ray of the bundle
// could meet that plane behind the lens or along it, or too many triangles meet it.
void trace_bundle_init(vec3 eye, vec3 right, vec3 up, vec3 fwd, float lens, float zf, vec4 q,
                       vec3 plane_p, vec3 plane_n) {
    trace_list_n[TRACE_LIST_CAMERA] = 0u;
    // The deepest point of the plane on a ray from a corner of the lens's square to a
    // corner of the footprint's box: where a ray's depth on the plane is largest
    // (a ratio of functions linear in each end point takes its extremes at corners).
    float zfar = 0.0;
    bool ok = true;
    float dir_sign = 0.0;
    // Where those rays meet the plane: a ray from any point of the lens's square through
    // any of the footprint's box meets it in the hull of the sixteen (for a fixed end,
    // the map from the other end to the plane is projective, and the plane lies ahead
    // of every ray: convex sets stay convex).
    trace_foot_lo = vec3(3.0e38);
    trace_foot_hi = vec3(-3.0e38);
    for (uint k = 0u; k < 16u; k++) {
        vec2 l = vec2((k & 1u) != 0u ? lens : -lens, (k & 2u) != 0u ? lens : -lens);
        vec2 f = vec2((k & 4u) != 0u ? q.y : q.x, (k & 8u) != 0u ? q.w : q.z);
        vec3 from = eye + l.x * right + l.y * up;
        vec3 to = eye + f.x * right + f.y * up + zf * fwd;
        float den = dot(plane_n, to - from);
        float s = dot(plane_n, plane_p - from) / den;
        float sg = sign(den);
        ok = ok && sg != 0.0 && (k == 0u || sg == dir_sign) && s > 0.0;
        dir_sign = sg;
        zfar = max(zfar, s * zf);
        vec3 at = from + s * (to - from);
        trace_foot_lo = min(trace_foot_lo, at);
        trace_foot_hi = max(trace_foot_hi, at);
    }
    trace_foot_ok = ok;
    if (!ok) return;
    trace_bundle_zf = zf;
    trace_bundle_zfar = zfar * 1.00001;
    trace_bundle_axis = vec4(fwd, -dot(fwd, eye));
    // x >= m + k z and x <= m' + k' z in the right / up coordinates x, depth z: from the
    // lens's edge (+-lens at depth 0) to the footprint's (at zf), and beyond zf from the
    // opposite edge of the lens.
    for (uint a = 0u; a < 2u; a++) {
        vec3 ax = a == 0u ? right : up;
        float lo = a == 0u ? q.x : q.z;
        float hi = a == 0u ? q.y : q.w;
        for (uint part = 0u; part < 2u; part++) {
            float m = part == 0u ? lens : -lens;   // the lens edge's side, up to zf / beyond
            // lower bound: x - k z + m >= 0, k = (lo + m) / zf
            vec3 n0 = ax - ((lo + m) / zf) * fwd;
            trace_bundle_plane[part * 4u + a * 2u] = vec4(n0, -dot(n0, eye) + m);
            // upper bound: -x + k' z + m >= 0, k' = (hi - m) / zf
            vec3 n1 = -ax + ((hi - m) / zf) * fwd;
            trace_bundle_plane[part * 4u + a * 2u + 1u] = vec4(n1, -dot(n1, eye) + m);
        }
    }
    if (!trace_bundle_collect(TRACE_LIST_CAMERA)) trace_list_n[TRACE_LIST_CAMERA] = 0u;
}

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
    bool closest = kind == TQ_CLOSEST || kind == TQ_CLOSEST_ESCAPE
        || kind == TQ_LIGHT_CLOSEST_ESCAPE;
    bool escape = kind == TQ_CLOSEST_ESCAPE || kind == TQ_LIGHT_CLOSEST_ESCAPE;
    Hit h_object;   // TQ_LIGHT_CLOSEST_ESCAPE: the object's closest hit (step 0)
    uint level = closest || kind == TQ_BLOCKED || kind == TQ_OBJECT ? 0u : 1u;
    bool any = kind == TQ_BLOCKED;
    Hit h = hit_none(tmax);
    // A camera ray of the bundle's pixel (the hint's): its closest hit on the object
    // among the bundle's triangles, taken without the object's traversal where it lies
    // no deeper than the bundle reaches.
    bool skip_first = false;   // the first level's traversal answered without it
    if ((closest || kind == TQ_OBJECT) && hint.prim != NO_HIT) {
        if (trace_bundle_size() > 0u) {
            trace_list_test(TRACE_LIST_CAMERA, tr, tmin, h);
            float depth = dot(trace_bundle_axis.xyz, o) + trace_bundle_axis.w
                + h.t * dot(trace_bundle_axis.xyz, d);
            skip_first = h.prim != NO_HIT && depth <= trace_bundle_zfar;
            trace_bundle_answered = skip_first;
        } else {
            trace_tri_test(hint.a, hint.b, hint.c, hint.prim, 0u, tr, tmin, h);
        }
    }
    // A shadow test toward a light triangle no other can hide from the ray's origin (the
    // hint's; src/scene/light_cover.rs): the lights' closest hit is that triangle's,
    // found by testing it alone; where the test misses it (rounding at its edges) or
    // meets it nearer than t_light, the lights' traversal as always.
    if (kind == TQ_LIGHT_VISIBLE && hint.prim != NO_HIT) {
        trace_tri_test(hint.a, hint.b, hint.c, hint.prim, 1u, tr, tmin, h);
        skip_first = h.prim != NO_HIT && h.t >= t_light;
        if (!skip_first) h = hit_none(tmax);
    }
    trace_shadow_answered = false;
    for (uint step = 0u; step < 2u; step++) {
        // The object's occlusion test inside the pixel's shadow bundle: its list.
        bool listed = any && level == 0u && trace_shadow_covers(o, d, h.t);
        if (listed) {
            trace_list_test(TRACE_LIST_SHADOW, tr, tmin, h);
            trace_shadow_answered = true;
        } else if (!(step == 0u && skip_first)) {
            trace_bvh(level, o, inv_d, tr, tmin, h, any);
        }
        if (step == 1u || kind == TQ_OBJECT) break;
        if (closest) {
            // No object hit: the lights' part left to the caller (TQ_CLOSEST_ESCAPE,
            // TQ_LIGHT_CLOSEST_ESCAPE).
            if (escape && h.prim == NO_HIT) {
                res.blocked = true;
                break;
            }
            // TQ_LIGHT_CLOSEST_ESCAPE: the lights unbounded (the first light, occluders
            // ignored), compared with the object's hit after the loop.
            h_object = h;
            if (kind == TQ_LIGHT_CLOSEST_ESCAPE) h = hit_none(tmax);
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
    // The closest hit of TQ_LIGHT_CLOSEST_ESCAPE: the light's where it is nearer than the
    // object's (at equal distance the object's, whose index is lower: what TQ_LIGHT_CLOSEST's
    // object traversal bounded by the light's hit keeps).
    if (kind == TQ_LIGHT_CLOSEST_ESCAPE && !res.blocked) {
        res.light = h;
        if (!(h.prim != NO_HIT && h.t < h_object.t)) h = h_object;
    }
    res.h = hit_finish(h);
    res.light = hit_finish(res.light);
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
