//! The software backend's data: an obvhs compressed wide BVH (CWBVH, eight children a
//! node) built on the CPU and re-quantized so the shader's child boxes are conservative
//! (`flatten_wide`), which glsl/common/trace_bvh.glsl traverses; and the obvhs BVH2
//! the CPU reference traversal (`cpu_closest_hit`) and the child-pair layout
//! (`flatten`, kept for comparisons in examples/bench_bvh) use.

use obvhs::bvh2::Bvh2;
use obvhs::cwbvh::CwBvh;
use obvhs::triangle::Triangle;

use crate::gpu_interface::{TRACE_WIDE_STACK, WideNode};

/// 64 bytes: both children's boxes. `*_min[3]` holds the child's node index (inner) or
/// first triangle (leaf) as bits; `*_max[3]` the triangle count as bits, 0 = inner.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuNode {
    pub l_min: [f32; 4],
    pub l_max: [f32; 4],
    pub r_min: [f32; 4],
    pub r_max: [f32; 4],
}

/// A triangle in BVH leaf order; `v0[3]` holds the original triangle index as bits.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuTri {
    pub v0: [f32; 4],
    pub v1: [f32; 4],
    pub v2: [f32; 4],
}

/// obvhs triangles for a mesh (original order).
pub fn obvhs_triangles(positions: &[glam::Vec3], triangles: &[[u32; 3]]) -> Vec<Triangle> {
    triangles
        .iter()
        .map(|t| Triangle {
            v0: positions[t[0] as usize].into(),
            v1: positions[t[1] as usize].into(),
            v2: positions[t[2] as usize].into(),
        })
        .collect()
}

/// obvhs's build presets (PLOC with reinsertion; `BvhBuildParams`), fastest to slowest.
/// Their build time and the traversal speed they give are measured by
/// `examples/bench_bvh` (docs/benchmarks.md, "BVH build presets").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BvhQuality {
    /// One triangle per leaf, no reinsertion, no collapse.
    Fastest,
    VeryFast,
    Fast,
    /// About Embree's build time with faster traversal (per obvhs).
    Medium,
    /// With pre-splitting of large triangles.
    Slow,
}

impl BvhQuality {
    pub const ALL: [BvhQuality; 5] = [
        BvhQuality::Fastest,
        BvhQuality::VeryFast,
        BvhQuality::Fast,
        BvhQuality::Medium,
        BvhQuality::Slow,
    ];

    pub fn name(self) -> &'static str {
        match self {
            BvhQuality::Fastest => "fastest",
            BvhQuality::VeryFast => "very_fast",
            BvhQuality::Fast => "fast",
            BvhQuality::Medium => "medium",
            BvhQuality::Slow => "slow",
        }
    }

    fn params(self) -> obvhs::BvhBuildParams {
        match self {
            BvhQuality::Fastest => obvhs::BvhBuildParams::fastest_build(),
            BvhQuality::VeryFast => obvhs::BvhBuildParams::very_fast_build(),
            BvhQuality::Fast => obvhs::BvhBuildParams::fast_build(),
            BvhQuality::Medium => obvhs::BvhBuildParams::medium_build(),
            BvhQuality::Slow => obvhs::BvhBuildParams::slow_build(),
        }
    }
}

/// The preset every scene is built with.
pub const DEFAULT_BVH_QUALITY: BvhQuality = BvhQuality::Medium;

/// Builds the BVH2 with [`DEFAULT_BVH_QUALITY`].
pub fn build_bvh(tris: &[Triangle]) -> Bvh2 {
    build_bvh_with(tris, DEFAULT_BVH_QUALITY)
}

/// Builds the BVH2 with obvhs's `quality` preset.
pub fn build_bvh_with(tris: &[Triangle], quality: BvhQuality) -> Bvh2 {
    let mut core = std::time::Duration::ZERO;
    obvhs::bvh2::builder::build_bvh2_from_tris(tris, quality.params(), &mut core)
}

