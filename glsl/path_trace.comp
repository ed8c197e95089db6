#version 460
//! variants: rq=TRACE_RAY_QUERY sw=TRACE_SOFTWARE
// Unidirectional path tracer for inspection images: pinhole camera, rough conductor
// object, Lambertian table, ring light (emissive triangles of a tessellated torus).
// Next-event estimation on the light (uniform by area over its triangles) combined with
// BSDF sampling by MIS (power heuristic), Russian roulette after 3 bounces. Each
// dispatch adds `sample_count` samples per pixel into `accum` (a running sum).
// See docs/rendering.md for every approximation and its parameter.
#include "common/trace.glsl"
#include "common/scramble.glsl"
#include "common/rng.glsl"
#include "common/offset_ray.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

#define MAT_CONDUCTOR 0u
#define MAT_TABLE 1u
#define MAT_LIGHT 2u

struct Tri { vec4 a; vec4 b; vec4 c; };
layout(std430, set = 0, binding = TRACE_BINDING_COUNT + 0) readonly buffer Geometry { Tri tris[]; };
layout(std430, set = 0, binding = TRACE_BINDING_COUNT + 1) readonly buffer Materials { uint mats[]; };
// x: triangle index, y: float bits of the inclusive area CDF.
layout(std430, set = 0, binding = TRACE_BINDING_COUNT + 2) readonly buffer Lights { uvec2 lights[]; };
layout(std430, set = 0, binding = TRACE_BINDING_COUNT + 3) readonly buffer Energy { float energy[]; };
float energy_at(uint i) { return energy[i]; }
#include "common/ggx.glsl"

layout(std430, set = 0, binding = TRACE_BINDING_COUNT + 4) readonly buffer Params {
    vec4 eye;       // xyz camera position
    vec4 right;     // image-plane x axis scaled to the half width at distance 1
    vec4 up;        // image-plane y axis scaled to the half height
    vec4 forward;   // unit view direction
    uint width; uint height; uint max_bounces; uint seed;
    float alpha; float ior_n; float ior_k; float f_avg;
    uint comp; uint light_count; uint pad0; uint pad1;
    float table_albedo; float radiance; float light_area; float pad2;
} prm;
layout(std430, set = 0, binding = TRACE_BINDING_COUNT + 5) buffer Accum { float accum[]; };

layout(push_constant) uniform Push {
    uint sample_start; uint sample_count; uint tiles_x; uint mult;
} pc;

float power_heuristic(float a, float b) {
    float a2 = a * a, b2 = b * b;
    return a2 + b2 > 0.0 ? a2 / (a2 + b2) : 0.0;
}

uint pick_light(float u) {
    uint lo = 0u, hi = prm.light_count - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (u < uintBitsToFloat(lights[mid].y)) hi = mid; else lo = mid + 1u;
    }
    return lights[lo].x;
}

vec3 tri_normal(Tri t) { return cross(t.b.xyz - t.a.xyz, t.c.xyz - t.a.xyz); }

// f * cos and pdf of the surface at a hit, in the local frame (normal +z).
float surface_eval(uint mat, Conductor c, vec3 wo, vec3 wi, out float pdf) {
    if (mat == MAT_TABLE) {
        pdf = wi.z > 0.0 ? wi.z / PI : 0.0;
        return wi.z > 0.0 && wo.z > 0.0 ? prm.table_albedo / PI * wi.z : 0.0;
    }
    pdf = conductor_pdf(c, wo, wi);
    return conductor_eval_cos(c, wo, wi);
}

bool surface_sample(uint mat, Conductor c, vec3 wo, vec3 u, out vec3 wi, out float weight, out float pdf) {
    if (mat == MAT_TABLE) {
        wi = cosine_hemisphere(u.y, u.z);
        pdf = wi.z / PI;
        weight = prm.table_albedo;
        return wi.z > 0.0 && wo.z > 0.0;
    }
    return conductor_sample(c, wo, u, wi, weight, pdf);
}

