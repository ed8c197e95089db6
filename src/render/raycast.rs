//! First-hit queries: a list of rays (tests, benchmarks) and a pinhole raycast image of
//! a mesh (depth and normals).

use std::sync::Arc;

use ash::vk;
use glam::Vec3;

use crate::graph::{Graph, PassTiming};
use crate::scene::Mesh;
use crate::trace::{TraceScene, scramble_multiplier, trace_pipeline};
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

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct HitsPush {
    count: u32,
    groups: u32,
    mult: u32,
    pad: u32,
}

/// Traces `rays` against `scene` on the GPU; returns the hits and the trace pass's time.
pub fn trace_rays(
    ctx: &Arc<Context>,
    scene: &TraceScene,
    rays: &[RayIn],
    profiler: Option<&Profiler>,
) -> Result<(Vec<HitOut>, PassTiming), VkError> {
    let off = TraceScene::binding_kinds(scene.backend).len() as u32;
    let pipeline = trace_pipeline(ctx, "hits", scene.backend, 2, 16, [64, 1, 1])?;
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let ray_buf = Buffer::from_slice(ctx, "rays", rays, storage)?;
    let hit_buf = Buffer::new(
        ctx,
        "hits",
        rays.len() as u64 * 16,
        storage,
        MemoryKind::Readback,
    )?;
    let groups = (rays.len() as u32).div_ceil(64);
    let max_groups = ctx.info.max_workgroup_count[0];
    if groups > max_groups {
        return Err(VkError::Other(format!(
            "{} rays exceed one dispatch ({} groups max)",
            rays.len(),
            max_groups
        )));
    }
    let push = HitsPush {
        count: rays.len() as u32,
        groups,
        mult: scramble_multiplier(groups),
        pad: 0,
    };
    let mut g = Graph::new(ctx, "trace rays");
    let refs = scene.import(&mut g);
    let r = g.import(&ray_buf);
    let mut h = g.import(&hit_buf);
    refs.bind(g.dispatch("trace", &pipeline, [groups, 1, 1]))
        .read(off, &r)
        .write(off + 1, &mut h)
        .push(&push)
        .submit();
    let timings = g.execute(profiler)?;
    let raw: Vec<[f32; 4]> = crate::vk::timed(profiler, "readback", || hit_buf.read())?;
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
    Ok((hits, timing))
}

/// A pinhole camera: position, unit forward, unit up and the vertical field of view.
#[derive(Clone, Copy, Debug)]
pub struct PinholeCamera {
    pub eye: Vec3,
    pub forward: Vec3,
    pub up: Vec3,
    pub vfov_deg: f32,
}

/// Vertical field of view of the raycast framing camera.
pub const FRAMING_VFOV_DEG: f32 = 40.0;
/// Margin around the bounding box in the framing camera (10 %).
pub const FRAMING_MARGIN: f32 = 1.1;

impl PinholeCamera {
    /// Looks straight down -Z from above the centre of the mesh's bounding box, image up
    /// = +Y, right = +X, far enough that the box's XY extent (plus 10 %) fills the view.
    pub fn framing(mesh: &Mesh, aspect: f32) -> PinholeCamera {
        let (lo, hi) = mesh.bounds();
        let c = (lo + hi) * 0.5;
        let half = (hi - lo) * 0.5;
        let tan = (FRAMING_VFOV_DEG.to_radians() * 0.5).tan();
        let half_h = (half.y.max(half.x / aspect) * FRAMING_MARGIN).max(1e-6);
        let dist = half_h / tan;
        PinholeCamera {
            eye: Vec3::new(c.x, c.y, hi.z + dist),
            forward: -Vec3::Z,
            up: Vec3::Y,
            vfov_deg: FRAMING_VFOV_DEG,
        }
    }

    /// Primary ray direction (unnormalised) through pixel centre (px, py), row 0 at top.
    pub fn ray_dir(&self, px: f32, py: f32, width: u32, height: u32) -> Vec3 {
        let (right, up) = self.plane_axes(width, height);
        let nx = (px + 0.5) / width as f32 * 2.0 - 1.0;
        let ny = (py + 0.5) / height as f32 * 2.0 - 1.0;
        (self.forward + nx * right - ny * up).normalize()
    }

    fn plane_axes(&self, width: u32, height: u32) -> (Vec3, Vec3) {
        let tan = (self.vfov_deg.to_radians() * 0.5).tan();
        let aspect = width as f32 / height as f32;
        let right = self.forward.cross(self.up).normalize() * tan * aspect;
        let up = right.cross(self.forward).normalize() * tan;
        (right, up)
    }
}

/// A pinhole camera as the shaders take it (push-constant block shared by the
/// first-hit passes): eye, image-plane axes scaled to the half extents at distance 1,
/// forward, image size, 8x8 tiles per row and the workgroup scramble multiplier.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct CameraPush {
    eye: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    forward: [f32; 4],
    width: u32,
    height: u32,
    tiles_x: u32,
    mult: u32,
}

impl CameraPush {
    pub fn new(cam: &PinholeCamera, width: u32, height: u32) -> Self {
        let tiles_x = width.div_ceil(8);
        let tiles = tiles_x * height.div_ceil(8);
        let (right, up) = cam.plane_axes(width, height);
        CameraPush {
            eye: cam.eye.extend(0.0).into(),
            right: right.extend(0.0).into(),
            up: up.extend(0.0).into(),
            forward: cam.forward.normalize().extend(0.0).into(),
            width,
            height,
            tiles_x,
            mult: scramble_multiplier(tiles),
        }
    }

    /// Number of 8x8 tiles (workgroups) covering the image.
    pub fn tiles(&self) -> u32 {
        self.tiles_x * self.height.div_ceil(8)
    }
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
    cam: &PinholeCamera,
    width: u32,
    height: u32,
    profiler: Option<&Profiler>,
) -> Result<RaycastImage, VkError> {
    let off = TraceScene::binding_kinds(scene.backend).len() as u32;
    let pipeline = trace_pipeline(
        ctx,
        "raycast",
        scene.backend,
        3,
        std::mem::size_of::<CameraPush>() as u32,
        [8, 8, 1],
    )?;
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let n = width as u64 * height as u64;
    let depth_buf = Buffer::new(ctx, "depth", n * 4, storage, MemoryKind::Readback)?;
    let normal_buf = Buffer::new(ctx, "normals", n * 4, storage, MemoryKind::Readback)?;
    let push = CameraPush::new(cam, width, height);
    let tiles = push.tiles();
    let mut g = Graph::new(ctx, "raycast");
    let refs = scene.import(&mut g);
    let geo = g.import(scene.shade_tris());
    let mut d = g.import(&depth_buf);
    let mut nb = g.import(&normal_buf);
    refs.bind(g.dispatch("raycast", &pipeline, [tiles, 1, 1]))
        .read(off, &geo)
        .write(off + 1, &mut d)
        .write(off + 2, &mut nb)
        .push(&push)
        .submit();
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
