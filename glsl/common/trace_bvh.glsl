// The BVH traversal of either level (`level` 0: the object, bindings 0 and 1; 1: the
// view's second level, bindings 2 and 3; both read as texel buffers), included by
// trace.glsl. One function for both levels, the level a value:
// a shader compiles one traversal per call site of trace_query (lavapipe inlines every
// call; two per level and query cost it minutes of LLVM compile).
BvhTri trace_tri(uint level, uint i) {
    uvec4 q[3];
    [[dont_flatten]] if (level == 0u) {
        [[unroll]] for (uint k = 0u; k < 3u; ++k) q[k] = texelFetch(trace_tris0, int(3u * i + k));
    } else {
        [[unroll]] for (uint k = 0u; k < 3u; ++k) q[k] = texelFetch(trace_tris1, int(3u * i + k));
    }
    return BvhTri(uintBitsToFloat(q[0]), uintBitsToFloat(q[1]), uintBitsToFloat(q[2]));
}

// A node: 5 (wide) or 4 (BVH2) times 16 bytes.
#if defined(TRACE_WIDE)
#define TRACE_NODE_VEC4S 5u
#else
#define TRACE_NODE_VEC4S 4u
#endif
TRACE_NODE trace_node(uint level, uint i) {
    uvec4 q[TRACE_NODE_VEC4S];
    [[dont_flatten]] if (level == 0u) {
        [[unroll]] for (uint k = 0u; k < TRACE_NODE_VEC4S; ++k)
            q[k] = texelFetch(trace_nodes0, int(TRACE_NODE_VEC4S * i + k));
    } else {
        [[unroll]] for (uint k = 0u; k < TRACE_NODE_VEC4S; ++k)
            q[k] = texelFetch(trace_nodes1, int(TRACE_NODE_VEC4S * i + k));
    }
#if defined(TRACE_WIDE)
    return WideNode(q[0], q[1], q[2], q[3], q[4]);
#else
    return BvhNode(uintBitsToFloat(q[0]), uintBitsToFloat(q[1]), uintBitsToFloat(q[2]),
                   uintBitsToFloat(q[3]));
#endif
}

// The watertight test of one triangle (corners v0, v1, v2, original index `prim`, of
// `level`) against ray r, taken into h where it is the closer hit.
void trace_tri_test(vec3 v0, vec3 v1, vec3 v2, uint prim, uint level, TraceRay r, float tmin,
                    inout Hit h) {
    precise vec3 a = v0 - r.o;
    precise vec3 b = v1 - r.o;
    precise vec3 c = v2 - r.o;
    precise float ax = a[r.kx] - r.s.x * a[r.kz];
    precise float ay = a[r.ky] - r.s.y * a[r.kz];
    precise float bx = b[r.kx] - r.s.x * b[r.kz];
    precise float by = b[r.ky] - r.s.y * b[r.kz];
    precise float cx = c[r.kx] - r.s.x * c[r.kz];
    precise float cy = c[r.ky] - r.s.y * c[r.kz];
    precise float u = cx * by - cy * bx;
    precise float v = ax * cy - ay * cx;
    precise float w = bx * ay - by * ax;
    // inside = !((u < 0 || v < 0 || w < 0) && (u > 0 || v > 0 || w > 0)), tested on the
    // bits: a float below 0 has bits above 0x80000000 unsigned (-0 excluded), one above 0
    // bits above 0 signed. NIR folds float compares joined by `||` into fmin / fmax,
    // which lavapipe compiles at 512-bit lanes as two 256-bit halves and a NaN fix-up
    // (docs/benchmarks/rendering.md, "What lavapipe compiles lane by lane"). A NaN
    // in u, v or w makes det and t NaN, and the hit is not taken either way.
    uvec3 ubits = floatBitsToUint(vec3(u, v, w));
    bool neg = any(greaterThan(ubits, uvec3(0x80000000u)));
    bool pos = any(greaterThan(ivec3(ubits), ivec3(0)));
    bool inside = !(neg && pos);
    precise float det = u + v + w;
    // The distance's division behind a real branch (`[[dont_flatten]]`; NIR makes selects
    // of a small `if`, which every lane pays for): lavapipe skips a branch no lane of the
    // subgroup takes, and often no lane's ray meets its triangle (0.974 of the path
    // tracing with Mitsuba's sampling, docs/benchmarks/rendering.md).
    [[dont_flatten]] if (inside && det != 0.0) {
        precise float tt = (u * (r.s.z * a[r.kz]) + v * (r.s.z * b[r.kz])) + w * (r.s.z * c[r.kz]);
        precise float t = tt / det;
        // Closest hit; at exactly equal distance (a ray through a shared edge) the lower
        // triangle index, so the result does not depend on the traversal order. Taken
        // with selects within the branch.
        bool take = t >= tmin && (t < h.t || (t == h.t && h.prim != NO_HIT && prim < h.prim));
        h.t = take ? t : h.t;
        h.prim = take ? prim : h.prim;
        h.bary = take ? vec2(v, w) : h.bary;   // divided by det when the query returns
        h.det = take ? det : h.det;
        h.inst = take ? level : h.inst;
    }
}

