//! First-hit queries: a list of rays (tests, benchmarks) and a raycast image of a mesh
//! (depth and normals) from a [`Camera`].

use std::sync::Arc;

use ash::vk;

use super::view::{Tiling, camera_block};
use crate::gpu_interface::{
    BundleBlock, HitsBinding, HitsPush, ImagePush, RaycastBinding, ShadowBlock, Tri,
};
use crate::graph::{Graph, PassTiming};
use crate::scene::Camera;
use crate::trace::{TraceScene, scramble_multiplier};
use crate::vk::{Buffer, Context, MemoryKind, Profiler, VkError};

/// A ray for [`trace_rays`]: origin, tmin, direction, tmax.
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct RayIn {
    pub origin: [f32; 3],
    pub tmin: f32,
    pub dir: [f32; 3],
    pub tmax: f32,
}

/// The closest hit of a ray: `t < 0` when missed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HitOut {
    pub t: f32,
    pub prim: u32,
    pub bary: [f32; 2],
}

impl HitOut {
    pub fn is_hit(&self) -> bool {
        self.t >= 0.0
    }
}

/// The ray sets of the throughput benchmarks (examples/bench_trace, `synosis bench-gpu`):
/// `side`^2 primary rays of a pinhole camera framing `mesh`, and `side`^2 random rays
/// (origins spread over 1.5 x its bounding box, uniform directions; Pcg64 seed 1).
pub fn benchmark_rays(mesh: &crate::scene::Mesh, side: u32) -> (Vec<RayIn>, Vec<RayIn>) {
    use glam::Vec3;
    use rand::{Rng, SeedableRng};
    let cam = Camera::framing(mesh, side, side);
    let primary = (0..side * side)
        .map(|i| RayIn {
            origin: cam.eye.into(),
            tmin: 0.0,
            dir: cam.pixel_dir(i % side, i / side).into(),
            tmax: 1e30,
        })
        .collect();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
    let (lo, hi) = mesh.bounds();
    let random = (0..side * side)
        .map(|_| {
            let o = lo + (hi - lo) * Vec3::new(rng.random(), rng.random(), rng.random()) * 1.5
                - (hi - lo) * 0.25;
            let u: f32 = rng.random_range(-1.0..1.0);
            let phi: f32 = rng.random_range(0.0..std::f32::consts::TAU);
            let s = (1.0 - u * u).sqrt();
            RayIn {
                origin: o.into(),
                tmin: 0.0,
                dir: [s * phi.cos(), s * phi.sin(), u],
                tmax: 1e30,
            }
        })
        .collect();
    (primary, random)
}

/// Box and triangle tests per ray of the BVH2 traversal over every `stride`-th ray of
/// `rays` (counted by the CPU reference, which visits a BVH2's nodes in the order of the
/// `software` backend's child-pair shader): the tree's quality, independent of the
/// machine (`examples/bench_trace`, `bench_bvh`).
pub fn traversal_work(
    bvh: &obvhs::bvh2::Bvh2,
    tris: &[obvhs::triangle::Triangle],
    rays: &[RayIn],
    stride: usize,
) -> (f64, f64) {
    use crate::trace::software_bvh::{TraversalStats, cpu_closest_hit_counted};
    let mut st = TraversalStats::default();
    for r in rays.iter().step_by(stride) {
        let (o, d) = (r.origin.into(), r.dir.into());
        cpu_closest_hit_counted(bvh, tris, o, d, r.tmin, r.tmax, &mut st);
    }
    let n = rays.len().div_ceil(stride).max(1) as f64;
    (st.box_tests as f64 / n, st.triangle_tests as f64 / n)
}

/// [`traversal_work`] of the shader's wide layout (`software_bvh::flatten_wide`'s nodes
/// and triangles), counted by its CPU mirror: (box tests, triangle tests, nodes loaded)
/// per ray.
pub fn wide_traversal_work(
    nodes: &[crate::gpu_interface::WideNode],
    tris: &[crate::trace::software_bvh::GpuTri],
    rays: &[RayIn],
    stride: usize,
) -> (f64, f64, f64) {
    use crate::trace::software_bvh::{TraversalStats, cpu_closest_hit_wide};
    let mut st = TraversalStats::default();
    for r in rays.iter().step_by(stride) {
        let (o, d) = (r.origin.into(), r.dir.into());
        cpu_closest_hit_wide(nodes, tris, o, d, r.tmin, r.tmax, &mut st);
    }
    let n = rays.len().div_ceil(stride).max(1) as f64;
    (
        st.box_tests as f64 / n,
        st.triangle_tests as f64 / n,
        st.node_visits as f64 / n,
    )
}

