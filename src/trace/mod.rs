//! The two intersection backends behind one GLSL interface (`glsl/common/trace.glsl`):
//! `ray-query` (KHR acceleration structures) and `software` (obvhs BVH2 traversed in the
//! shader). A pipeline is built from the shader variant of the chosen backend; the
//! backend's bindings come first (0 .. `binding_kinds().len()`), the pass's after them.

pub mod software_bvh;
pub mod watertight;

use std::sync::Arc;

use ash::vk;

use crate::graph::{AccelRef, BufferRef, DispatchBuilder, Graph};
use crate::scene::Mesh;
use crate::vk::{
    BindingKind, Buffer, ComputePipeline, Context, Profiler, TriangleAccel, VkError, timed,
};

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
}

/// A concrete backend.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Backend {
    RayQuery,
    Software,
}

impl Backend {
    /// Suffix of the shader variants built for this backend.
    pub fn shader_suffix(self) -> &'static str {
        match self {
            Backend::RayQuery => "rq",
            Backend::Software => "sw",
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Backend::RayQuery => "ray-query",
            Backend::Software => "software",
        }
    }
}

/// The backend `auto` picks, and why. On a GPU with ray query, the hardware traversal
/// wins. On lavapipe (a CPU device) our software BVH traces about twice as fast as
/// lavapipe's own ray query (measured, docs/benchmarks.md), so auto picks software there.
pub fn auto_backend(ctx_info: &crate::vk::DeviceInfo) -> (Backend, &'static str) {
    if !ctx_info.ray_query_supported {
        (Backend::Software, "the device has no ray query")
    } else if ctx_info.is_cpu {
        (
            Backend::Software,
            "CPU device (lavapipe): the software BVH is measured faster than its ray query",
        )
    } else {
        (Backend::RayQuery, "the device has hardware ray query")
    }
}

/// Resolves a choice against a device; ray-query on a device without it is an error.
pub fn resolve(choice: AccelChoice, info: &crate::vk::DeviceInfo) -> Result<Backend, VkError> {
    match choice {
        AccelChoice::Auto => Ok(auto_backend(info).0),
        AccelChoice::Software => Ok(Backend::Software),
        AccelChoice::RayQuery if info.ray_query_enabled => Ok(Backend::RayQuery),
        AccelChoice::RayQuery => Err(VkError::RayQueryUnavailable),
    }
}

/// Per-triangle corner positions in original order (3 x vec4), for shading.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ShadeTri {
    pub a: [f32; 4],
    pub b: [f32; 4],
    pub c: [f32; 4],
}

enum Data {
    RayQuery(TriangleAccel),
    Software { nodes: Buffer, tris: Buffer },
}

/// A mesh uploaded for tracing with one backend.
pub struct TraceScene {
    pub backend: Backend,
    data: Data,
    /// Original-order triangles for shading (normals, labels live elsewhere).
    pub shade_tris: Buffer,
    pub triangle_count: usize,
    /// CPU time of the BVH build (software) or device time of the BLAS+TLAS build.
    pub build_ms: f64,
}

/// Handles of a TraceScene inside one graph.
pub enum TraceRefs {
    RayQuery(AccelRef),
    Software(BufferRef, BufferRef),
}

impl TraceRefs {
    /// Binds the backend's resources (bindings 0..) to a dispatch.
    pub fn bind<'g, 'a>(&self, d: DispatchBuilder<'g, 'a>) -> DispatchBuilder<'g, 'a> {
        match self {
            TraceRefs::RayQuery(a) => d.accel(0, *a),
            TraceRefs::Software(n, t) => d.read(0, n).read(1, t),
        }
    }
}

impl TraceScene {
    pub fn build(
        ctx: &Arc<Context>,
        mesh: &Mesh,
        backend: Backend,
        profiler: Option<&Profiler>,
    ) -> Result<Self, VkError> {
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let shade: Vec<ShadeTri> = timed(profiler, "upload geometry", || {
            mesh.triangles
                .iter()
                .map(|t| {
                    let p = t.map(|i| mesh.positions[i as usize]);
                    ShadeTri {
                        a: p[0].extend(0.0).into(),
                        b: p[1].extend(0.0).into(),
                        c: p[2].extend(0.0).into(),
                    }
                })
                .collect()
        });
        let shade_tris = Buffer::from_slice(ctx, "shade triangles", &shade, storage)?;
        let start = std::time::Instant::now();
        let data = match backend {
            Backend::RayQuery => {
                let pos: Vec<[f32; 3]> = mesh.positions.iter().map(|p| p.to_array()).collect();
                let accel = timed(profiler, "AS build (BLAS+TLAS)", || {
                    TriangleAccel::build(ctx, &pos, &mesh.triangles)
                })?;
                Data::RayQuery(accel)
            }
            Backend::Software => {
                let tris = software_bvh::obvhs_triangles(&mesh.positions, &mesh.triangles);
                let (nodes, gtris) = timed(profiler, "BVH build (obvhs)", || {
                    software_bvh::flatten(&software_bvh::build_bvh(&tris), &tris)
                });
                timed(profiler, "upload BVH", || -> Result<Data, VkError> {
                    Ok(Data::Software {
                        nodes: Buffer::from_slice(ctx, "bvh nodes", &nodes, storage)?,
                        tris: Buffer::from_slice(ctx, "bvh triangles", &gtris, storage)?,
                    })
                })?
            }
        };
        Ok(TraceScene {
            backend,
            data,
            shade_tris,
            triangle_count: mesh.triangles.len(),
            build_ms: start.elapsed().as_secs_f64() * 1e3,
        })
    }

    /// Descriptor kinds of the backend's bindings (they come first in every pipeline).
    pub fn binding_kinds(backend: Backend) -> Vec<BindingKind> {
        match backend {
            Backend::RayQuery => vec![BindingKind::AccelerationStructure],
            Backend::Software => vec![BindingKind::StorageBuffer, BindingKind::StorageBuffer],
        }
    }

    /// Makes the backend's resources known to a graph.
    pub fn import<'a>(&'a self, g: &mut Graph<'a>) -> TraceRefs {
        match &self.data {
            Data::RayQuery(a) => TraceRefs::RayQuery(g.import_accel(&a.tlas)),
            Data::Software { nodes, tris } => TraceRefs::Software(g.import(nodes), g.import(tris)),
        }
    }
}

/// Creates the pipeline of shader `name` for `backend`, with `extra` pass bindings
/// (storage buffers) after the backend's.
pub fn trace_pipeline(
    ctx: &Arc<Context>,
    name: &str,
    backend: Backend,
    extra: usize,
    push_size: u32,
    local_size: [u32; 3],
) -> Result<ComputePipeline, VkError> {
    let variant = format!("{name}.{}", backend.shader_suffix());
    let spirv = crate::shaders::spirv(&variant)
        .ok_or_else(|| VkError::Other(format!("no shader variant {variant}")))?;
    let mut kinds = TraceScene::binding_kinds(backend);
    kinds.extend(std::iter::repeat_n(BindingKind::StorageBuffer, extra));
    ComputePipeline::new(ctx, &variant, &spirv, &kinds, push_size, local_size)
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
