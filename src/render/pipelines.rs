//! Every compute pipeline the renderer builds, each made by one function here, and
//! [`prepare`]: every pipeline of some backends run once on a tiny scene, the backends
//! at once on threads of their own, so the driver's shader cache holds them before the
//! first image.
//!
//! Why: lavapipe compiles a pipeline's machine code at its first dispatch, and the path
//! tracer's takes about 10 s a backend on a cold cache on a 2-core machine (150 s before
//! it read the scene through device addresses); a process that renders meets its
//! pipelines one at a time.

use std::sync::Arc;
use std::time::{Duration, Instant};

use super::energy::EnergyTables;
use super::path_trace::{FrameOptions, RenderError};
use super::raycast::RayIn;
use crate::gpu_interface::{
    AnnotateBinding, HitsBinding, HitsPush, ImagePush, PathPush, PathTraceBinding, RaycastBinding,
    TILE,
};
use crate::scene::Camera;
use crate::scene::assemble::{RenderScene, load_object};
use crate::scene::config::SceneConfig;
use crate::trace::{Backend, TraceScene, trace_pipeline};
use crate::vk::{BindingKind, ComputePipeline, Context, ContextOptions, VkError};

/// The path tracer (`glsl/path_trace.comp`), with `specialization` (from
/// `PathParams::specialization`) its settings compiled in, or none: read at run time;
/// `split_paths`: its variant whose first hit's BSDF directions each go on as a path
/// (`[render] split_paths`; compiled apart, SPLIT_PATHS, so that the loop over those
/// branches costs nothing where they are off).
pub fn path_trace(
    ctx: &Arc<Context>,
    backend: Backend,
    split_paths: bool,
    specialization: &[(u32, u32)],
) -> Result<ComputePipeline, VkError> {
    let push = std::mem::size_of::<PathPush>() as u32;
    trace_pipeline(
        ctx,
        "path_trace",
        if split_paths { "s" } else { "" },
        backend,
        &path_trace_kinds(),
        push,
        [TILE, TILE, 1],
        specialization,
    )
}

/// The path tracer's bindings after the backend's: storage buffers, but the object's
/// and the lights' triangles, which `fetch_tri` reads as texel buffers, and the slope
/// maps' headers (`map_header`), read the same way (16 bytes a
/// fetch: lavapipe reads a texel a lane with one load where a storage buffer or a
/// device address is a load a lane and word, docs/architecture.md).
fn path_trace_kinds() -> Vec<BindingKind> {
    (0..PathTraceBinding::COUNT)
        .map(|i| {
            if i == PathTraceBinding::Geometry as usize
                || i == PathTraceBinding::LightGeometry as usize
                || i == PathTraceBinding::MapHeaders as usize
            {
                BindingKind::TexelBuffer
            } else {
                BindingKind::StorageBuffer
            }
        })
        .collect()
}

/// The annotation pass (`glsl/annotate.comp`).
pub fn annotate(ctx: &Arc<Context>, backend: Backend) -> Result<ComputePipeline, VkError> {
    let push = std::mem::size_of::<ImagePush>() as u32;
    trace_pipeline(
        ctx,
        "annotate",
        "",
        backend,
        &[BindingKind::StorageBuffer; AnnotateBinding::COUNT],
        push,
        [TILE, TILE, 1],
        &[],
    )
}

/// Closest hits of a list of rays (`glsl/hits.comp`).
pub fn hits(ctx: &Arc<Context>, backend: Backend) -> Result<ComputePipeline, VkError> {
    let push = std::mem::size_of::<HitsPush>() as u32;
    trace_pipeline(
        ctx,
        "hits",
        "",
        backend,
        &[BindingKind::StorageBuffer; HitsBinding::COUNT],
        push,
        [64, 1, 1],
        &[],
    )
}

/// Depth and normals of a camera's first hits (`glsl/raycast.comp`).
pub fn raycast(ctx: &Arc<Context>, backend: Backend) -> Result<ComputePipeline, VkError> {
    let push = std::mem::size_of::<ImagePush>() as u32;
    trace_pipeline(
        ctx,
        "raycast",
        "",
        backend,
        &[BindingKind::StorageBuffer; RaycastBinding::COUNT],
        push,
        [TILE, TILE, 1],
        &[],
    )
}

