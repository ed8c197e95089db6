//! The Vulkan backend on ash: device, memory, commands, pipelines, acceleration
//! structures, timestamps. Nothing here knows about scenes, lights or materials.

pub mod accel;
pub mod commands;
pub mod context;
pub mod memory;
pub mod pipeline;
pub mod profiler;

pub use accel::{AccelStructure, Blas, Tlas};
pub use context::{Context, ContextOptions, DeviceInfo, ValidationLog};
pub use memory::{Buffer, Image, MemoryKind};
pub use pipeline::{BindingKind, ComputePipeline};
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
    #[error("buffer {0:?} is not host-visible")]
    NotMappable(String),
    #[error("Vulkan call failed: {0}")]
    Vk(#[from] ash::vk::Result),
    #[error("GPU memory allocation failed: {0}")]
    Alloc(#[from] gpu_allocator::AllocationError),
    #[error("Vulkan validation reported {count} error(s); first: {first}")]
    Validation { count: usize, first: String },
    #[error("{0}")]
    Other(String),
}