// A hit of the traversal with its barycentrics divided out (the same division the test
// would have done: v / det, w / det).
Hit hit_finish(Hit h) {
    h.bary = vec2(h.bary.x / h.det, h.bary.y / h.det);
    h.det = 1.0;
    return h;
}

void trace_leaf(uint level, uint first, uint count, TraceRay r, float tmin, inout Hit h) {
    for (uint i = first; i < first + count; ++i) {
        BvhTri tri = trace_tri(level, i);
        trace_tri_test(tri.v0.xyz, tri.v1.xyz, tri.v2.xyz, floatBitsToUint(tri.v0.w), level, r,
                       tmin, h);
    }
}

#if defined(TRACE_WIDE)
// Closest hit in a compressed wide BVH (Ylitie, Karras, Laine 2017): the stack holds
// node groups (first child node, a mask of the children still to visit in the top byte
// and the node's inner-child mask in the low byte); hit leaves' triangles are a mask of
// up to 24 bits from a first triangle. Children are visited in the order the builder
// arranged for the ray's octant (trace_wide_half, glsl/common/trace.glsl). With `any`
// it stops at the first hit found: an occlusion test.
void trace_bvh(uint level, vec3 o, vec3 inv_d, TraceRay tr, float tmin, inout Hit h, bool any) {
    uint oct_inv = (inv_d.x < 0.0 ? 0u : 4u) | (inv_d.y < 0.0 ? 0u : 2u) | (inv_d.z < 0.0 ? 0u : 1u);
    uint64_t stack[TRACE_WIDE_STACK + 1];   // the last: a spare slot written when full
    int sp = 0;
    uvec2 group = uvec2(0u, 0x80000000u);   // the root, as the only child of a virtual node
    uvec2 tris = uvec2(0u);
    while (true) {
        while (tris.y != 0u) {
            int b = findMSB(tris.y);
            tris.y &= ~(1u << uint(b));
            trace_leaf(level, tris.x + uint(b), 1u, tr, tmin, h);
        }
        if (any && h.prim != NO_HIT) break;
        if ((group.y & 0xff000000u) != 0u) {
            uint hits = group.y;
            uint bit = uint(findMSB(hits));
            group.y &= ~(1u << bit);
            // Pushed without a branch (lanes run both sides of one on lavapipe): the
            // entry is written always and kept only if the group has more children. One
            // 64-bit word an entry: lavapipe writes a private array lane by lane, each
            // component apart (0.95 of the path tracing's time against a uvec2 entry).
            stack[min(sp, TRACE_WIDE_STACK)] = packUint2x32(group);
            sp += (group.y & 0xff000000u) != 0u && sp < TRACE_WIDE_STACK ? 1 : 0;
            uint slot = (bit - 24u) ^ oct_inv;
            uint node = group.x + uint(bitCount(hits & ~(0xffffffffu << slot)));
            WideNode n = trace_node(level, node);
            vec3 nmin = uintBitsToFloat(n.head.xyz);
            uint ew = n.head.w;
            vec3 cell = uintBitsToFloat(uvec3(ew & 0xffu, (ew >> 8u) & 0xffu, (ew >> 16u) & 0xffu) << 23u);
            // Slots 0-3 in the x (minima) and z (maxima) words, 4-7 in y and w.
            uint hitmask =
                trace_wide_half(n.meta.z, uvec3(n.qx.x, n.qy.x, n.qz.x), uvec3(n.qx.z, n.qy.z, n.qz.z),
                                nmin, cell, o, inv_d, tmin, h.t, oct_inv)
                | trace_wide_half(n.meta.w, uvec3(n.qx.y, n.qy.y, n.qz.y), uvec3(n.qx.w, n.qy.w, n.qz.w),
                                  nmin, cell, o, inv_d, tmin, h.t, oct_inv);
            group = uvec2(n.meta.x, (hitmask & 0xff000000u) | (ew >> 24u));
            tris = uvec2(n.meta.y, hitmask & 0x00ffffffu);
        } else {
            group = uvec2(0u);
        }
        if (tris.y == 0u && (group.y & 0xff000000u) == 0u) {
            if (sp == 0) break;
            --sp;
            group = unpackUint2x32(stack[sp]);
        }
    }
}

