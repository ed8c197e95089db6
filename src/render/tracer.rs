//! The path tracer of one device and backend: its pipelines and the energy tables,
//! built once per process and shared by every scene and view.
//!
//! Its pipeline that reads the settings at run time (what every render uses unless
//! `[render] specialize`) is made on a thread of its own from [`PathTracer::new`] on:
//! lavapipe takes 2.5 to 5 s to create it on a 2-core machine (its SPIR-V turned into
//! its own IR, whatever the shader cache holds), which a process then spends on the
//! scene (loading the object, its maps and slopes, the BVH) instead of after it.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use ash::vk;

use super::RenderError;
use super::energy::EnergyTables;
use crate::gpu_interface::{PATH_SPEC_COUNT, PathParams};
use crate::trace::{Backend, TraceScene};
use crate::vk::{Buffer, ComputePipeline, Context, VkError};

/// How many path tracers this process has built; tests and the dataset's stage report
/// use it to show that pipelines are built once.
static BUILT: AtomicUsize = AtomicUsize::new(0);

/// Whether the path tracer can run on a device with these features: it needs subgroup
/// arithmetic in compute shaders (`subgroupMax`, glsl/common/analytic_light.glsl
/// `recorded_loop2`); refused by name where it is missing. (The trace backends' own
/// needs are `trace::resolve`'s.)
fn path_tracer_supported(info: &crate::vk::DeviceInfo) -> Result<(), VkError> {
    if !info.subgroup_arithmetic {
        return Err(VkError::NoSubgroupArithmetic);
    }
    Ok(())
}

/// A path-tracing pipeline: whether it is the variant with split paths (`[render]
/// split_paths`, compiled apart), and the settings it was specialized for
/// (`PathParams::specialization`), or none: it reads them at run time.
type PathKey = (bool, Option<[(u32, u32); PATH_SPEC_COUNT]>);

/// Pipelines (path tracing, annotation) and the energy tables for one device + backend.
pub struct PathTracer {
    pub(crate) ctx: Arc<Context>,
    pub backend: Backend,
    /// The path tracer's pipelines made so far, one per distinct setting it was
    /// specialized for (`[render] specialize`) and one reading them at run time, per
    /// variant (split paths or not), each taken at its first use (the one reading them
    /// without split paths begun by `new`) and kept for the process.
    paths: Mutex<Vec<(PathKey, Arc<ComputePipeline>)>>,
    /// The pipeline reading its settings at run time (without split paths) while its
    /// thread makes it (taken into `paths` at its first use).
    unspecialized: Mutex<Option<JoinHandle<Result<ComputePipeline, VkError>>>>,
    pub(crate) annotate: ComputePipeline,
    pub(crate) energy: Buffer,
}

impl PathTracer {
    /// The path tracer of `backend` on `ctx`, its pipeline that reads the settings at
    /// run time begun on a thread of its own, unless `SYNOSIS_SPECIALIZE=1` says that
    /// this process's renders use specialized ones ([`PathTracer::beginning`]).
    pub fn new(
        ctx: &Arc<Context>,
        backend: Backend,
        tables: &EnergyTables,
    ) -> Result<PathTracer, RenderError> {
        let specialized = super::settings::specialize_from_env()
            .ok()
            .flatten()
            .unwrap_or(false);
        Self::beginning(ctx, backend, tables, !specialized)
    }

    /// [`PathTracer::new`], saying whether to begin the pipeline that reads its settings
    /// at run time now: false where every render will be `specialize`d (the pipeline is
    /// then made at its first use, if it has one), so that the driver's compile of a
    /// pipeline no render uses (seconds of a core on lavapipe) is not paid.
    pub fn beginning(
        ctx: &Arc<Context>,
        backend: Backend,
        tables: &EnergyTables,
        begin_unspecialized: bool,
    ) -> Result<PathTracer, RenderError> {
        path_tracer_supported(&ctx.info)?;
        let unspecialized = if begin_unspecialized {
            let ctx = ctx.clone();
            std::thread::Builder::new()
                .name("path tracer pipeline".into())
                .spawn(move || super::pipelines::path_trace(&ctx, backend, false, &[]))
                .ok()
        } else {
            None
        };
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
            paths: Mutex::new(Vec::new()),
            unspecialized: Mutex::new(unspecialized),
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

    /// The path-tracing pipeline for a view's parameters: with `specialize`, compiled for
    /// their settings (`PathParams::specialization`: the driver drops the code they
    /// switch off), made at its first use, else the one that reads them at run time
    /// (without split paths begun by [`PathTracer::new`] on a thread of its own, waited
    /// for here); `split_paths`: the variant with split paths (`[render] split_paths`).
    pub(crate) fn path_pipeline(
        &self,
        params: &PathParams,
        specialize: bool,
        split_paths: bool,
    ) -> Result<Arc<ComputePipeline>, RenderError> {
        let key: PathKey = (split_paths, specialize.then(|| params.specialization()));
        let mut paths = self.paths.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, p)) = paths.iter().find(|(k, _)| *k == key) {
            return Ok(p.clone());
        }
        let made = match key {
            (false, None) => self
                .unspecialized
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .take(),
            _ => None,
        };
        let spec = key.1.as_ref().map_or(&[][..], |k| &k[..]);
        let p = Arc::new(match made {
            Some(thread) => thread.join().map_err(|_| {
                VkError::Other("the thread making the path tracer's pipeline panicked".into())
            })??,
            // No thread could be started, or a specialized pipeline: made here.
            None => super::pipelines::path_trace(&self.ctx, self.backend, split_paths, spec)?,
        });
        paths.push((key, p.clone()));
        Ok(p)
    }

    /// How many path-tracing pipelines this tracer has made (one per distinct setting).
    pub fn path_pipeline_count(&self) -> usize {
        self.paths.lock().unwrap_or_else(|e| e.into_inner()).len()
    }

    /// Path tracers built by this process so far.
    pub fn built_count() -> usize {
        BUILT.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vk::DeviceInfo;

    /// A device without subgroup arithmetic is refused by name before any pipeline is
    /// made; one with it passes.
    #[test]
    fn path_tracer_needs_subgroup_arithmetic() {
        let without = DeviceInfo {
            subgroup_arithmetic: false,
            ..DeviceInfo::test_device()
        };
        let e = path_tracer_supported(&without).unwrap_err();
        assert!(matches!(e, VkError::NoSubgroupArithmetic), "{e}");
        assert!(e.to_string().contains("subgroup arithmetic"), "{e}");
        assert!(path_tracer_supported(&DeviceInfo::test_device()).is_ok());
    }
}
