//! The software backend's data: an obvhs BVH2 built on the CPU, flattened into the
//! child-pair node layout that glsl/common/trace.glsl traverses.

use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;

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

/// Flattens `bvh` into GPU nodes (root at 0) and leaf-ordered triangles.
pub fn flatten(bvh: &Bvh2, tris: &[Triangle]) -> (Vec<GpuNode>, Vec<GpuTri>) {
    let gpu_tris: Vec<GpuTri> = bvh
        .primitive_indices
        .iter()
        .map(|&p| {
            let t = &tris[p as usize];
            GpuTri {
                v0: [t.v0.x, t.v0.y, t.v0.z, f32::from_bits(p)],
                v1: [t.v1.x, t.v1.y, t.v1.z, 0.0],
                v2: [t.v2.x, t.v2.y, t.v2.z, 0.0],
            }
        })
        .collect();
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

/// Work done by a traversal: box tests and triangle tests.
#[derive(Clone, Copy, Debug, Default)]
pub struct TraversalStats {
    pub box_tests: u64,
    pub triangle_tests: u64,
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
                        Some((tb, pb)) => t < tb || p < pb,
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
            // Nodes farther than a hit found since they were pushed are dropped.
            [None, None] => match std::iter::from_fn(|| stack.pop()).find(|&(t, _)| t <= t_best) {
                Some((_, n)) => n,
                None => break,
            },
        };
    }
    best
}
