// The scene's lights for path_trace.comp (docs/rendering.md, "Lights"). Included after
// the Params block, the Lights, LightGeometry and LightWeights addresses and fetch_tri /
// tri_normal.
//
// `EMITTERS[e]` (LightBlock, src/gpu_interface.in) describes light e: its triangles
// (shape.x: first light triangle, counted from prm.light_first; shape.y: how many),
// shape.z its sampling (LIGHT_UNIFORM: by area; LIGHT_FACING: ring segments, shape.w of
// them; LIGHT_SPOT: a point light, no triangles), emit.x its radiance (area light) or
// intensity times 1e6 mm^2/m^2 (spot), emit.y its area (mm^2), emit.w the inclusive CDF
// of choosing it (by power); pos / dir the spot's position and axis, w: cos of the cone
// edge and of the inner edge of the soft falloff. `LIGHT_TRI_WORDS[k]`: emitter of light
// triangle k (x), the inclusive area CDF of k within its emitter (y, float bits), and
// the guide table's entry of the emitter's bucket k - shape.x (zw: pick_area_tri).

// (LightList, a storage buffer: path_trace.comp.) Read only at a lane-uniform index:
// lavapipe then loads each word once for all lanes, where a per-lane index costs a
// branch and a load per lane and word (docs/architecture.md). A lane's own light, at a
// per-lane index, comes from emitter_block; loops over the lights keep their index
// uniform (no per-lane `continue`, `break` or `return` inside them).
#define EMITTERS pt_emitters

// Light ei's block, for an index that may differ between lanes: every block is read at
// a uniform index and the lane's kept (one light: one read, no loop).
LightBlock emitter_block(uint ei) {
    LightBlock b = EMITTERS[0];
    for (uint k = 1u; k < uint(EMITTERS.length()); k++) {
        LightBlock c = EMITTERS[k];
        if (k == ei) b = c;
    }
    return b;
}

// Probability of choosing emitter e.
float emitter_pdf(uint e) {
    float lo = 0.0, hi = EMITTERS[0].emit.w;
    for (uint k = 1u; k < uint(EMITTERS.length()); k++) {
        float below = EMITTERS[k - 1u].emit.w, w = EMITTERS[k].emit.w;
        if (k == e) { lo = below; hi = w; }
    }
    return hi - lo;
}

// Chooses an emitter with u in [0, 1) by the CDF and rescales u to [0, 1) within the
// chosen interval (one light: u unchanged): the first emitter whose inclusive CDF
// exceeds u, else the last (the CDF does not decrease).
uint choose_emitter(inout float u) {
    uint e = 0u;
    float lo = 0.0, hi = EMITTERS[0].emit.w;
    bool found = false;
    for (uint k = 0u; k + 1u < PRM_EMITTER_COUNT; k++) {
        float w = EMITTERS[k].emit.w, next = EMITTERS[k + 1u].emit.w;
        found = found || u < w;
        if (!found) { e = k + 1u; lo = w; hi = next; }
    }
    float p = hi - lo;
    if (p > 0.0) u = clamp((u - lo) / p, 0.0, 0.99999994);
    return e;
}

