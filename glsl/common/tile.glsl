// Tile decode shared by the image passes: each workgroup is one TILE x TILE tile of the
// image; the workgroup index (offset by the dispatch's first group, for images rendered
// in several dispatches) is scrambled (scramble.glsl) before it picks its tile.
// Needs interface.glsl (TileBlock, TILE).
#ifndef TILE_GLSL
#define TILE_GLSL
#include "scramble.glsl"

uvec2 tile_pixel(TileBlock t) {
    uint tile = scramble_group(gl_WorkGroupID.x + t.group_base, t.tile_count, t.mult);
    return uvec2((tile % t.tiles_x) * TILE + gl_LocalInvocationID.x,
                 (tile / t.tiles_x) * TILE + gl_LocalInvocationID.y);
}
#endif
