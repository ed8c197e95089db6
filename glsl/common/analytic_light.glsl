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
// both over the ring's part above the table where the table hides the rest
// (ring_table_clip: a great circle cuts A's loops and G's samples alike),
// so E[G] = A exactly whatever the lobe's fit, at every shading point where each ray
// meets the ring at most once and no other light stands in front of it (ring_cv_valid;
// elsewhere the ring is left to the sampled estimator alone): the estimate stays
// unbiased, and its variance falls where f V ~ g over the ring. ("Exactly" up to the
// closed form's arithmetic: each edge's angle from a rational fit within 1.5e-6 of it,
// polygon_edge.glsl, and float rounding.)
#ifndef ANALYTIC_LIGHT_GLSL
#define ANALYTIC_LIGHT_GLSL
#extension GL_EXT_control_flow_attributes : require
#include "polygon_edge.glsl"

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

// The lobe of conductor `c` seen from wo (shading frame tb, bt, ns; wo local) with
// amplitude fc = f(wo, r) cos(r) at the mirror direction r given: the exact value
// (conductor_lobe) or any stand-in for it (the extra camera rays' line in wo.z,
// pixel_plane_lobe). False where it has no mass above the surface (the mirror direction
// at or below it, or fc <= 0).
bool conductor_lobe_fc(Conductor c, float fc, vec3 wo, vec3 tb, vec3 bt, vec3 ns, out Lobe l) {
    vec3 r_local = vec3(-wo.x, -wo.y, wo.z);
    vec3 wo_w = from_frame(wo, tb, bt, ns);
    l.r = normalize(from_frame(r_local, tb, bt, ns));
    vec3 across = cross(ns, wo_w);
    float al = length(across);
    l.t2 = al > 1e-6 ? across / al : tb;
    l.t1 = cross(l.t2, l.r);
    l.a1 = max(2.0 * c.alpha, 1e-4);
    l.a2 = max(2.0 * c.alpha * wo.z, 1e-4);
    l.c = fc * PI * l.a1 * l.a2;
    return fc > 0.0 && wo.z > 0.0;
}

// The lobe of conductor `c` seen from wo with its exact amplitude.
bool conductor_lobe(Conductor c, vec3 wo, vec3 tb, vec3 bt, vec3 ns, out Lobe l) {
    float fc = conductor_eval_cos(c, wo, vec3(-wo.x, -wo.y, wo.z));
    return conductor_lobe_fc(c, fc, wo, tb, bt, ns, l);
}

// The amplitude fc of an isotropic conductor's lobe is a function of wo.z alone (the
// half vector is the normal): fc at wo.z = mu.
float conductor_lobe_amplitude(Conductor c, float mu) {
    float s = sqrt(max(1.0 - mu * mu, 0.0));
    return conductor_eval_cos(c, vec3(s, 0.0, mu), vec3(-s, 0.0, mu));
}

// Rings recorded as seen from one point (record_rings): the world vertices of their
// boundary loops, for the extra camera rays of `[render] analytic_rays`, whose closed
// forms (recorded_rings2) take a pixel's rings as seen from one reference point and so
// need the walk once per pixel, not once per ray. Up to REC_RINGS rings, each two loops
// of at most REC_LOOP_VERTS vertices (a ring whose loops are longer is not recorded).
#define REC_RING_COUNT 2
#define REC_RINGS uint(REC_RING_COUNT)
#define REC_LOOP_VERTS 64u
// The vertices of each loop that recorded_loop2 reads at constant indices (its loop
// written out to here, recorded_rings2's rings too): lavapipe reads a private array at
// a constant index with one vector load, at any other a lane at a time (below). A pixel's
// loops hold 17 vertices on the paper job (the coarse ring's 16 sections and the closing
// one); the rest of a longer loop is read in a loop.
#define REC_UNROLLED 17u
// Each vertex as its unit direction in one word (rec_pack): lavapipe reads a private
// array at any index but a constant one a lane at a time, a scalar load and insert per
// lane and component (docs/benchmarks/dataset.md, "The recorded vertices in one word"),
// so a vec3 cost three such loads a vertex where this costs one (and where the index is
// a constant, REC_UNROLLED, one vector load). The extra rays' closed
// form A' need only be one function of the camera ray: directions rounded by at most
// 6.3e-5 rad keep the estimate unbiased.
uint rec_w[2u * REC_RINGS * REC_LOOP_VERTS];
uint rec_n[2u * REC_RINGS];   // vertices of loop i (ring i / 2, its lo loop first)
float rec_le[REC_RINGS];      // the ring's radiance
// A cone holding the ring's recorded vertices as seen from the recording point: unit
// axis and the sine of its half-angle (2 where it is a hemisphere or wider): a lobe
// whose shading normal keeps the cone above its horizon has every vertex above it, one
// test per ray and ring instead of one per vertex (recorded_rings2).
vec4 rec_cone[REC_RINGS];
uint rec_rings = 0u;

