#version 460
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require
#extension GL_KHR_shader_subgroup_arithmetic : require
//! variants: rq=TRACE_RAY_QUERY sw=TRACE_SOFTWARE sw8=TRACE_SOFTWARE_WIDE rqs=TRACE_RAY_QUERY+SPLIT_PATHS sws=TRACE_SOFTWARE+SPLIT_PATHS sw8s=TRACE_SOFTWARE_WIDE+SPLIT_PATHS
// (The variants ending in s: with SPLIT_PATHS, `[render] split_paths`, below.)
// Unidirectional path tracer for inspection images: pinhole camera, rough conductor
// object (materials per region: common/material.glsl), Lambertian table, lights (area
// lights as emissive triangles: ring, bar, panel, dome; spot lights as points,
// common/lights.glsl). Next-event estimation (a light by power, then a point on it)
// combined with BSDF sampling by MIS (power heuristic; spot lights by NEE only), Russian
// roulette after 3 bounces. Each
// dispatch adds `sample_count` samples per pixel into `accum` (a running sum).
// See docs/rendering.md for every approximation and its parameter.
#include "common/trace.glsl"
#include "interface.glsl"
#include "common/tile.glsl"
#include "common/camera.glsl"
#include "common/sampler.glsl"
#include "common/offset_ray.glsl"
#include "common/convert.glsl"
#include "common/octahedral.glsl"
#include "common/labels.glsl"

layout(local_size_x = TILE, local_size_y = TILE) in;

