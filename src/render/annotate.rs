//! The annotation pass: class, defect instance and face of the first hit per pixel, and
//! the defect coverage fraction, from the same camera and geometry as the image.

use std::path::Path;
use std::sync::Arc;

use ash::vk;

use super::gpu_scene::label_word;
use super::view::{Tiling, camera_block};
use crate::gpu_interface::{AnnotateBinding, CameraBlock, ImagePush};
use crate::graph::{BufferRef, Graph, PassTiming};
use crate::scene::{Camera, Mesh};
use crate::trace::{TraceRefs, TraceScene};
use crate::vk::{Buffer, ComputePipeline, Context, MemoryKind, Profiler, VkError};

/// Default stratified grid per pixel for the coverage fraction (4 x 4 = 16 rays).
pub const DEFAULT_COVERAGE_GRID: u32 = 4;

/// Per-pixel labels, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Annotation {
    pub width: u32,
    pub height: u32,
    /// 0 background / no defect, 1 dent, 2 scratch (the centre ray's first hit).
    pub class: Vec<u8>,
    /// Defect instance id, 0 = none.
    pub instance: Vec<u16>,
    /// Face id of the first hit: 0 other or nothing, 1 A, 2 B, 3 C.
    pub face: Vec<u8>,
    /// Share of the pixel's grid rays whose first hit is a defect triangle, in [0, 1].
    pub coverage: Vec<f32>,
}

/// One defect's visible pixel count (centre-ray labels).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct VisibleDefect {
    pub instance: u16,
    pub class: u8,
    pub pixels: u32,
}

impl Annotation {
    /// Visible pixels per defect instance, sorted by instance.
    pub fn visible_defects(&self) -> Vec<VisibleDefect> {
        let mut map = std::collections::BTreeMap::new();
        for (&inst, &class) in self.instance.iter().zip(&self.class) {
            if inst != 0 {
                map.entry(inst).or_insert((class, 0u32)).1 += 1;
            }
        }
        map.into_iter()
            .map(|(instance, (class, pixels))| VisibleDefect {
                instance,
                class,
                pixels,
            })
            .collect()
    }

    /// Writes mask.png (class ids), instances.png (16-bit), faces.png and coverage.png
    /// (coverage x 255) into `dir`, each atomically.
    pub fn write_pngs(&self, dir: &Path) -> std::io::Result<()> {
        use crate::image_io::{write_png_gray8, write_png_gray16};
        let (w, h) = (self.width, self.height);
        write_png_gray8(&dir.join("mask.png"), w, h, &self.class)?;
        write_png_gray16(&dir.join("instances.png"), w, h, &self.instance)?;
        write_png_gray8(&dir.join("faces.png"), w, h, &self.face)?;
        let cov: Vec<u8> = self
            .coverage
            .iter()
            .map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect();
        write_png_gray8(&dir.join("coverage.png"), w, h, &cov)
    }
}

/// Adds the annotation dispatch(es) to `g`: labels of the first hits of `cam`'s rays,
/// written into `targets` (ids, coverage). `sampling`: (SAMPLER_* kind, seed) of the
/// path tracer, whose first `grid^2` primary rays label a pixel under a thin lens.
#[allow(clippy::too_many_arguments)]
pub fn record_annotate<'a>(
    g: &mut Graph<'a>,
    pipeline: &'a ComputePipeline,
    trace: &TraceRefs,
    backend_bindings: u32,
    labels: &BufferRef,
    targets: (&mut BufferRef, &mut BufferRef),
    cam: &CameraBlock,
    (width, height): (u32, u32),
    grid: u32,
    tiling: &Tiling,
    (sampler, seed): (u32, u32),
) {
    let off = backend_bindings;
    let mut cam = *cam;
    cam.centre[3] = sampler as f32;
    for (tiles, groups) in tiling.dispatches() {
        let push = ImagePush {
            cam,
            width,
            height,
            grid: grid.clamp(1, 16),
            seed,
            tiles,
        };
        trace
            .bind(g.dispatch("annotate", pipeline, [groups, 1, 1]))
            .read(AnnotateBinding::Labels.at(off), labels)
            .write(AnnotateBinding::Ids.at(off), targets.0)
            .write(AnnotateBinding::Coverage.at(off), targets.1)
            .push(&push)
            .submit();
    }
}

