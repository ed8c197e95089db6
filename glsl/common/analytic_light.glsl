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
// shading point: quads between the two points of each tube circle (at the ring's own
// segment angles) where the view ray grazes the smooth tube. The control variate is
//     A - G,  A = sum over bands of Le c integral(D over band)  (closed form),
//             G = the same integrand (c D Le times the number of band quads that contain
//                 the direction) estimated with the very light and BSDF samples of the
//                 path tracer's next-event estimation, with the same MIS weights,
// so E[G] = A exactly whatever the lobe's fit and the band's match with the tessellated
// ring: the estimate stays unbiased, and its variance falls where f V ~ g over the ring.
#ifndef ANALYTIC_LIGHT_GLSL
#define ANALYTIC_LIGHT_GLSL

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

// The two contour points of the smooth tube circle in direction e (unit, in the ring's
// plane; centre c, axis ax, radii big_r, r) seen from x, as directions from x (not
// normalised): the points p = c + big_r e + r n, n = cos(psi) e + sin(psi) ax, with
// n . (p - x) = 0, i.e. cos(psi - beta) = -r / rho for (rho cos beta, rho sin beta) =
// (e . d, ax . d), d = c + big_r e - x; written without trigonometric calls.
void ring_contour(vec3 c, vec3 e, vec3 ax, float big_r, float r, vec3 x,
                  out vec3 wp, out vec3 wm) {
    vec3 d = c + big_r * e - x;
    float a = dot(e, d), b = dot(ax, d);
    float rho = max(sqrt(a * a + b * b), 1e-30);
    float cb = a / rho, sb = b / rho;
    float cd = clamp(-r / rho, -1.0, 1.0);
    float sd = sqrt(max(1.0 - cd * cd, 0.0));
    float r_cb = r * (cb * cd), r_sb = r * (sb * sd), r_sbc = r * (sb * cd), r_cbs = r * (cb * sd);
    wp = d + (r_cb - r_sb) * e + (r_sbc + r_cbs) * ax;
    wm = d + (r_cb + r_sb) * e + (r_sbc - r_cbs) * ax;
}

// Ring `ring`'s contour band seen from x: the integral of the lobe's D over its quads (each
// quad once), and for directions w1, w2 (unit, world; 0: none) how many quads contain
// them (m1, m2). The band has emit.z quads (src/render/view.rs: the ring's own segments,
// at most RING_BAND_MAX), at the angles of the ring's segments (ring_light's frame,
// src/scene/camera.rs).
float ring_band(LightBlock ring, Lobe l, vec3 x, vec3 w1, vec3 w2, out float m1, out float m2) {
    vec3 c = ring.pos.xyz, ax = ring.dir.xyz;
    float big_r = ring.pos.w, r = ring.dir.w;
    uint n = clamp(uint(ring.emit.z), 3u, RING_BAND_MAX);
    vec3 u = normalize(cross(ax, abs(ax.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0)));
    vec3 l1 = lobe_local(l, w1), l2 = lobe_local(l, w2);
    float step = 2.0 * PI / float(n);
    float cs = cos(step), sn = sin(step);
    // One pass: the two contour loops' edges (when every vertex is above the cosine
    // space's horizon and every quad is wound the same way, the rungs, shared by
    // neighbouring quads in opposite directions, cancel: this is the band's integral),
    // the quads' windings and the directions' membership.
    vec3 wp, wm;
    ring_contour(c, u, ax, big_r, r, x, wp, wm);
    vec3 p0 = normalize(lobe_local(l, wp)), q0 = normalize(lobe_local(l, wm));
    vec3 e = u;   // turned by `step` per quad (the same turns in both passes)
    vec3 pa = p0, qa = q0;
    vec3 rung = cross(qa, pa);
    float r1 = dot(l1, rung), r2 = dot(l2, rung);
    bool above = pa.z > 0.0 && qa.z > 0.0;
    float sum = 0.0, wound = 0.0;
    m1 = 0.0;
    m2 = 0.0;
    for (uint i = 0u; i < n; i++) {
        vec3 pb = p0, qb = q0;   // the last quad closes on the first pair exactly
        if (i + 1u < n) {
            e = normalize(cs * e + sn * cross(ax, e));
            ring_contour(c, e, ax, big_r, r, x, wp, wm);
            pb = normalize(lobe_local(l, wp));
            qb = normalize(lobe_local(l, wm));
            above = above && pb.z > 0.0 && qb.z > 0.0;
        }
        vec3 outer = cross(pa, pb);
        vec3 inner = cross(qb, qa);
        vec3 rung_b = cross(qb, pb);
        wound += dot(outer, qa) > 0.0 ? 1.0 : -1.0;
        float so = length(outer), si = length(inner);
        sum += (so > 0.0 ? atan(so, dot(pa, pb)) * outer.z / so : 0.0)
             + (si > 0.0 ? atan(si, dot(qb, qa)) * inner.z / si : 0.0);
        // Quad (pa, pb, qb, qa): edge planes outer, -rung_b, inner, rung.
        float r1b = dot(l1, rung_b), r2b = dot(l2, rung_b);
        float a0 = dot(l1, outer), a2 = dot(l1, inner);
        bool in1 = (a0 >= 0.0 && r1b <= 0.0 && a2 >= 0.0 && r1 >= 0.0)
                || (a0 <= 0.0 && r1b >= 0.0 && a2 <= 0.0 && r1 <= 0.0);
        m1 += in1 && dot(l1, pa + qb) > 0.0 ? 1.0 : 0.0;
        float b0 = dot(l2, outer), b2 = dot(l2, inner);
        bool in2 = (b0 >= 0.0 && r2b <= 0.0 && b2 >= 0.0 && r2 >= 0.0)
                || (b0 <= 0.0 && r2b >= 0.0 && b2 <= 0.0 && r2 <= 0.0);
        m2 += in2 && dot(l2, pa + qb) > 0.0 ? 1.0 : 0.0;
        r1 = r1b;
        r2 = r2b;
        pa = pb;
        qa = qb;
    }
    if (above && abs(wound) == float(n)) return abs(sum) * (0.5 / PI);
    // Otherwise each quad on its own, clipped to the horizon (a second pass).
    sum = 0.0;
    pa = p0;
    qa = q0;
    e = u;
    for (uint i = 0u; i < n; i++) {
        vec3 pb = p0, qb = q0;
        if (i + 1u < n) {
            e = normalize(cs * e + sn * cross(ax, e));
            ring_contour(c, e, ax, big_r, r, x, wp, wm);
            pb = normalize(lobe_local(l, wp));
            qb = normalize(lobe_local(l, wm));
        }
        vec3 q[4] = vec3[4](pa, pb, qb, qa);
        sum += quad_cos_integral(q);
        pa = pb;
        qa = qb;
    }
    return sum;
}
#endif