/// A BVH no ray can hit anything in: one node whose two children are the same leaf of one
/// degenerate triangle (all corners at the origin: the watertight test's determinant is
/// 0, so it never reports a hit). Bindings may not be empty; this fills an empty level.
pub fn empty() -> (Vec<GpuNode>, Vec<GpuTri>) {
    let leaf_min = [0.0, 0.0, 0.0, f32::from_bits(0)];
    let leaf_max = [0.0, 0.0, 0.0, f32::from_bits(1)];
    (
        vec![GpuNode {
            l_min: leaf_min,
            l_max: leaf_max,
            r_min: leaf_min,
            r_max: leaf_max,
        }],
        vec![GpuTri::default()],
    )
}

/// The triangles in a BVH's leaf order (`indices`: its primitive indices), each with its
/// original index in `v0[3]` as bits.
fn leaf_order(indices: &[u32], tris: &[Triangle]) -> Vec<GpuTri> {
    indices
        .iter()
        .map(|&p| {
            let t = &tris[p as usize];
            GpuTri {
                v0: [t.v0.x, t.v0.y, t.v0.z, f32::from_bits(p)],
                v1: [t.v1.x, t.v1.y, t.v1.z, 0.0],
                v2: [t.v2.x, t.v2.y, t.v2.z, 0.0],
            }
        })
        .collect()
}

/// Flattens `bvh` into GPU nodes (root at 0) and leaf-ordered triangles.
pub fn flatten(bvh: &Bvh2, tris: &[Triangle]) -> (Vec<GpuNode>, Vec<GpuTri>) {
    let gpu_tris = leaf_order(&bvh.primitive_indices, tris);
    let nodes = &bvh.nodes;
    let child = |idx: usize, gpu_index: u32| -> ([f32; 4], [f32; 4]) {
        let n = &nodes[idx];
        let (r, c) = if n.prim_count > 0 {
            (n.first_index, n.prim_count)
        } else {
            (gpu_index, 0)
        };
        (
            [n.aabb.min.x, n.aabb.min.y, n.aabb.min.z, f32::from_bits(r)],
            [n.aabb.max.x, n.aabb.max.y, n.aabb.max.z, f32::from_bits(c)],
        )
    };
    if nodes.is_empty() {
        return (vec![GpuNode::default()], gpu_tris);
    }
    if nodes[0].prim_count > 0 {
        // A root leaf: the right child repeats it (testing a triangle twice is harmless,
        // and avoids an "empty box" whose slab test would be NaN-prone).
        let (mn, mx) = child(0, 0);
        return (
            vec![GpuNode {
                l_min: mn,
                l_max: mx,
                r_min: mn,
                r_max: mx,
            }],
            gpu_tris,
        );
    }
    // Breadth-first over inner nodes: GPU index assigned when a node is queued.
    let mut gpu_of = vec![u32::MAX; nodes.len()];
    let mut queue = std::collections::VecDeque::from([0usize]);
    gpu_of[0] = 0;
    let mut next = 1u32;
    let mut out = Vec::new();
    while let Some(i) = queue.pop_front() {
        let first = nodes[i].first_index as usize;
        let mut pair = [([0.0; 4], [0.0; 4]); 2];
        for (k, c) in [first, first + 1].into_iter().enumerate() {
            if nodes[c].prim_count == 0 {
                gpu_of[c] = next;
                next += 1;
                queue.push_back(c);
            }
            pair[k] = child(c, gpu_of[c]);
        }
        out.push(GpuNode {
            l_min: pair[0].0,
            l_max: pair[0].1,
            r_min: pair[1].0,
            r_max: pair[1].1,
        });
    }
    (out, gpu_tris)
}

/// Builds obvhs's compressed wide BVH (PLOC, reinsertion, the BVH2 collapsed into nodes of
/// eight children and leaves of up to `max_prims_per_leaf` (at most 3) triangles) with the
/// `quality` preset.
pub fn build_wide_with(tris: &[Triangle], quality: BvhQuality) -> CwBvh {
    let mut core = std::time::Duration::ZERO;
    obvhs::cwbvh::builder::build_cwbvh_from_tris(tris, quality.params(), &mut core)
}

/// One wide node with no children: no ray hits anything (an empty level; bindings may not
/// be empty), and one degenerate triangle.
pub fn empty_wide() -> (Vec<WideNode>, Vec<GpuTri>) {
    (vec![WideNode::default()], vec![GpuTri::default()])
}

