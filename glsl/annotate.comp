#version 460
//! variants: rq=TRACE_RAY_QUERY sw=TRACE_SOFTWARE sw8=TRACE_SOFTWARE_WIDE
// Annotation pass: per pixel the label of the first surface hit by the centre ray
// (class, defect instance, face) and the share of an n x n stratified grid of rays in
// the pixel whose first hit is a defect triangle. Occlusion is exact: these are first
// hits of camera rays against the same geometry the image is rendered from.
// Under a thin lens (cam.eye.w > 0) the rays are the path tracer's first n x n primary
// rays (same sampler, seed, pixel jitter and aperture points): the label is the label
// word most of them hit (ties: the earliest sample), coverage the share hitting a defect
// (common/labels.glsl; the path tracer resolves its own samples' words the same way when
// `[render] labels` takes them from its samples, and then this pass does not run).
#include "common/trace.glsl"
#include "interface.glsl"
#include "common/tile.glsl"
#include "common/camera.glsl"
#include "common/sampler.glsl"
#include "common/labels.glsl"

layout(local_size_x = TILE, local_size_y = TILE) in;

// Per original triangle: face | class << LABEL_CLASS_SHIFT | instance << LABEL_INSTANCE_SHIFT.
layout(std430, set = 0, binding = AN_LABELS) readonly buffer Labels { uint labels[]; };
layout(std430, set = 0, binding = AN_IDS) writeonly buffer Ids { uint ids[]; };
layout(std430, set = 0, binding = AN_COVERAGE) writeonly buffer Coverage { float coverage[]; };

layout(push_constant) uniform Push { ImagePush pc; };

uint label_at(vec2 pixel_pos) {
    vec3 dir = camera_dir(pc.cam, pixel_pos, vec2(pc.width, pc.height));
    Hit h = trace(pc.cam.eye.xyz, dir, 0.0, 3.0e38);
    // Triangles past the labelled ones (a second trace level: the view's light) carry none.
    return h.prim == NO_HIT || h.prim >= uint(labels.length()) ? 0u : labels[h.prim];
}

uint label_of_ray(vec3 o, vec3 d) {
    Hit h = trace(o, d, 0.0, 3.0e38);
    return h.prim == NO_HIT || h.prim >= uint(labels.length()) ? 0u : labels[h.prim];
}

// Thin lens: the path tracer's first n x n primary rays of pixel i.
void lens_labels(uint i, uint px, uint py, uint n) {
    uint count = min(n * n, LABEL_MAX_SAMPLES);
    uint words[LABEL_MAX_SAMPLES];
    for (uint s = 0u; s < count; ++s) {
        Sampler rng = sampler_init(uint(pc.cam.centre.w), i, s, pc.seed);
        vec2 jitter = sample_2d(rng);
        vec2 lens = sample_2d(rng);
        vec3 o, d;
        camera_ray(pc.cam, vec2(px, py) + jitter, vec2(pc.width, pc.height), lens, o, d);
        words[s] = label_of_ray(o, d);
    }
    ids[i] = label_majority(words, count);
    coverage[i] = label_coverage(words, count);
}

void main() {
    uvec2 pix = tile_pixel(pc.tiles);
    uint px = pix.x, py = pix.y;
    if (px >= pc.width || py >= pc.height) return;
    uint i = py * pc.width + px;
    if (pc.cam.eye.w > 0.0) {
        lens_labels(i, px, py, max(pc.grid, 1u));
        return;
    }
    ids[i] = label_at(vec2(px, py) + 0.5);
    uint n = max(pc.grid, 1u);
    uint defect = 0u;
    for (uint sy = 0u; sy < n; ++sy) {
        for (uint sx = 0u; sx < n; ++sx) {
            vec2 sub = (vec2(sx, sy) + 0.5) / float(n);
            uint l = label_at(vec2(px, py) + sub);
            defect += label_is_defect(l) ? 1u : 0u;
        }
    }
    coverage[i] = float(defect) / float(n * n);
}
