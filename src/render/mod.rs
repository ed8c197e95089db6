//! GPU passes that make images: first-hit raycasts (and, later, the path tracer).

pub mod bsdf;
pub mod energy;
pub mod path_trace;
pub mod raycast;
pub mod sensor;