// Unit-free direction w from the shading point in the lobe's cosine space, or below its
// horizon (z < 0, failing a loop's `above`) where w is below the shading point's shading
// (ns) or geometric (ng) horizon, where E takes no light (its light sample needs both; G
// would count what E cannot).
vec3 lobe_point(Lobe l, vec3 ns, vec3 ng, vec3 w) {
    return dot(w, ns) > 0.0 && dot(w, ng) > 0.0 ? lobe_local(l, w) : vec3(0.0, 0.0, -1.0);
}

// A closed loop of directions (world vectors from the shading point, any length) whose
// edges are summed as edge_z in the lobe's cosine space: `sum` (edge_z: over 2 pi) is the
// clamped-cosine integral over the region it bounds when every vertex is above the
// horizons (`above`, lobe_point). With `rec` >= 0 the loop only records its world
// vertices as recorded loop `rec` (`n` of them; more than REC_LOOP_VERTS: not recorded),
// `above` then where each is above the geometric horizon (ng). With a clip (`clip.w` >
// 0, ring_table_clip) the loop is first cut to the directions w with dot(w, clip.xyz) >
// 0 (Sutherland-Hodgman against that great circle: each crossing edge is cut where it
// meets the plane, and from the point where the loop leaves the kept side to where it
// comes back the loop runs along the great circle; the integral over the region the
// cut loop bounds is the old one's over its kept part).
struct Loop {
    vec3 first;     // first vertex kept (cosine space; unused when recording)
    vec3 prev;      // last vertex kept
    float sum;
    bool above;
    int rec;
    uint n;         // vertices kept
    vec4 clip;
    vec3 in_first;  // the loop's own first vertex (world) and its last one
    vec3 in_prev;
};

// Vertex w (world) kept as the loop's next.
void loop_keep(inout Loop lp, vec3 ns, vec3 ng, Lobe l, vec3 w) {
    if (lp.rec >= 0) {
        if (lp.n < REC_LOOP_VERTS) rec_w[uint(lp.rec) * REC_LOOP_VERTS + lp.n] = rec_pack(w);
        lp.above = lp.above && dot(w, ng) > 0.0;
    } else {
        vec3 v = lobe_point(l, ns, ng, w);
        if (lp.n == 0u) {
            lp.first = v;
        } else {
            lp.sum += edge_z(lp.prev, v);
        }
        lp.prev = v;
        lp.above = lp.above && v.z > 0.0;
    }
    lp.n++;
}

// The clip of the loop's edge from its last vertex to w: the point where it crosses the
// great circle, kept, if it does.
void loop_cut(inout Loop lp, vec3 ns, vec3 ng, Lobe l, vec3 w) {
    float da = dot(lp.in_prev, lp.clip.xyz), db = dot(w, lp.clip.xyz);
    [[dont_flatten]] if ((da > 0.0) != (db > 0.0)) {
        loop_keep(lp, ns, ng, l, mix(lp.in_prev, w, da / (da - db)));
    }
}

void loop_start(out Loop lp, vec3 ns, vec3 ng, Lobe l, vec3 w, int rec, vec4 clip) {
    lp.rec = rec;
    lp.n = 0u;
    lp.sum = 0.0;
    lp.above = true;
    lp.clip = clip;
    lp.first = lp.prev = vec3(0.0);
    lp.in_first = lp.in_prev = w;
    if (!(clip.w > 0.0) || dot(w, clip.xyz) > 0.0) loop_keep(lp, ns, ng, l, w);
}

// The clip's work sits behind real branches (`[[dont_flatten]]`): lavapipe skips a
// branch no lane of the subgroup takes, where as selects (what the compiler makes of
// small `if`s) every vertex of every loop would pay for a cut point's edge term.
void loop_add(inout Loop lp, vec3 ns, vec3 ng, Lobe l, vec3 w) {
    bool keep = true;
    [[dont_flatten]] if (lp.clip.w > 0.0) {
        loop_cut(lp, ns, ng, l, w);
        lp.in_prev = w;
        keep = dot(w, lp.clip.xyz) > 0.0;
    }
    if (keep) loop_keep(lp, ns, ng, l, w);
}