/// One level of the software backend in the shader's layout: the node array as bytes
/// (the wide layout's if `wide`, else the child pairs') and the triangles in leaf order.
/// An empty mesh gets the layout's empty level (bindings may not be empty).
pub fn gpu_level(
    tris: &[Triangle],
    quality: BvhQuality,
    wide: bool,
) -> Result<(Vec<u8>, Vec<GpuTri>), String> {
    fn bytes<T: bytemuck::Pod>((nodes, tris): (Vec<T>, Vec<GpuTri>)) -> (Vec<u8>, Vec<GpuTri>) {
        (bytemuck::cast_slice(&nodes).to_vec(), tris)
    }
    Ok(match (wide, tris.is_empty()) {
        (true, true) => bytes(empty_wide()),
        (false, true) => bytes(empty()),
        (true, false) => bytes(flatten_wide(&build_wide_with(tris, quality), tris)?),
        (false, false) => bytes(flatten(&build_bvh_with(tris, quality), tris)),
    })
}

/// A byte of a node's per-slot arrays (`slot` 0..8 of the two words from `w`).
fn slot_byte(words: [u32; 2], slot: usize) -> u32 {
    (words[slot / 4] >> ((slot % 4) * 8)) & 0xff
}

/// Grid cell size of exponent byte `e` (2^(e - 127)), as the shader decodes it.
fn cell(e: u32) -> f32 {
    f32::from_bits(e << 23)
}

/// A child-box plane as the shader computes it: `min + q * cell` in f32 (q * cell is
/// exact, a power of two times an integer below 256, so a fused multiply-add gives the
/// same bits).
fn plane(min: f32, q: u32, e: u32) -> f32 {
    min + q as f32 * cell(e)
}

/// The quantized grid of one axis of a node: the smallest exponent whose 255 cells reach
/// `max` from `min`, and for each child box [lo, hi] the largest q with plane <= lo and
/// the smallest with plane >= hi. Rounding is monotonic, so the planes enclose the box.
fn quantize_axis(min: f32, max: f32, children: &[(f32, f32)]) -> (u32, Vec<(u32, u32)>) {
    let extent = (max - min).max(f32::MIN_POSITIVE);
    let mut e = ((extent / 255.0).log2().ceil() as i32 + 127).clamp(1, 254) as u32;
    while e > 1 && plane(min, 255, e - 1) >= max {
        e -= 1;
    }
    while e < 254 && plane(min, 255, e) < max {
        e += 1;
    }
    let qs = children
        .iter()
        .map(|&(lo, hi)| {
            let guess = |v: f32| ((v - min) / cell(e)).clamp(0.0, 255.0) as u32;
            let mut ql = guess(lo);
            while ql > 0 && plane(min, ql, e) > lo {
                ql -= 1;
            }
            while ql < 255 && plane(min, ql + 1, e) <= lo {
                ql += 1;
            }
            let mut qh = guess(hi).max(ql);
            while qh < 255 && plane(min, qh, e) < hi {
                qh += 1;
            }
            while qh > ql && plane(min, qh - 1, e) >= hi {
                qh -= 1;
            }
            (ql, qh)
        })
        .collect();
    (e, qs)
}

/// The box of `slot` of a wide node as the shader decodes it (glsl/common/trace.glsl,
/// `trace_wide_half`): per axis `min + q * cell` for the slot's grid minimum and maximum.
fn slot_box(n: &WideNode, slot: usize) -> (glam::Vec3, glam::Vec3) {
    let q = [n.qx, n.qy, n.qz];
    let corner = |lo_hi: usize| {
        glam::Vec3::from_array(std::array::from_fn(|a| {
            let e = (n.head[3] >> (8 * a)) & 0xff;
            let qv = slot_byte([q[a][2 * lo_hi], q[a][2 * lo_hi + 1]], slot);
            plane(f32::from_bits(n.head[a]), qv, e)
        }))
    };
    (corner(0), corner(1))
}

/// Where a wide node's child in `slot` points: an inner node's index, or a leaf's
/// triangles (first, count) in `primitive_indices` order.
enum WideChild {
    Inner(usize),
    Leaf(u32, u32),
}

