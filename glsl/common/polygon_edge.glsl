// One edge of the clamped-cosine polygon integral (the closed form of the analytic direct
// light, analytic_light.glsl; LTC, Heitz et al. 2016): the angle between two directions
// times the z of their unit normal, over 2 pi. Apart from analytic_light.glsl so that
// glsl/edge_check.comp can test it against float64 (tests/shader_convert.rs).
#ifndef POLYGON_EDGE_GLSL
#define POLYGON_EDGE_GLSL
#extension GL_EXT_control_flow_attributes : require

// theta / (2 pi sin theta) of an angle theta in (0, pi / 2], from y = |cos theta|: a
// rational fit (Hill's, of the LTC reference code; relative error below 1.5e-6 over
// that range, and an obtuse angle's 1 / (2 sin theta) minus the fit within 1e-6 of the
// angle: measured in float64 over 2 million angles). One edge of the clamped-cosine
// polygon integral is this times the z of the edge's cross product (edge_z, edge_z_unit).
float edge_fit(float y) {
    return (0.8543985 + (0.4965155 + 0.0145206 * y) * y) / (3.4175940 + (4.1616724 + y) * y);
}

// One edge of the clamped-cosine polygon integral between a and b (any lengths), over
// 2 pi: the angle between them times the z of their unit normal, / (2 pi). From the
// fit above, not `atan`: NIR's atan is itself a polynomial (relative error 2.1e-5 for
// short edges, the ring's), with a division, a reciprocal and minima and maxima that
// lavapipe splits into 256-bit halves; the fit is 12 times closer (1.7e-6 of the angle
// against 2.1e-5 on lavapipe, tests/shader_convert.rs) and cheaper
// (docs/benchmarks/dataset.md, "The closed form's edges without atan"). An obtuse edge
// (x <= 0) takes pi / sin theta minus the fit, sin theta from the cross product's
// length (accurate near pi too), behind a real branch (few edges are obtuse). 0 where a or
// b is 0 or they are opposite.
float edge_z(vec3 a, vec3 b) {
    float r2 = dot(a, a) * dot(b, b);
    float inv_r = inversesqrt(r2);
    float x = dot(a, b) * inv_r;
    float ts = edge_fit(abs(x));
    bool ok = r2 > 0.0;
    [[dont_flatten]] if (!(x > 0.0)) {
        float s = length(cross(a, b)) * inv_r;
        ts = 0.5 / s - ts;
        ok = ok && s > 0.0;
    }
    return ok ? (a.x * b.y - a.y * b.x) * inv_r * ts : 0.0;
}

// One edge of the clamped-cosine polygon integral between unit a and b, over 2 pi:
// edge_z for unit vectors (edge_fit; no normalisation), what the extra camera rays'
// closed form takes. An obtuse edge (one passing near the lobe's axis: few of a loop's)
// takes pi / sin(angle) minus the acute fit; that square root and division sit behind a
// real branch (`[[dont_flatten]]`): as a select, which the compiler makes of so small an
// `if`, lavapipe computed them for every edge of every lane (the same values; with the
// cone's horizon test, recorded_rings2, 0.987x the path tracing of whole paper frames,
// docs/benchmarks/dataset.md).
float edge_z_unit(vec3 a, vec3 b) {
    float x = dot(a, b);
    float v = edge_fit(abs(x));
    float ts = v;
    [[dont_flatten]] if (!(x > 0.0)) ts = 0.5 * inversesqrt(max(1.0 - x * x, 1e-7)) - v;
    return (a.x * b.y - a.y * b.x) * ts;
}

#endif
