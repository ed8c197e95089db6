//! The intersection backends behind one GLSL interface (`glsl/common/trace.glsl`):
//! `ray-query` (KHR acceleration structures), `software` (an obvhs BVH2 traversed in the
//! shader, child pairs) and `software-wide` (an obvhs compressed wide BVH, eight children
//! a node, traversed in the shader). A pipeline is built from the shader variant of the
//! chosen backend; the backend's bindings come first (0 .. `binding_kinds().len()`), the
//! pass's after them.

pub mod software_bvh;
pub mod watertight;

use std::sync::Arc;

use ash::vk;

use bytemuck::Zeroable;
use glam::Vec3;

use crate::graph::{AccelRef, BufferRef, DispatchBuilder, Graph};
use crate::vk::{
    BindingKind, Blas, Buffer, ComputePipeline, Context, Profiler, Tlas, VkError, timed,
};

/// Ray-query instance masks (glsl/common/trace.glsl): `trace` takes every instance,
/// `trace_query`'s light queries only the view's lights.
const MASK_OBJECT: u8 = 0x01;
const MASK_LIGHTS: u8 = 0x02;

/// What `--accel` asks for.
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "kebab-case")]
pub enum AccelChoice {
    #[default]
    Auto,
    RayQuery,
    Software,
    SoftwareWide,
}

/// A concrete backend.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Backend {
    RayQuery,
    /// The software BVH in child-pair nodes (obvhs BVH2).
    Software,
    /// The software BVH in compressed wide nodes (obvhs CWBVH, Ylitie et al. 2017).
    SoftwareWide,
}

impl Backend {
    /// Suffix of the shader variants built for this backend.
    pub fn shader_suffix(self) -> &'static str {
        match self {
            Backend::RayQuery => "rq",
            Backend::Software => "sw",
            Backend::SoftwareWide => "sw8",
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Backend::RayQuery => "ray-query",
            Backend::Software => "software",
            Backend::SoftwareWide => "software-wide",
        }
    }

    /// Whether the backend traverses our own BVH in the shader (both software layouts).
    pub fn is_software(self) -> bool {
        matches!(self, Backend::Software | Backend::SoftwareWide)
    }
}

/// The backend `auto` picks, and why. On a GPU with ray query, the hardware traversal
/// wins. On lavapipe (a CPU device) our software BVH traces about twice as fast as
/// lavapipe's own ray query (measured, docs/benchmarks.md), so auto picks software there,
/// in the wide layout: as fast as the child pairs on coherent rays and 1.1x to 1.25x
/// faster per path-traced sample (docs/benchmarks/rendering.md, "Compressed wide BVH
/// nodes"). GPUs without ray query (data-centre GPUs) get the wide layout too, the one
/// the literature measured fastest on them (Ylitie et al. 2017: about 2x on incoherent
/// rays); not measured here yet.
pub fn auto_backend(ctx_info: &crate::vk::DeviceInfo) -> (Backend, &'static str) {
    if !ctx_info.ray_query_supported {
        (
            Backend::SoftwareWide,
            "the device has no ray query: the software BVH, compressed wide nodes",
        )
    } else if ctx_info.is_cpu {
        (
            Backend::SoftwareWide,
            "CPU device (lavapipe): the software BVH (compressed wide nodes) is measured faster than its ray query",
        )
    } else {
        (Backend::RayQuery, "the device has hardware ray query")
    }
}

/// Resolves a choice against a device; ray-query on a device without it is an error.
/// A software backend on a device without buffer device addresses or 64-bit shader
/// integers is an error too.
pub fn resolve(choice: AccelChoice, info: &crate::vk::DeviceInfo) -> Result<Backend, VkError> {
    let backend = match choice {
        AccelChoice::Auto => auto_backend(info).0,
        AccelChoice::Software => Backend::Software,
        AccelChoice::SoftwareWide => Backend::SoftwareWide,
        AccelChoice::RayQuery if info.ray_query_enabled => Backend::RayQuery,
        AccelChoice::RayQuery => return Err(VkError::RayQueryUnavailable),
    };
    if backend.is_software() && !info.buffer_device_address {
        return Err(VkError::NoBufferDeviceAddress);
    }
    if backend.is_software() && !info.shader_int64 {
        return Err(VkError::NoShaderInt64);
    }
    Ok(backend)
}

