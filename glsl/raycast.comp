#version 460
//! variants: rq=TRACE_RAY_QUERY sw=TRACE_SOFTWARE sw8=TRACE_SOFTWARE_WIDE
// Primary rays of a pinhole camera: hit distance and geometric normal per pixel.
#include "common/trace.glsl"
#include "interface.glsl"
#include "common/tile.glsl"
#include "common/camera.glsl"

layout(local_size_x = TILE, local_size_y = TILE) in;

// Original-order triangle corners (xyz) for shading.
layout(std430, set = 0, binding = RC_GEOMETRY) readonly buffer Geometry { Tri tris[]; };
layout(std430, set = 0, binding = RC_DEPTH) writeonly buffer Depth { float depth[]; };
layout(std430, set = 0, binding = RC_NORMALS) writeonly buffer Normals { uint normals[]; };

layout(push_constant) uniform Push { ImagePush pc; };

void main() {
    uvec2 pix = tile_pixel(pc.tiles);
    uint px = pix.x, py = pix.y;
    if (px >= pc.width || py >= pc.height) return;
    // Pixel centres; row 0 at the top.
    vec3 dir = camera_dir(pc.cam, vec2(px, py) + 0.5, vec2(pc.width, pc.height));
    Hit h = trace(pc.cam.eye.xyz, dir, 0.0, 3.0e38);
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
