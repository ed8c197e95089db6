// Analytic direct light from ring lights, used as a control variate at the primary hit
// (`[render] direct_light = "analytic"`; docs/rendering.md, "Analytic direct light").
// Included by path_trace.comp after lights.glsl.
//
// The conductor's lobe f(wo, wi) cos(wi) is approximated by g = c D, D a linearly
// transformed cosine (Heitz et al. 2016) built from the GGX lobe, not fitted: axis the
// mirror direction r, widths 2 alpha in the plane of incidence and 2 alpha cos(theta_o)
// across it (the half-vector -> reflected-direction Jacobian for small alpha), amplitude
// c so that g(r) = f(wo, r) cos(r). D integrates in closed form over spherical polygons.
// D integrates in closed form over each ring light's tessellated torus as seen from the
// shading point: over the quads facing it, as edge terms along their boundary
// (ring_integral). The control variate is
//     A - G,  A = sum over rings of Le c integral(D over the ring)  (closed form),
//             G = the same integrand c D Le estimated with the very light and BSDF
//                 samples of the path tracer's next-event estimation, with the same MIS
//                 weights (the BSDF sample counts where the light triangle it meets first,
//                 occluders ignored, is the ring's),
// so E[G] = A exactly whatever the lobe's fit, at every shading point where each ray
// meets the ring at most once and no other light stands in front of it (ring_cv_valid;
// elsewhere the ring is left to the sampled estimator alone): the estimate stays
// unbiased, and its variance falls where f V ~ g over the ring.
#ifndef ANALYTIC_LIGHT_GLSL
#define ANALYTIC_LIGHT_GLSL
#extension GL_KHR_shader_subgroup_vote : require

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

// A closed loop of directions (cosine space, any length) whose edges are summed as
// edge_z: `sum` / (2 pi) is the clamped-cosine integral over the region it bounds when
// every vertex is above the horizon (`above`).
struct Loop {
    vec3 first;
    vec3 prev;
    float sum;
    bool above;
};

void loop_start(out Loop lp, vec3 w) {
    lp.first = w;
    lp.prev = w;
    lp.sum = 0.0;
    lp.above = w.z > 0.0;
}

void loop_add(inout Loop lp, vec3 w) {
    lp.sum += edge_z(lp.prev, w);
    lp.prev = w;
    lp.above = lp.above && w.z > 0.0;
}

// One ring (a tessellated torus, as src/scene/camera.rs `ring_light` makes it) as the
// walk over its segments sees it from x, with the segment being walked.
struct Ring {
    vec3 d0;     // centre - x
    vec3 ax;     // unit axis
    float big_r; // major radius
    float r;     // tube radius
    int m;       // segments around the tube
    vec2 step;   // cos, sin of 2 pi / m
    vec2 half_step; // of pi / m
    float a, b, k;  // the segment's facing test (ring_integral)
    vec3 ns, ng;    // the shading point's shading and geometric normals
};

vec2 rot(vec2 v, vec2 cs) { return vec2(v.x * cs.x - v.y * cs.y, v.y * cs.x + v.x * cs.y); }
vec2 rot_back(vec2 v, vec2 cs) { return vec2(v.x * cs.x + v.y * cs.y, v.y * cs.x - v.x * cs.y); }

// Whether the quad whose first tube vertex has angle cos, sin `v` (the quad's normal at
// v turned by half a step) faces x, in the segment of g.a, g.b, g.k.
bool ring_faces(Ring g, vec2 v) {
    vec2 f = rot(v, g.half_step);
    return f.x * g.a + f.y * g.b > g.k;
}

// The tube vertex at angle cos, sin `v` of the section whose radial direction is `rad`
// (at that angle from `rad` towards the axis, as ring_light places it), as a direction
// from x in the lobe's cosine space; below its horizon (z < 0, failing the loop's
// `above`) where it is below the shading point's shading or geometric horizon, where E
// takes no light (its light sample needs both; G would count what E cannot).
vec3 ring_point(Ring g, Lobe l, vec3 rad, vec2 v) {
    vec3 w = g.d0 + rad * (g.big_r + g.r * v.x) + g.ax * (g.r * v.y);
    return dot(w, g.ns) > 0.0 && dot(w, g.ng) > 0.0 ? lobe_local(l, w) : vec3(0.0, 0.0, -1.0);
}

// One side of the facing run: its boundary loop and its tube vertex (cos, sin of its
// angle): `lo` the first facing quad's first vertex, else the vertex after the last
// facing quad.
struct Side {
    Loop lp;
    vec2 v;
};

// Whether tube vertex `v` is the current segment's run boundary already (what
// ring_side checks before it steps): the first facing quad's first vertex (`lo`), else
// the vertex after the last facing quad.
bool ring_settled(Ring g, vec2 v, bool lo) {
    bool after = ring_faces(g, v);
    bool before = ring_faces(g, rot_back(v, g.step));
    return lo ? after && !before : !after && before;
}

