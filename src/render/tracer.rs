//! The path tracer of one device and backend: its pipelines and the energy tables,
//! built once per process and shared by every scene and view.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use ash::vk;

use super::RenderError;
use super::energy::EnergyTables;
use crate::trace::{Backend, TraceScene};
use crate::vk::{Buffer, ComputePipeline, Context};

/// How many path tracers this process has built (each compiles two pipelines); tests
/// and the dataset's stage report use it to show that pipelines are built once.
static BUILT: AtomicUsize = AtomicUsize::new(0);

/// Pipelines (path tracing, annotation) and the energy tables for one device + backend.
pub struct PathTracer {
    pub(crate) ctx: Arc<Context>,
    pub backend: Backend,
    pub(crate) path: ComputePipeline,
    pub(crate) annotate: ComputePipeline,
    pub(crate) energy: Buffer,
}

impl PathTracer {
    pub fn new(
        ctx: &Arc<Context>,
        backend: Backend,
        tables: &EnergyTables,
    ) -> Result<PathTracer, RenderError> {
        let path = super::pipelines::path_trace(ctx, backend)?;
        let annotate = super::pipelines::annotate(ctx, backend)?;
        let energy = Buffer::from_slice(
            ctx,
            "energy tables",
            &tables.packed(),
            vk::BufferUsageFlags::STORAGE_BUFFER,
        )?;
        BUILT.fetch_add(1, Ordering::Relaxed);
        Ok(PathTracer {
            ctx: ctx.clone(),
            backend,
            path,
            annotate,
            energy,
        })
    }

    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }

    /// Number of the backend's bindings (a pass's own come after them).
    pub fn backend_bindings(&self) -> u32 {
        TraceScene::binding_kinds(self.backend).len() as u32
    }

    /// Path tracers built by this process so far.
    pub fn built_count() -> usize {
        BUILT.load(Ordering::Relaxed)
    }
}
