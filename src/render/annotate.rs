//! The annotation pass: class, defect instance and face of the first hit per pixel, and
//! the defect coverage fraction, from the same camera and geometry as the image.

use std::path::Path;
use std::sync::Arc;

use ash::vk;

use crate::graph::{BufferRef, Graph, PassTiming};
use crate::render::raycast::{CameraPush, PinholeCamera};
use crate::scene::{Mesh, TriLabel};
use crate::trace::{TraceRefs, TraceScene, trace_pipeline};
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

fn pack(l: &TriLabel) -> u32 {
    l.face as u32 | (l.class as u32) << 8 | (l.instance as u32) << 16
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct AnnotatePush {
    cam: CameraPush,
    grid: u32,
    pad: [u32; 3],
}

/// The annotation pass's pipeline and per-mesh label buffer, reusable across images
/// of the same mesh and backend.
pub struct AnnotatePass {
    pipeline: ComputePipeline,
    labels: Buffer,
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
        let push = std::mem::size_of::<AnnotatePush>() as u32;
        let pipeline = trace_pipeline(ctx, "annotate", scene.backend, 3, push, [8, 8, 1])?;
        let packed: Vec<u32> = mesh.labels.iter().map(pack).collect();
        let labels = Buffer::from_slice(
            ctx,
            "triangle labels",
            &packed,
            vk::BufferUsageFlags::STORAGE_BUFFER,
        )?;
        Ok(AnnotatePass {
            pipeline,
            labels,
            grid: grid.clamp(1, 16),
        })
    }

    /// Adds the pass to `g`, writing into `ids` and `coverage` (imported from targets).
    pub fn record<'a>(
        &'a self,
        g: &mut Graph<'a>,
        trace: &TraceRefs,
        backend_bindings: u32,
        cam: &PinholeCamera,
        targets: (&mut BufferRef, &mut BufferRef),
        size: (u32, u32),
    ) {
        let labels = g.import(&self.labels);
        let cam = CameraPush::new(cam, size.0, size.1);
        let tiles = cam.tiles();
        let push = AnnotatePush {
            cam,
            grid: self.grid,
            pad: [0; 3],
        };
        let off = backend_bindings;
        trace
            .bind(g.dispatch("annotate", &self.pipeline, [tiles, 1, 1]))
            .read(off, &labels)
            .write(off + 1, targets.0)
            .write(off + 2, targets.1)
            .push(&push)
            .submit();
    }
}

/// Annotates one view: builds the pass, runs it in its own graph and reads it back.
pub fn annotate(
    ctx: &Arc<Context>,
    scene: &TraceScene,
    mesh: &Mesh,
    cam: &PinholeCamera,
    (width, height): (u32, u32),
    grid: u32,
    profiler: Option<&Profiler>,
) -> Result<(Annotation, PassTiming), VkError> {
    let pass = AnnotatePass::new(ctx, scene, mesh, grid)?;
    let targets = AnnotationTargets::new(ctx, width, height)?;
    let mut g = Graph::new(ctx, "annotation");
    let refs = scene.import(&mut g);
    let mut ids = g.import(&targets.ids);
    let mut cov = g.import(&targets.coverage);
    let nb = TraceScene::binding_kinds(scene.backend).len() as u32;
    pass.record(
        &mut g,
        &refs,
        nb,
        cam,
        (&mut ids, &mut cov),
        (width, height),
    );
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
