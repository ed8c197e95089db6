// Analytic direct light from ring lights, used as a control variate at the primary hit
// (`[render] direct_light = "analytic"`; docs/rendering.md, "Analytic direct light").
// Included by path_trace.comp after lights.glsl.
//
// The conductor's lobe f(wo, wi) cos(wi) is approximated by g = c D, D a linearly
// transformed cosine (Heitz et al. 2016) built from the GGX lobe, not fitted: axis the
// mirror direction r, widths 2 alpha in the plane of incidence and 2 alpha cos(theta_o)
// across it (the half-vector -> reflected-direction Jacobian for small alpha), amplitude
// c so that g(r) = f(wo, r) cos(r). D integrates in closed form over spherical polygons.
// Each ring light (a torus) is replaced, for g only, by its contour band seen from the
// shading point: BAND_SEGMENTS quads between the two points of each tube circle where
// the view ray grazes the smooth tube. The control variate is
//     A - G,  A = sum over bands of Le c integral(D over band)  (closed form),
//             G = the same integrand (c D Le times the number of band quads that contain
//                 the direction) estimated with the very light and BSDF samples of the
//                 path tracer's next-event estimation, with the same MIS weights,
// so E[G] = A exactly whatever the lobe's fit and the band's match with the tessellated
// ring: the estimate stays unbiased, and its variance falls where f V ~ g over the ring.
#ifndef ANALYTIC_LIGHT_GLSL
#define ANALYTIC_LIGHT_GLSL

// Quads of a ring's contour band (the tube's contour is sampled at this many angles
// around the ring axis).
const uint BAND_SEGMENTS = 48u;

// A linearly transformed cosine in world space: orthonormal frame (t1, t2, r), r its
// axis, widths a1 along t1 and a2 along t2; g = c D.
struct Lobe {
    vec3 t1;
    vec3 t2;
    vec3 r;
    float a1;
    float a2;
    float c;
};

// w (any length) in the lobe's cosine space: M^-1 w.
vec3 lobe_local(Lobe l, vec3 w) {
    return vec3(dot(w, l.t1) / l.a1, dot(w, l.t2) / l.a2, dot(w, l.r));
}

// D at unit direction w: D_o(M^-1 w / |M^-1 w|) |M^-1| / |M^-1 w|^3, D_o = cos / pi.
float lobe_d(Lobe l, vec3 w) {
    vec3 v = lobe_local(l, w);
    if (v.z <= 0.0) return 0.0;
    float q = dot(v, v);
    return v.z / (PI * l.a1 * l.a2 * q * q);
}

// The lobe of conductor `c` seen from wo (shading frame tb, bt, ns; wo local). False
// where it has no mass above the surface (the mirror direction at or below it).
bool conductor_lobe(Conductor c, vec3 wo, vec3 tb, vec3 bt, vec3 ns, out Lobe l) {
    vec3 r_local = vec3(-wo.x, -wo.y, wo.z);
    float fc = conductor_eval_cos(c, wo, r_local);
    vec3 wo_w = wo.x * tb + wo.y * bt + wo.z * ns;
    l.r = normalize(r_local.x * tb + r_local.y * bt + r_local.z * ns);
    vec3 across = cross(ns, wo_w);
    float al = length(across);
    l.t2 = al > 1e-6 ? across / al : tb;
    l.t1 = cross(l.t2, l.r);
    l.a1 = max(2.0 * c.alpha, 1e-4);
    l.a2 = max(2.0 * c.alpha * wo.z, 1e-4);
    l.c = fc * PI * l.a1 * l.a2;
    return fc > 0.0 && wo.z > 0.0;
}

// Angle between unit a and b times the z of their unit normal: one edge of the
// clamped-cosine polygon integral (atan2 form: exact for short edges too).
float edge_z(vec3 a, vec3 b) {
    vec3 c = cross(a, b);
    float s = length(c);
    return s > 0.0 ? atan(s, dot(a, b)) * c.z / s : 0.0;
}