// The loop's last edge, back to its first vertex (a recorded loop closes when it is
// summed: recorded_loop2).
void loop_close(inout Loop lp, vec3 ns, vec3 ng, Lobe l) {
    if (lp.clip.w > 0.0) loop_cut(lp, ns, ng, l, lp.in_first);
    if (lp.rec < 0 && lp.n > 0u) lp.sum += edge_z(lp.prev, lp.first);
}

// The table's clip of ring e seen from x (`PathParams::table`; the table is the plane
// z = table.z, square): where the ring's plane crosses the table's plane within the
// table and x lies above it, the ring's part below the table is hidden from x. Seen
// from x, the line where the two planes meet is a great circle; the closed form and G
// both take the ring on the upper side of it alone (directions w with dot(w, m) > 0,
// returned as (m, 1); (0, 0, 0, 0): no clip). The ring's mid-plane is cut there exactly,
// its tube (of radius r) to within about r / distance: that is the approximation, a
// loss of variance reduction only (E[G] = A holds for any clip, as long as G and A take
// the same one). No clip where the ring's plane is within 3 degrees of the table's,
// where its centre circle stays above the table, or where the table's edge is nearer
// than the hidden part (the crossings and the lowest point's shadow must lie on the
// table).
vec4 ring_table_clip(LightBlock e, vec3 x) {
    vec4 t = prm.table;
    vec3 c = e.pos.xyz, a = e.dir.xyz;
    float big_r = e.pos.w;
    float s = sqrt(max(1.0 - a.z * a.z, 0.0));
    if (!(t.w > 0.0) || !(x.z > t.z) || s < 0.05 || !(c.z - big_r * s < t.z)) return vec4(0.0);
    // Down the ring's plane (unit), and the line where it meets the table's plane.
    vec3 dn = (vec3(0.0, 0.0, -1.0) + a * a.z) / s;
    vec3 l0 = c + dn * ((c.z - t.z) / s);
    vec3 ld = normalize(cross(a, vec3(0.0, 0.0, 1.0)));
    float h2 = big_r * big_r - dot(l0 - c, l0 - c);
    if (!(h2 > 0.0)) return vec4(0.0);
    float h = sqrt(h2);
    vec3 low = c + dn * big_r;
    vec3 b = x + (low - x) * ((x.z - t.z) / (x.z - low.z));
    vec2 p0 = l0.xy + ld.xy * h - t.xy, p1 = l0.xy - ld.xy * h - t.xy;
    float edge = max(max(max(abs(p0.x), abs(p0.y)), max(abs(p1.x), abs(p1.y))),
                     max(abs(b.x - t.x), abs(b.y - t.y)));
    if (!(edge < t.w)) return vec4(0.0);
    vec3 m = normalize(cross(ld, l0 - x));
    // The kept side holds the ring's plane above the line (l0 - dn).
    return vec4(dot(m, dn) > 0.0 ? -m : m, 1.0);
}