/// Runs every pipeline of `backend` once on a tiny scene (the built-in test body, 16 x 16
/// pixels, 1 sample, labels from the annotation pass; a raycast; a list of one ray), and
/// with `split_paths` the path tracer's split-paths variant too (a second render with
/// `split_paths = true`): lavapipe compiles a pipeline's machine code at its first
/// dispatch, not at its creation, and keeps it in its shader cache from then on.
pub fn exercise(
    ctx: &Arc<Context>,
    backend: Backend,
    tables: &EnergyTables,
    split_paths: bool,
) -> Result<(), RenderError> {
    let base = "[render]\nspp = 1\nbatch_spp = 1\nlabels = \"pass\"\n";
    let split = "bsdf_samples = 2\nsplit_paths = true\n";
    let mut cfg = SceneConfig::parse(base).expect("the warm-up scene parses");
    cfg.set_resolution(16, 16).expect("16 x 16 is a valid size");
    let object = load_object(&cfg)?;
    let scene = RenderScene::assemble(&object, &cfg)?;
    let opts = FrameOptions {
        annotate_grid: Some(1),
        ..Default::default()
    };
    super::render_scene(ctx, &scene, &cfg, backend, tables, opts, |_| {})?;
    if split_paths {
        let mut cfg =
            SceneConfig::parse(&format!("{base}{split}")).expect("the split warm-up scene parses");
        cfg.set_resolution(16, 16).expect("16 x 16 is a valid size");
        let scene = RenderScene::assemble(&object, &cfg)?;
        super::render_scene(ctx, &scene, &cfg, backend, tables, opts, |_| {})?;
    }
    let traced = TraceScene::build(ctx, &object, backend, None)?;
    super::raycast::raycast(ctx, &traced, &Camera::framing(&object, 2, 2), None)?;
    let ray = RayIn {
        origin: [0.0, 0.0, 1.0e3],
        tmin: 0.0,
        dir: [0.0, 0.0, -1.0],
        tmax: 1.0e30,
    };
    super::raycast::trace_rays(ctx, &traced, &[ray], None)?;
    Ok(())
}

/// [`exercise`] for each of `backends`, all at once, each on a thread and a device of its
/// own (lavapipe runs a device's dispatches, and so compiles their code, on that device's
/// one queue thread; the path tracers' compiles are by far the longest): afterwards the
/// driver's shader cache holds every pipeline, so later processes on this machine start
/// rendering at once. Calls `done(backend, time)` as each backend finishes, from its
/// thread; validation messages are errors, and so is a shader variant of the backend
/// (`<name>.<suffix>`) that [`exercise`] did not dispatch; the first error is returned
/// after the others finish. The path tracer's split-paths variants (`<suffix>s`,
/// `[render] split_paths`, opt-in) are warmed, and checked, only with `split_paths`
/// (otherwise made at their first use).
pub fn prepare(
    options: &ContextOptions,
    backends: &[Backend],
    split_paths: bool,
    done: &(dyn Fn(Backend, Duration) + Sync),
) -> Result<(), RenderError> {
    let tables = EnergyTables::compute();
    std::thread::scope(|s| {
        let runs: Vec<_> = backends
            .iter()
            .map(|&b| {
                let tables = &tables;
                s.spawn(move || {
                    let t = Instant::now();
                    let ctx = Context::new(options)?;
                    exercise(&ctx, b, tables, split_paths)?;
                    ctx.check_validation()?;
                    let suffix = format!(".{}", b.shader_suffix());
                    let split_suffix = format!("{suffix}s");
                    let ran = ctx.dispatched_pipelines();
                    let missed: Vec<&str> = crate::shaders::names()
                        .filter(|n| {
                            n.ends_with(&suffix) || (split_paths && n.ends_with(&split_suffix))
                        })
                        .filter(|n| !ran.contains(*n))
                        .collect();
                    if !missed.is_empty() {
                        return Err(RenderError::Vk(VkError::Other(format!(
                            "the warm-up (render::pipelines::exercise) never dispatched {}",
                            missed.join(", ")
                        ))));
                    }
                    done(b, t.elapsed());
                    Ok(())
                })
            })
            .collect();
        runs.into_iter()
            .map(|r| r.join().expect("a warm-up thread panicked"))
            .collect::<Result<Vec<()>, RenderError>>()
    })?;
    Ok(())
}