// The scene's buffers are read through their device addresses (PathTraceBinding's
// Addresses in src/gpu_interface.in: one uvec2 per binding, in binding order; the
// bindings stay bound so that the graph sees the reads): lavapipe (Mesa 25.0) loads a
// storage buffer at a per-lane index one lane and one word at a time behind branches,
// a buffer reference as one masked gather per word. Params, the light list, the sums,
// the label targets and the pixel list stay storage buffers (read at a lane-uniform or
// consecutive index).
layout(std430, set = 0, binding = PT_ADDRESSES) readonly buffer Addresses { uvec2 pt_addr[]; };
#define PT_ADDR(b) pt_addr[(b) - TRACE_BINDING_COUNT]
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer UintRef { uint v[]; };
layout(buffer_reference, std430, buffer_reference_align = 8) readonly buffer Uvec2Ref { uvec2 v[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer Uvec4Ref { uvec4 v[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer FloatRef { float v[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer CurvedMapRef { CurvedMapBlock v[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer SurfaceRef { SurfaceBlock v[]; };
layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer LightTriRef { LightTri v[]; };
// Geometry: the object's triangles (Tri), Materials: their material words,
// LightGeometry: the view's light triangles (Tri), Lights: per light triangle, x its
// emitter, y float bits of the inclusive area CDF within it, zw a guide table's entry
// (lights.glsl pick_area_tri). The two triangle arrays are read as texel buffers, a Tri
// in three 16-byte fetches (lavapipe: one load a lane and texel, where a load through an
// address is one a lane and word; docs/architecture.md).
layout(set = 0, binding = PT_GEOMETRY) uniform usamplerBuffer pt_object_tris;
layout(set = 0, binding = PT_LIGHT_GEOMETRY) uniform usamplerBuffer pt_light_tris;
// LightList: one LightBlock a light (lights.glsl EMITTERS), a storage buffer read at a
// lane-uniform index only (lavapipe then loads a word once for all lanes; emitter_block
// picks a lane's own block by a uniform loop over the few lights).
layout(std430, set = 0, binding = PT_LIGHT_LIST) readonly buffer LightList { LightBlock pt_emitters[]; };
Tri object_tri(uint prim) {
    int i = int(3u * prim);
    return Tri(uintBitsToFloat(texelFetch(pt_object_tris, i)),
               uintBitsToFloat(texelFetch(pt_object_tris, i + 1)),
               uintBitsToFloat(texelFetch(pt_object_tris, i + 2)));
}
Tri light_tri(uint k) {
    int i = int(3u * k);
    return Tri(uintBitsToFloat(texelFetch(pt_light_tris, i)),
               uintBitsToFloat(texelFetch(pt_light_tris, i + 1)),
               uintBitsToFloat(texelFetch(pt_light_tris, i + 2)));
}
#define MATERIAL_WORDS UintRef(PT_ADDR(PT_MATERIALS)).v
#define LIGHT_TRI_WORDS Uvec4Ref(PT_ADDR(PT_LIGHTS)).v
// LightWeights: per light triangle its centroid, twice its area and unit normal (LightTri).
#define LIGHT_TRI_WEIGHTS LightTriRef(PT_ADDR(PT_LIGHT_WEIGHTS)).v
#include "common/ggx.glsl"

// See PathParams in src/gpu_interface.in.
layout(std430, set = 0, binding = PT_PARAMS) readonly buffer Params { PathParams prm; };

layout(std430, set = 0, binding = PT_ACCUM) buffer Accum { float accum[]; };
// The per-pixel sums behind `[render] noise_target`'s variance estimate
// (src/render/noise.rs), by PRM_NOISE_SUMS: NOISE_SQUARES, the sum of each sample's
// squared radiance (one float a pixel); NOISE_HALVES, the radiance of sample indices
// [2^(L-1), 2^L) (level L >= 1; level 0: index 0) summed into float L & 1 of the pixel's
// two, each cleared at its level's first sample, so they hold the last two levels;
// NOISE_OFF: a placeholder of one float, never written. With `prm.cv_ray_sums` a tail
// of two floats a pixel after those (at width x height x the estimate's floats): the sum
// over the pixel's samples of each one's mean of its rays' closed forms
// (cv_rays_of_sample), and of its square (`[render] analytic_rays_max`).
layout(std430, set = 0, binding = PT_NOISE_SUMS) buffer NoiseSums { float noise_sums[]; };
// Labels from the path tracer's own samples (pc.labels = n != 0): the per-triangle label
// words (face | class << 8 | instance << 16, as annotate.comp reads them; declared for
// their count, read through their address) and the annotation targets; otherwise
// one-word placeholders never written.
layout(std430, set = 0, binding = PT_LABEL_WORDS) readonly buffer LabelWords { uint label_words[]; };
layout(std430, set = 0, binding = PT_LABEL_IDS) writeonly buffer LabelIds { uint label_ids[]; };
layout(std430, set = 0, binding = PT_LABEL_COVERAGE) writeonly buffer LabelCoverage { float label_coverage_out[]; };
// With pc.pixel_count != 0 the pixels this dispatch samples (y * width + x), TILE x TILE
// a workgroup (`[render] adaptive_radius`); otherwise a placeholder never read.
layout(std430, set = 0, binding = PT_PIXEL_LIST) readonly buffer PixelList { uint pixel_list[]; };
#include "common/material.glsl"

// Slope maps, one header per slot: slot 0 (table, light) never has a map, slot r + 1 is
// planar region r of the object; see src/render/slope.rs. MapHeader: origin (xyz map
// centre, world mm; w texels per mm), axis_x (map x axis), axis_up (map up axis, -y),
// dims (width, height, first texel, buffer + 1 | MAP_WRAP; 0 = no map).
// MapHeaders: per map slot its MapHeader, read as a texel buffer (four 16-byte texels a
// header; the slot differs between lanes: a texel is one load a lane, where a word
// through an address is a branch and a load a lane, docs/architecture.md).
layout(set = 0, binding = PT_MAP_HEADERS) uniform usamplerBuffer pt_map_headers;
MapHeader map_header(uint slot) {
    int i = int(4u * slot);
    return MapHeader(uintBitsToFloat(texelFetch(pt_map_headers, i)),
                     uintBitsToFloat(texelFetch(pt_map_headers, i + 1)),
                     uintBitsToFloat(texelFetch(pt_map_headers, i + 2)),
                     texelFetch(pt_map_headers, i + 3));
}
// A slot's MapHeader::dims alone.
uvec4 map_dims(uint slot) { return texelFetch(pt_map_headers, int(4u * slot + 3u)); }
// Texels of up to three distinct maps, one buffer each (Slopes0-2): two f16 slopes
// [dh/dx, dh/dy] per uint.

// Curved patches' projections (MAP_REVOLVED slots), one per slot; see
// src/scene/curved.rs and CurvedMapBlock in src/gpu_interface.in.
#define CURVED_MAPS CurvedMapRef(PT_ADDR(PT_CURVED_MAPS)).v

// Map-plane coordinates of p (mm along the map's x and up axes from its centre): the
// planar projection, or on a curved patch u = arc radius * theta about the axis and v
// along the generatrix, both functions of p alone (continuous across facets).
vec2 map_plane(uint slot, MapHeader m, vec3 p) {
    vec3 d = p - m.origin.xyz;
    if ((m.dims.w & MAP_REVOLVED) == 0u) return vec2(dot(d, m.axis_x.xyz), dot(d, m.axis_up.xyz));
    CurvedMapBlock c = CURVED_MAPS[slot];
    vec3 a = m.axis_up.xyz;
    float h = dot(d, a);
    vec3 r = d - h * a;
    float theta = atan(dot(r, cross(a, m.axis_x.xyz)), dot(r, m.axis_x.xyz));
    return vec2(c.profile.z * theta - c.place.x,
                length(r) * c.profile.x + h * c.profile.y - c.place.y);
}

// The map's x and up axes at p: the header's, or on a curved patch the unit tangents
// about the axis and along the generatrix (their cross product is the outward normal).
void map_axes(uint slot, MapHeader m, vec3 p, out vec3 ax, out vec3 up) {
    ax = m.axis_x.xyz;
    up = m.axis_up.xyz;
    if ((m.dims.w & MAP_REVOLVED) != 0u) {
        CurvedMapBlock c = CURVED_MAPS[slot];
        vec3 d = p - m.origin.xyz;
        vec3 r = d - dot(d, up) * up;
        float rl = length(r);
        r = rl > 0.0 ? r / rl : vec3(0.0);
        ax = cross(up, r);
        up = r * c.profile.x + up * c.profile.y;
    }
}

// The address of map buffer `buf` (1 to 3, MAP_BUFFER_MASK) of the three consecutive
// bindings from `first` (Slopes0-2, Moments0-2), picked by selects of lane-uniform reads
// (an index into the table that differs per lane would be read lane by lane).
uvec2 map_buffer_addr(uint first, uint buf) {
    return buf == 1u ? PT_ADDR(first) : buf == 2u ? PT_ADDR(first + 1u) : PT_ADDR(first + 2u);
}

vec2 slope_texel(uint buf, uint i) {
    return unpackHalf2x16(UintRef(map_buffer_addr(PT_SLOPES0, buf)).v[i]);
}

layout(push_constant) uniform Push { PathPush pc; };

float power_heuristic(float a, float b) {
    float a2 = a * a, b2 = b * b;
    return a2 + b2 > 0.0 ? a2 / (a2 + b2) : 0.0;
}

// Triangles are numbered object (with the table) first, then the view's lights: the
// object's live in Geometry, the lights' in LightGeometry (a second trace level).
Tri fetch_tri(uint prim) {
    return prim < prm.light_first ? object_tri(prim) : light_tri(prim - prm.light_first);
}

// Material in the low byte, slope-map slot above it (MAT_MAP_SHIFT); light triangles are
// MAT_LIGHT.
uint mat_word(uint prim) {
    return prim < prm.light_first ? MATERIAL_WORDS[prim] : MAT_LIGHT;
}

vec3 tri_normal(Tri t) { return cross(t.b.xyz - t.a.xyz, t.c.xyz - t.a.xyz); }

#include "common/lights.glsl"
#include "common/analytic_light.glsl"

// Steepest slope a map may give (85 degrees): keeps the shading normal off the tangent
// plane so its frame stays well conditioned.
const float MAX_SLOPE = 11.43;
// The viewer must sit at least this far (cosine) above the shading hemisphere; see
// bend_towards_viewer.
const float SHADE_MIN_COS = 0.1;

// Bilinear slopes [dh/dx, dh/dy] (image axes, y down) at map-plane coordinates q (mm
// along the map's x and up axes from its centre): zero outside the map, or the map
// repeated (MAP_WRAP). The header must have a map (buffer != 0).
vec2 slopes_at(MapHeader m, vec2 q) {
    uint buf = m.dims.w & MAP_BUFFER_MASK;
    vec2 wh = vec2(m.dims.xy);
    float x = q.x * m.origin.w + 0.5 * wh.x;
    float y = -q.y * m.origin.w + 0.5 * wh.y;
    uint x0, y0, x1, y1;
    float tx, ty;
    if ((m.dims.w & MAP_WRAP) != 0u) {
        // Texel centres at i + 0.5; the last texel's neighbour is the first.
        float fx = x - 0.5, fy = y - 0.5;
        fx -= wh.x * floor(fx / wh.x);
        fy -= wh.y * floor(fy / wh.y);
        if (!(fx >= 0.0 && fy >= 0.0)) return vec2(0.0); // NaN (degenerate header)
        x0 = min(f2u(fx), m.dims.x - 1u);
        y0 = min(f2u(fy), m.dims.y - 1u);
        x1 = x0 + 1u == m.dims.x ? 0u : x0 + 1u;
        y1 = y0 + 1u == m.dims.y ? 0u : y0 + 1u;
        tx = fx - float(x0);
        ty = fy - float(y0);
    } else {
        if (!(x >= 0.0 && y >= 0.0 && x <= wh.x && y <= wh.y)) return vec2(0.0);
        float fx = clamp(x - 0.5, 0.0, wh.x - 1.0);
        float fy = clamp(y - 0.5, 0.0, wh.y - 1.0);
        x0 = f2u(fx);
        y0 = f2u(fy);
        x1 = min(x0 + 1u, m.dims.x - 1u);
        y1 = min(y0 + 1u, m.dims.y - 1u);
        tx = fx - float(x0);
        ty = fy - float(y0);
    }
    uint b = m.dims.z;
    vec2 a = mix(slope_texel(buf, b + y0 * m.dims.x + x0), slope_texel(buf, b + y0 * m.dims.x + x1), tx);
    vec2 c = mix(slope_texel(buf, b + y1 * m.dims.x + x0), slope_texel(buf, b + y1 * m.dims.x + x1), tx);
    return mix(a, c, ty);
}

// Bilinear slopes at p on a planar or revolved slot (zero without a map).
vec2 map_slopes(uint slot, vec3 p) {
    MapHeader m = map_header(slot);
    if ((m.dims.w & MAP_BUFFER_MASK) == 0u) return vec2(0.0);
    return slopes_at(m, map_plane(slot, m, p));
}

// The smooth normal of an object triangle of a triplanar patch at barycentrics bary.
vec3 smooth_normal(uint prim, vec2 bary) {
    Tri t = object_tri(prim);
    vec3 n = oct_decode(t.a.w) * (1.0 - bary.x - bary.y)
        + oct_decode(t.b.w) * bary.x + oct_decode(t.c.w) * bary.y;
    float l = length(n);
    return l > 0.0 ? n / l : n;
}

// Smallest triplanar weight whose projection is read (render::slope::TRIPLANAR_MIN_WEIGHT).
const float TRIPLANAR_MIN_WEIGHT = 1e-3;

// Shading normal on a triplanar slot (MAP_TRIPLANAR; CPU mirror: triplanar_normal in
// src/render/slope.rs): the map projected along the frame's three axes (x = axis_x,
// z = axis_up, y = z x x), each projection's slope vector brought into ng's tangent
// plane, summed with weights |n_k|^4 / sum of the smooth normal ns.
vec3 triplanar_normal(uint slot, MapHeader m, vec3 p, vec3 ng, vec3 ns) {
    if (dot(ns, ng) <= 0.0) return ng;
    // The frame as three vectors picked by selects, no array: a loop indexing a local
    // array with its counter is unrolled by the compiler (three copies of slopes_at).
    vec3 e0 = m.axis_x.xyz;
    vec3 e2 = m.axis_up.xyz;
    vec3 e1 = cross(e2, e0);
    vec3 local = vec3(dot(ns, e0), dot(ns, e1), dot(ns, e2));
    vec3 w = abs(local);
    w = (w * w) * (w * w);
    float sum = w.x + w.y + w.z;
    w = sum > 0.0 ? w / sum : vec3(0.0, 0.0, 1.0);
    vec3 d = p - m.origin.xyz;
    vec2 place = CURVED_MAPS[slot].place.xy;
    vec3 delta = vec3(0.0);
    for (uint k = 0u; k < 3u; k++) {
        float wk = k == 0u ? w.x : k == 1u ? w.y : w.z;
        float lk = k == 0u ? local.x : k == 1u ? local.y : local.z;
        if (wk < TRIPLANAR_MIN_WEIGHT) continue;
        vec3 ax = (k == 0u ? e1 : k == 1u ? e2 : e0) * (lk >= 0.0 ? 1.0 : -1.0);
        vec3 up = k == 0u ? e2 : k == 1u ? e0 : e1;
        vec2 s = slopes_at(m, vec2(dot(d, ax) - place.x, dot(d, up) - place.y));
        float len = length(s);
        if (len > MAX_SLOPE) s *= MAX_SLOPE / len;
        ax -= dot(ax, ng) * ng;
        up -= dot(up, ng) * ng;
        delta += wk * (-s.x * ax + s.y * up);
    }
    if (delta == vec3(0.0)) return ng;
    return normalize(ng + delta);
}

// Shading normal from the region's slope map; ng is the geometric normal facing the ray.
// Exactly ng where the slopes are zero (a flat map renders as no map). The map axes are
// projected into the triangle's plane, so triangles that are not coplanar with the
// region (defect patches given to it) still get a normal in their own hemisphere.
vec3 shading_normal(uint slot, vec3 p, vec3 ng, uint prim, vec2 bary) {
    MapHeader m = map_header(slot);
    if ((m.dims.w & MAP_BUFFER_MASK) == 0u) return ng;
    if ((m.dims.w & MAP_TRIPLANAR) != 0u) {
        return triplanar_normal(slot, m, p, ng, smooth_normal(prim, bary));
    }
    vec3 mx, mu;
    map_axes(slot, m, p, mx, mu);
    // Seen from inside (not the region's outward side): no perturbation.
    if (dot(cross(mx, mu), ng) <= 0.0) return ng;
    vec2 s = map_slopes(slot, p);
    if (s.x == 0.0 && s.y == 0.0) return ng;
    float len = length(s);
    if (len > MAX_SLOPE) s *= MAX_SLOPE / len;
    vec3 ax = mx - dot(mx, ng) * ng;
    vec3 up = mu - dot(mu, ng) * ng;
    // n = normalize(-dh/dx, -dh/dup, 1) in (x, up, n) with dh/dup = -dh/dy.
    return normalize(ng - s.x * ax + s.y * up);
}

// LEAN filtering (`[render] texture_filter = "lean"`; docs/rendering.md, "Filtered slope
// maps"; CPU mirror: lookup_lean in src/render/slope.rs). Per map a pyramid of slope
// moments, levels 1 up to 1 x 1 (level k: ceil(w / 2^k) x ceil(h / 2^k) texels), three
// uints a texel: f16 [mean dh/dx, mean dh/dy], [var dh/dx, var dh/dy], [cov, 0].
// (Moments0-2, one buffer per map as the slopes.)
uint moment_word(uint buf, uint i) {
    return UintRef(map_buffer_addr(PT_MOMENTS0, buf)).v[i];
}

// Smallest |cos| between the primary ray and the surface in the footprint.
const float LEAN_MIN_COS = 0.05;

// Highest level of a map's pyramid: ceil(log2(max(w, h))).
uint lean_top(MapHeader m) {
    return uint(findMSB(max(max(m.dims.x, m.dims.y), 1u) - 1u) + 1);
}

// Bilinear mean slope and slope variance (var x + var y) at level k >= 1: the mixture of
// the four texels' distributions. False outside a clipped map.
bool lean_level(uint slot, vec3 p, uint k, out vec2 mean, out float var) {
    mean = vec2(0.0);
    var = 0.0;
    MapHeader m = map_header(slot);
    uint buf = m.dims.w & MAP_BUFFER_MASK;
    uint w = (m.dims.x + (1u << k) - 1u) >> k;
    uint ht = (m.dims.y + (1u << k) - 1u) >> k;
    vec3 d = p - m.origin.xyz;
    float s = 1.0 / float(1u << k);
    float x = (dot(d, m.axis_x.xyz) * m.origin.w + 0.5 * float(m.dims.x)) * s;
    float y = (-dot(d, m.axis_up.xyz) * m.origin.w + 0.5 * float(m.dims.y)) * s;
    vec2 wh = vec2(w, ht);
    uint x0, y0, x1, y1;
    float tx, ty;
    if ((m.dims.w & MAP_WRAP) != 0u) {
        float fx = x - 0.5, fy = y - 0.5;
        fx -= wh.x * floor(fx / wh.x);
        fy -= wh.y * floor(fy / wh.y);
        if (!(fx >= 0.0 && fy >= 0.0)) return false;
        x0 = min(f2u(fx), w - 1u);
        y0 = min(f2u(fy), ht - 1u);
        x1 = x0 + 1u == w ? 0u : x0 + 1u;
        y1 = y0 + 1u == ht ? 0u : y0 + 1u;
        tx = fx - float(x0);
        ty = fy - float(y0);
    } else {
        if (!(x >= 0.0 && y >= 0.0 && x <= float(m.dims.x) * s && y <= float(m.dims.y) * s)) return false;
        float fx = clamp(x - 0.5, 0.0, wh.x - 1.0);
        float fy = clamp(y - 0.5, 0.0, wh.y - 1.0);
        x0 = f2u(fx);
        y0 = f2u(fy);
        x1 = min(x0 + 1u, w - 1u);
        y1 = min(y0 + 1u, ht - 1u);
        tx = fx - float(x0);
        ty = fy - float(y0);
    }
    uint base = 0u;
    for (uint j = 1u; j < k; j++) {
        base += ((m.dims.x + (1u << j) - 1u) >> j) * ((m.dims.y + (1u << j) - 1u) >> j) * 3u;
    }
    uint idx[4] = uint[4](y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1);
    float wt[4] = float[4]((1.0 - tx) * (1.0 - ty), tx * (1.0 - ty), (1.0 - tx) * ty, tx * ty);
    vec2 mi[4];
    float vi[4];
    for (int i = 0; i < 4; i++) {
        uint a = base + idx[i] * 3u;
        mi[i] = unpackHalf2x16(moment_word(buf, a));
        vec2 v = unpackHalf2x16(moment_word(buf, a + 1u));
        vi[i] = v.x + v.y;
        mean += wt[i] * mi[i];
    }
    for (int i = 0; i < 4; i++) {
        vec2 e = mi[i] - mean;
        var += wt[i] * (vi[i] + dot(e, e));
    }
    return true;
}

// Mean slope and slope variance at mip level `lambda` (trilinear between floor and
// floor + 1, clamped to the top level; level 0 is the point lookup with no spread).
vec2 lean_slopes(uint slot, vec3 p, float lambda, out float var) {
    var = 0.0;
    vec2 m0 = map_slopes(slot, p);
    MapHeader m = map_header(slot);
    uint top = lean_top(m);
    if (!(lambda > 0.0) || top == 0u) return m0;
    float l = min(lambda, float(top));
    uint k = f2u(floor(l));
    float f = l - float(k);
    // Levels k (level 0: m0) and, unless f = 0, k + 1 (clamped), by one call of
    // lean_level in a loop: the shader compiles one copy of it.
    vec2 ma = m0, mb = vec2(0.0);
    float va = 0.0, vb = 0.0;
    for (uint step = 0u; step < 2u; step++) {
        if (step == 0u && k == 0u) continue;
        if (step == 1u && f == 0.0) break;
        vec2 mk;
        float vk;
        if (!lean_level(slot, p, step == 0u ? k : min(k + 1u, top), mk, vk)) return m0;
        if (step == 0u) {
            ma = mk;
            va = vk;
        } else {
            mb = mk;
            vb = vk;
        }
    }
    if (f == 0.0) {
        var = va;
        return ma;
    }
    vec2 mm = mix(ma, mb, f);
    vec2 ea = ma - mm, eb = mb - mm;
    var = (1.0 - f) * (va + dot(ea, ea)) + f * (vb + dot(eb, eb));
    return mm;
}

// shading_normal with the filtered mean slope at level `lambda` (> 0); `var`: the slope
// variance under the footprint (0 where the map does not apply).
vec3 shading_normal_lean(uint slot, vec3 p, vec3 ng, float lambda, out float var) {
    var = 0.0;
    MapHeader m = map_header(slot);
    if ((m.dims.w & MAP_BUFFER_MASK) == 0u) return ng;
    if (dot(cross(m.axis_x.xyz, m.axis_up.xyz), ng) <= 0.0) return ng;
    vec2 s = lean_slopes(slot, p, lambda, var);
    if (s.x == 0.0 && s.y == 0.0) return ng;
    float len = length(s);
    if (len > MAX_SLOPE) s *= MAX_SLOPE / len;
    vec3 ax = m.axis_x.xyz - dot(m.axis_x.xyz, ng) * ng;
    vec3 up = m.axis_up.xyz - dot(m.axis_up.xyz, ng) * ng;
    return normalize(ng - s.x * ax + s.y * up);
}

// A perturbed normal can face away from the viewer (slope + view angle > 90 degrees),
// which would make the BSDF zero there: black fringes. The normal is rotated towards wo,
// in the plane of (ns, wo), until cos(ns, wo) = min(SHADE_MIN_COS, cos(ng, wo)); the
// rotated normal stays in ng's hemisphere (both components have a positive dot with ng)
// and an unperturbed normal (ns = ng) is never changed.
vec3 bend_towards_viewer(vec3 ns, vec3 ng, vec3 wo) {
    float target = min(SHADE_MIN_COS, dot(ng, wo));
    float c = dot(ns, wo);
    if (c >= target) return ns;
    vec3 perp = ns - c * wo;
    float pl = length(perp);
    if (!(pl > 1e-6)) return ng;
    return normalize(perp * (sqrt(max(1.0 - target * target, 0.0)) / pl) + target * wo);
}

// The shading normal at hit h of the ray along d (point p, geometric normal ng facing
// -d, material word `word`, at path depth `depth`): the slope-mapped normal (object
// material with a map; entries with finish = "none" have slot 0), bent towards the viewer
// if needed, else ng. With LEAN at the primary hit the map's slope variance also widens
// surf's lobe. Side and visibility tests use ng: directions below the geometric surface
// are never lit nor continued (no light leaks).
vec3 surface_normal(Hit h, vec3 d, vec3 p, vec3 ng, uint word, uint depth, inout Surface surf) {
    uint mat = word & 0xffu;
    uint slot = (word >> MAT_MAP_SHIFT) & MAT_SLOT_MASK;
    if (mat == MAT_TABLE || slot == 0u || ((word & MAT_LABELLED) == 0u
            && (map_dims(slot).w & MAP_LABELLED_ONLY) != 0u)) {
        return ng;
    }
    // LEAN at the primary hit: footprint = the pixel cone's width at the hit (its angle
    // shrinks off axis as cos^1.5), over |cos| on the surface, in texels; secondary hits
    // read level 0, and so do curved (revolved and triplanar) patches (LEAN there is not
    // done: lean_level uses the planar projection).
    float lambda = 0.0;
    if (PRM_TEXTURE_FILTER == FILTER_LEAN && depth == 0u
            && (map_dims(slot).w & (MAP_REVOLVED | MAP_TRIPLANAR)) == 0u) {
        float c = max(dot(d, prm.cam.forward.xyz), 0.1);
        float width = prm.pixel_angle * c * sqrt(c) * h.t / max(abs(dot(ng, d)), LEAN_MIN_COS);
        lambda = log2(width * map_header(slot).origin.w * prm.filter_scale);
    }
    if (lambda > 0.0) {
        float var;
        vec3 ns = bend_towards_viewer(shading_normal_lean(slot, p, ng, lambda, var), ng, -d);
        // The slope variance widens the lobe (isotropic LEAN: alpha^2 + var).
        if (var > 0.0 && !surf.diffuse) {
            surf.c.alpha = min(sqrt(surf.c.alpha * surf.c.alpha + var), 1.0);
        }
        return ns;
    }
    return bend_towards_viewer(shading_normal(slot, p, ng, h.prim, h.bary), ng, -d);
}

// The conductor the path tracer shades the object with (PathParams' material).
Conductor path_conductor() {
    Conductor cond;
    cond.alpha = clamp(prm.alpha, 1e-4, 1.0);
    cond.n = prm.ior_n;
    cond.k = prm.ior_k;
    cond.comp = prm.comp != 0u;
    cond.f_avg = prm.f_avg;
    return cond;
}

// The camera ray o, d through pixel (px, py): its jitter from the sampler's next two
// dimensions, then under a thin lens the aperture point from the next two (the pinhole
// draws none).
void pixel_ray(uint px, uint py, inout Sampler rng, out vec3 o, out vec3 d) {
    vec2 jitter = sample_2d(rng);
    vec2 lens = prm.cam.eye.w > 0.0 ? sample_2d(rng) : vec2(0.0);
    camera_ray(prm.cam, vec2(px, py) + jitter, vec2(prm.width, prm.height), lens, o, d);
}

// The point of triangle t at barycentrics `bary`: as exact as the triangle itself,
// unlike o + t d whose error grows with the distance travelled.
vec3 hit_point(Tri t, vec2 bary) {
    return t.a.xyz * (1.0 - bary.x - bary.y) + t.b.xyz * bary.x + t.c.xyz * bary.y;
}

// The extra camera rays' closed form A' (`[render] analytic_rays`): per pixel a
// reference point, where the ray through the pixel's centre (and the lens's) first meets
// the scene; where that is a conductor, the rings the control variate may use there are
// recorded as seen from it over the coarser ring (record_rings, CV_EXTRA_RING_DIVISOR).
// A' of a camera ray is then, with no trace: the ray meets the reference triangle's
// plane at p; the shading normal there (the reference triangle's map, material and
// frame, extrapolated beyond its edges) and the lobe as the path tracer builds them at a
// primary hit; the lobe's closed form over the recorded rings (recorded_rings2). One fixed
// function of the camera ray per pixel, which is all the extra-ray term needs to stay
// unbiased; on a face it follows the texture under the pixel as A does (A' ignores what
// lies off the reference plane: edges, defects, other faces, where it only helps less).
// The extra rays' lobe amplitude (pixel_plane_lobe) is not evaluated per ray: fc =
// f(wo, r) cos(r) at the mirror direction, a function of wo.z alone, is replaced by its
// secant through the centre ray's cosine to the reference plane +- this (a fixed function
// of the camera ray, so the estimate stays unbiased; the sample's own A keeps the exact
// amplitude). docs/rendering.md, "Analytic direct light".
const float PLANE_FC_STEP = 0.05;
struct PixelPlane {
    vec3 p;       // the reference point
    vec3 ng;      // its triangle's normal, towards the camera
    uint prim;
    uint word;
    Surface surf;
    vec3 a;       // its triangle's first corner,
    vec3 ba;      // and the rows taking p - a to barycentrics in its plane (plane_bary)
    vec3 ca;
    float fc0;    // the lobe amplitude's line in wo.z, fc ~ fc0 + fc1 wo.z (the secant
    float fc1;    // through the centre ray's cosine to the plane +- PLANE_FC_STEP)
};
PixelPlane pix_plane;
// The object triangle the pixel's centre ray meets first (pixel_plane_init), the hint of
// its camera rays' closest-hit queries (trace_query_hinted: the same hits, found with
// less traversal); prim NO_HIT: none.
TraceHint pix_hint;

// Sets pix_hint and the pixel's camera-ray and shadow-ray bundles where the pixel's
// centre ray meets the object (main clears the hint); with `plane` (the analytic direct
// light's extra camera rays) also the pixel's reference point and its rings (none where
// the centre ray meets no conductor). One function for both: lavapipe inlines a
// traversal per trace call.
void pixel_plane_init(uint px, uint py, bool plane) {
    rec_rings = 0u;
    vec3 o, d;
    camera_ray(prm.cam, vec2(px, py) + 0.5, vec2(prm.width, prm.height), vec2(0.5), o, d);
    Hit h = trace(o, d, 0.0, 3.0e38);
    if (h.prim == NO_HIT) return;
    if (h.prim < prm.light_first) {
        Tri ht = object_tri(h.prim);
        pix_hint.a = ht.a.xyz;
        pix_hint.b = ht.b.xyz;
        pix_hint.c = ht.c.xyz;
        pix_hint.prim = h.prim;
        // The pixel's camera rays as one bundle (their object hits among a few triangles).
        vec3 right = normalize(prm.cam.right.xyz), up = normalize(prm.cam.up.xyz);
        vec3 fwd = prm.cam.forward.xyz;
        float lens = prm.cam.eye.w;
        float zf = lens > 0.0 ? prm.cam.forward.w : 1.0;
        vec4 q = camera_pixel_footprint(prm.cam, vec2(px, py), vec2(prm.width, prm.height),
                                        right, up, fwd, zf);
        trace_bundle_init(prm.cam.eye.xyz, right, up, fwd, lens, zf, q, pix_hint.a,
                          cross(pix_hint.b - pix_hint.a, pix_hint.c - pix_hint.a));
        // Its shadow rays as one bundle: from where its camera rays meet that triangle's
        // plane, moved off it by offset_ray (at most 256 ulps, 3.05e-5 of a coordinate,
        // or 1/65536 near 0; widened to 4e-5 and 2e-5 for the hit point's rounding), to
        // the lights' box.
        vec3 flo, fhi;
        if (PRM_EMITTER_COUNT > 0u && prm.lights_lo.w != 0.0 && trace_bundle_footprint(flo, fhi)) {
            vec3 big = max(abs(flo), abs(fhi));
            float m = 4e-5 * max(big.x, max(big.y, big.z)) + 2e-5;
            trace_shadow_init(flo - m, fhi + m, prm.lights_lo.xyz, prm.lights_hi.xyz);
        }
    }
    if (!plane) return;
    uint word = mat_word(h.prim);
    uint mat = word & 0xffu;
    if (mat == MAT_LIGHT) return;
    Surface surf = surface_of(mat, path_conductor());
    if (surf.diffuse) return;
    Tri t = fetch_tri(h.prim);
    vec3 ng = normalize(tri_normal(t));
    if (dot(ng, d) > 0.0) ng = -ng;
    pix_plane.p = hit_point(t, h.bary);
    pix_plane.ng = ng;
    pix_plane.prim = h.prim;
    pix_plane.word = word;
    pix_plane.surf = surf;
    // Barycentrics in t's plane, beyond its edges too: p - a against the dual basis of
    // its edges e1, e2 (what plane_bary solved per point).
    vec3 e1 = t.b.xyz - t.a.xyz, e2 = t.c.xyz - t.a.xyz;
    float d00 = dot(e1, e1), d01 = dot(e1, e2), d11 = dot(e2, e2);
    float inv = 1.0 / (d00 * d11 - d01 * d01);
    pix_plane.a = t.a.xyz;
    pix_plane.ba = (d11 * e1 - d01 * e2) * inv;
    pix_plane.ca = (d00 * e2 - d01 * e1) * inv;
    float mu = clamp(-dot(d, ng), PLANE_FC_STEP, 1.0);
    float lo = max(mu - PLANE_FC_STEP, 0.02), hi = min(mu + PLANE_FC_STEP, 1.0);
    float f_lo = conductor_lobe_amplitude(surf.c, lo);
    float f_hi = conductor_lobe_amplitude(surf.c, hi);
    pix_plane.fc1 = (f_hi - f_lo) / (hi - lo);
    pix_plane.fc0 = f_lo - pix_plane.fc1 * lo;
    record_rings(offset_ray(pix_plane.p, ng), ng, CV_EXTRA_RING_DIVISOR);
}

// The lobe and shading normal of A' for the camera ray o, d (pixel_plane_init's pixel);
// false (A' = 0) where the pixel has no recorded ring or the ray does not meet the
// reference plane in front of the camera.
bool pixel_plane_lobe(vec3 o, vec3 d, out Lobe lobe, out vec3 ns) {
    ns = pix_plane.ng;
    lobe.t1 = lobe.t2 = lobe.r = ns;
    lobe.a1 = lobe.a2 = lobe.c = 1.0;
    if (rec_rings == 0u) return false;
    float dn = dot(d, pix_plane.ng);
    if (!(dn < 0.0)) return false;
    Hit h;
    h.t = dot(pix_plane.p - o, pix_plane.ng) / dn;
    if (!(h.t > 0.0)) return false;
    vec3 p = o + h.t * d;
    h.prim = pix_plane.prim;
    vec3 v = p - pix_plane.a;
    h.bary = vec2(dot(v, pix_plane.ba), dot(v, pix_plane.ca));
    h.inst = 0u;
    Surface surf = pix_plane.surf;
    ns = surface_normal(h, d, p, pix_plane.ng, pix_plane.word, 0u, surf);
    vec3 tb, bt;
    onb(ns, tb, bt);
    vec3 wo = to_frame(-d, tb, bt, ns);
    // Where LEAN widened this ray's lobe (alpha not the line's), the exact amplitude.
    if (surf.c.alpha != pix_plane.surf.c.alpha) {
        return conductor_lobe(surf.c, wo, tb, bt, ns, lobe);
    }
    float fc = max(pix_plane.fc0 + pix_plane.fc1 * wo.z, 0.0);
    return conductor_lobe_fc(surf.c, fc, wo, tb, bt, ns, lobe);
}

// The MIS weight of a BSDF sample (solid-angle pdf `pdf`, from o with geometric normal
// n) whose ray meets the light triangle `prim` at distance t, facing it with cosine
// cos_l > 0: the power heuristic against the pdf NEE would have had for that point.
float bsdf_mis_weight(uint prim, float t, float cos_l, vec3 o, vec3 n, float pdf) {
    return power_heuristic(pdf, t * t / cos_l * light_area_pdf(prim, o, n));
}

// The control variate's BSDF-sample term at the primary hit, once the path's next trace
// has told `light`, the first light triangle on the ray o, d with occluders ignored (or
// a miss): its radiance times its MIS weight as E's own (BSDF pdf `pdf`, shading
// point's geometric normal n) where that triangle faces o and belongs to a ring of
// `mask` on the kept side of its table clip (ring_table_clip), else 0.
float cv_bsdf_weight(vec3 o, vec3 d, float pdf, vec3 n, Hit light, uint mask) {
    if (light.prim == NO_HIT) return 0.0;
    uint k = emitter_of(light.prim);
    if (k >= 32u || (mask & (1u << k)) == 0u) return 0.0;
    float cos_l = -dot(normalize(tri_normal(fetch_tri(light.prim))), d);
    LightBlock e = emitter_block(k);
    if (!(cos_l > 0.0) || !ring_clip_keeps(ring_table_clip(e, o), d)) return 0.0;
    return e.emit.x * bsdf_mis_weight(light.prim, light.t, cos_l, o, n, pdf)
        / float(max(PRM_BSDF_SAMPLES, 1u));
}

// The last radiance_sample's mean of its camera rays' closed forms A' (the extra rays'
// and its own; 0 without extra rays or without `prm.cv_ray_sums`).
float cv_rays_of_sample = 0.0;

// A path's last trace put off (radiance_sample with `defer`): its ray left the object
// at a bounce (TQ_CLOSEST_ESCAPE, TQ_LIGHT_CLOSEST_ESCAPE), so all that is left of the
// path is the light the ray meets (the lights' closest hit, TQ_LIGHTS) and what it adds:
// the control variate's pending term (cv_pending, cv_mask; the first bounce's ray of a
// primary hit that has one) and the light's term, then the analytic light's extra camera
// rays' term (`extra`, computed when the path was put off), in the order the sample
// would have added them to its partial radiance L. `slot`: the sample's place in main's
// window.
struct PathLookup {
    vec3 o; float T; vec3 d; float prev_pdf; vec3 prev_n; float prev_nb;
    float L; float cv_pending; uint cv_mask; float extra; uint slot;
};
// Set by radiance_sample: whether its path was put off, and what is left of it.
bool path_put_off = false;
PathLookup path_left;

// Lights' lookups of paths put off (`main`) can be gathered from several samples: a
// sample whose last terms are those of the light a bounce's ray meets after leaving the
// object. Not with `[render] light_shortcuts = false` (every ray traced as it comes: the
// comparison that tests/lights.rs `light_shortcuts_change_no_pixel` makes).
#define PATH_DEFER (PRM_SHORTCUTS != 0u)
// Samples a window of main holds (their lookups, the lanes' put-off paths' lights, are
// made together at its end).
#define PATH_WINDOW 8u

// One sample's radiance, or with `lookup` the radiance of a path put off (`path_left`:
// its partial radiance and what its ray's light adds; no sample is drawn). With `defer`
// (PATH_DEFER), a path whose bounce's ray leaves the object ends here with its last
// terms left out and put off (`path_put_off`, `path_left`; the partial radiance
// returned): the caller looks them up later, with the lookups of other samples, so that
// lanes trace the lights together (see `main`).
// `label_word`: with `want_label`, the label word of the primary ray's first hit (0:
// nothing, or a triangle past the labelled ones, the view's light), as annotate.comp's
// label_of_ray; 0 without (no label read on samples that do not label). `label_only`:
// the sample is traced for its label alone (its camera ray's first hit, then 0 returned).
float radiance_sample(uint pixel, uint px, uint py, uint s, bool want_label, bool label_only,
                      bool defer, bool lookup, out uint label_word) {
    label_word = 0u;
    cv_rays_of_sample = 0.0;
    path_put_off = false;
    Sampler rng = sampler_init(PRM_SAMPLE_GEN, pixel, s, prm.seed);
    vec3 o = path_left.o, d = path_left.d;
    [[dont_flatten]] if (!lookup) pixel_ray(px, py, rng, o, d);
    Conductor cond = path_conductor();
    // This sample's camera ray, kept for its A' (the extra camera rays' term below; a
    // lookup's was computed when its path was put off).
    uint extra_rays = PRM_DIRECT_LIGHT == DIRECT_ANALYTIC ? PRM_CV_EXTRA_RAYS : 0u;
    uint extra = lookup ? 0u : extra_rays;
    vec3 o0 = o, d0 = d;

    float L = lookup ? path_left.L : 0.0;
    float T = lookup ? path_left.T : 1.0;
    // The control variate (primary hit): its rings (analytic_rings) and its BSDF-sample
    // term c D / pdf, awaiting the light the next trace meets (cv_bsdf_weight).
    uint cv_mask = lookup ? path_left.cv_mask : 0u;
    float cv_pending = lookup ? path_left.cv_pending : 0.0;
    float prev_pdf = lookup ? path_left.prev_pdf : 0.0;   // solid-angle pdf of the BSDF sample that made this ray; 0 = camera
    vec3 prev_n = lookup ? path_left.prev_n : vec3(0.0); // geometric normal at the ray's origin (facing light pdf)
    float prev_nb = lookup ? path_left.prev_nb : 1.0;     // BSDF samples taken at the ray's origin for its direct light
    // Split paths (`[render] split_paths`; the shader's variants with SPLIT_PATHS, so that
    // the others are the path tracer without them, at no cost): each of the first hit's
    // `bsdf_samples` BSDF directions continues as a path (a branch) of weight
    // 1 / `bsdf_samples`, where otherwise only the path's own goes on and the others are
    // traced to the first light they meet. Branch 0 is the path's own (from the camera);
    // branch b > 0 starts again at the first hit, draws its direction there and goes on
    // from depth 1. Each branch resolves its own control-variate term (its rings:
    // cv_mask, set at the first hit); only the last can be put off (a lookup finishes
    // one path). The first hit is kept in few registers (what the camera ray d0 and its
    // triangle give again, the same values, is made again): its ray origin, shading
    // normal, triangle and lobe width.
#if defined(SPLIT_PATHS)
    uint branches = lookup ? 1u : max(PRM_BSDF_SAMPLES, 1u);
    float fbranches = float(branches);
    vec3 v_origin = vec3(0.0), v_ns = vec3(0.0);
    uint v_prim = NO_HIT;   // NO_HIT: no first hit kept (no branches)
    float v_alpha = 0.0;
    for (uint branch = 0u; branch < branches; branch++) {
#else
    const uint branch = 0u, branches = 1u;
    const float fbranches = 1.0;
    {
#endif
        // The path stopped with a control-variate term pending: one more trip through the
        // loop's trace, for the light alone (every trace of the path is that one call: the
        // shader compiles one traversal for it).
        bool stop = false;
        uint depth_first = lookup ? 1u : 0u;
#if defined(SPLIT_PATHS)
        if (branch > 0u) {
            if (v_prim == NO_HIT) break;
            // The first hit again: its geometric normal facing the camera ray, surface
            // (the lobe as LEAN widened it) and frame.
            vec3 v_ng = normalize(tri_normal(fetch_tri(v_prim)));
            if (dot(v_ng, d0) > 0.0) v_ng = -v_ng;
            Surface v_surf = surface_of(mat_word(v_prim) & 0xffu, cond);
            v_surf.c.alpha = v_alpha;
            vec3 tb, bt;
            onb(v_ns, tb, bt);
            vec3 v_wo = to_frame(-d0, tb, bt, v_ns);
            // This branch's direction from there, its weight and pdf, and its
            // control-variate term (cv_bsdf_weight's, as the path's own at step nl below).
            vec3 u = vec3(sample_1d(rng), sample_2d(rng));
            vec3 wi;
            float weight, pdf;
            bool sampled = surface_sample(v_surf, v_wo, u, wi, weight, pdf);
            d = sampled ? normalize(from_frame(wi, tb, bt, v_ns)) : vec3(0.0);
            o = v_origin;
            T = weight / fbranches;
            prev_pdf = pdf;
            prev_n = v_ng;
            prev_nb = 1.0;
            cv_pending = 0.0;
            if (cv_mask != 0u && sampled) {
                Lobe lobe;
                conductor_lobe(v_surf.c, v_wo, tb, bt, v_ns, lobe);
                cv_pending = lobe.c * lobe_d(lobe, d) / pdf;
            }
            if (!sampled) continue;
            if (!(T > 0.0) || dot(d, v_ng) <= 0.0) {
                if (cv_pending == 0.0) continue;
                stop = true;
            }
            depth_first = 1u;
        }
#endif
        for (uint depth = depth_first; depth <= PRM_MAX_BOUNCES || stop; depth++) {
            // The ray's closest hit; with a control-variate term pending also the first light
            // on it with occluders ignored (cv_bsdf_weight), or that light alone if stopped
            // or looked up.
            uint kind = stop || lookup ? TQ_LIGHTS : cv_pending != 0.0 ? TQ_LIGHT_CLOSEST : TQ_CLOSEST;
            // A ray that can meet no light: the object alone (the same hit, no light).
            if (!stop && !lookup && misses_lights(o, d)) kind = TQ_OBJECT;
            // A bounce's ray whose path can be put off: the lights only where it meets the
            // object (where it does not, the lights' hit is the lookup's).
            bool escape = defer && depth > 0u && branch + 1u == branches
                && (kind == TQ_CLOSEST || kind == TQ_LIGHT_CLOSEST);
            if (escape) kind = kind == TQ_CLOSEST ? TQ_CLOSEST_ESCAPE : TQ_LIGHT_CLOSEST_ESCAPE;
            TraceResult tq = trace_query_hinted(kind, o, d, 0.0, 3.0e38, 0.0,
                                                depth == 0u ? pix_hint : trace_no_hint());
            if (escape && tq.blocked) {
                // The extra rays' term is still computed (below), kept in path_left.extra.
                path_put_off = true;
                path_left = PathLookup(o, T, d, prev_pdf, prev_n, prev_nb, L, cv_pending,
                                       cv_mask, 0.0, 0u);
                break;
            }
            Hit h = tq.h;
            if (cv_pending != 0.0) {
                L -= cv_bsdf_weight(o, d, prev_pdf, prev_n, tq.light, cv_mask) * cv_pending;
                cv_pending = 0.0;
            }
            if (stop) break;
            if (want_label && depth == 0u && h.prim != NO_HIT
                    && h.prim < uint(label_words.length())) {
                label_word = UintRef(PT_ADDR(PT_LABEL_WORDS)).v[h.prim];
            }
            if (label_only) return 0.0;
            if (h.prim == NO_HIT) break;   // no environment light
            Tri t = fetch_tri(h.prim);
            uint mat = mat_word(h.prim) & 0xffu;
            uint word = mat_word(h.prim);
            vec3 ng_raw = tri_normal(t);
            vec3 ng = normalize(ng_raw);
            if (mat == MAT_LIGHT) {
                float cos_l = -dot(ng, d);
                if (cos_l > 0.0) {
                    float w = 1.0;
                    if (prev_pdf > 0.0) {
                        w = bsdf_mis_weight(h.prim, h.t, cos_l, o, prev_n, prev_pdf) / prev_nb;
                    }
                    L += T * tri_radiance(h.prim) * w;
                }
                break;
            }
            if (depth == PRM_MAX_BOUNCES) break;
            Surface surf = surface_of(mat, cond);
            vec3 p = hit_point(t, h.bary);
            if (dot(ng, d) > 0.0) ng = -ng;
            // Shading frame (surface_normal).
            vec3 ns = surface_normal(h, d, p, ng, word, depth, surf);
            vec3 tb, bt;
            onb(ns, tb, bt);
            vec3 wo = to_frame(-d, tb, bt, ns);
            vec3 origin = offset_ray(p, ng);

            // Analytic direct light (control variate) at the primary hit of a conductor.
            Lobe lobe;
            bool cv = PRM_DIRECT_LIGHT == DIRECT_ANALYTIC && depth == 0u && !surf.diffuse
                && PRM_EMITTER_COUNT > 0u && conductor_lobe(surf.c, wo, tb, bt, ns, lobe);
            // A (closed form, over the rings of cv_rings) and G's light-sample term.
            uint cv_rings = 0u;
            float cv_a = cv ? analytic_rings(lobe, origin, ns, ng, 1u, cv_rings) : 0.0;
            float cv_nee_val = 0.0;

            // Next-event estimation: a light by power, then a point on it (a spot light is
            // a point: no MIS, it cannot be hit). At the camera ray's first hit
            // `[render] light_samples` = K of them and `bsdf_samples` = M BSDF directions
            // (below), each strategy's samples averaged under the one-sample MIS weights
            // (which sum to 1 whatever K and M: unbiased; the counts are not put into the
            // heuristic, which measured worse where the light sampler is the better one).
            uint nl = depth == 0u ? max(PRM_LIGHT_SAMPLES, 1u) : 1u;
            float fnl = float(nl);
            uint nb = depth == 0u ? max(PRM_BSDF_SAMPLES, 1u) : 1u;
            float fnb = float(nb);
            // The first vertex's direct light in one loop with one trace call (lavapipe
            // inlines a whole traversal at each call site): steps 0 to nl - 1 the light
            // samples and their shadow rays, step nl the path's own BSDF sample (no trace),
            // then the nb - 1 more BSDF directions and the first light each meets. The same
            // samples drawn and the same terms added in the same order as one loop each.
            uint lights = PRM_EMITTER_COUNT > 0u ? nl : 0u;
            // Split paths: the nb - 1 more directions are branches of their own (above).
            uint steps = PRM_EMITTER_COUNT > 0u ? nl + (branches > 1u ? 1u : nb) : 1u;
#if defined(SPLIT_PATHS)
            if (depth == 0u) {
                // The first hit, kept for the branches.
                v_origin = origin;
                v_ns = ns;
                v_prim = h.prim;
                v_alpha = surf.c.alpha;
            }
#endif
            // The path's own BSDF sample (step nl): its direction (local), weight and pdf.
            vec3 wi_path = vec3(0.0);
            float weight = 0.0, pdf = 0.0;
            bool sampled = false;
            vec3 d_next = vec3(0.0);
            for (uint k = 0u; k < steps; k++) {
                // This step's trace: its query, direction, bounds, and whether it is made.
                uint shadow = TQ_BLOCKED;
                vec3 shadow_d = vec3(0.0);
                float shadow_max = 0.0, shadow_light = 0.0, add = 0.0;
                bool test = false;
                float weight_j = 0.0, pdf_j = 0.0;
                TraceHint light_j = trace_no_hint();
                if (k < lights) {
                    float ue = sample_1d(rng);
                    uint ei = choose_emitter(ue);
                    LightBlock e = emitter_block(ei);
                    vec2 ul = sample_2d(rng);
                    // The sample's shadow ray (one trace for both kinds of light, below) and what
                    // it adds where nothing blocks it.
                    if (e.shape.z == LIGHT_SPOT) {
                        vec3 to = e.pos.xyz - origin;
                        float dist2 = dot(to, to);
                        float dist = sqrt(dist2);
                        vec3 wi_w = to / dist;
                        float I = spot_intensity(e, -wi_w);
                        vec3 wi = to_frame(wi_w, tb, bt, ns);
                        if (I > 0.0 && wi.z > 0.0 && dot(wi_w, ng) > 0.0) {
                            float pdf_b;
                            float f = surface_eval(surf, wo, wi, pdf_b);
                            if (f > 0.0) {
                                test = true;
                                shadow_d = wi_w;
                                shadow_max = dist;
                                add = T * f * I / (dist2 * emitter_pdf(ei) * fnl);
                            }
                        }
                    } else {
                        float area_pdf;
                        uint li = choose_light_pdf(e, ue, origin, ng, emitter_pdf(ei), area_pdf);
                        Tri lt = fetch_tri(li);
                        float su = sqrt(ul.x);
                        float u2 = ul.y;
                        vec3 q = lt.a.xyz * (1.0 - su) + lt.b.xyz * (su * (1.0 - u2)) + lt.c.xyz * (su * u2);
                        vec3 to = q - origin;
                        float dist2 = dot(to, to);
                        float dist = sqrt(dist2);
                        vec3 wi_w = to / dist;
                        float cos_l = -dot(normalize(tri_normal(lt)), wi_w);
                        vec3 wi = to_frame(wi_w, tb, bt, ns);
                        bool lit = cos_l > 0.0 && wi.z > 0.0 && dot(wi_w, ng) > 0.0;
                        // The control variate's light sample: on a ring it uses (cv_rings; such a
                        // ring lies above both horizons, so the sample is also lit, up to rounding).
                        bool cv_light = ei < 32u && (cv_rings & (1u << ei)) != 0u && cos_l > 0.0
                            && ring_clip_keeps(ring_table_clip(e, origin), wi_w);
                        float pdf_b = 0.0;
                        float f = lit || cv_light ? surface_eval(surf, wo, wi, pdf_b) : 0.0;
                        float pdf_light = dist2 / cos_l * area_pdf;
                        if (cv_light) {
                            // The control variate's light sample: MIS weight times c D Le / pdf.
                            cv_nee_val += pdf_light > 0.0
                                ? power_heuristic(pdf_light, pdf_b) * lobe.c * lobe_d(lobe, wi_w)
                                    * e.emit.x / (pdf_light * fnl)
                                : 0.0;
                        }
                        if (lit && f > 0.0) {
                            // Visible: nothing up to the sampled point, or a light triangle no
                            // nearer than it (up to rounding).
                            test = true;
                            shadow = TQ_LIGHT_VISIBLE;
                            shadow_d = wi_w;
                            shadow_max = dist * 1.001;
                            shadow_light = dist * 0.999;
                            // No other light triangle can hide this one from the origin's
                            // cell: the trace tests it alone for the lights' part.
                            uvec4 lcover = LIGHT_TRI_WEIGHTS[li - prm.light_first].cover;
                            uint cell = light_cover_cell(origin);
                            if (light_unhidden(lcover.x, cell)) {
                                light_j.a = lt.a.xyz; light_j.b = lt.b.xyz; light_j.c = lt.c.xyz;
                                light_j.prim = li;
                            }
#if defined(TRACE_SOFTWARE)
                            // Else, from the grid, only the triangle's hiders can stand in front
                            // of it (LightTri::cover.yz, src/scene/light_cover.rs): it and they
                            // tested alone give the lights' closest hit up to it, as their
                            // traversal would (the same test, ray and bounds); nearer than
                            // t_light a light hides the sample, else that hit stands for the
                            // lights' traversal as the triangle's own does above.
                            if (light_j.prim == NO_HIT && lcover.z > 0u && cell != NO_COVER_CELL) {
                                TraceRay lr = trace_setup(origin, wi_w);
                                Hit hl = hit_none(shadow_max);
                                trace_tri_test(lt.a.xyz, lt.b.xyz, lt.c.xyz, li, 1u, lr, 0.0, hl);
                                for (uint m = 0u; m < lcover.z; m++) {
                                    uint k = prm.light_first
                                        + UintRef(PT_ADDR(PT_LIGHT_WEIGHTS)).v[lcover.y + m];
                                    Tri tk = fetch_tri(k);
                                    trace_tri_test(tk.a.xyz, tk.b.xyz, tk.c.xyz, k, 1u, lr, 0.0, hl);
                                }
                                if (hl.prim != NO_HIT && hl.t < shadow_light) {
                                    test = false;   // hidden by another light triangle
                                } else if (hl.prim != NO_HIT) {
                                    Tri th = fetch_tri(hl.prim);
                                    light_j.a = th.a.xyz; light_j.b = th.b.xyz; light_j.c = th.c.xyz;
                                    light_j.prim = hl.prim;
                                }
                            }
#endif
                            add = T * f * e.emit.x * power_heuristic(pdf_light, pdf_b) / (pdf_light * fnl);
                        }
                    }
                } else if (k == lights) {
                    // BSDF sampling continues the path.
                    float u_lobe = sample_1d(rng);
                    vec3 u = vec3(u_lobe, sample_2d(rng));
                    sampled = surface_sample(surf, wo, u, wi_path, weight, pdf);
                    d_next = sampled ? normalize(from_frame(wi_path, tb, bt, ns)) : vec3(0.0);
                    if (cv_rings != 0u) {
                        cv_mask = cv_rings;
                        L += cv_a - cv_nee_val;
                        cv_pending = sampled ? lobe.c * lobe_d(lobe, d_next) / pdf : 0.0;
                    }
                } else {
                    // More BSDF samples for the direct light alone (`[render] bsdf_samples` =
                    // M at the camera ray's first hit): each of M directions (the path's own
                    // and M - 1 more) adds the light it meets with its MIS weight over M, and
                    // the control variate's term likewise; only the path's own direction goes
                    // on. The trace: the first light on the ray with occluders ignored, and
                    // whether the object hides it (the answer the closest hit would give, as
                    // a light sample's shadow test).
                    vec3 uj = vec3(sample_1d(rng), sample_2d(rng));
                    vec3 wj;
                    test = surface_sample(surf, wo, uj, wj, weight_j, pdf_j);
                    if (test) shadow_d = normalize(from_frame(wj, tb, bt, ns));
                    // A direction that can meet no light adds nothing: no trace.
                    test = test && !misses_lights(origin, shadow_d);
                    shadow = TQ_LIGHT_SEEN;
                    shadow_max = 3.0e38;
                }
                TraceResult seen;
                seen.blocked = true;
                seen.light = hit_none(3.0e38);
                if (test) seen = trace_query_hinted(shadow, origin, shadow_d, 0.0, shadow_max, shadow_light, light_j);
                if (k < lights) {
                    if (test && !seen.blocked) L += add;
                } else if (k > lights && test && seen.light.prim != NO_HIT) {
                    // Counted where the light met faces the ray above the surface.
                    Hit lj = seen.light;
                    vec3 dj = shadow_d;
                    float cos_j = -dot(normalize(tri_normal(fetch_tri(lj.prim))), dj);
                    if (cos_j > 0.0 && dot(dj, ng) > 0.0 && !seen.blocked) {
                        L += T * weight_j * tri_radiance(lj.prim)
                            * bsdf_mis_weight(lj.prim, lj.t, cos_j, origin, ng, pdf_j) / fnb;
                    }
                    if (cv_rings != 0u) {
                        L -= cv_bsdf_weight(origin, dj, pdf_j, ng, lj, cv_rings) * lobe.c * lobe_d(lobe, dj) / pdf_j;
                    }
                }
            }
            if (!sampled) break;
            // The next ray (also where a pending control-variate term is resolved when the
            // path stops here).
            prev_pdf = pdf;
            prev_n = ng;
            // (A split path's branches carry 1 / nb in T: each counts its light in full.)
            prev_nb = branches > 1u ? 1.0 : fnb;
            o = origin;
            d = d_next;
            T *= weight;
            if (depth == 0u && branches > 1u) T /= fbranches;
            bool end = !(T > 0.0);
            if (!end && depth >= 3u) {
                // (On the throughput without the branches' 1 / nb.)
                float q = min(T * fbranches, 0.95);
                if (sample_1d(rng) >= q) break;
                T /= q;
            }
            end = end || dot(d, ng) <= 0.0;   // reflected into the surface by a shading normal
            // A primary BSDF sample whose path stops before its next trace: that trace
            // still resolves the control variate's pending term.
            if (end) {
                if (cv_pending == 0.0) break;
                stop = true;
            }
        }
    }
    // More camera rays for the closed form alone (`[render] analytic_rays` = M + 1): the
    // pixel's mean of A(u) over its camera rays u estimated from this sample's ray and M
    // more (their own stratified sequence: sample index s M + j under another seed):
    // L + (sum_j A'(u_j) - M A'(u_0)) / (M + 1), zero mean for any M and any one
    // function A' of the camera ray; A' is pixel_plane_lobe's lobe over the recorded
    // rings (no trace, the rings walked once per pixel), close enough to A on a face that
    // the difference's variance is left.
    // A'(u_0) is the loop's first step (one call of pixel_plane_lobe in the shader:
    // lavapipe compiles each call's inlined copy, and this one is large).
    // The rays go in pairs (0 and 1, 2 and 3, ...) whose two lobes share one pass over
    // the recorded loops (recorded_rings2: each vertex read once); the first of a pair
    // waits for the second; a last ray without a partner (an odd count) fills both slots
    // and keeps the first. The same sums in the same order as one ray at a time.
    if (extra > 0u) {
        float sum_a = 0.0, cv_a0 = 0.0;
        Lobe first_lobe;
        vec3 first_ns = vec3(0.0, 0.0, 1.0);
        bool first_ok = false;
        for (uint j = 0u; j <= extra; j++) {
            o = o0;
            d = d0;
            if (j > 0u) {
                Sampler r = sampler_init(PRM_SAMPLE_GEN, pixel, s * extra + j - 1u, prm.cv_seed);
                pixel_ray(px, py, r, o, d);
            }
            Lobe lobe;
            vec3 ns;
            bool ok = pixel_plane_lobe(o, d, lobe, ns);
            bool pair = (j & 1u) == 1u;
            if (!pair && j < extra) {
                first_lobe = lobe;
                first_ns = ns;
                first_ok = ok;
                continue;
            }
            vec2 a = recorded_rings2(pair ? first_lobe : lobe, pair ? first_ns : ns, lobe, ns);
            float a_first = (pair ? first_ok : ok) ? a.x : 0.0;
            uint j_first = pair ? j - 1u : j;
            if (j_first == 0u) {
                cv_a0 = a_first;
            } else {
                sum_a += a_first;
            }
            if (pair) sum_a += ok ? a.y : 0.0;
        }
        float extra_term = (sum_a - float(extra) * cv_a0) / float(extra + 1u);
        if (path_put_off) {
            path_left.extra = extra_term;
        } else {
            L += extra_term;
        }
        // The rays' mean, whose variance from sample to sample is their share of the
        // sample's (what more rays would average further), for `[render]
        // analytic_rays_max`'s choice.
        if (prm.cv_ray_sums != 0u) cv_rays_of_sample = (sum_a + cv_a0) / float(extra + 1u);
    }
    // A lookup: its path's extra rays' term, last, as the sample would have added it.
    if (lookup && extra_rays > 0u) L += path_left.extra;
    return L;
}

void main() {
    uint px, py;
    if (pc.pixel_count == 0u) {
        uvec2 pix = tile_pixel(pc.tiles);
        px = pix.x;
        py = pix.y;
        if (px >= prm.width || py >= prm.height) return;
    } else {
        uint e = (gl_WorkGroupID.x + pc.tiles.group_base) * (TILE * TILE) + gl_LocalInvocationIndex;
        if (e >= pc.pixel_count) return;
        px = pixel_list[e] % prm.width;
        py = pixel_list[e] / prm.width;
    }
    uint i = py * prm.width + px;
    // Each sample is added to the pixel's running sums in sample order (read once here,
    // written back at the end), so a render's sums do not depend on how its samples were
    // split into batches: an image stopped at n samples equals one of n samples in any
    // batches (the "halves" sums below work the same way).
    float sum = accum[i];
    float sq = PRM_NOISE_SUMS == NOISE_SQUARES ? noise_sums[i] : 0.0;
    vec2 halves = PRM_NOISE_SUMS == NOISE_HALVES
        ? vec2(noise_sums[2u * i], noise_sums[2u * i + 1u]) : vec2(0.0);
    // Labels from the first n x n samples (the caller makes sure this dispatch starts at
    // sample 0): the annotation pass's thin-lens rays, traced once. Those past this
    // batch's samples are traced for their labels alone (camera ray and first hit, as
    // the pass would), so a first batch of fewer samples needs no pass either.
    uint label_count = min(pc.labels * pc.labels, LABEL_MAX_SAMPLES);
    pix_hint = trace_no_hint();
    // The centre ray's hint and bundles serve every camera ray and first-hit shadow ray
    // of a traversal that takes them; the reference plane only the analytic extra rays.
    bool plane = PRM_DIRECT_LIGHT == DIRECT_ANALYTIC && PRM_CV_EXTRA_RAYS > 0u;
    if (plane || TRACE_TAKES_HINTS) pixel_plane_init(px, py, plane);
    uint words[LABEL_MAX_SAMPLES];
    vec2 rays = vec2(0.0);
    seg_memo_clear();
    // The samples go in windows of PATH_WINDOW. A path whose bounce's ray leaves the
    // object is put off with its last terms, those of the light that ray meets
    // (radiance_sample's `defer`); at the window's end the lanes look their put-off
    // paths' lights up together (`lookup`), a lane its first, then its second, ..., so
    // that one traversal of the lights serves the lookups of many lanes where each
    // sample's bounces ran one for the few lanes whose rays came near a light (lanes run
    // a traversal together, to the longest). Then the window's samples are added to the
    // pixel's sums in sample order: the same sums, bit for bit (a lookup finishes its
    // sample from the partial radiance the path left, adding the terms put off in the
    // order the sample would have).
    float window_r[PATH_WINDOW];
    float window_rays[PATH_WINDOW];
    PathLookup put_off[PATH_WINDOW];
    uint window_n = 0u;     // samples in the window (the same in every lane)
    uint put_off_n = 0u;    // this lane's paths put off in the window
    uint looked_up = 0u;    // lookups done at the window's end (the same in every lane)
    bool looking = false;   // at the window's end (the same in every lane)
    uint s = 0u;
    while (true) {
        if (!looking && window_n > 0u && (window_n == PATH_WINDOW || s >= pc.sample_count)) {
            looking = true;
            looked_up = 0u;
        }
        if (looking && looked_up >= subgroupMax(put_off_n)) {
            uint first = pc.sample_start + s - window_n;
            for (uint k = 0u; k < window_n; k++) {
                float r = window_r[k];
                sum += r;
                sq += r * r;
                rays += vec2(window_rays[k], window_rays[k] * window_rays[k]);
                if (PRM_NOISE_SUMS == NOISE_HALVES) {
                    uint j = first + k;
                    uint level = j == 0u ? 0u : uint(findMSB(j)) + 1u;
                    bool level_starts = (j & (j - 1u)) == 0u;   // j = 0 or a power of two
                    if ((level & 1u) == 0u) {
                        halves.x = (level_starts ? 0.0 : halves.x) + r;
                    } else {
                        halves.y = (level_starts ? 0.0 : halves.y) + r;
                    }
                }
            }
            looking = false;
            window_n = 0u;
            put_off_n = 0u;
            continue;
        }
        if (!looking && s >= max(pc.sample_count, label_count)) break;
        uint word;
        bool label = !looking && s < label_count;
        bool label_only = !looking && s >= pc.sample_count;
        bool run = !looking || looked_up < put_off_n;
        if (looking && run) path_left = put_off[looked_up];
        float r = 0.0;
        if (run) {
            r = radiance_sample(i, px, py, pc.sample_start + s, label, label_only,
                                PATH_DEFER && !label_only, looking, word);
        }
        if (looking) {
            if (run) window_r[path_left.slot] = r;
            looked_up++;
            continue;
        }
        if (label) words[s] = word;
        s++;
        if (label_only) continue;
        window_r[window_n] = r;
        window_rays[window_n] = cv_rays_of_sample;
        if (path_put_off) {
            path_left.slot = window_n;
            put_off[put_off_n] = path_left;
            put_off_n++;
        }
        window_n++;
    }
    accum[i] = sum;
    if (PRM_NOISE_SUMS == NOISE_SQUARES) {
        noise_sums[i] = sq;
    } else if (PRM_NOISE_SUMS == NOISE_HALVES) {
        noise_sums[2u * i] = halves.x;
        noise_sums[2u * i + 1u] = halves.y;
    }
    if (prm.cv_ray_sums != 0u && PRM_NOISE_SUMS != NOISE_OFF) {
        uint tail = prm.width * prm.height * (PRM_NOISE_SUMS == NOISE_HALVES ? 2u : 1u);
        noise_sums[tail + 2u * i] += rays.x;
        noise_sums[tail + 2u * i + 1u] += rays.y;
    }
    if (label_count > 0u) {
        label_ids[i] = label_majority(words, label_count);
        label_coverage_out[i] = label_coverage(words, label_count);
    }
}