// Whether the control variate takes direction w (from x) for ring e: on the kept side
// of the table's clip (ring_table_clip), or no clip.
bool ring_clip_keeps(vec4 clip, vec3 w) {
    return !(clip.w > 0.0) || dot(w, clip.xyz) > 0.0;
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
// (at that angle from `rad` towards the axis, as ring_light places it), from x.
vec3 ring_vertex(Ring g, vec3 rad, vec2 v) {
    return g.d0 + rad * (g.big_r + g.r * v.x) + g.ax * (g.r * v.y);
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
        if (add) loop_add(s.lp, g.ns, g.ng, l, ring_vertex(g, rad, s.v));
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
// axis become n / divisor (at least 3), its tube keeps its m, and its major radius grows
// so that each chord between two sections lies as far from the axis on average (over the
// chord's angle) as the light's circle: R / (cos h (1 + h^2 / 6)), h half a section's
// angle (1.3 % wider at 16 sections, its chords then within +1.3 % / -0.64 % of R of the
// circle), where the chords alone would pull the whole band inwards (by up to 1.9 % of R
// between two sections at 16). With `rec` >= 0 the walk
// only records the two loops' world vertices as ring `rec` of the recorded rings (`ok`:
// the walk found the boundary, its loops fit and lie above the geometric horizon ng; the
// lobe and the shading horizon are not used).
float ring_integral(LightBlock e, Lobe l, vec3 x, vec3 ns, vec3 ng, uint divisor, int rec,
                    vec4 clip, out bool ok) {
    ok = false;
    uint n = f2u(e.emit.z);
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
    if (divisor > 1u) {
        float h = 0.5 * dphi;
        g.big_r /= cos(h) * (1.0 + h * h / 6.0);
    }
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
    loop_start(lo.lp, ns, ng, l, ring_vertex(g, e1, lo.v), rec < 0 ? -1 : 2 * rec, clip);
    loop_start(hi.lp, ns, ng, l, ring_vertex(g, e1, hi.v), rec < 0 ? -1 : 2 * rec + 1, clip);
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
            // (a real branch, which lavapipe skips where no lane of the subgroup takes
            // it; a subgroup vote here cost a loop over the lanes per segment).
            bool settled = ring_settled(g, lo.v, true) && ring_settled(g, hi.v, false);
            [[dont_flatten]] if (!settled) {
                if (!ring_side(lo, g, l, rad, true, true)
                        || !ring_side(hi, g, l, rad, false, true)) {
                    return 0.0;
                }
            }
        }
        loop_add(lo.lp, ns, ng, l, ring_vertex(g, rad_next, lo.v));
        loop_add(hi.lp, ns, ng, l, ring_vertex(g, rad_next, hi.v));
        phi = phi_next;
        rad = rad_next;
    }
    // Back at section 0: along it to segment 0's run boundary, and closed.
    g.a = a0;
    if (!ring_side(lo, g, l, e1, true, true) || !ring_side(hi, g, l, e1, false, true)) return 0.0;
    loop_close(lo.lp, ns, ng, l);
    loop_close(hi.lp, ns, ng, l);
    if (rec >= 0) {
        // Recorded: its vertices, if they fit.
        rec_n[2 * rec] = lo.lp.n;
        rec_n[2 * rec + 1] = hi.lp.n;
        // (A loop the table's clip emptied has no vertex: kept where the other has.)
        ok = lo.lp.above && hi.lp.above && lo.lp.n <= REC_LOOP_VERTS && hi.lp.n <= REC_LOOP_VERTS
            && lo.lp.n + hi.lp.n > 0u;
        return 0.0;
    }
    ok = lo.lp.above && hi.lp.above;
    return abs(lo.lp.sum - hi.lp.sum);
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
    LightBlock e = EMITTERS[k];
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
    // Every other light checked, at a lane-uniform index (EMITTERS, lights.glsl).
    bool clear = true;
    for (uint j = 0u; j < PRM_EMITTER_COUNT; j++) {
        LightBlock o = EMITTERS[j];
        if (j == k || o.reach.y < 0.0) continue;   // itself, or a spot (nothing to hit)
        vec3 dj = o.pos.xyz - x;
        float lj = length(dj);
        bool ok_j;
        if (lj < o.reach.x) {
            // x inside the light's inner shell (a dome): all of it beyond the ring?
            ok_j = o.reach.x - lj > far_k;
        } else {
            ok_j = !(lj <= o.reach.y || lj - o.reach.y <= far_k
                     && acos(clamp(dot(dj, d) / (lj * dist), -1.0, 1.0)) <= cone_k + asin(o.reach.y / lj));
        }
        clear = clear && ok_j;
    }
    return clear;
}

// The control variate's closed form at x (shading and geometric normals ns, ng): the
// sum over the rings it may use (bit k of `mask`, rings among the first 32 lights) of
// c Le times the integral of D over the ring; with `divisor` > 1 over the coarser ring
// of ring_integral (what the extra camera rays of `[render] analytic_rays` take).
float analytic_rings(Lobe l, vec3 x, vec3 ns, vec3 ng, uint divisor, out uint mask) {
    mask = 0u;
    float a = 0.0;
    for (uint k = 0u; k < min(PRM_EMITTER_COUNT, 32u); k++) {
        LightBlock e = EMITTERS[k];
        if (e.emit.z > 0.0 && ring_cv_valid(k, x)) {
            bool ok;
            float integral = ring_integral(e, l, x, ns, ng, divisor, -1, ring_table_clip(e, x), ok);
            if (ok) {
                a += l.c * e.emit.x * integral;
                mask |= 1u << k;
            }
        }
    }
    return a;
}

