#version 460
//! variants: rq=TRACE_RAY_QUERY sw=TRACE_SOFTWARE
// Annotation pass: per pixel the label of the first surface hit by the centre ray
// (class, defect instance, face) and the share of an n x n stratified grid of rays in
// the pixel whose first hit is a defect triangle. Occlusion is exact: these are first
// hits of camera rays against the same geometry the image is rendered from.
#include "common/trace.glsl"
#include "common/scramble.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

// Per original triangle: face | class << 8 | instance << 16.
layout(std430, set = 0, binding = TRACE_BINDING_COUNT + 0) readonly buffer Labels { uint labels[]; };
layout(std430, set = 0, binding = TRACE_BINDING_COUNT + 1) writeonly buffer Ids { uint ids[]; };
layout(std430, set = 0, binding = TRACE_BINDING_COUNT + 2) writeonly buffer Coverage { float coverage[]; };

layout(push_constant) uniform Push {
    vec4 eye; vec4 right; vec4 up; vec4 forward;
    uint width; uint height; uint tiles_x; uint mult;
    uint grid; uint pad0; uint pad1; uint pad2;
} pc;

uint label_at(vec2 pixel_pos) {
    vec2 ndc = pixel_pos / vec2(pc.width, pc.height) * 2.0 - 1.0;
    vec3 dir = normalize(pc.forward.xyz + ndc.x * pc.right.xyz - ndc.y * pc.up.xyz);
    Hit h = trace(pc.eye.xyz, dir, 0.0, 3.0e38);
    // Triangles past the labelled ones (a second trace level: the view's light) carry none.
    return h.prim == NO_HIT || h.prim >= uint(labels.length()) ? 0u : labels[h.prim];
}

void main() {
    uint tiles = pc.tiles_x * ((pc.height + 7u) / 8u);
    uint tile = scramble_group(gl_WorkGroupID.x, tiles, pc.mult);
    uint px = (tile % pc.tiles_x) * 8u + gl_LocalInvocationID.x;
    uint py = (tile / pc.tiles_x) * 8u + gl_LocalInvocationID.y;
    if (px >= pc.width || py >= pc.height) return;
    uint i = py * pc.width + px;
    ids[i] = label_at(vec2(px, py) + 0.5);
    uint n = max(pc.grid, 1u);
    uint defect = 0u;
    for (uint sy = 0u; sy < n; ++sy) {
        for (uint sx = 0u; sx < n; ++sx) {
            vec2 sub = (vec2(sx, sy) + 0.5) / float(n);
            uint l = label_at(vec2(px, py) + sub);
            defect += ((l >> 8) & 0xffu) != 0u ? 1u : 0u;
        }
    }
    coverage[i] = float(defect) / float(n * n);
}