/// The annotation pass's pipeline and per-mesh label buffer, for annotating a mesh on
/// its own (the path tracer's views use [`record_annotate`] with the scene's labels).
pub struct AnnotatePass {
    pipeline: ComputePipeline,
    labels: Buffer,
    max_groups: u32,
    /// Rays per pixel side for the coverage fraction.
    pub grid: u32,
}
/// Output buffers of one annotation, owned by the caller so the pass can join any graph.
pub struct AnnotationTargets {
    pub ids: Buffer,
    pub coverage: Buffer,
    pub width: u32,
    pub height: u32,
}

impl AnnotationTargets {
    pub fn new(ctx: &Arc<Context>, width: u32, height: u32) -> Result<Self, VkError> {
        let n = width as u64 * height as u64 * 4;
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER;
        Ok(AnnotationTargets {
            ids: Buffer::new(ctx, "annotation ids", n, usage, MemoryKind::Readback)?,
            coverage: Buffer::new(ctx, "annotation coverage", n, usage, MemoryKind::Readback)?,
            width,
            height,
        })
    }

    /// Reads the finished annotation back.
    pub fn read(&self) -> Result<Annotation, VkError> {
        let ids: Vec<u32> = self.ids.read()?;
        let coverage: Vec<f32> = self.coverage.read()?;
        Ok(Annotation {
            width: self.width,
            height: self.height,
            face: ids.iter().map(|&v| (v & 0xff) as u8).collect(),
            class: ids.iter().map(|&v| ((v >> 8) & 0xff) as u8).collect(),
            instance: ids.iter().map(|&v| (v >> 16) as u16).collect(),
            coverage,
        })
    }
}

impl AnnotatePass {
    pub fn new(
        ctx: &Arc<Context>,
        scene: &TraceScene,
        mesh: &Mesh,
        grid: u32,
    ) -> Result<Self, VkError> {
        if mesh.labels.len() != scene.object().triangle_count {
            return Err(VkError::Other(format!(
                "mesh has {} labels for {} traced object triangles",
                mesh.labels.len(),
                scene.object().triangle_count
            )));
        }
        let pipeline = super::pipelines::annotate(ctx, scene.backend)?;
        let packed: Vec<u32> = mesh.labels.iter().map(label_word).collect();
        let labels = Buffer::from_slice(
            ctx,
            "triangle labels",
            &packed,
            vk::BufferUsageFlags::STORAGE_BUFFER,
        )?;
        Ok(AnnotatePass {
            pipeline,
            labels,
            max_groups: ctx.info.max_workgroup_count[0],
            grid: grid.clamp(1, 16),
        })
    }

    /// Adds the pass to `g`, writing into `ids` and `coverage` (imported from targets).
    pub fn record<'a>(
        &'a self,
        g: &mut Graph<'a>,
        trace: &TraceRefs,
        backend_bindings: u32,
        cam: &Camera,
        targets: (&mut BufferRef, &mut BufferRef),
    ) {
        let labels = g.import(&self.labels);
        let size = (cam.width, cam.height);
        let tiling = Tiling::new(cam.width, cam.height, self.max_groups);
        let block = camera_block(cam);
        record_annotate(
            g,
            &self.pipeline,
            trace,
            backend_bindings,
            &labels,
            targets,
            &block,
            size,
            self.grid,
            &tiling,
            (crate::gpu_interface::SAMPLER_SOBOL, 0),
        );
    }
}

/// Annotates one view: builds the pass, runs it in its own graph and reads it back.
pub fn annotate(
    ctx: &Arc<Context>,
    scene: &TraceScene,
    mesh: &Mesh,
    cam: &Camera,
    grid: u32,
    profiler: Option<&Profiler>,
) -> Result<(Annotation, PassTiming), VkError> {
    let (width, height) = (cam.width, cam.height);
    let pass = AnnotatePass::new(ctx, scene, mesh, grid)?;
    let targets = AnnotationTargets::new(ctx, width, height)?;
    let mut g = Graph::new(ctx, "annotation");
    let refs = scene.import(&mut g);
    let mut ids = g.import(&targets.ids);
    let mut cov = g.import(&targets.coverage);
    let nb = TraceScene::binding_kinds(scene.backend).len() as u32;
    pass.record(&mut g, &refs, nb, cam, (&mut ids, &mut cov));
    let timing = g
        .execute(profiler)?
        .into_iter()
        .next()
        .unwrap_or(PassTiming {
            name: "annotate".into(),
            gpu_ms: f64::NAN,
        });
    let ann = crate::vk::timed(profiler, "readback", || targets.read())?;
    Ok((ann, timing))
}
