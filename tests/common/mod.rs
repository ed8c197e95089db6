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

/// Runs shard `shard` of the smoke job (scenes/smoke-dataset.toml) made smaller (32 x 24,
/// 1 spp) with `renderer` into `out`.
pub fn run_small_smoke(
    renderer: &mut dyn synosis::dataset::ImageRenderer,
    out: &std::path::Path,
    shard: synosis::dataset::Shard,
) -> synosis::dataset::RunReport {
    use synosis::dataset::{self, RunOptions};
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenes/smoke-dataset.toml"
    ))
    .unwrap()
    .replace("width = 64", "width = 32")
    .replace("height = 48", "height = 24")
    .replace("spp = 4", "spp = 1");
    let scenes = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"));
    let prep = dataset::prepare_text(&text, "smoke", scenes).unwrap();
    let mut textures = synosis::dataset::texture_bridge::ModuleTextures::default();
    let opts = RunOptions {
        shard,
        fail_after: None,
        progress: None,
    };
    dataset::run(&prep, out, renderer, &mut textures, opts).unwrap()
}
