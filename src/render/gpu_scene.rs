//! A stage on the GPU: the object's acceleration structure, its materials and labels,
//! and the slope maps on its faces. Built once per mesh and reused by every view of it
//! (the dataset caches it by mesh key); only the slope maps can change in between.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use ash::vk;

use super::RenderError;
use super::slope::{self, FaceMap};
use super::tracer::PathTracer;
use crate::gpu_interface::{LABEL_CLASS_SHIFT, LABEL_INSTANCE_SHIFT, MAT_FACE_SHIFT};
use crate::scene::assemble::Stage;
use crate::scene::{FaceFrame, TriLabel};
use crate::trace::TraceGeometry;
use crate::vk::{Buffer, Profiler};

static BUILT: AtomicUsize = AtomicUsize::new(0);

/// The annotation pass's word per triangle: face | class << 8 | instance << 16.
pub fn label_word(l: &TriLabel) -> u32 {
    l.face as u32
        | (l.class as u32) << LABEL_CLASS_SHIFT
        | (l.instance as u32) << LABEL_INSTANCE_SHIFT
}

/// Slope-map headers and texels as uploaded, with what they were made from (so the same
/// maps are not uploaded twice).
struct MapBuffers {
    key: Vec<(usize, u32, [u32; 2], u8)>,
    headers: Buffer,
    texels: [Buffer; 3],
}

/// The GPU side of a [`Stage`].
pub struct GpuScene {
    pub(crate) geometry: Arc<TraceGeometry>,
    pub(crate) materials: Buffer,
    pub(crate) labels: Buffer,
    maps: MapBuffers,
    face_frames: Vec<FaceFrame>,
    pub table_albedo: f32,
    /// Triangles of the stage (the view's light is numbered after them).
    pub triangle_count: u32,
}

impl GpuScene {
    /// Builds the acceleration structure and uploads materials and labels; no slope maps.
    pub fn new(
        tracer: &PathTracer,
        stage: &Stage,
        profiler: Option<&Profiler>,
    ) -> Result<GpuScene, RenderError> {
        let ctx = &tracer.ctx;
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let geometry = Arc::new(TraceGeometry::build(
            ctx,
            &stage.mesh,
            tracer.backend,
            0,
            profiler,
        )?);
        // Material in the low byte, inspected face id in the next: the shader finds the
        // face's slope map without another buffer.
        let mat_words: Vec<u32> = stage
            .materials
            .iter()
            .zip(&stage.mesh.labels)
            .map(|(&m, l)| m | (l.face as u32) << MAT_FACE_SHIFT)
            .collect();
        let labels: Vec<u32> = stage.mesh.labels.iter().map(label_word).collect();
        let maps = upload_maps(tracer, &[], &stage.face_frames)?;
        BUILT.fetch_add(1, Ordering::Relaxed);
        Ok(GpuScene {
            geometry,
            materials: Buffer::from_slice(ctx, "materials", &mat_words, storage)?,
            labels: Buffer::from_slice(ctx, "triangle labels", &labels, storage)?,
            maps,
            face_frames: stage.face_frames.clone(),
            table_albedo: stage.table_albedo,
            triangle_count: stage.mesh.triangles.len() as u32,
        })
    }

    /// Puts `maps` on the faces (replacing any before); uploads only when they differ
    /// from the current ones (same map objects at the same placement: nothing to do).
    pub fn set_face_maps(
        &mut self,
        tracer: &PathTracer,
        maps: &[FaceMap],
    ) -> Result<(), RenderError> {
        if map_key(maps) != self.maps.key {
            self.maps = upload_maps(tracer, maps, &self.face_frames)?;
        }
        Ok(())
    }

    /// Frames of the stage's inspected faces (where views and slope maps are placed).
    pub fn face_frames(&self) -> &[FaceFrame] {
        &self.face_frames
    }

    pub(crate) fn map_buffers(&self) -> (&Buffer, &[Buffer; 3]) {
        (&self.maps.headers, &self.maps.texels)
    }

    /// GPU scenes built by this process so far.
    pub fn built_count() -> usize {
        BUILT.load(Ordering::Relaxed)
    }
}

fn map_key(maps: &[FaceMap]) -> Vec<(usize, u32, [u32; 2], u8)> {
    maps.iter()
        .map(|m| {
            (
                Arc::as_ptr(&m.slopes) as usize,
                m.rotation_deg.to_bits(),
                m.offset_mm.map(f32::to_bits),
                m.face,
            )
        })
        .collect()
}

fn upload_maps(
    tracer: &PathTracer,
    maps: &[FaceMap],
    frames: &[FaceFrame],
) -> Result<MapBuffers, RenderError> {
    let ctx = &tracer.ctx;
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let (headers, texels) = slope::pack(maps, frames, ctx.info.max_storage_buffer_range as u64)?;
    let buf = |texels: &[u32], name: &str| {
        // A binding may not be empty; a face without a map never reads it.
        let data: &[u32] = if texels.is_empty() { &[0] } else { texels };
        Buffer::from_slice(ctx, name, data, storage)
    };
    Ok(MapBuffers {
        key: map_key(maps),
        headers: Buffer::from_slice(ctx, "slope map headers", &headers, storage)?,
        texels: [
            buf(&texels[0], "slopes A")?,
            buf(&texels[1], "slopes B")?,
            buf(&texels[2], "slopes C")?,
        ],
    })
}