/// Per-triangle corner positions in original order (3 x vec4), for shading.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ShadeTri {
    pub a: [f32; 4],
    pub b: [f32; 4],
    pub c: [f32; 4],
}

/// Anything made of indexed triangles (a scene mesh, a light's tessellation). The trace
/// layer sees geometry only through this, so it does not depend on the scene module.
pub trait Triangles {
    fn positions(&self) -> &[Vec3];
    fn triangles(&self) -> &[[u32; 3]];
    /// A value per triangle corner for the shader, stored in `ShadeTri`'s w components
    /// (the scene's smooth normals of triplanar patches: `Tri` in src/gpu_interface.in);
    /// None: zeros.
    fn corner_w(&self) -> Option<&[[f32; 3]]> {
        None
    }
    /// The axis-aligned box of the corners the triangles use ([lower, upper]); None
    /// without triangles.
    fn corner_bounds(&self) -> Option<[Vec3; 2]> {
        let positions = self.positions();
        let triangles = self.triangles();
        (!triangles.is_empty()).then(|| {
            triangles
                .iter()
                .flatten()
                .fold([Vec3::INFINITY, Vec3::NEG_INFINITY], |[lo, hi], &i| {
                    [lo.min(positions[i as usize]), hi.max(positions[i as usize])]
                })
        })
    }
}

/// Plain indexed triangles.
#[derive(Clone, Debug, Default)]
pub struct TriangleSoup {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

impl Triangles for TriangleSoup {
    fn positions(&self) -> &[Vec3] {
        &self.positions
    }
    fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
}

enum Data {
    /// None for an empty level (no BLAS can be built over nothing).
    RayQuery(Option<Blas>),
    Software {
        nodes: Buffer,
        tris: Buffer,
    },
}

/// One level of traceable geometry: a BVH (software) or BLAS (ray query) over one set of
/// triangles, plus their corners in original order for shading. Built once per mesh and
/// shared (`Arc`) by every view of it. Its triangles are numbered from `first_prim` in
/// the scene's index space.
pub struct TraceGeometry {
    pub backend: Backend,
    data: Data,
    /// Original-order triangles for shading (normals; labels live elsewhere).
    pub shade_tris: Buffer,
    pub triangle_count: usize,
    pub first_prim: u32,
    /// The lower and upper corner of the box around its triangles (None: none).
    pub bounds: Option<[Vec3; 2]>,
    /// CPU time of the BVH build (software) or device time of the BLAS build.
    pub build_ms: f64,
}

impl TraceGeometry {
    pub fn build(
        ctx: &Arc<Context>,
        geo: &impl Triangles,
        backend: Backend,
        first_prim: u32,
        profiler: Option<&Profiler>,
    ) -> Result<Self, VkError> {
        Self::build_with(
            ctx,
            geo,
            backend,
            first_prim,
            software_bvh::DEFAULT_BVH_QUALITY,
            profiler,
        )
    }

    /// As [`TraceGeometry::build`], the software BVH built with obvhs's `quality` preset
    /// (the ray-query backend ignores it).
    pub fn build_with(
        ctx: &Arc<Context>,
        geo: &impl Triangles,
        backend: Backend,
        first_prim: u32,
        quality: software_bvh::BvhQuality,
        profiler: Option<&Profiler>,
    ) -> Result<Self, VkError> {
        let mut level = LevelData::build(geo, backend, quality, profiler)?;
        level.number_from(first_prim);
        Self::upload(ctx, &level, profiler)
    }