// The bundle's triangles (trace_bundle_init, glsl/common/trace.glsl): every object leaf
// whose box meets the bundle, in any order; false where they are more than
// TRACE_BUNDLE_MAX. Into list `list` (TRACE_LIST_*, glsl/common/trace.glsl): the camera
// rays' bundle or the shadow rays' (trace_shadow_init, at most TRACE_SHADOW_MAX).
bool trace_bundle_collect(uint list) {
    uvec2 stack[TRACE_WIDE_STACK];
    int sp = 0;
    uvec2 group = uvec2(0u, 0x80000000u);
    while (true) {
        if ((group.y & 0xff000000u) != 0u) {
            uint hits = group.y;
            uint bit = uint(findMSB(hits));
            group.y &= ~(1u << bit);
            if ((group.y & 0xff000000u) != 0u) {
                if (sp >= TRACE_WIDE_STACK) return false;
                stack[sp] = group;
                ++sp;
            }
            uint slot = bit - 24u;   // children in slot order (octant 0)
            uint node = group.x + uint(bitCount(hits & ~(0xffffffffu << slot)));
            WideNode n = trace_node(0u, node);
            vec3 nmin = uintBitsToFloat(n.head.xyz);
            uint ew = n.head.w;
            vec3 cell = uintBitsToFloat(uvec3(ew & 0xffu, (ew >> 8u) & 0xffu, (ew >> 16u) & 0xffu) << 23u);
            uint hitmask = 0u;
            for (uint k = 0u; k < 8u; ++k) {
                uint sh = (k & 3u) * 8u;
                bool hi = k >= 4u;
                uint meta = ((hi ? n.meta.w : n.meta.z) >> sh) & 0xffu;
                uvec3 qlo = hi ? uvec3(n.qx.y, n.qy.y, n.qz.y) : uvec3(n.qx.x, n.qy.x, n.qz.x);
                uvec3 qhi = hi ? uvec3(n.qx.w, n.qy.w, n.qz.w) : uvec3(n.qx.z, n.qy.z, n.qz.z);
                vec3 bmin = nmin + vec3((qlo >> sh) & 0xffu) * cell;
                vec3 bmax = nmin + vec3((qhi >> sh) & 0xffu) * cell;
                uint at = meta & 0x1fu;
                hitmask |= meta != 0u && trace_list_box(list, bmin, bmax) ? ((meta >> 5u) & 7u) << at : 0u;
            }
            group = uvec2(n.meta.x, (hitmask & 0xff000000u) | (ew >> 24u));
            uint tris = hitmask & 0x00ffffffu;
            while (tris != 0u) {
                int b = findLSB(tris);
                tris &= ~(1u << uint(b));
                if (!trace_list_add(list, n.meta.y + uint(b), 1u)) return false;
            }
        } else {
            group = uvec2(0u);
        }
        if ((group.y & 0xff000000u) == 0u) {
            if (sp == 0) break;
            --sp;
            group = stack[sp];
        }
    }
    return true;
}
#else
// Closest hit in a child-pair BVH2; with `any` the first hit found: an occlusion test.
void trace_bvh(uint level, vec3 o, vec3 inv_d, TraceRay tr, float tmin, inout Hit h, bool any) {
    // Each pushed node keeps its entry distance, so a node farther than a hit found
    // meanwhile is dropped on pop without loading it.
    uint stack[TRACE_STACK];
    float stack_t[TRACE_STACK];
    int sp = 0;
    uint node = 0u;
    while (true) {
        BvhNode n = trace_node(level, node);
        float nl, nr;
        bool hl = trace_box(n.l_min.xyz, n.l_max.xyz, o, inv_d, tmin, h.t, nl);
        bool hr = trace_box(n.r_min.xyz, n.r_max.xyz, o, inv_d, tmin, h.t, nr);
        uint lc = floatBitsToUint(n.l_max.w);
        uint rc = floatBitsToUint(n.r_max.w);
        if (hl && lc > 0u) { trace_leaf(level, floatBitsToUint(n.l_min.w), lc, tr, tmin, h); hl = false; }
        if (hr && rc > 0u) { trace_leaf(level, floatBitsToUint(n.r_min.w), rc, tr, tmin, h); hr = false; }
        if (any && h.prim != NO_HIT) break;
        uint li = floatBitsToUint(n.l_min.w);
        uint ri = floatBitsToUint(n.r_min.w);
        if (hl && hr) {
            uint near = nl <= nr ? li : ri;
            uint far = nl <= nr ? ri : li;
            if (sp < TRACE_STACK) { stack[sp] = far; stack_t[sp] = max(nl, nr); ++sp; }
            node = near;
        } else if (hl) {
            node = li;
        } else if (hr) {
            node = ri;
        } else {
            bool found = false;
            while (sp > 0) {
                --sp;
                // Widened as the slab test's far distance: a node whose entry rounds
                // past an equally distant hit (a ray through a shared vertex) is still
                // visited, so ties go to the lower index whatever the order.
                if (stack_t[sp] <= h.t * 1.0000004) { node = stack[sp]; found = true; break; }
            }
            if (!found) break;
        }
    }
}

