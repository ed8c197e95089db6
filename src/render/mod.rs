//! GPU passes that make images, by lifetime: a [`PathTracer`] per device (pipelines,
//! energy tables), a [`GpuScene`] per mesh (acceleration structure, materials, labels,
//! slope maps), a [`View`] per image (camera, light, accumulation, annotation); and the
//! CPU-side models they share (BSDF, energy tables, slope maps, pixel values).

pub mod annotate;
pub mod bsdf;
pub mod cpu;
pub mod device_maps;
pub mod energy;
pub mod gpu_scene;
pub mod noise;
pub mod optics;
pub mod path_trace;
pub mod pipelines;
pub mod pixels;
pub mod raycast;
pub mod sensor;
pub mod settings;
pub mod slope;
pub mod tracer;
pub mod view;

pub use gpu_scene::{GpuScene, PreparedScene};
pub use path_trace::{
    Frame, FrameOptions, Radiance, RenderError, render_frame, render_scene, render_scene_on,
};
pub use settings::{Material, RenderSettings};
pub use tracer::PathTracer;
pub use view::View;