/// Traces `rays` against `scene` on the GPU; returns the hits and the trace pass's time.
pub fn trace_rays(
    ctx: &Arc<Context>,
    scene: &TraceScene,
    rays: &[RayIn],
    profiler: Option<&Profiler>,
) -> Result<(Vec<HitOut>, PassTiming), VkError> {
    trace_rays_hinted(ctx, scene, rays, None, profiler)
}

/// A closest-hit hint for [`trace_rays_hinted`]: a triangle of the scene (its corners in
/// the mesh's order and its index), or none.
#[derive(Clone, Copy, Debug)]
pub struct RayHint {
    pub corners: [[f32; 3]; 3],
    pub prim: Option<u32>,
}

/// [`trace_rays`] with a hint per ray (`hints`, as many as `rays`): the path tracer's
/// camera rays start their closest-hit query from the triangle the pixel's centre ray met
/// (glsl/common/trace.glsl, TraceHint); whatever the hint, the hit must be the same.
///
/// # Panics
/// If `hints` is given and its length is not `rays`'.
pub fn trace_rays_hinted(
    ctx: &Arc<Context>,
    scene: &TraceScene,
    rays: &[RayIn],
    hints: Option<&[RayHint]>,
    profiler: Option<&Profiler>,
) -> Result<(Vec<HitOut>, PassTiming), VkError> {
    trace_rays_with(ctx, scene, rays, hints, None, None, profiler).map(|(h, _, t)| (h, t))
}

/// A pixel's camera-ray bundle for [`trace_rays_bundled`] (glsl/common/trace.glsl
/// `trace_bundle_init`): the camera's eye, unit right, up and forward axes, its aperture's
/// radius (0: a pinhole) and the depth of its plane of focus, the pixel's footprint box on
/// that plane (`[x0, x1, y0, y1]` along right and up, from the eye), and a point and a
/// normal of the plane of the triangle the pixel's centre ray met.
#[derive(Clone, Copy, Debug)]
pub struct RayBundle {
    pub eye: [f32; 3],
    pub right: [f32; 3],
    pub up: [f32; 3],
    pub forward: [f32; 3],
    pub lens_radius: f32,
    pub focus_depth: f32,
    pub footprint: [f32; 4],
    pub plane_point: [f32; 3],
    pub plane_normal: [f32; 3],
}

/// What became of a ray's bundle in [`trace_rays_bundled`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BundleUse {
    /// None was built (a ray of it could meet the plane behind the lens or along it, or
    /// too many triangles meet it).
    None,
    /// Built; the ray's hit lay beyond it, so the object was traversed.
    Traversed,
    /// The ray's hit was taken from the bundle's triangles, without the traversal.
    Answered,
}

/// [`trace_rays_hinted`] with, for each ray, its pixel's camera-ray bundle, built before
/// its query as the path tracer builds one per pixel: the hit must be the same. Each ray
/// needs a hint (the bundle is used for hinted queries only). Returns the hits and what
/// became of each bundle (the ray-query backend builds none).
///
/// # Panics
/// If `hints` or `bundles` are not as many as `rays`.
pub fn trace_rays_bundled(
    ctx: &Arc<Context>,
    scene: &TraceScene,
    rays: &[RayIn],
    hints: &[RayHint],
    bundles: &[RayBundle],
) -> Result<(Vec<HitOut>, Vec<BundleUse>), VkError> {
    trace_rays_with(ctx, scene, rays, Some(hints), Some(bundles), None, None)
        .map(|(h, u, _)| (h, u))
}

/// A pixel's shadow bundle for [`trace_rays_shadowed`] (glsl/common/trace.glsl
/// `trace_shadow_init`): the box the shadow rays start in and the box their segments end
/// in (min and max corners).
#[derive(Clone, Copy, Debug)]
pub struct RayShadow {
    pub origin: [[f32; 3]; 2],
    pub light: [[f32; 3]; 2],
}