// Whether ray o + t d (t >= 0) meets no light triangle, decided without a trace
// (conservative: false where unsure). A spot has none; any other light's lie in the
// sphere of radius reach.y about pos (widened here by a part in 10^4 and 10^-3 mm for
// f32); a ring's also outside its hole and inside its slab (reach.z, reach.w:
// src/scene/light_cover.rs `ring_room`), so a ray that meets its slab only inside the
// hole misses it (the squared distance from the axis along the ray is convex: its
// largest at the slab's faces). Rays within a twentieth of parallel to a ring's plane
// are not decided. Dark lights (no emitter counted) still block rays: not decided.
// Never with `[render] light_shortcuts = false` (PathParams::shortcuts 0).
// misses_lights for one light b (dd = dot(d, d)).
bool light_missed(LightBlock b, vec3 o, vec3 d, float dd) {
    if (b.reach.y < 0.0) return true;   // a spot: nothing to hit
    vec3 p = o - b.pos.xyz;
    float r = b.reach.y * 1.0001 + 1e-3;
    float pd = dot(p, d);
    float c = dot(p, p) - r * r;
    if (c > 0.0 && (pd >= 0.0 || pd * pd < dd * c)) return true;   // the sphere missed
    if (b.reach.w <= 0.0) return false;   // not a ring: met for all we know
    vec3 a = b.dir.xyz;
    float z0 = dot(p, a);
    float dz = dot(d, a);
    if (abs(dz) < 0.05 * sqrt(dd)) return false;
    float t1 = (-b.reach.w - z0) / dz;
    float t2 = (b.reach.w - z0) / dz;
    float thi = max(t1, t2);
    if (thi < 0.0) return true;   // the slab behind the ray
    vec3 q1 = p + max(min(t1, t2), 0.0) * d;
    vec3 q2 = p + thi * d;
    vec3 r1 = q1 - dot(q1, a) * a;
    vec3 r2 = q2 - dot(q2, a) * a;
    float h2 = b.reach.z * b.reach.z;
    if (dot(r1, r1) < h2 && dot(r2, r2) < h2) return true;   // through the hole only
    // Around the ring only: the slab crossed outside the cylinder of the sphere's radius
    // (no point of the light is farther from the axis than from the centre), where the
    // crossing's nearest approach to the axis (its projection on the plane, a segment)
    // stays outside it.
    vec3 e = r2 - r1;
    float ee = dot(e, e);
    float tc = ee > 0.0 ? clamp(-dot(r1, e) / ee, 0.0, 1.0) : 0.0;
    vec3 rc = r1 + tc * e;
    return dot(rc, rc) > r * r;
}

bool misses_lights(vec3 o, vec3 d) {
    if (PRM_SHORTCUTS == 0u) return false;   // [render] light_shortcuts = false
    if (PRM_LIGHT_COUNT == 0u) return true;
    if (PRM_EMITTER_COUNT == 0u) return false;
    float dd = dot(d, d);
    bool missed = true;
    for (uint e = 0u; e < PRM_EMITTER_COUNT; e++) {
        bool m = light_missed(EMITTERS[e], o, d, dd);
        missed = missed && m;
    }
    return missed;
}

// The light cover's grid cell that point x lies in, as the bit of a light triangle's
// mask (LightTri::cover.x, src/scene/light_cover.rs), or NO_COVER_CELL outside the grid
// (where no mask marks it and no hider list, LightTri::cover.yz, holds).
const uint NO_COVER_CELL = 0xffffffffu;
uint light_cover_cell(vec3 x) {
    vec3 c = (x - prm.cover_lo.xyz) / prm.cover_cell.xyz;
    float side = float(LIGHT_COVER_SIDE);
    if (!all(greaterThanEqual(c, vec3(0.0))) || !all(lessThan(c, vec3(side)))) return NO_COVER_CELL;
    uvec3 ci = f2u(c);
    return ci.x + LIGHT_COVER_SIDE * (ci.y + LIGHT_COVER_SIDE * ci.z);
}

// Whether no other light triangle can hide the light triangle whose cover mask is
// `mask` from the points of grid cell `cell` (light_cover_cell; outside the grid: no).
bool light_unhidden(uint mask, uint cell) {
    return cell != NO_COVER_CELL && ((mask >> cell) & 1u) != 0u;
}

// Emitter of scene triangle `tri` (a light triangle).
uint emitter_of(uint tri) { return LIGHT_TRI_WORDS[tri - prm.light_first].x; }

// Radiance of light triangle `tri`.
float tri_radiance(uint tri) { return emitter_block(emitter_of(tri)).emit.x; }