    /// Puts a level built on the CPU ([`LevelData::build`], which may run on another
    /// thread and serve several devices) on `ctx`'s device: its buffers, or its BLAS
    /// built there.
    pub fn upload(
        ctx: &Arc<Context>,
        level: &LevelData,
        profiler: Option<&Profiler>,
    ) -> Result<Self, VkError> {
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let texels = storage | vk::BufferUsageFlags::UNIFORM_TEXEL_BUFFER;
        let backend = level.backend;
        // Read by the path tracer as a texel buffer (its `fetch_tri`), as the software
        // levels' nodes and triangles are by the traversal (16 bytes a fetch;
        // glsl/common/trace_bvh.glsl `trace_node`, `trace_tri`): each within the device's
        // texel limit.
        let cause = format!("the mesh has too many triangles ({})", level.triangle_count);
        let within_texels =
            |what: &str, bytes: usize| ctx.info.fits_texel_buffer(what, bytes, &cause);
        within_texels("shading triangles", std::mem::size_of_val(&level.shade[..]))?;
        let shade_tris = Buffer::from_slice(ctx, "shade triangles", &level.shade, texels)?;
        let start = std::time::Instant::now();
        let data = match &level.kind {
            LevelKind::RayQuery { positions, .. } if positions.is_empty() => Data::RayQuery(None),
            LevelKind::RayQuery {
                positions,
                triangles,
            } => {
                let blas = timed(profiler, "AS build (BLAS+TLAS)", || {
                    Blas::build(ctx, positions, triangles)
                })?;
                Data::RayQuery(Some(blas))
            }
            LevelKind::Software { nodes, tris } => {
                // The passes over a software scene read their own buffers through device
                // addresses, and the wide traversal's stack holds 64-bit words.
                if !ctx.info.buffer_device_address {
                    return Err(VkError::NoBufferDeviceAddress);
                }
                if !ctx.info.shader_int64 {
                    return Err(VkError::NoShaderInt64);
                }
                within_texels("BVH's nodes", nodes.len())?;
                within_texels("BVH's triangles", std::mem::size_of_val(&tris[..]))?;
                timed(profiler, "upload BVH", || -> Result<Data, VkError> {
                    Ok(Data::Software {
                        nodes: Buffer::from_slice(ctx, "bvh nodes", nodes, texels)?,
                        tris: Buffer::from_slice(ctx, "bvh triangles", tris, texels)?,
                    })
                })?
            }
        };
        Ok(TraceGeometry {
            backend,
            data,
            shade_tris,
            triangle_count: level.triangle_count,
            first_prim: level.first_prim,
            bounds: level.bounds,
            build_ms: level.build_ms + start.elapsed().as_secs_f64() * 1e3,
        })
    }
}

enum LevelKind {
    /// Positions and triangles for the BLAS, built on the device at upload.
    RayQuery {
        positions: Vec<[f32; 3]>,
        triangles: Vec<[u32; 3]>,
    },
    /// The software BVH's nodes (bytes) and triangles in leaf order.
    Software {
        nodes: Vec<u8>,
        tris: Vec<software_bvh::GpuTri>,
    },
}

/// The CPU side of one [`TraceGeometry`]: its shading triangles, box and (software
/// backends) BVH, built without a device, so that a dataset run can make an object's
/// once on its preparing thread and put it on every renderer's device
/// ([`TraceGeometry::upload`]).
pub struct LevelData {
    pub backend: Backend,
    shade: Vec<ShadeTri>,
    bounds: Option<[Vec3; 2]>,
    triangle_count: usize,
    /// The scene index of its first triangle ([`LevelData::number_from`]; 0 as built).
    first_prim: u32,
    kind: LevelKind,
    /// CPU time of the BVH build, ms.
    build_ms: f64,
}

impl LevelData {
    /// The level of `geo`'s triangles for `backend`, its software BVH with obvhs's
    /// `quality` preset (the ray-query backend builds its BLAS at upload).
    pub fn build(
        geo: &impl Triangles,
        backend: Backend,
        quality: software_bvh::BvhQuality,
        profiler: Option<&Profiler>,
    ) -> Result<LevelData, VkError> {
        let (positions, triangles) = (geo.positions(), geo.triangles());
        let corner_w = geo.corner_w();
        let shade: Vec<ShadeTri> = timed(profiler, "upload geometry", || {
            triangles
                .iter()
                .enumerate()
                .map(|(k, t)| {
                    let p = t.map(|i| positions[i as usize]);
                    let w = corner_w.and_then(|c| c.get(k)).copied().unwrap_or([0.0; 3]);
                    ShadeTri {
                        a: p[0].extend(w[0]).into(),
                        b: p[1].extend(w[1]).into(),
                        c: p[2].extend(w[2]).into(),
                    }
                })
                .collect()
        });
        // A binding may not be empty: an empty level gets one degenerate triangle that
        // no ray can hit (its determinant is 0).
        let shade = if shade.is_empty() {
            vec![ShadeTri::zeroed()]
        } else {
            shade
        };
        let bounds = geo.corner_bounds();
        let start = std::time::Instant::now();
        let kind = match backend {
            Backend::RayQuery => LevelKind::RayQuery {
                positions: if triangles.is_empty() {
                    Vec::new()
                } else {
                    positions.iter().map(|p| p.to_array()).collect()
                },
                triangles: triangles.to_vec(),
            },
            Backend::Software | Backend::SoftwareWide => {
                let tris = software_bvh::obvhs_triangles(positions, triangles);
                let wide = backend == Backend::SoftwareWide;
                let build = || software_bvh::gpu_level(&tris, quality, wide);
                let (nodes, tris) = if tris.is_empty() {
                    build()
                } else {
                    timed(profiler, "BVH build (obvhs)", build)
                }
                .map_err(VkError::Bvh)?;
                LevelKind::Software { nodes, tris }
            }
        };
        Ok(LevelData {
            backend,
            shade,
            bounds,
            triangle_count: triangles.len(),
            first_prim: 0,
            kind,
            build_ms: match backend {
                Backend::RayQuery => 0.0,
                _ => start.elapsed().as_secs_f64() * 1e3,
            },
        })
    }