/// Occlusion tests (the path tracer's shadow-ray query of the object, TQ_BLOCKED: is
/// anything within [tmin, tmax]), each ray with a shadow bundle of its own built first
/// (`Some`) or none: the answer must be the same. Returns whether each ray is blocked and
/// what became of its bundle (`Answered`: from the bundle's list, without the object's
/// traversal; the ray-query backend builds none).
///
/// # Panics
/// If `shadows` is not as many as `rays`.
pub fn trace_rays_shadowed(
    ctx: &Arc<Context>,
    scene: &TraceScene,
    rays: &[RayIn],
    shadows: &[Option<RayShadow>],
) -> Result<(Vec<bool>, Vec<BundleUse>), VkError> {
    assert_eq!(
        shadows.len(),
        rays.len(),
        "trace_rays_shadowed: one entry a ray"
    );
    trace_rays_with(ctx, scene, rays, None, None, Some(shadows), None)
        .map(|(h, u, _)| (h.iter().map(|h| h.t != 0.0).collect(), u))
}

fn trace_rays_with(
    ctx: &Arc<Context>,
    scene: &TraceScene,
    rays: &[RayIn],
    hints: Option<&[RayHint]>,
    bundles: Option<&[RayBundle]>,
    shadows: Option<&[Option<RayShadow>]>,
    profiler: Option<&Profiler>,
) -> Result<(Vec<HitOut>, Vec<BundleUse>, PassTiming), VkError> {
    if let Some(h) = hints {
        assert_eq!(h.len(), rays.len(), "trace_rays_hinted: one hint a ray");
    }
    if let Some(b) = bundles {
        assert_eq!(b.len(), rays.len(), "trace_rays_bundled: one bundle a ray");
        assert!(hints.is_some(), "trace_rays_bundled: bundles need hints");
    }
    let off = TraceScene::binding_kinds(scene.backend).len() as u32;
    let pipeline = super::pipelines::hits(ctx, scene.backend)?;
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let ray_buf = Buffer::from_slice(ctx, "rays", rays, storage)?;
    let hint_tris: Vec<Tri> = match hints {
        Some(h) => h
            .iter()
            .map(|h| {
                let [a, b, c] = h.corners;
                Tri {
                    a: [a[0], a[1], a[2], f32::from_bits(h.prim.unwrap_or(u32::MAX))],
                    b: [b[0], b[1], b[2], 0.0],
                    c: [c[0], c[1], c[2], 0.0],
                }
            })
            .collect(),
        None => vec![bytemuck::Zeroable::zeroed()],
    };
    let hint_buf = Buffer::from_slice(ctx, "ray hints", &hint_tris, storage)?;
    let v4 = |v: [f32; 3], w: f32| [v[0], v[1], v[2], w];
    let bundle_blocks: Vec<BundleBlock> = match bundles {
        Some(b) => b
            .iter()
            .map(|b| BundleBlock {
                eye: v4(b.eye, b.lens_radius),
                right: v4(b.right, 0.0),
                up: v4(b.up, 0.0),
                fwd: v4(b.forward, b.focus_depth),
                footprint: b.footprint,
                plane_p: v4(b.plane_point, 0.0),
                plane_n: v4(b.plane_normal, 0.0),
            })
            .collect(),
        None => vec![bytemuck::Zeroable::zeroed()],
    };
    let bundle_buf = Buffer::from_slice(ctx, "ray bundles", &bundle_blocks, storage)?;
    let p4 = |v: [f32; 3], w: f32| [v[0], v[1], v[2], w];
    let shadow_blocks: Vec<ShadowBlock> = match shadows {
        Some(s) => s
            .iter()
            .map(|s| match s {
                Some(s) => ShadowBlock {
                    origin_lo: p4(s.origin[0], 1.0),
                    origin_hi: p4(s.origin[1], 0.0),
                    light_lo: p4(s.light[0], 0.0),
                    light_hi: p4(s.light[1], 0.0),
                },
                None => bytemuck::Zeroable::zeroed(),
            })
            .collect(),
        None => vec![bytemuck::Zeroable::zeroed()],
    };
    let shadow_buf = Buffer::from_slice(ctx, "ray shadow bundles", &shadow_blocks, storage)?;
    let readback =
        |name: &str, bytes: u64| Buffer::new(ctx, name, bytes, storage, MemoryKind::Readback);
    let uses_len = bundle_blocks.len().max(shadow_blocks.len());
    let use_buf = readback("bundle use", uses_len as u64 * 4)?;
    let hit_buf = readback("hits", rays.len() as u64 * 16)?;
    // More groups than one dispatch allows: the graph refuses it (VkError::WorkgroupLimit).
    let groups = (rays.len() as u32).div_ceil(64);
    let push = HitsPush {
        count: rays.len() as u32,
        groups,
        mult: scramble_multiplier(groups),
        hinted: if shadows.is_some() {
            3
        } else if bundles.is_some() {
            2
        } else {
            u32::from(hints.is_some())
        },
    };
    let mut g = Graph::new(ctx, "trace rays");
    let refs = scene.import(&mut g);
    let r = g.import(&ray_buf);
    let hb = g.import(&hint_buf);
    let mut h = g.import(&hit_buf);
    let bb = g.import(&bundle_buf);
    let mut ub = g.import(&use_buf);
    let sb = g.import(&shadow_buf);
    refs.bind(g.dispatch("trace", &pipeline, [groups, 1, 1]))
        .read(HitsBinding::Rays.at(off), &r)
        .read(HitsBinding::Hints.at(off), &hb)
        .read(HitsBinding::Bundles.at(off), &bb)
        .read(HitsBinding::Shadows.at(off), &sb)
        .write(HitsBinding::Hits.at(off), &mut h)
        .write(HitsBinding::BundleUse.at(off), &mut ub)
        .push(&push)
        .submit();
    let timings = g.execute(profiler)?;
    let raw: Vec<[f32; 4]> = crate::vk::timed(profiler, "readback", || hit_buf.read())?;
    let uses: Vec<BundleUse> = if bundles.is_some() || shadows.is_some() {
        use_buf
            .read::<u32>()?
            .iter()
            .map(|&u| match u {
                0 => BundleUse::None,
                1 => BundleUse::Traversed,
                _ => BundleUse::Answered,
            })
            .collect()
    } else {
        Vec::new()
    };
    let hits = raw
        .iter()
        .map(|v| HitOut {
            t: v[0],
            prim: v[1].to_bits(),
            bary: [v[2], v[3]],
        })
        .collect();
    let timing = timings.into_iter().next().unwrap_or(PassTiming {
        name: "trace".into(),
        gpu_ms: f64::NAN,
    });
    Ok((hits, uses, timing))
}