// The bundle's triangles (trace_bundle_init, glsl/common/trace.glsl): every object leaf
// whose box meets the bundle, in any order; false where they are more than
// TRACE_BUNDLE_MAX. Into list `list` (TRACE_LIST_*, glsl/common/trace.glsl): the camera
// rays' bundle or the shadow rays' (trace_shadow_init, at most TRACE_SHADOW_MAX).
bool trace_bundle_collect(uint list) {
    uint stack[TRACE_STACK];
    int sp = 0;
    uint node = 0u;
    while (true) {
        BvhNode n = trace_node(0u, node);
        bool hl = trace_list_box(list, n.l_min.xyz, n.l_max.xyz);
        bool hr = trace_list_box(list, n.r_min.xyz, n.r_max.xyz);
        uint lc = floatBitsToUint(n.l_max.w);
        uint rc = floatBitsToUint(n.r_max.w);
        uint li = floatBitsToUint(n.l_min.w);
        uint ri = floatBitsToUint(n.r_min.w);
        if (hl && lc > 0u) { if (!trace_list_add(list, li, lc)) return false; hl = false; }
        if (hr && rc > 0u) { if (!trace_list_add(list, ri, rc)) return false; hr = false; }
        if (hl && hr) {
            if (sp >= TRACE_STACK) return false;
            stack[sp] = ri;
            ++sp;
            node = li;
        } else if (hl) {
            node = li;
        } else if (hr) {
            node = ri;
        } else {
            if (sp == 0) break;
            --sp;
            node = stack[sp];
        }
    }
    return true;
}
#endif