fn wide_child(n: &WideNode, slot: usize) -> Option<WideChild> {
    let meta = slot_byte([n.meta[2], n.meta[3]], slot);
    if meta == 0 {
        return None;
    }
    let imask = n.head[3] >> 24;
    Some(if imask & (1 << slot) != 0 {
        let rank = (imask & ((1 << slot) - 1)).count_ones();
        WideChild::Inner((n.meta[0] + rank) as usize)
    } else {
        WideChild::Leaf(n.meta[1] + (meta & 0x1f), (meta >> 5).count_ones())
    })
}

/// Flattens obvhs's `cw` into the shader's nodes (root at 0) and leaf-ordered triangles,
/// re-quantizing every node's child boxes from the exact bounds of their triangles so
/// the boxes the shader decodes contain them (obvhs quantizes with rounded float
/// arithmetic, which can cut a box by an ulp; a ray through that ulp would be lost).
/// Fails if the tree is deeper than the shader's stack (TRACE_WIDE_STACK).
pub fn flatten_wide(cw: &CwBvh, tris: &[Triangle]) -> Result<(Vec<WideNode>, Vec<GpuTri>), String> {
    let gpu_tris = leaf_order(&cw.primitive_indices, tris);
    if cw.nodes.is_empty() {
        return Ok((vec![WideNode::default()], gpu_tris));
    }
    let mut nodes: Vec<WideNode> = cw.nodes.iter().map(|n| bytemuck::cast(*n)).collect();
    type Bounds = (glam::Vec3, glam::Vec3);
    let leaf_bounds = |first: u32, count: u32| -> Bounds {
        let mut b = (glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY);
        for t in &gpu_tris[first as usize..(first + count) as usize] {
            for v in [t.v0, t.v1, t.v2] {
                let v = glam::Vec3::new(v[0], v[1], v[2]);
                b = (b.0.min(v), b.1.max(v));
            }
        }
        b
    };
    // Children come after their parent, so one backward sweep has every child's bounds
    // before its parent needs them.
    let mut bounds: Vec<Bounds> = vec![(glam::Vec3::ZERO, glam::Vec3::ZERO); nodes.len()];
    let mut depth = vec![1usize; nodes.len()];
    for i in (0..nodes.len()).rev() {
        let n = nodes[i];
        let mut kids: Vec<(usize, Bounds)> = Vec::with_capacity(8);
        for slot in 0..8 {
            let b = match wide_child(&n, slot) {
                None => continue,
                Some(WideChild::Inner(c)) => {
                    depth[i] = depth[i].max(depth[c] + 1);
                    bounds[c]
                }
                Some(WideChild::Leaf(first, count)) => leaf_bounds(first, count),
            };
            kids.push((slot, b));
        }
        let all = kids.iter().fold(
            (glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY),
            |a, (_, b)| (a.0.min(b.0), a.1.max(b.1)),
        );
        if kids.is_empty() {
            continue;
        }
        bounds[i] = all;
        let node = &mut nodes[i];
        node.head[0] = all.0.x.to_bits();
        node.head[1] = all.0.y.to_bits();
        node.head[2] = all.0.z.to_bits();
        let mut head_w = node.head[3] & 0xff00_0000;
        for axis in 0..3 {
            let child_ranges: Vec<(f32, f32)> =
                kids.iter().map(|(_, b)| (b.0[axis], b.1[axis])).collect();
            let (e, qs) = quantize_axis(all.0[axis], all.1[axis], &child_ranges);
            head_w |= e << (8 * axis);
            let q = match axis {
                0 => &mut node.qx,
                1 => &mut node.qy,
                _ => &mut node.qz,
            };
            for (&(slot, _), &(ql, qh)) in kids.iter().zip(&qs) {
                let (w, shift) = (slot / 4, (slot % 4) * 8);
                q[w] = (q[w] & !(0xff << shift)) | (ql << shift);
                q[2 + w] = (q[2 + w] & !(0xff << shift)) | (qh << shift);
            }
        }
        node.head[3] = head_w;
    }
    if depth[0] > TRACE_WIDE_STACK as usize {
        return Err(format!(
            "the wide BVH is {} levels deep; the shader's traversal stack holds {TRACE_WIDE_STACK} \
             (degenerate geometry?)",
            depth[0]
        ));
    }
    Ok((nodes, gpu_tris))
}

