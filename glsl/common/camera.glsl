// Camera rays shared by the image passes. Needs interface.glsl (CameraBlock).
// The model is src/scene/camera.rs's `Camera::dir` (OpenCV intrinsics and distortion,
// src/scene/calibration.rs); both must change together.
#ifndef CAMERA_GLSL
#define CAMERA_GLSL
// Newton steps inverting the distortion: calibration::UNDISTORT_ITERATIONS.
#define UNDISTORT_ITERATIONS 8
// Distorted normalised coordinates -> undistorted (OpenCV's k1, k2, p1, p2, k3), by
// Newton's method from xd; the same arithmetic as `Distortion::undistort`.
vec2 undistort(vec2 xd, float k1, float k2, float p1, float p2, float k3) {
    float x = xd.x, y = xd.y;
    for (int i = 0; i < UNDISTORT_ITERATIONS; ++i) {
        float x2 = x * x, y2 = y * y, xy = x * y;
        float r2 = x2 + y2;
        float rad = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        float drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
        float fx = x * rad + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2) - xd.x;
        float fy = y * rad + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy - xd.y;
        float j00 = rad + 2.0 * x2 * drad + 2.0 * p1 * y + 6.0 * p2 * x;
        float j01 = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y;
        float j11 = rad + 2.0 * y2 * drad + 6.0 * p1 * y + 2.0 * p2 * x;
        float det = j00 * j11 - j01 * j01;
        if (abs(det) < 1e-12) break;
        x -= (j11 * fx - j01 * fy) / det;
        y -= (j00 * fy - j01 * fx) / det;
    }
    return vec2(x, y);
}

// Unit direction through image position `pixel_pos` (pixels, row 0 at the top, (0, 0)
// the image's top-left corner) of an image of `size` pixels.
vec3 camera_dir(CameraBlock c, vec2 pixel_pos, vec2 size) {
    vec2 ndc = pixel_pos / size * 2.0 - 1.0;
    if (c.centre.xyz == vec3(0.0) && c.dist == vec4(0.0)) {
        return normalize(c.forward.xyz + ndc.x * c.right.xyz - ndc.y * c.up.xyz);
    }
    vec2 tan_half = vec2(length(c.right.xyz), length(c.up.xyz));
    vec2 xd = (ndc - c.centre.xy) * tan_half;
    vec2 xu = undistort(xd, c.dist.x, c.dist.y, c.dist.z, c.dist.w, c.centre.z);
    return normalize(c.forward.xyz + (xu.x / tan_half.x) * c.right.xyz
                     - (xu.y / tan_half.y) * c.up.xyz);
}

// The bounding box (x0, x1, y0, y1) of pixel `p`'s footprint (p to p + 1, pixels) on the
// plane at depth zf along the unit forward axis `fwd`, in coordinates along the unit
// `right` and `up` axes from the eye: its corners' rays there, widened by a tenth of its
// size (a lens's distortion bends a pixel's edges by far less). The camera rays' bundle
// of path_trace.comp (trace_bundle_init).
vec4 camera_pixel_footprint(CameraBlock c, vec2 p, vec2 size, vec3 right, vec3 up, vec3 fwd,
                            float zf) {
    vec4 q = vec4(3.0e38, -3.0e38, 3.0e38, -3.0e38);
    for (uint k = 0u; k < 4u; k++) {
        vec3 d = camera_dir(c, p + vec2(float(k & 1u), float(k >> 1u)), size);
        vec2 xy = vec2(dot(d, right), dot(d, up)) * (zf / dot(d, fwd));
        q = vec4(min(q.x, xy.x), max(q.y, xy.x), min(q.z, xy.y), max(q.w, xy.y));
    }
    float pad = 0.1 * max(q.y - q.x, q.w - q.z);
    return q + vec4(-pad, pad, -pad, pad);
}

// Shirley-Chiu concentric map of [0, 1)^2 onto the unit disc (keeps stratification).
vec2 concentric_disc(vec2 u) {
    vec2 o = 2.0 * u - 1.0;
    if (o.x == 0.0 && o.y == 0.0) return vec2(0.0);
    float r, phi;
    if (abs(o.x) > abs(o.y)) {
        r = o.x;
        phi = 0.78539816339 * (o.y / o.x);
    } else {
        r = o.y;
        phi = 1.57079632679 - 0.78539816339 * (o.x / o.y);
    }
    return r * vec2(cos(phi), sin(phi));
}

// Primary ray of the thin lens (eye.w = aperture radius, forward.w = focus distance):
// the pinhole ray through `pixel_pos` meets the plane of focus (perpendicular to forward
// at the focus distance); the ray leaves the lens point `lens` (u in [0, 1)^2, mapped
// onto the aperture disc) towards that point. Radius 0: the pinhole ray, o = eye.
// Same model as `Camera::lens_ray`.
void camera_ray(CameraBlock c, vec2 pixel_pos, vec2 size, vec2 lens, out vec3 o, out vec3 d) {
    d = camera_dir(c, pixel_pos, size);
    o = c.eye.xyz;
    if (c.eye.w > 0.0) {
        vec3 focus = o + d * (c.forward.w / dot(d, c.forward.xyz));
        vec2 a = concentric_disc(lens) * c.eye.w;
        o += a.x * normalize(c.right.xyz) + a.y * normalize(c.up.xyz);
        d = normalize(focus - o);
    }
}
#endif
