//! GPU passes that make images: first-hit raycasts (and, later, the path tracer).

pub mod annotate;
pub mod raycast;
