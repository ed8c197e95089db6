//! The production renderer behind [`ImageRenderer`]: the Vulkan path tracer plus the
//! annotation pass.
//!
//! Neither has landed in this build (no path tracer with slope-mapped textures, no
//! annotation pass in `src/render/`), so [`GpuRenderer::new`] refuses with a clear
//! error rather than producing placeholder images.

use super::renderer::{ImageRenderer, ImageRequest, RenderedImage};

pub const UNAVAILABLE: &str = "the GPU renderer is not available in this build (the path tracer and annotation pass have not landed in src/render/)";

/// The GPU path tracer + annotation pass.
pub struct GpuRenderer {
    _private: (),
}

impl GpuRenderer {
    /// Opens the Vulkan device and builds the pipelines.
    pub fn new() -> Result<GpuRenderer, String> {
        Err(UNAVAILABLE.into())
    }
}

impl ImageRenderer for GpuRenderer {
    fn describe(&self) -> String {
        "gpu".into()
    }

    fn render(&mut self, _req: &ImageRequest) -> Result<RenderedImage, String> {
        Err(UNAVAILABLE.into())
    }
}