    /// Numbers its triangles from `first_prim` in the scene's index space (a second
    /// level's after the object's): the leaf triangles carry their scene index.
    pub fn number_from(&mut self, first_prim: u32) {
        if let LevelKind::Software { tris, .. } = &mut self.kind {
            for t in tris {
                t.v0[3] = f32::from_bits(t.v0[3].to_bits() - self.first_prim + first_prim);
            }
        }
        self.first_prim = first_prim;
    }
}

/// What a pass traces against: the object's geometry (shared between views) and a
/// second level (the view's own geometry, e.g. the camera-mounted ring light; empty when
/// there is none). The closest hit over both is returned, with triangle indices in one
/// space: the object's from 0, the second level's from its `first_prim`.
pub struct TraceScene {
    pub backend: Backend,
    object: Arc<TraceGeometry>,
    second: TraceGeometry,
    tlas: Option<Tlas>,
    /// Triangles of both levels.
    pub triangle_count: usize,
    /// Build time of both levels (and the TLAS), ms.
    pub build_ms: f64,
}

/// Handles of a TraceScene inside one graph.
pub enum TraceRefs {
    RayQuery(AccelRef),
    /// The object's nodes and triangles, and the second level's (texel buffers).
    Software([BufferRef; 4]),
}

impl TraceRefs {
    /// Binds the backend's resources (bindings 0..) to a dispatch.
    pub fn bind<'g, 'a>(&self, d: DispatchBuilder<'g, 'a>) -> DispatchBuilder<'g, 'a> {
        match self {
            TraceRefs::RayQuery(a) => d.accel(0, *a),
            TraceRefs::Software([n, t, n2, t2]) => d.read(0, n).read(1, t).read(2, n2).read(3, t2),
        }
    }
}

impl TraceScene {
    /// One mesh, nothing else.
    pub fn build(
        ctx: &Arc<Context>,
        mesh: &impl Triangles,
        backend: Backend,
        profiler: Option<&Profiler>,
    ) -> Result<Self, VkError> {
        let object = Arc::new(TraceGeometry::build(ctx, mesh, backend, 0, profiler)?);
        Self::layered(ctx, object, &TriangleSoup::default(), profiler)
    }