/// Every triangle of `nodes` as the shader's traversal would reach it, with the boxes it
/// decodes on the way: (triangle position in leaf order, the decoded boxes of its
/// ancestors' slots, innermost last). For tests of [`flatten_wide`].
pub fn wide_paths(nodes: &[WideNode]) -> Vec<(u32, Vec<(glam::Vec3, glam::Vec3)>)> {
    let mut out = Vec::new();
    let mut todo = vec![(0usize, Vec::new())];
    while let Some((i, path)) = todo.pop() {
        let n = &nodes[i];
        for slot in 0..8 {
            let Some(child) = wide_child(n, slot) else {
                continue;
            };
            let mut p = path.clone();
            p.push(slot_box(n, slot));
            match child {
                WideChild::Inner(c) => todo.push((c, p)),
                WideChild::Leaf(first, count) => {
                    out.extend((first..first + count).map(|t| (t, p.clone())));
                }
            }
        }
    }
    out
}

/// Closest hit in the shader's wide layout, visiting nodes in the shader's order
/// (glsl/common/trace_bvh.glsl, mirrored step by step): node groups on a stack, children
/// in the octant order, each decoded box tested with the widened slab test. Returns
/// (t, original triangle) and counts the work: box tests (eight slots a node, empty ones
/// not counted), triangle tests and node visits in `stats`.
pub fn cpu_closest_hit_wide(
    nodes: &[WideNode],
    tris: &[GpuTri],
    origin: glam::Vec3,
    dir: glam::Vec3,
    tmin: f32,
    tmax: f32,
    stats: &mut TraversalStats,
) -> Option<(f32, u32)> {
    let o = glam::Vec3A::from(origin);
    let inv_d = glam::Vec3A::from(dir).recip();
    let sheared = super::watertight::ShearedRay::new(origin, dir);
    let oct_inv = (if dir.x < 0.0 { 0 } else { 4 })
        | (if dir.y < 0.0 { 0 } else { 2 })
        | (if dir.z < 0.0 { 0 } else { 1 });
    let mut best: Option<(f32, u32)> = None;
    let mut t_best = tmax;
    let mut stack: Vec<[u32; 2]> = Vec::with_capacity(TRACE_WIDE_STACK as usize);
    let mut group = [0u32, 0x8000_0000];
    let mut leaf = [0u32, 0];
    loop {
        while leaf[1] != 0 {
            let b = 31 - leaf[1].leading_zeros();
            leaf[1] &= !(1 << b);
            let t = &tris[(leaf[0] + b) as usize];
            let p = t.v0[3].to_bits();
            stats.triangle_tests += 1;
            let corner = |v: [f32; 4]| glam::Vec3::new(v[0], v[1], v[2]);
            let hit = sheared.intersect(
                corner(t.v0),
                corner(t.v1),
                corner(t.v2),
                tmin,
                t_best.next_up(),
            );
            if let Some((th, _)) = hit {
                let closer = match best {
                    Some((tb, pb)) => th < tb || (th == tb && p < pb),
                    None => th < t_best,
                };
                if closer {
                    t_best = th;
                    best = Some((th, p));
                }
            }
        }
        if group[1] & 0xff00_0000 != 0 {
            let hits = group[1];
            let bit = 31 - hits.leading_zeros();
            group[1] &= !(1 << bit);
            if group[1] & 0xff00_0000 != 0 {
                stack.push(group);
            }
            let slot = (bit - 24) ^ oct_inv;
            let n = &nodes[(group[0] + (hits & !(u32::MAX << slot)).count_ones()) as usize];
            stats.node_visits += 1;
            let mut hitmask = 0u32;
            for s in 0..8 {
                let meta = slot_byte([n.meta[2], n.meta[3]], s);
                if meta == 0 {
                    continue;
                }
                stats.box_tests += 1;
                let (lo, hi) = slot_box(n, s);
                if robust_box_t(lo.into(), hi.into(), o, inv_d, tmin, t_best).is_some() {
                    let inner = meta & 0x18 == 0x18;
                    let at = if inner {
                        (meta ^ oct_inv) & 0x1f
                    } else {
                        meta & 0x1f
                    };
                    hitmask |= ((meta >> 5) & 7) << at;
                }
            }
            group = [n.meta[0], (hitmask & 0xff00_0000) | (n.head[3] >> 24)];
            leaf = [n.meta[1], hitmask & 0x00ff_ffff];
        } else {
            group = [0, 0];
        }
        if leaf[1] == 0 && group[1] & 0xff00_0000 == 0 {
            match stack.pop() {
                Some(g) => group = g,
                None => break,
            }
        }
    }
    best
}