// Moves side `s` to the current segment's run boundary, one tube vertex at a time (the
// boundary's edges along the section at `rad`, added to the loop when `add`); false if
// it takes more than m steps (no quad of the segment faces x, or every one does).
bool ring_side(inout Side s, Ring g, Lobe l, vec3 rad, bool lo, bool add) {
    // lo: the quad after the vertex faces x, the one before does not; hi: the reverse.
    bool after = ring_faces(g, s.v);
    bool up = lo ? !after : after;
    for (int q = 0; q <= g.m; q++) {
        if (up) {
            if (q > 0 && (lo ? after : !after)) return true;
            s.v = rot(s.v, g.step);
            after = ring_faces(g, s.v);
        } else {
            bool before = ring_faces(g, rot_back(s.v, g.step));
            if (lo ? !before : before) return true;
            s.v = rot_back(s.v, g.step);
        }
        if (add) loop_add(s.lp, ring_point(g, l, rad, s.v));
    }
    return false;
}

// The integral of the lobe's D over the directions from x that meet ring light e (its
// tessellated torus): the sum of D over the quads facing x, written (Stokes) as edge
// terms along the boundary of the facing set, the contour generator. Within a ring
// segment (between sections i and i + 1) the quad of tube angles theta_j, theta_j+1
// faces x when
//     cos(theta) (X_r - R cn) + sin(theta) cn X_a > r cn cos(pi / m),
// theta = theta_j + pi / m its normal's tube angle, X_r and X_a x - centre along the
// segment's middle radial direction and along the axis, cn = cos(pi / n): one run of
// tube indices per segment. The boundary is two loops: per segment the ring-direction
// edge at the run's first vertex (its last), and along the next section from one
// segment's run boundary to the next one's (ring_side walks there; the first segment's
// boundary is solved in closed form). Each facing quad is counted once where no ray from
// x meets the tube twice (ring_cv_valid). False (`ok`) where a segment has no facing
// quad or every one, or a loop vertex lies at or below the cosine space's horizon or
// below the shading point's shading (ns) or geometric (ng) horizon: the ring's image is
// then within all three (each a hemisphere, the image within 53 degrees).
// With `divisor` > 1 the same over a coarser torus: the light's n sections around its
// axis become n / divisor (at least 3), its tube keeps its m.
float ring_integral(LightBlock e, Lobe l, vec3 x, vec3 ns, vec3 ng, uint divisor, out bool ok) {
    ok = false;
    uint n = uint(e.emit.z);
    Ring g;
    g.ns = ns;
    g.ng = ng;
    g.d0 = e.pos.xyz - x;
    g.ax = e.dir.xyz;
    g.big_r = e.pos.w;
    g.r = e.dir.w;
    g.m = n >= 3u ? int(e.shape.y / (2u * n)) : 0;
    if (g.m < 3) return 0.0;
    n = max(n / divisor, 3u);
    float dth = 2.0 * PI / float(g.m), dphi = 2.0 * PI / float(n);
    g.step = vec2(cos(dth), sin(dth));
    g.half_step = vec2(cos(0.5 * dth), sin(0.5 * dth));
    vec2 ring_step = vec2(cos(dphi), sin(dphi));
    float cn = cos(0.5 * dphi);
    g.k = g.r * cn * g.half_step.x;
    g.b = -cn * dot(g.ax, g.d0);
    // The same first radial direction as ring_light (src/scene/camera.rs).
    vec3 e1 = normalize(cross(g.ax, abs(g.ax.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0)));
    vec3 e2 = cross(g.ax, e1);
    // X_r - R cn of a segment from its two radial directions (their sum is 2 cn long).
    float d0_1 = dot(g.d0, e1), d0_2 = dot(g.d0, e2);
    // Segment 0's run in closed form: quads with cos(theta - beta) > k / rho.
    float a0 = -d0_1 * (1.0 + ring_step.x) / (2.0 * cn) - d0_2 * ring_step.y / (2.0 * cn)
        - g.big_r * cn;
    g.a = a0;
    float rho = length(vec2(g.a, g.b));
    if (!(rho > g.k)) return 0.0;
    float beta = atan(g.b, g.a), delta = acos(g.k / rho);
    float th_lo = ceil((beta - delta) / dth - 0.5) * dth;
    float th_hi = (floor((beta + delta) / dth - 0.5) + 1.0) * dth;
    Side lo, hi;
    lo.v = vec2(cos(th_lo), sin(th_lo));
    hi.v = vec2(cos(th_hi), sin(th_hi));
    // (Rounding may leave the closed form a vertex off: the walk settles it.)
    if (!ring_side(lo, g, l, e1, true, false) || !ring_side(hi, g, l, e1, false, false)) return 0.0;
    loop_start(lo.lp, ring_point(g, l, e1, lo.v));
    loop_start(hi.lp, ring_point(g, l, e1, hi.v));
    vec2 phi = vec2(1.0, 0.0);   // cos, sin of section i's angle
    vec3 rad = e1;
    for (uint i = 0u; i < n; i++) {
        vec2 phi_next = normalize(rot(phi, ring_step));
        vec3 rad_next = i + 1u == n ? e1 : e1 * phi_next.x + e2 * phi_next.y;
        if (i > 0u) {
            g.a = -(d0_1 * (phi.x + phi_next.x) + d0_2 * (phi.y + phi_next.y)) / (2.0 * cn)
                - g.big_r * cn;
            // Most segments keep both boundaries: the walk (a loop whose steps every lane
            // of a subgroup pays for on lavapipe) runs only where a lane's boundary moves
            // (a vote: a uniform branch, skipped for real).
            bool settled = ring_settled(g, lo.v, true) && ring_settled(g, hi.v, false);
            if (subgroupAny(!settled)
                    && (!ring_side(lo, g, l, rad, true, true) || !ring_side(hi, g, l, rad, false, true))) {
                return 0.0;
            }
        }
        loop_add(lo.lp, ring_point(g, l, rad_next, lo.v));
        loop_add(hi.lp, ring_point(g, l, rad_next, hi.v));
        phi = phi_next;
        rad = rad_next;
    }
    // Back at section 0: along it to segment 0's run boundary, and closed.
    g.a = a0;
    if (!ring_side(lo, g, l, e1, true, true) || !ring_side(hi, g, l, e1, false, true)) return 0.0;
    loop_add(lo.lp, lo.lp.first);
    loop_add(hi.lp, hi.lp.first);
    ok = lo.lp.above && hi.lp.above;
    return abs(lo.lp.sum - hi.lp.sum) * (0.5 / PI);
}