    /// One mesh, its software BVH built with obvhs's `quality` preset (benchmarks).
    pub fn build_with(
        ctx: &Arc<Context>,
        mesh: &impl Triangles,
        backend: Backend,
        quality: software_bvh::BvhQuality,
        profiler: Option<&Profiler>,
    ) -> Result<Self, VkError> {
        let object = Arc::new(TraceGeometry::build_with(
            ctx, mesh, backend, 0, quality, profiler,
        )?);
        Self::layered(ctx, object, &TriangleSoup::default(), profiler)
    }

    /// `object` (built once, shared) plus `second`, numbered after the object's triangles.
    pub fn layered(
        ctx: &Arc<Context>,
        object: Arc<TraceGeometry>,
        second: &impl Triangles,
        profiler: Option<&Profiler>,
    ) -> Result<Self, VkError> {
        let backend = object.backend;
        let first = object.triangle_count as u32;
        let second = TraceGeometry::build(ctx, second, backend, first, profiler)?;
        let start = std::time::Instant::now();
        let tlas = match (&object.data, &second.data) {
            (Data::RayQuery(a), Data::RayQuery(b)) => {
                let inst: Vec<(&Blas, u32, u8)> = a
                    .iter()
                    .map(|a| (a, 0, MASK_OBJECT))
                    .chain(b.iter().map(|b| (b, first, MASK_LIGHTS)))
                    .collect();
                Some(timed(profiler, "AS build (BLAS+TLAS)", || {
                    Tlas::build(ctx, &inst)
                })?)
            }
            _ => None,
        };
        let build_ms = second.build_ms + start.elapsed().as_secs_f64() * 1e3;
        Ok(TraceScene {
            backend,
            triangle_count: object.triangle_count + second.triangle_count,
            build_ms: object.build_ms + build_ms,
            object,
            second,
            tlas,
        })
    }

    /// The shared object level.
    pub fn object(&self) -> &Arc<TraceGeometry> {
        &self.object
    }

    /// Original-order triangles of the object level (for shading).
    pub fn shade_tris(&self) -> &Buffer {
        &self.object.shade_tris
    }

    /// Original-order triangles of the second level (one degenerate triangle if empty).
    pub fn second_shade_tris(&self) -> &Buffer {
        &self.second.shade_tris
    }

    /// Descriptor kinds of the backend's bindings (they come first in every pipeline):
    /// the software backends' four level buffers, read as texel buffers (as
    /// TRACE_BINDING_COUNT in glsl/common/trace.glsl).
    pub fn binding_kinds(backend: Backend) -> Vec<BindingKind> {
        match backend {
            Backend::RayQuery => vec![BindingKind::AccelerationStructure],
            Backend::Software | Backend::SoftwareWide => vec![BindingKind::TexelBuffer; 4],
        }
    }

    /// Makes the backend's resources known to a graph.
    pub fn import<'a>(&'a self, g: &mut Graph<'a>) -> TraceRefs {
        match (&self.object.data, &self.second.data, &self.tlas) {
            (_, _, Some(t)) => TraceRefs::RayQuery(g.import_accel(&t.accel)),
            (
                Data::Software { nodes, tris },
                Data::Software {
                    nodes: n2,
                    tris: t2,
                },
                None,
            ) => TraceRefs::Software([g.import(nodes), g.import(tris), g.import(n2), g.import(t2)]),
            _ => unreachable!("both levels are built for one backend"),
        }
    }
}