float radiance_sample(uint pixel, uint px, uint py, uint s) {
    Rng rng = rng_init(pixel, s, prm.seed);
    vec2 jitter = vec2(rng_next(rng), rng_next(rng));
    vec2 ndc = (vec2(px, py) + jitter) / vec2(prm.width, prm.height) * 2.0 - 1.0;
    vec3 o = prm.eye.xyz;
    vec3 d = normalize(prm.forward.xyz + ndc.x * prm.right.xyz - ndc.y * prm.up.xyz);
    Conductor cond;
    cond.alpha = clamp(prm.alpha, 1e-4, 1.0);
    cond.n = prm.ior_n;
    cond.k = prm.ior_k;
    cond.comp = prm.comp != 0u;
    cond.f_avg = prm.f_avg;

    float L = 0.0;
    float T = 1.0;
    float prev_pdf = 0.0;   // solid-angle pdf of the BSDF sample that made this ray; 0 = camera
    for (uint depth = 0u; depth <= prm.max_bounces; depth++) {
        Hit h = trace(o, d, 0.0, 3.0e38);
        if (h.prim == NO_HIT) break;   // no environment light
        Tri t = tris[h.prim];
        uint mat = mats[h.prim];
        vec3 ng_raw = tri_normal(t);
        vec3 ng = normalize(ng_raw);
        if (mat == MAT_LIGHT) {
            float cos_l = -dot(ng, d);
            if (cos_l > 0.0) {
                float w = 1.0;
                if (prev_pdf > 0.0) {
                    float pdf_light = h.t * h.t / (cos_l * prm.light_area);
                    w = power_heuristic(prev_pdf, pdf_light);
                }
                L += T * prm.radiance * w;
            }
            break;
        }
        if (depth == prm.max_bounces) break;
        // The hit point from the barycentrics is as exact as the triangle itself,
        // unlike o + t d whose error grows with the distance travelled.
        vec3 p = t.a.xyz * (1.0 - h.bary.x - h.bary.y) + t.b.xyz * h.bary.x + t.c.xyz * h.bary.y;
        if (dot(ng, d) > 0.0) ng = -ng;
        vec3 tb, bt;
        onb(ng, tb, bt);
        vec3 wo = vec3(dot(-d, tb), dot(-d, bt), dot(-d, ng));
        vec3 origin = offset_ray(p, ng);

        // Next-event estimation on the ring light.
        if (prm.light_count > 0u && prm.radiance > 0.0) {
            uint li = pick_light(rng_next(rng));
            Tri lt = tris[li];
            float su = sqrt(rng_next(rng));
            float u2 = rng_next(rng);
            vec3 q = lt.a.xyz * (1.0 - su) + lt.b.xyz * (su * (1.0 - u2)) + lt.c.xyz * (su * u2);
            vec3 to = q - origin;
            float dist2 = dot(to, to);
            float dist = sqrt(dist2);
            vec3 wi_w = to / dist;
            float cos_l = -dot(normalize(tri_normal(lt)), wi_w);
            vec3 wi = vec3(dot(wi_w, tb), dot(wi_w, bt), dot(wi_w, ng));
            if (cos_l > 0.0 && wi.z > 0.0) {
                float pdf_b;
                float f = surface_eval(mat, cond, wo, wi, pdf_b);
                if (f > 0.0) {
                    Hit s = trace(origin, wi_w, 0.0, dist * 1.001);
                    bool visible = s.prim == NO_HIT
                        || (mats[s.prim] == MAT_LIGHT && s.t >= dist * 0.999);
                    if (visible) {
                        float pdf_light = dist2 / (cos_l * prm.light_area);
                        L += T * f * prm.radiance * power_heuristic(pdf_light, pdf_b) / pdf_light;
                    }
                }
            }
        }

        // BSDF sampling continues the path.
        vec3 u = vec3(rng_next(rng), rng_next(rng), rng_next(rng));
        vec3 wi;
        float weight, pdf;
        if (!surface_sample(mat, cond, wo, u, wi, weight, pdf)) break;
        T *= weight;
        if (!(T > 0.0)) break;
        if (depth >= 3u) {
            float q = min(T, 0.95);
            if (rng_next(rng) >= q) break;
            T /= q;
        }
        prev_pdf = pdf;
        o = origin;
        d = normalize(wi.x * tb + wi.y * bt + wi.z * ng);
    }
    return L;
}

void main() {
    uint tiles = pc.tiles_x * ((prm.height + 7u) / 8u);
    uint tile = scramble_group(gl_WorkGroupID.x, tiles, pc.mult);
    uint px = (tile % pc.tiles_x) * 8u + gl_LocalInvocationID.x;
    uint py = (tile / pc.tiles_x) * 8u + gl_LocalInvocationID.y;
    if (px >= prm.width || py >= prm.height) return;
    uint i = py * prm.width + px;
    float sum = 0.0;
    for (uint s = 0u; s < pc.sample_count; s++) {
        sum += radiance_sample(i, px, py, pc.sample_start + s);
    }
    accum[i] += sum;
}
