#version 460
//! variants: rq=TRACE_RAY_QUERY sw=TRACE_SOFTWARE
// Annotation pass: per pixel the label of the first surface hit by the centre ray
// (class, defect instance, face) and the share of an n x n stratified grid of rays in
// the pixel whose first hit is a defect triangle. Occlusion is exact: these are first
// hits of camera rays against the same geometry the image is rendered from.
#include "common/trace.glsl"
#include "interface.glsl"
#include "common/tile.glsl"
#include "common/camera.glsl"

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

void main() {
    uvec2 pix = tile_pixel(pc.tiles);
    uint px = pix.x, py = pix.y;
    if (px >= pc.width || py >= pc.height) return;
    uint i = py * pc.width + px;
    ids[i] = label_at(vec2(px, py) + 0.5);
    uint n = max(pc.grid, 1u);
    uint defect = 0u;
    for (uint sy = 0u; sy < n; ++sy) {
        for (uint sx = 0u; sx < n; ++sx) {
            vec2 sub = (vec2(sx, sy) + 0.5) / float(n);
            uint l = label_at(vec2(px, py) + sub);
            defect += ((l >> LABEL_CLASS_SHIFT) & 0xffu) != 0u ? 1u : 0u;
        }
    }
    coverage[i] = float(defect) / float(n * n);
}
