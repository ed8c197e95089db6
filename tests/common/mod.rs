//! Shared by the GPU integration tests: a lavapipe context with validation always on.

#![allow(dead_code)]

use std::sync::Arc;

use synosis::trace::Backend;
use synosis::vk::{Context, ContextOptions};

/// A device with validation and ray query enabled (ray query is required on these
/// machines: tools/setup installs Mesa 25).
pub fn gpu() -> Arc<Context> {
    let ctx = Context::new(&ContextOptions {
        validation: true,
        ray_query: true,
    })
    .expect("Vulkan device (run tools/setup)");
    assert!(ctx.info.validation, "validation must be on in tests");
    assert!(
        ctx.info.ray_query_enabled,
        "tests need ray query (Mesa >= 25 lavapipe); run tools/setup"
    );
    ctx
}

pub const BACKENDS: [Backend; 2] = [Backend::RayQuery, Backend::Software];

/// Fails the test on any validation error collected so far.
pub fn assert_clean(ctx: &Context) {
    let errors = ctx.validation_errors();
    assert!(
        errors.is_empty(),
        "{} validation error(s):\n{}",
        errors.len(),
        errors.join("\n")
    );
}