// The cone of recorded ring r's two loops (rec_cone): axis the mean of their unit
// vertices, half-angle the widest (once per pixel).
vec4 recorded_cone(uint r) {
    vec3 axis = vec3(0.0);
    for (uint i = 2u * r; i < 2u * r + 2u; i++) {
        for (uint j = 0u; j < rec_n[i]; j++) axis += normalize(rec_unpack(rec_w[i * REC_LOOP_VERTS + j]));
    }
    axis = normalize(axis);
    float c = 1.0;
    for (uint i = 2u * r; i < 2u * r + 2u; i++) {
        for (uint j = 0u; j < rec_n[i]; j++) {
            c = min(c, dot(normalize(rec_unpack(rec_w[i * REC_LOOP_VERTS + j])), axis));
        }
    }
    return vec4(axis, c > 0.0 ? sqrt(max(1.0 - c * c, 0.0)) : 2.0);
}

// Records the rings the control variate may use at x (geometric normal ng; bit k of
// analytic_rings' mask), over the coarser ring of `divisor`, as seen from x: the first
// REC_RINGS of them whose loops fit (rec_rings of them; recorded_rings2 sums them).
void record_rings(vec3 x, vec3 ng, uint divisor) {
    rec_rings = 0u;
    Lobe unused;   // the walk records only: no lobe is evaluated
    unused.t1 = unused.t2 = unused.r = ng;
    unused.a1 = unused.a2 = unused.c = 1.0;
    for (uint k = 0u; k < min(PRM_EMITTER_COUNT, 32u); k++) {
        LightBlock e = EMITTERS[k];
        if (rec_rings < REC_RINGS && e.emit.z > 0.0 && ring_cv_valid(k, x)) {
            bool ok;
            ring_integral(e, unused, x, ng, ng, divisor, int(rec_rings), ring_table_clip(e, x), ok);
            if (ok) {
                rec_le[rec_rings] = e.emit.x;
                rec_cone[rec_rings] = recorded_cone(rec_rings);
                rec_rings++;
            }
        }
    }
}

// Recorded vertex w in the cosine space of lobe l (reciprocal widths rt1, rt2, axis r),
// unit length (z <= 0: at or below the cosine space's horizon).
vec3 recorded_point(vec3 w, vec3 rt1, vec3 rt2, vec3 r) {
    vec3 v = vec3(dot(w, rt1), dot(w, rt2), dot(w, r));
    return v * inversesqrt(dot(v, v));
}

// One vertex (its word, rec_w) of recorded_loop2's loop for both lobes (reciprocal
// widths t1*, t2*, axes r*), where `live` (the lane's loop has it): the edges from the
// previous vertices added to the sums, the vertex kept as the previous and in `above`.
void recorded_step2(uint word, bool live, vec3 t10, vec3 t20, vec3 r0, vec3 t11, vec3 t21,
                    vec3 r1, inout vec3 prev0, inout vec3 prev1, inout float sum0,
                    inout float sum1, inout bool ab0, inout bool ab1) {
    vec3 w = rec_unpack(word);
    if (live) {
        vec3 v0 = recorded_point(w, t10, t20, r0);
        vec3 v1 = recorded_point(w, t11, t21, r1);
        sum0 += edge_z_unit(prev0, v0);
        sum1 += edge_z_unit(prev1, v1);
        prev0 = v0;
        prev1 = v1;
        ab0 = ab0 && v0.z > 0.0;
        ab1 = ab1 && v1.z > 0.0;
    }
}