// Whether the control variate may use ring k at x: no ray from x can meet its tube twice
// (a ray's path through the torus bends, in the tube's section plane, at most by
// 1 / ((R - r) tan^2 e), e its elevation over the ring's plane: it cannot leave and
// re-enter a tube of radius r while tan^2 e >= r / (R - r), checked for the lowest ray
// from x to the ring), the ring lies within 53 degrees of its centre's direction (its
// facing set's image is then on the near side of any great circle its loops keep above),
// and no other light can stand in front of it seen from x (their `reach` shells against
// the ring's bounding cone and farthest distance): where these hold, the light triangle
// a ray meets first with occluders ignored is the ring's where the ray meets the ring.
bool ring_cv_valid(uint k, vec3 x) {
    LightBlock e = emitters[k];
    vec3 d = e.pos.xyz - x;
    float big_r = e.pos.w, r = e.dir.w;
    float h = abs(dot(e.dir.xyz, d));
    float dist = length(d);
    float rho = sqrt(max(dist * dist - h * h, 0.0));
    float t = (h - r) / (rho + big_r + r);
    if (!(h > r) || t * t * (big_r - r) < r) return false;
    float sin_k = (big_r + r) / dist;
    if (!(sin_k < 0.8)) return false;
    float far_k = dist + big_r + r;
    float cone_k = asin(sin_k);
    for (uint j = 0u; j < prm.emitter_count; j++) {
        LightBlock o = emitters[j];
        if (j == k || o.reach.y < 0.0) continue;   // itself, or a spot (nothing to hit)
        vec3 dj = o.pos.xyz - x;
        float lj = length(dj);
        if (lj < o.reach.x) {
            // x inside the light's inner shell (a dome): all of it beyond the ring?
            if (o.reach.x - lj > far_k) continue;
            return false;
        }
        if (lj <= o.reach.y || lj - o.reach.y <= far_k
                && acos(clamp(dot(dj, d) / (lj * dist), -1.0, 1.0)) <= cone_k + asin(o.reach.y / lj)) {
            return false;
        }
    }
    return true;
}

// The control variate's closed form at x (shading and geometric normals ns, ng): the
// sum over the rings it may use (bit k of `mask`, rings among the first 32 lights) of
// c Le times the integral of D over the ring; with `divisor` > 1 over the coarser ring
// of ring_integral (what the extra camera rays of `[render] analytic_rays` take).
float analytic_rings(Lobe l, vec3 x, vec3 ns, vec3 ng, uint divisor, out uint mask) {
    mask = 0u;
    float a = 0.0;
    for (uint k = 0u; k < min(prm.emitter_count, 32u); k++) {
        LightBlock e = emitters[k];
        if (e.emit.z <= 0.0 || !ring_cv_valid(k, x)) continue;
        bool ok;
        float integral = ring_integral(e, l, x, ns, ng, divisor, ok);
        if (!ok) continue;
        a += l.c * e.emit.x * integral;
        mask |= 1u << k;
    }
    return a;
}
#endif
