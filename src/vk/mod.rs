//! The Vulkan backend on ash: device, memory, commands, pipelines, acceleration
//! structures, timestamps. Nothing here knows about scenes, lights or materials.

pub mod accel;
pub mod commands;
pub mod context;
pub mod lanes;
pub mod memory;
pub mod pipeline;
pub mod profiler;

pub use accel::{AccelStructure, Blas, Tlas};
pub use context::{Context, ContextOptions, DeviceInfo, ValidationLog};
pub use lanes::LaneWidth;
pub use memory::{Buffer, Image, MemoryInUse, MemoryKind};
pub use pipeline::{BindingKind, ComputePipeline, TEXEL_BUFFER_FORMAT};
pub use profiler::{Profiler, Span, timed};

#[derive(Debug, thiserror::Error)]
pub enum VkError {
    #[error("cannot load the Vulkan loader (libvulkan.so.1): {0}; run tools/setup")]
    Loader(String),
    #[error(
        "no Vulkan 1.2 device with a compute queue was found (is mesa-vulkan-drivers installed? run tools/setup)"
    )]
    NoDevice,
    #[error(
        "validation was asked for (SYNOSIS_VALIDATION=1) but VK_LAYER_KHRONOS_validation is not installed; run tools/setup"
    )]
    MissingValidationLayer,
    #[error(
        "the ray-query backend was asked for but this device has no VK_KHR_ray_query / acceleration structures; use --accel software"
    )]
    RayQueryUnavailable,
    #[error(
        "this device does not offer buffer device addresses (Vulkan 1.2 feature bufferDeviceAddress, required from Vulkan 1.3), through which the path tracer and the software trace backends read their buffers (ray query needs them too), so no trace backend can run on it"
    )]
    NoBufferDeviceAddress,
    #[error(
        "this device does not offer 64-bit integers in shaders (Vulkan 1.0 feature shaderInt64), with which the software trace backends load their BVH; use --accel ray-query where the device has ray query"
    )]
    NoShaderInt64,
    #[error(
        "this device does not offer subgroup arithmetic in compute shaders (Vulkan 1.1 subgroup properties: supportedOperations ARITHMETIC, supportedStages COMPUTE), which the path tracer uses"
    )]
    NoSubgroupArithmetic,
    #[error("buffer {0:?} is not host-visible")]
    NotMappable(String),
    /// The software backend's BVH cannot be traversed (src/trace/software_bvh.rs).
    #[error("software BVH: {0}")]
    Bvh(String),
    #[error("Vulkan call failed: {0}")]
    Vk(#[from] ash::vk::Result),
    #[error("GPU memory allocation failed: {0}")]
    Alloc(#[from] gpu_allocator::AllocationError),
    #[error("Vulkan validation reported {count} error(s); first: {first}")]
    Validation { count: usize, first: String },
    /// A render-graph dispatch leaves a binding of its pipeline without a resource.
    #[error("pass {pass:?}: binding {binding} ({kind:?}) of pipeline {pipeline:?} is not bound")]
    UnboundBinding {
        pass: String,
        pipeline: String,
        binding: u32,
        kind: BindingKind,
    },
    /// A render-graph dispatch binds a resource where its pipeline declares none, or
    /// one of another kind (`declared` is `None` past the pipeline's last binding).
    #[error(
        "pass {pass:?}: binding {binding} is given a {bound:?} but pipeline {pipeline:?} declares {declared:?} there (it has bindings 0..{count})"
    )]
    BindingMismatch {
        pass: String,
        pipeline: String,
        binding: u32,
        bound: BindingKind,
        declared: Option<BindingKind>,
        count: usize,
    },
    /// A render-graph dispatch pushes a block of another size than its pipeline's.
    #[error(
        "pass {pass:?}: push constants are {given} bytes but pipeline {pipeline:?} declares {expected}"
    )]
    PushConstantSize {
        pass: String,
        pipeline: String,
        expected: u32,
        given: usize,
    },
    /// A render-graph dispatch asks for more workgroups than the device allows.
    #[error(
        "pass {pass:?}: {groups:?} workgroups exceed the device's limit of {max:?} per dimension"
    )]
    WorkgroupLimit {
        pass: String,
        groups: [u32; 3],
        max: [u32; 3],
    },
    #[error("{0}")]
    Other(String),
}