// A triangle of area light e by area, from its CDF: the first whose inclusive CDF
// exceeds u, else the last. Searched within the range the guide table gives for u's
// bucket (one of shape.y equal parts of [0, 1), bucket j's entry in the zw of light
// triangle shape.x + j; src/render/view.rs `area_guide`): the same triangle as a search
// of all of them, in a step or two instead of log2(shape.y).
uint pick_area_tri(LightBlock e, float u) {
    uint lo = e.shape.x, hi = e.shape.x + e.shape.y - 1u;
    if (e.shape.y > 0u) {
        uvec2 range = LIGHT_TRI_WORDS[e.shape.x + min(f2u(u * float(e.shape.y)), e.shape.y - 1u)].zw;
        lo = e.shape.x + range.x;
        hi = e.shape.x + range.y;
    }
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (u < uintBitsToFloat(LIGHT_TRI_WORDS[mid].y)) hi = mid; else lo = mid + 1u;
    }
    return prm.light_first + lo;
}

// Facing sampling: selection weight of one light triangle seen from x (normal n), an
// estimate of its contribution from the centroid: area cos_l cos_x / d^2, each cosine
// floored at 0.05 so every triangle keeps a non-zero probability (unbiased even where
// the centroid faces away but part of the triangle does not).
// The triangle's centroid, area and unit normal come made per view (LightTri: 7 words
// read where its corners are 9, no cross product or square root per weight; the same
// weights to float rounding, docs/benchmarks/rendering.md, "The path tracer's buffers
// through device addresses").
float light_weight(uint tri, vec3 x, vec3 n) {
    LightTri lt = LIGHT_TRI_WEIGHTS[tri - prm.light_first];
    vec3 to = lt.center.xyz - x;
    float d2 = max(dot(to, to), 1e-12);
    vec3 w = to * inversesqrt(d2);
    float cl = max(-dot(lt.normal.xyz, w), 0.0) + 0.05;
    float cx = max(dot(n, w), 0.0) + 0.05;
    return lt.center.w * cl * cx / d2;
}

// Sum of the weights of one ring segment's triangles (segment_tris each, from `base`).
float segment_weight(uint base, uint segment_tris, vec3 x, vec3 n) {
    float sum = 0.0;
    for (uint k = 0u; k < segment_tris; k++) sum += light_weight(base + k, x, n);
    return sum;
}

// The last facing segment sum light_area_pdf took (segment_weight of the segment whose
// first triangle is `base`, from x with normal n): the BSDF directions of one shading
// point (the path's own and those of `[render] bsdf_samples`, each asked for its MIS
// weight once for the estimate and once for the control variate) mostly meet one ring
// segment under a narrow lobe, so one sum of its 32 weights serves them all. The same
// function of the same numbers: the same pdf bit for bit. seg_memo_clear empties it.
struct SegmentMemo {
    uint base;   // first triangle of the segment; NO_SEGMENT: empty
    vec3 x;
    vec3 n;
    float wsum;
};
const uint NO_SEGMENT = 0xffffffffu;
SegmentMemo seg_memo;

void seg_memo_clear() { seg_memo.base = NO_SEGMENT; }

// segment_weight through the memo.
float segment_weight_memo(uint base, uint segment_tris, vec3 x, vec3 n) {
    if (seg_memo.base == base && seg_memo.x == x && seg_memo.n == n) return seg_memo.wsum;
    float wsum = segment_weight(base, segment_tris, x, n);
    seg_memo.base = base;
    seg_memo.x = x;
    seg_memo.n = n;
    seg_memo.wsum = wsum;
    return wsum;
}