/// Depth (hit distance, 0 = miss) and packed RGBA8 normals of a raycast image.
pub struct RaycastImage {
    pub width: u32,
    pub height: u32,
    pub depth: Vec<f32>,
    pub normals: Vec<u32>,
    pub timing: PassTiming,
}

pub fn raycast(
    ctx: &Arc<Context>,
    scene: &TraceScene,
    cam: &Camera,
    profiler: Option<&Profiler>,
) -> Result<RaycastImage, VkError> {
    let (width, height) = (cam.width, cam.height);
    let off = TraceScene::binding_kinds(scene.backend).len() as u32;
    let pipeline = super::pipelines::raycast(ctx, scene.backend)?;
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let n = width as u64 * height as u64;
    let depth_buf = Buffer::new(ctx, "depth", n * 4, storage, MemoryKind::Readback)?;
    let normal_buf = Buffer::new(ctx, "normals", n * 4, storage, MemoryKind::Readback)?;
    let mut g = Graph::new(ctx, "raycast");
    let refs = scene.import(&mut g);
    let geo = g.import(scene.shade_tris());
    let mut d = g.import(&depth_buf);
    let mut nb = g.import(&normal_buf);
    let tiling = Tiling::new(width, height, ctx.info.max_workgroup_count[0]);
    for (tiles, groups) in tiling.dispatches() {
        let push = ImagePush {
            cam: camera_block(cam),
            width,
            height,
            tiles,
            ..Default::default()
        };
        refs.bind(g.dispatch("raycast", &pipeline, [groups, 1, 1]))
            .read(RaycastBinding::Geometry.at(off), &geo)
            .write(RaycastBinding::Depth.at(off), &mut d)
            .write(RaycastBinding::Normals.at(off), &mut nb)
            .push(&push)
            .submit();
    }
    let timings = g.execute(profiler)?;
    let read =
        || -> Result<_, VkError> { Ok((depth_buf.read::<f32>()?, normal_buf.read::<u32>()?)) };
    let (depth, normals) = crate::vk::timed(profiler, "readback", read)?;
    let timing = timings.into_iter().next().unwrap_or(PassTiming {
        name: "raycast".into(),
        gpu_ms: f64::NAN,
    });
    Ok(RaycastImage {
        width,
        height,
        depth,
        normals,
        timing,
    })
}
