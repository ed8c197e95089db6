// Pinhole camera rays shared by the image passes. Needs interface.glsl (CameraBlock).
#ifndef CAMERA_GLSL
#define CAMERA_GLSL
// Unit direction through image position `pixel_pos` (pixels, row 0 at the top) of an
// image of `size` pixels.
vec3 camera_dir(CameraBlock c, vec2 pixel_pos, vec2 size) {
    vec2 ndc = pixel_pos / size * 2.0 - 1.0;
    return normalize(c.forward.xyz + ndc.x * c.right.xyz - ndc.y * c.up.xyz);
}
#endif