// Area pdf of a point on light triangle `tri`, as chosen from x with normal n: the
// probability of choosing its emitter times the area pdf within it.
float light_area_pdf(uint tri, vec3 x, vec3 n) {
    if (tri < prm.light_first) return 0.0;
    uint ei = emitter_of(tri);
    LightBlock e = emitter_block(ei);
    float sel = emitter_pdf(ei);
    if (e.shape.z != LIGHT_FACING) return (1.0 / e.emit.y) * sel;
    uint segments = e.shape.w;
    uint segment_tris = e.shape.y / segments;
    uint k = tri - prm.light_first - e.shape.x;
    uint seg = k / segment_tris;
    if (seg >= segments) return 0.0;
    uint base = prm.light_first + e.shape.x + seg * segment_tris;
    float wsum = segment_weight_memo(base, segment_tris, x, n);
    float area = 0.5 * length(tri_normal(fetch_tri(tri)));
    return wsum > 0.0 ? light_weight(tri, x, n) / (wsum * float(segments) * area) * sel : 0.0;
}

// Picks a triangle of area light e with u in [0, 1): by area from its CDF, or (facing) a
// ring segment uniformly (they have equal areas) and within it a triangle by weight.
uint choose_light(LightBlock e, float u, vec3 x, vec3 n) {
    if (e.shape.z != LIGHT_FACING) return pick_area_tri(e, u);
    uint segments = e.shape.w;
    uint segment_tris = e.shape.y / segments;
    float fs = u * float(segments);
    uint seg = min(f2u(fs), segments - 1u);
    uint base = prm.light_first + e.shape.x + seg * segment_tris;
    float target = clamp(fs - float(seg), 0.0, 1.0) * segment_weight(base, segment_tris, x, n);
    float acc = 0.0;
    uint k = 0u;
    for (; k + 1u < segment_tris; k++) {
        acc += light_weight(base + k, x, n);
        if (acc > target) break;
    }
    return base + k;
}

// Largest ring segment (triangles) whose weights choose_light_pdf keeps in a table.
const uint FACING_TABLE = 64u;

// choose_light and, for the triangle it returns, light_area_pdf times the probability of
// choosing emitter ei (`sel`): the same choice for the same u and the same numbers, but a
// facing ring segment's weights are evaluated once, kept in a table (segments of up to
// FACING_TABLE triangles; larger ones take choose_light and light_area_pdf).
uint choose_light_pdf(LightBlock e, float u, vec3 x, vec3 n, float sel, out float area_pdf) {
    uint segments = e.shape.w;
    uint segment_tris = segments == 0u ? 0u : e.shape.y / segments;
    if (e.shape.z != LIGHT_FACING || segment_tris > FACING_TABLE) {
        uint tri = choose_light(e, u, x, n);
        area_pdf = light_area_pdf(tri, x, n);
        return tri;
    }
    float fs = u * float(segments);
    uint seg = min(f2u(fs), segments - 1u);
    uint base = prm.light_first + e.shape.x + seg * segment_tris;
    float w[FACING_TABLE];
    float wsum = 0.0;
    for (uint k = 0u; k < segment_tris; k++) {
        w[k] = light_weight(base + k, x, n);
        wsum += w[k];
    }
    float target = clamp(fs - float(seg), 0.0, 1.0) * wsum;
    float acc = 0.0;
    uint k = 0u;
    for (; k + 1u < segment_tris; k++) {
        acc += w[k];
        if (acc > target) break;
    }
    float area = 0.5 * length(tri_normal(fetch_tri(base + k)));
    area_pdf = wsum > 0.0 ? w[k] / (wsum * float(segments) * area) * sel : 0.0;
    return base + k;
}

// Intensity of spot e towards direction w (unit, from the light), times 1e6 mm^2/m^2:
// full inside the inner cone, zero beyond the edge, smoothstep between.
float spot_intensity(LightBlock e, vec3 w) {
    float c = dot(w, e.dir.xyz);
    float c_edge = e.pos.w, c_inner = e.dir.w;
    if (c >= c_inner) return e.emit.x;
    if (c <= c_edge) return 0.0;
    float t = (c - c_edge) / (c_inner - c_edge);
    return e.emit.x * t * t * (3.0 - 2.0 * t);
}