/// Slab test with the far distance widened as in the shader (Ize 2013), so a ray through
/// a vertex on a box face is never dropped by rounding. obvhs's own `ray_traverse` uses an
/// exact slab test and misses such rays (measured: about 3 % of vertex-aimed rays on a
/// 51k-triangle sphere), which is why the reference traversal lives here.
fn robust_box_t(
    min: glam::Vec3A,
    max: glam::Vec3A,
    o: glam::Vec3A,
    inv_d: glam::Vec3A,
    tmin: f32,
    tmax: f32,
) -> Option<f32> {
    let t0 = (min - o) * inv_d;
    let t1 = (max - o) * inv_d;
    let near = t0.min(t1).max_element().max(tmin);
    let far = t0.max(t1).min_element().min(tmax) * 1.000_000_4;
    (near <= far).then_some(near)
}

/// Closest hit on the CPU: stack traversal of the obvhs BVH2 with the watertight triangle
/// test (the reference the GPU backends are tested against). obvhs's Moeller-Trumbore test
/// leaks through shared vertices (measured: 3 % of vertex-aimed rays), so it is not used.
/// Returns (t, original triangle).
pub fn cpu_closest_hit(
    bvh: &Bvh2,
    tris: &[Triangle],
    origin: glam::Vec3,
    dir: glam::Vec3,
    tmin: f32,
    tmax: f32,
) -> Option<(f32, u32)> {
    cpu_closest_hit_counted(
        bvh,
        tris,
        origin,
        dir,
        tmin,
        tmax,
        &mut TraversalStats::default(),
    )
}

/// Work done by a traversal: box tests, triangle tests, nodes loaded.
#[derive(Clone, Copy, Debug, Default)]
pub struct TraversalStats {
    pub box_tests: u64,
    pub triangle_tests: u64,
    /// Nodes loaded (the wide traversal's; the BVH2 reference leaves it 0).
    pub node_visits: u64,
}

