//! The path-traced inspection image (glsl/path_trace.comp): `render_frame` composes the
//! three lifetimes of the render layer, a [`PathTracer`] per device, a [`GpuScene`] per
//! mesh and a [`View`] per image, and runs the view's batches of samples.

use std::sync::Arc;

use super::annotate::Annotation;
use super::energy::EnergyTables;
use super::gpu_scene::GpuScene;
use super::settings::RenderSettings;
use super::tracer::PathTracer;
use super::view::View;
use crate::graph::Graph;
use crate::scene::assemble::ViewSetup;
use crate::trace::Backend;
use crate::vk::{Context, Profiler, VkError};

pub use crate::gpu_interface::{MAT_CONDUCTOR, MAT_LIGHT, MAT_TABLE};
pub use crate::scene::assemble::{RenderScene, load_object};

/// Why a render could not be set up or run.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(transparent)]
    Assemble(#[from] crate::scene::assemble::AssembleError),
    #[error(transparent)]
    Vk(#[from] VkError),
    #[error(transparent)]
    Slope(#[from] super::slope::SlopeError),
}

/// A finished render: mean radiance per pixel (row 0 at the top) and GPU time.
pub struct Radiance {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
    pub gpu_ms: f64,
}

/// What [`render_frame`] does besides path tracing.
#[derive(Clone, Copy, Default)]
pub struct FrameOptions<'a> {
    /// Run the annotation pass too, with this many coverage rays per pixel side.
    pub annotate_grid: Option<u32>,
    pub profiler: Option<&'a Profiler>,
}

/// A rendered image and, when asked for, its annotation from the same camera rays'
/// first hits (the annotation pass runs in the first batch's graph).
pub struct Frame {
    pub radiance: Radiance,
    pub annotation: Option<Annotation>,
}

/// Renders one view of `scene`; `progress(done_spp)` after each batch (one graph each).
pub fn render_frame(
    tracer: &PathTracer,
    scene: &GpuScene,
    setup: &ViewSetup,
    settings: &RenderSettings,
    opts: FrameOptions<'_>,
    mut progress: impl FnMut(u32),
) -> Result<Frame, RenderError> {
    let view = View::new(
        tracer,
        scene,
        setup,
        settings,
        opts.annotate_grid,
        opts.profiler,
    )?;
    let (spp, batch) = (settings.spp, settings.batch_spp.max(1));
    let mut done = 0u32;
    let mut gpu_ms = 0.0;
    while done < spp {
        let count = batch.min(spp - done);
        let mut g = Graph::new(tracer.context(), "path trace");
        view.record_batch(tracer, &mut g, done, count);
        let timings = g.execute(opts.profiler)?;
        gpu_ms += timings
            .iter()
            .map(|t| t.gpu_ms)
            .filter(|t| t.is_finite())
            .sum::<f64>();
        done += count;
        progress(done);
    }
    let (data, annotation) = view.read(spp)?;
    let (width, height) = (setup.camera.width, setup.camera.height);
    let radiance = Radiance {
        width,
        height,
        data,
        gpu_ms,
    };
    Ok(Frame {
        radiance,
        annotation,
    })
}

/// Renders a whole assembled scene once: builds the path tracer and the GPU scene for
/// this one image (a job over many images keeps them; see `dataset::gpu`).
pub fn render_scene(
    ctx: &Arc<Context>,
    scene: &RenderScene,
    settings: impl Into<RenderSettings>,
    backend: Backend,
    tables: &EnergyTables,
    opts: FrameOptions<'_>,
    progress: impl FnMut(u32),
) -> Result<Frame, RenderError> {
    let tracer = PathTracer::new(ctx, backend, tables)?;
    let settings: RenderSettings = settings.into();
    let mut gpu = GpuScene::new(&tracer, &scene.stage, opts.profiler)?;
    crate::vk::timed(opts.profiler, "place and upload maps", || {
        gpu.set_face_maps_filtered(
            &tracer,
            &scene.face_maps,
            &scene.placement,
            settings.texture_filter,
        )
    })?;
    render_frame(&tracer, &gpu, &scene.view, &settings, opts, progress)
}

/// The radiance of [`render_scene`] without annotation.
pub fn path_trace(
    ctx: &Arc<Context>,
    scene: &RenderScene,
    settings: impl Into<RenderSettings>,
    backend: Backend,
    tables: &EnergyTables,
    profiler: Option<&Profiler>,
    progress: impl FnMut(u32),
) -> Result<Radiance, RenderError> {
    let opts = FrameOptions {
        annotate_grid: None,
        profiler,
    };
    render_scene(ctx, scene, settings, backend, tables, opts, progress).map(|f| f.radiance)
}