/// Creates the pipeline of shader `name` for `backend` (its variant `<name>.<backend's
/// suffix><tag>`), with the pass's bindings `extra` after the backend's and the given
/// specialization constants ((constant_id, value); none: the shader's defaults).
#[allow(clippy::too_many_arguments)]
pub fn trace_pipeline(
    ctx: &Arc<Context>,
    name: &str,
    tag: &str,
    backend: Backend,
    extra: &[BindingKind],
    push_size: u32,
    local_size: [u32; 3],
    specialization: &[(u32, u32)],
) -> Result<ComputePipeline, VkError> {
    let variant = format!("{name}.{}{tag}", backend.shader_suffix());
    let spirv = crate::shaders::spirv(&variant)
        .ok_or_else(|| VkError::Other(format!("no shader variant {variant}")))?;
    let mut kinds = TraceScene::binding_kinds(backend);
    kinds.extend_from_slice(extra);
    ComputePipeline::new(
        ctx,
        &variant,
        &spirv,
        &kinds,
        push_size,
        local_size,
        specialization,
    )
}

/// A multiplier coprime with `count` for the workgroup scramble (see scramble.glsl).
pub fn scramble_multiplier(count: u32) -> u32 {
    fn gcd(a: u64, b: u64) -> u64 {
        if b == 0 { a } else { gcd(b, a % b) }
    }
    if count > 65_535 {
        return 1; // group * mult must stay below 2^32 in the shader
    }
    // Golden-ratio step, made coprime by search.
    let mut m = ((count as f64 * 0.618_033_988_7) as u64).max(1);
    while count > 1 && gcd(m, count as u64) != 1 {
        m += 1;
    }
    (m % count.max(1) as u64).max(1) as u32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vk::DeviceInfo;

    fn device(ray_query: bool, buffer_device_address: bool) -> DeviceInfo {
        device_int64(ray_query, buffer_device_address, true)
    }

    fn device_int64(
        ray_query: bool,
        buffer_device_address: bool,
        shader_int64: bool,
    ) -> DeviceInfo {
        DeviceInfo {
            ray_query_supported: ray_query,
            ray_query_enabled: ray_query,
            buffer_device_address,
            shader_int64,
            ..DeviceInfo::test_device()
        }
    }

    /// The passes over a software scene read their buffers through buffer device
    /// addresses: a device without them is refused by name for every choice that would
    /// pick a software backend; with them
    /// the choices resolve as before (ray query only where the device has it).
    #[test]
    fn software_backends_need_buffer_device_addresses() {
        let without = device(false, false);
        for choice in [
            AccelChoice::Auto,
            AccelChoice::Software,
            AccelChoice::SoftwareWide,
        ] {
            let e = resolve(choice, &without).unwrap_err();
            assert!(
                matches!(e, VkError::NoBufferDeviceAddress),
                "{choice:?}: {e}"
            );
            assert!(e.to_string().contains("bufferDeviceAddress"), "{e}");
        }
        let with = device(false, true);
        assert_eq!(
            resolve(AccelChoice::Auto, &with).unwrap(),
            Backend::SoftwareWide
        );
        assert_eq!(
            resolve(AccelChoice::Software, &with).unwrap(),
            Backend::Software
        );
        let rq = device(true, true);
        assert_eq!(
            resolve(AccelChoice::RayQuery, &rq).unwrap(),
            Backend::RayQuery
        );
        assert!(matches!(
            resolve(AccelChoice::RayQuery, &with).unwrap_err(),
            VkError::RayQueryUnavailable
        ));
    }

    /// The software backends load their BVH eight bytes at a time: a device without
    /// 64-bit shader integers is refused by name for each of them (and for `auto` where
    /// it would pick one); ray query does not need them.
    #[test]
    fn software_backends_need_64_bit_integers() {
        let without = device_int64(false, true, false);
        for choice in [
            AccelChoice::Auto,
            AccelChoice::Software,
            AccelChoice::SoftwareWide,
        ] {
            let e = resolve(choice, &without).unwrap_err();
            assert!(matches!(e, VkError::NoShaderInt64), "{choice:?}: {e}");
            assert!(e.to_string().contains("shaderInt64"), "{e}");
        }
        let rq = device_int64(true, true, false);
        assert_eq!(resolve(AccelChoice::Auto, &rq).unwrap(), Backend::RayQuery);
        assert_eq!(
            resolve(AccelChoice::RayQuery, &rq).unwrap(),
            Backend::RayQuery
        );
    }
}