/// [`cpu_closest_hit`], counting its work. The order is the shader's: both children's
/// boxes are tested, leaves are intersected at once, the nearer inner child is visited
/// first and the farther one pushed, so the counts describe the GPU traversal too.
pub fn cpu_closest_hit_counted(
    bvh: &Bvh2,
    tris: &[Triangle],
    origin: glam::Vec3,
    dir: glam::Vec3,
    tmin: f32,
    tmax: f32,
    stats: &mut TraversalStats,
) -> Option<(f32, u32)> {
    let o = glam::Vec3A::from(origin);
    let inv_d = glam::Vec3A::from(dir).recip();
    let mut best: Option<(f32, u32)> = None;
    let mut t_best = tmax;
    let sheared = super::watertight::ShearedRay::new(origin, dir);
    let mut leaf =
        |n: &obvhs::bvh2::node::Bvh2Node, t_best: &mut f32, stats: &mut TraversalStats| {
            for k in n.first_index..n.first_index + n.prim_count {
                let p = bvh.primitive_indices[k as usize];
                let tri = &tris[p as usize];
                stats.triangle_tests += 1;
                // Ties at exactly the same distance go to the lower triangle index, as in
                // the shader, so the hit does not depend on the traversal order.
                let hit = sheared.intersect(
                    tri.v0.into(),
                    tri.v1.into(),
                    tri.v2.into(),
                    tmin,
                    t_best.next_up(),
                );
                if let Some((t, _)) = hit {
                    let closer = match best {
                        Some((tb, pb)) => t < tb || (t == tb && p < pb),
                        None => t < *t_best,
                    };
                    if closer {
                        *t_best = t;
                        best = Some((t, p));
                    }
                }
            }
        };
    let root = bvh.nodes.first()?;
    if root.prim_count > 0 {
        leaf(root, &mut t_best, stats);
        return best;
    }
    let mut stack: Vec<(f32, usize)> = Vec::with_capacity(64);
    let mut node = 0usize;
    loop {
        let first = bvh.nodes[node].first_index as usize;
        let mut near: [Option<(f32, usize)>; 2] = [None, None];
        for (k, c) in [first, first + 1].into_iter().enumerate() {
            let n = &bvh.nodes[c];
            stats.box_tests += 1;
            if let Some(t) = robust_box_t(n.aabb.min, n.aabb.max, o, inv_d, tmin, t_best) {
                if n.prim_count > 0 {
                    leaf(n, &mut t_best, stats);
                } else {
                    near[k] = Some((t, c));
                }
            }
        }
        node = match near {
            [Some(a), Some(b)] => {
                let (n, f) = if a.0 <= b.0 { (a, b) } else { (b, a) };
                stack.push(f);
                n.1
            }
            [Some(a), None] | [None, Some(a)] => a.1,
            // Nodes farther than a hit found since they were pushed are dropped; the
            // comparison is widened as the slab test's far distance is, so a node whose
            // entry rounds past an equally distant hit (a ray through a shared vertex)
            // is still visited and the tie goes to the lower index whatever the order.
            [None, None] => {
                match std::iter::from_fn(|| stack.pop()).find(|&(t, _)| t <= t_best * 1.000_000_4) {
                    Some((_, n)) => n,
                    None => break,
                }
            }
        };
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// The six faces of an axis-aligned box split into n x n quads each: flat node boxes
    /// (zero extent on an axis), planes shared by many leaves.
    fn box_faces(lo: Vec3, hi: Vec3, n: u32) -> Vec<Triangle> {
        let mut out = Vec::new();
        for axis in 0..3 {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            for side in [lo[axis], hi[axis]] {
                let at = |i: u32, j: u32| {
                    let mut p = Vec3::ZERO;
                    p[axis] = side;
                    p[u] = lo[u] + (hi[u] - lo[u]) * i as f32 / n as f32;
                    p[v] = lo[v] + (hi[v] - lo[v]) * j as f32 / n as f32;
                    p
                };
                for i in 0..n {
                    for j in 0..n {
                        let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                        out.push(Triangle {
                            v0: a.into(),
                            v1: b.into(),
                            v2: c.into(),
                        });
                        out.push(Triangle {
                            v0: a.into(),
                            v1: c.into(),
                            v2: d.into(),
                        });
                    }
                }
            }
        }
        out
    }

    fn meshes() -> Vec<(&'static str, Vec<Triangle>)> {
        // 3000 small triangles scattered in a slab (a simple LCG: no scene module here).
        let mut state = 0x2545_f491_u32;
        let mut rnd = move || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) as f32 / (1 << 24) as f32
        };
        let soup: Vec<Triangle> = (0..3000)
            .map(|_| {
                let c = Vec3::new(rnd() * 40.0 - 20.0, rnd() * 40.0 - 20.0, rnd() * 2.0);
                let mut corner = || (c + (Vec3::new(rnd(), rnd(), rnd()) - 0.5) * 1.5).into();
                Triangle {
                    v0: corner(),
                    v1: corner(),
                    v2: corner(),
                }
            })
            .collect();
        let one = Triangle {
            v0: Vec3::new(0.1, 0.2, 0.3).into(),
            v1: Vec3::new(1.0, 0.2, 0.3).into(),
            v2: Vec3::new(0.1, 1.7, 0.3).into(),
        };
        vec![
            ("triangle soup", soup),
            // Far from the origin, small against its coordinates: every plane rounds.
            (
                "small box far away",
                box_faces(
                    Vec3::splat(1234.567),
                    Vec3::splat(1234.567) + Vec3::new(0.003, 0.0071, 0.0019),
                    9,
                ),
            ),
            (
                "box about the origin",
                box_faces(Vec3::new(-3.1, -0.0, -1e-3), Vec3::new(2.9, 7.3, 1e-3), 12),
            ),
            ("one triangle", vec![one]),
            (
                "two triangles",
                box_faces(Vec3::ZERO, Vec3::ONE, 1)[..2].to_vec(),
            ),
        ]
    }

    #[test]
    fn every_decoded_box_contains_its_triangles() {
        for (name, tris) in meshes() {
            let (nodes, gtris) =
                flatten_wide(&build_wide_with(&tris, DEFAULT_BVH_QUALITY), &tris).expect("shallow");
            let paths = wide_paths(&nodes);
            assert_eq!(
                paths.len(),
                tris.len(),
                "{name}: every triangle in one leaf"
            );
            for (t, boxes) in paths {
                let tri = gtris[t as usize];
                for v in [tri.v0, tri.v1, tri.v2] {
                    let v = Vec3::new(v[0], v[1], v[2]);
                    for (lo, hi) in &boxes {
                        assert!(
                            v.cmpge(*lo).all() && v.cmple(*hi).all(),
                            "{name}: corner {v} of triangle {t} outside a decoded box {lo}..{hi}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn the_quantized_grid_is_tight_and_conservative() {
        // A child that is the whole node spans the grid; one in the middle is enclosed
        // by the planes next to it, no wider.
        let (e, qs) = quantize_axis(1.0, 2.0, &[(1.0, 2.0), (1.25, 1.5)]);
        assert!(
            plane(1.0, 255, e) >= 2.0 && plane(1.0, 255, e - 1) < 2.0,
            "smallest exponent"
        );
        assert_eq!(qs[0].0, 0);
        assert!(plane(1.0, qs[0].1, e) >= 2.0 && plane(1.0, qs[0].1 - 1, e) < 2.0);
        let (ql, qh) = qs[1];
        assert!(plane(1.0, ql, e) <= 1.25 && plane(1.0, ql + 1, e) > 1.25);
        assert!(plane(1.0, qh, e) >= 1.5 && plane(1.0, qh - 1, e) < 1.5);
        // Flat: both planes decode to the plane itself.
        let (e, qs) = quantize_axis(5.5, 5.5, &[(5.5, 5.5)]);
        assert_eq!((plane(5.5, qs[0].0, e), plane(5.5, qs[0].1, e)), (5.5, 5.5));
    }

    #[test]
    fn the_wide_traversal_finds_the_references_hits() {
        for (name, tris) in meshes() {
            let bvh = build_bvh(&tris);
            let (nodes, gtris) =
                flatten_wide(&build_wide_with(&tris, DEFAULT_BVH_QUALITY), &tris).expect("shallow");
            let (lo, hi) = tris
                .iter()
                .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |b, t| {
                    let (a, c, d): (Vec3, Vec3, Vec3) = (t.v0.into(), t.v1.into(), t.v2.into());
                    (b.0.min(a).min(c).min(d), b.1.max(a).max(c).max(d))
                });
            let centre = (lo + hi) * 0.5;
            let r = (hi - lo).length().max(1.0);
            let mut hits = 0;
            // Rays from a sphere around the mesh at its vertices (where watertightness
            // and box rounding are tested hardest) and at triangle centres.
            for (k, t) in tris.iter().enumerate().step_by((tris.len() / 500).max(1)) {
                let targets: [Vec3; 2] = [
                    t.v0.into(),
                    (Vec3::from(t.v0) + Vec3::from(t.v1) + Vec3::from(t.v2)) / 3.0,
                ];
                for (j, target) in targets.into_iter().enumerate() {
                    let a = (k * 2 + j) as f32 * 2.399_963;
                    let z = ((k * 7 + j * 3) % 97) as f32 / 48.0 - 1.0;
                    let s = (1.0 - z * z).sqrt();
                    let origin = centre + r * Vec3::new(s * a.cos(), s * a.sin(), z);
                    let dir = (target - origin).normalize();
                    let want = cpu_closest_hit(&bvh, &tris, origin, dir, 0.0, 1e30);
                    let got = cpu_closest_hit_wide(
                        &nodes,
                        &gtris,
                        origin,
                        dir,
                        0.0,
                        1e30,
                        &mut TraversalStats::default(),
                    );
                    assert_eq!(got.map(|h| h.1), want.map(|h| h.1), "{name}: ray {k}/{j}");
                    assert_eq!(got.map(|h| h.0), want.map(|h| h.0), "{name}: ray {k}/{j}");
                    hits += got.is_some() as usize;
                }
            }
            assert!(hits > 0, "{name}: the rays hit");
        }
    }
}