// Recorded loop i summed as ring_integral sums a loop, for two lobes at once (the extra
// camera rays go in pairs): lobes l0 and l1, closed, over 2 pi; `above` where every
// vertex is above each lobe's cosine-space horizon (record_rings kept only loops above
// the geometric horizon; the shading horizon is the cone's test, recorded_rings2). The
// lobes' widths are taken as reciprocals and the edges from edge_z_unit
// (roundings of their own: A' needs only to be one function of the camera ray). Each
// vertex is read once for both lobes (a private array's read at any but a constant
// index is a load a lane on lavapipe, one word a vertex: rec_w) and
// the two sums give the loop's body independent work; each sum is what a pass of its
// own would give, bit for bit. Pairs measured 0.91x to 0.92x the path tracing
// of one ray at a time, groups of four 1.02x pairs' (docs/benchmarks/dataset.md, "The extra
// rays' edge sums in pairs").
vec2 recorded_loop2(uint i, Lobe l0, Lobe l1, out bvec2 above) {
    uint base = i * REC_LOOP_VERTS;
    vec3 t10 = l0.t1 * (1.0 / l0.a1), t20 = l0.t2 * (1.0 / l0.a2);
    vec3 t11 = l1.t1 * (1.0 / l1.a1), t21 = l1.t2 * (1.0 / l1.a2);
    uint n = rec_n[i];
    // (A loop the table's clip emptied, n = 0: any unit vector, whose one edge is 0.)
    vec3 w = n > 0u ? rec_unpack(rec_w[base]) : l0.r;
    vec3 first0 = recorded_point(w, t10, t20, l0.r);
    vec3 first1 = recorded_point(w, t11, t21, l1.r);
    vec3 prev0 = first0, prev1 = first1;
    float sum0 = 0.0, sum1 = 0.0;
    bool ab0 = n == 0u || first0.z > 0.0, ab1 = n == 0u || first1.z > 0.0;
    // To the subgroup's longest loop, so that j is one value for all lanes; a lane past
    // its own loop keeps its sums. The first REC_UNROLLED vertices written out (with i a
    // constant, recorded_rings2: every index a constant), the rest in a loop.
    uint n_all = subgroupMax(n);
    [[unroll]] for (uint j = 1u; j < REC_UNROLLED; j++) {
        [[dont_flatten]] if (j < n_all) {
            recorded_step2(rec_w[base + j], j < n, t10, t20, l0.r, t11, t21, l1.r,
                           prev0, prev1, sum0, sum1, ab0, ab1);
        }
    }
    for (uint j = REC_UNROLLED; j < n_all; j++) {
        recorded_step2(rec_w[base + j], j < n, t10, t20, l0.r, t11, t21, l1.r,
                       prev0, prev1, sum0, sum1, ab0, ab1);
    }
    above = bvec2(ab0, ab1);
    return vec2(sum0 + edge_z_unit(prev0, first0), sum1 + edge_z_unit(prev1, first1));
}

// Recorded ring r's part of recorded_rings2: 0 for a lobe unless both loops are above
// its cosine space's horizon and the cone (rec_cone) above its shading horizon.
vec2 recorded_ring2(uint r, Lobe l0, vec3 ns0, Lobe l1, vec3 ns1) {
    bvec2 above_lo, above_hi;
    vec2 lo = recorded_loop2(2u * r, l0, l1, above_lo);
    vec2 hi = recorded_loop2(2u * r + 1u, l0, l1, above_hi);
    vec4 cone = rec_cone[r];
    bool up0 = dot(cone.xyz, ns0) > cone.w, up1 = dot(cone.xyz, ns1) > cone.w;
    return vec2(up0 && above_lo.x && above_hi.x ? l0.c * rec_le[r] * abs(lo.x - hi.x) : 0.0,
                up1 && above_lo.y && above_hi.y ? l1.c * rec_le[r] * abs(lo.y - hi.y) : 0.0);
}

// analytic_rings' closed form for lobes l0 and l1 over the recorded rings (as seen from
// the point they were recorded at) and shading normals ns0, ns1, each ring counted
// where its loops are above the cosine spaces' horizons and its cone (rec_cone) above
// the shading horizon. (A' of a ray whose shading horizon cuts the cone but not the
// loops is 0 where a per-vertex test would have kept the ring: rare, and A' need only
// be one function of the camera ray.)
vec2 recorded_rings2(Lobe l0, vec3 ns0, Lobe l1, vec3 ns1) {
    vec2 a = vec2(0.0);
    // Lane-uniform as recorded_loop2's vertex loop. The rings written out, not a loop,
    // so that each recorded_loop2's i, and so its vertices' indices, are constants:
    // 0.90 of the paper crops' path tracing at the 2-spp floor against a loop over the
    // rings (lavapipe gathered each vertex a lane at a time; docs/benchmarks/dataset.md,
    // "The recorded vertices read at constant indices"), the same sums bit for bit.
    uint rings_all = subgroupMax(rec_rings);
#if REC_RING_COUNT != 2
#error "recorded_rings2 writes out REC_RINGS = 2 rings"
#endif
    [[dont_flatten]] if (rings_all > 0u) {
        [[dont_flatten]] if (rec_rings > 0u) a += recorded_ring2(0u, l0, ns0, l1, ns1);
    }
    [[dont_flatten]] if (rings_all > 1u) {
        [[dont_flatten]] if (rec_rings > 1u) a += recorded_ring2(1u, l0, ns0, l1, ns1);
    }
    return a;
}
#endif
