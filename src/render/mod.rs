//! GPU passes that make images: the path tracer, the annotation pass, first-hit
//! raycasts, and the CPU-side models they share (BSDF, energy tables, the pixel pipeline).

pub mod annotate;
pub mod bsdf;
pub mod energy;
pub mod path_trace;
pub mod pixels;
pub mod raycast;
pub mod slope;
