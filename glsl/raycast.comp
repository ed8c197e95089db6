#version 460
//! variants: rq=TRACE_RAY_QUERY sw=TRACE_SOFTWARE
// Primary rays of a pinhole camera: hit distance and geometric normal per pixel.
#include "common/trace.glsl"
#include "common/scramble.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

// Original-order triangle corners (xyz) for shading.
struct Tri { vec4 a; vec4 b; vec4 c; };
layout(std430, set = 0, binding = TRACE_BINDING_COUNT + 0) readonly buffer Geometry { Tri tris[]; };
layout(std430, set = 0, binding = TRACE_BINDING_COUNT + 1) writeonly buffer Depth { float depth[]; };
layout(std430, set = 0, binding = TRACE_BINDING_COUNT + 2) writeonly buffer Normals { uint normals[]; };

layout(push_constant) uniform Push {
    vec4 eye;        // xyz camera position
    vec4 right;      // xyz: image-plane x axis, scaled to half the plane width at distance 1
    vec4 up;         // xyz: image-plane y axis (up), scaled to half the plane height
    vec4 forward;    // xyz: unit viewing direction
    uint width; uint height; uint tiles_x; uint mult;
} pc;

void main() {
    uint tiles = pc.tiles_x * ((pc.height + 7u) / 8u);
    uint tile = scramble_group(gl_WorkGroupID.x, tiles, pc.mult);
    uint px = (tile % pc.tiles_x) * 8u + gl_LocalInvocationID.x;
    uint py = (tile / pc.tiles_x) * 8u + gl_LocalInvocationID.y;
    if (px >= pc.width || py >= pc.height) return;
    // Pixel centres; row 0 at the top.
    vec2 ndc = vec2((float(px) + 0.5) / float(pc.width), (float(py) + 0.5) / float(pc.height)) * 2.0 - 1.0;
    vec3 dir = normalize(pc.forward.xyz + ndc.x * pc.right.xyz - ndc.y * pc.up.xyz);
    Hit h = trace(pc.eye.xyz, dir, 0.0, 3.0e38);
    uint i = py * pc.width + px;
    if (h.prim == NO_HIT) {
        depth[i] = 0.0;
        normals[i] = 0u;
        return;
    }
    depth[i] = h.t;
    Tri t = tris[h.prim];
    vec3 n = normalize(cross(t.b.xyz - t.a.xyz, t.c.xyz - t.a.xyz));
    // Shown as seen: the side facing the camera.
    if (dot(n, dir) > 0.0) n = -n;
    uvec3 c = uvec3(clamp(n * 0.5 + 0.5, 0.0, 1.0) * 255.0 + 0.5);
    normals[i] = c.x | (c.y << 8) | (c.z << 16) | (255u << 24);
}
