// Tile decode shared by the image passes: each workgroup is one TILE x TILE tile of the
// image; the workgroup index (offset by the dispatch's first group, for images rendered
// in several dispatches) is scrambled (scramble.glsl) before it picks its tile.
// Needs interface.glsl (TileBlock, TILE).
#ifndef TILE_GLSL
#define TILE_GLSL
#include "scramble.glsl"

// Within the tile the invocations take its pixels in Morton order (x from the even bits
// of the invocation index, y from the odd ones; TILE a power of two up to 16), so a
// subgroup of 16 consecutive invocations (lavapipe at 512-bit lanes) is a 4 x 4 block
// and one of 8 a 4 x 2 block rather than rows of 8: neighbouring rays, whose traversals
// go alike (docs/benchmarks/rendering.md, "What lavapipe compiles lane by lane").
uvec2 tile_pixel(TileBlock t) {
    uint tile = scramble_group(gl_WorkGroupID.x + t.group_base, t.tile_count, t.mult);
    uint l = gl_LocalInvocationIndex;
    uint lx = (l & 1u) | ((l >> 1u) & 2u) | ((l >> 2u) & 4u) | ((l >> 3u) & 8u);
    uint ly = ((l >> 1u) & 1u) | ((l >> 2u) & 2u) | ((l >> 3u) & 4u) | ((l >> 4u) & 8u);
    return uvec2((tile % t.tiles_x) * TILE + lx, (tile / t.tiles_x) * TILE + ly);
}
#endif