// Integral of D_o = max(z, 0) / pi over the spherical polygon of the four directions v
// (cosine space, any length), clipped to z >= 0; either winding.
float quad_cos_integral(vec3 v[4]) {
    vec3 p[8];
    uint n = 0u;
    for (uint k = 0u; k < 4u; k++) {
        vec3 a = v[k], b = v[(k + 1u) & 3u];
        if (a.z >= 0.0) p[n++] = a;
        if ((a.z >= 0.0) != (b.z >= 0.0)) {
            vec3 m = mix(a, b, a.z / (a.z - b.z));
            m.z = 0.0;
            p[n++] = m;
        }
    }
    if (n < 3u) return 0.0;
    vec3 first = normalize(p[0]);
    vec3 prev = first;
    float sum = 0.0;
    for (uint k = 1u; k < n; k++) {
        vec3 cur = normalize(p[k]);
        sum += edge_z(prev, cur);
        prev = cur;
    }
    sum += edge_z(prev, first);
    return abs(sum) * (0.5 / PI);
}

// Whether direction w (cosine space, any length; 0: none) lies in the convex spherical
// quad v (either winding).
float quad_contains(vec3 v[4], vec3 w) {
    float s0 = dot(w, cross(v[0], v[1]));
    float s1 = dot(w, cross(v[1], v[2]));
    float s2 = dot(w, cross(v[2], v[3]));
    float s3 = dot(w, cross(v[3], v[0]));
    bool pos = s0 >= 0.0 && s1 >= 0.0 && s2 >= 0.0 && s3 >= 0.0;
    bool neg = s0 <= 0.0 && s1 <= 0.0 && s2 <= 0.0 && s3 <= 0.0;
    return (pos || neg) && dot(w, v[0] + v[2]) > 0.0 ? 1.0 : 0.0;
}

// The two contour points of the smooth tube circle at angle phi (ring frame u, v, axis
// ax; centre c, radii big_r, r) seen from x, as directions from x (not normalised): the
// points p = ci + r n with n . (p - x) = 0.
void ring_contour(vec3 c, vec3 u, vec3 v, vec3 ax, float big_r, float r, vec3 x, float phi,
                  out vec3 wp, out vec3 wm) {
    vec3 e = cos(phi) * u + sin(phi) * v;
    vec3 d = c + big_r * e - x;
    float a = dot(e, d), b = dot(ax, d);
    float rho = sqrt(a * a + b * b);
    float beta = atan(b, a);
    float delta = acos(clamp(-r / max(rho, 1e-30), -1.0, 1.0));
    wp = d + r * (cos(beta + delta) * e + sin(beta + delta) * ax);
    wm = d + r * (cos(beta - delta) * e + sin(beta - delta) * ax);
}

// Ring e's contour band seen from x: the integral of the lobe's D over its quads (each
// quad once), and for directions w1, w2 (unit, world; 0: none) how many quads contain
// them (m1, m2).
float ring_band(LightBlock e, Lobe l, vec3 x, vec3 w1, vec3 w2, out float m1, out float m2) {
    vec3 c = e.pos.xyz, ax = e.dir.xyz;
    float big_r = e.pos.w, r = e.dir.w;
    vec3 u, v;
    onb(ax, u, v);
    vec3 l1 = lobe_local(l, w1), l2 = lobe_local(l, w2);
    vec3 wp, wm;
    ring_contour(c, u, v, ax, big_r, r, x, 0.0, wp, wm);
    vec3 p0 = lobe_local(l, wp), m0 = lobe_local(l, wm);
    vec3 pa = p0, ma = m0;
    float sum = 0.0;
    m1 = 0.0;
    m2 = 0.0;
    float step = 2.0 * PI / float(BAND_SEGMENTS);
    for (uint i = 0u; i < BAND_SEGMENTS; i++) {
        vec3 pb = p0, mb = m0;   // the last quad closes on the first pair exactly
        if (i + 1u < BAND_SEGMENTS) {
            ring_contour(c, u, v, ax, big_r, r, x, float(i + 1u) * step, wp, wm);
            pb = lobe_local(l, wp);
            mb = lobe_local(l, wm);
        }
        vec3 q[4] = vec3[4](pa, pb, mb, ma);
        sum += quad_cos_integral(q);
        m1 += quad_contains(q, l1);
        m2 += quad_contains(q, l2);
        pa = pb;
        ma = mb;
    }
    return sum;
}
#endif
