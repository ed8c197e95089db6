//! A stage on the GPU: the object's acceleration structure, its materials and labels,
//! and the slope maps on its planar regions. Built once per mesh and reused by every view of it
//! (the dataset caches it by mesh key); only the slope maps can change in between.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use ash::vk;

use super::RenderError;
use super::cpu::on_render_pool;
use super::device_maps::{self, SharedMapError};
use super::settings::TextureFilter;
use super::slope::{self, FaceMap, Placement};
use super::tracer::PathTracer;
use crate::gpu_interface::{
    LABEL_CLASS_SHIFT, LABEL_INSTANCE_SHIFT, MAP_BUFFER_MASK, MAT_LABELLED, MAT_MAP_SHIFT,
    MAT_REGION_FIRST, MAT_SLOT_MASK, SURFACE_CONDUCTOR, SURFACE_DIFFUSE, SurfaceBlock,
};
use crate::scene::assemble::{PlacedCurved, RegionFrame, Stage, place_curved_maps, place_maps};
use crate::scene::curved::CurvedPatch;
use crate::scene::materials::{Finish, SurfaceKind, SurfaceMaterial};
use crate::scene::mesh::{FACE_A, FACE_C};
use crate::scene::{FaceFrame, TriLabel};
use crate::trace::software_bvh::DEFAULT_BVH_QUALITY;
use crate::trace::{Backend, LevelData, TraceGeometry};
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
    key: MapKey,
    headers: Buffer,
    /// Each distinct map's texel words, shared with the other scenes on the device that
    /// show it (`device_maps`); one unused word where a buffer has no map.
    texels: [Arc<Buffer>; slope::MAP_BUFFERS],
    /// The curved patches' projections, one per slot.
    curved: Buffer,
    /// Each map's moment pyramid (`slope::moments_pyramid`) when uploaded for
    /// `TextureFilter::Lean` (shared likewise); one unused word each otherwise.
    moments: [Arc<Buffer>; slope::MAP_BUFFERS],
    /// Whether any slot has a map.
    any: bool,
}

/// What a set of uploaded maps was made from: each face map's identity and placement,
/// and how they were spread over the regions.
#[derive(PartialEq)]
struct MapKey {
    maps: Vec<(usize, u32, [u32; 2], u8)>,
    placement: Option<(crate::scene::assemble::Cover, u64, u32)>,
    filter: TextureFilter,
}

/// What a [`GpuScene`] is made of before any device: the stage and its object's
/// acceleration structure built on the CPU ([`LevelData`]). A dataset run makes one per
/// object instance on its preparing thread and every renderer uploads it
/// ([`GpuScene::from_prepared`]), so that neither the region search nor the BVH build
/// runs on a render thread, nor once per renderer.
pub struct PreparedScene {
    pub stage: Stage,
    object: LevelData,
}

static PREPARED: AtomicUsize = AtomicUsize::new(0);

impl PreparedScene {
    /// `stage` and its object's level for `backend` (software: obvhs's default preset).
    pub fn new(
        stage: Stage,
        backend: Backend,
        profiler: Option<&Profiler>,
    ) -> Result<PreparedScene, RenderError> {
        let object = LevelData::build(&stage, backend, DEFAULT_BVH_QUALITY, profiler)?;
        PREPARED.fetch_add(1, Ordering::Relaxed);
        Ok(PreparedScene { stage, object })
    }

    /// The backend its acceleration structure is for.
    pub fn backend(&self) -> Backend {
        self.object.backend
    }

    /// Scenes prepared by this process so far (tests: one per object instance, however
    /// many renderers).
    pub fn prepared_count() -> usize {
        PREPARED.load(Ordering::Relaxed)
    }
}

/// The GPU side of a [`Stage`].
pub struct GpuScene {
    pub(crate) geometry: Arc<TraceGeometry>,
    pub(crate) materials: Buffer,
    /// The material table (`SurfaceBlock` per `[[material.region]]` entry).
    pub(crate) surfaces: Buffer,
    /// What `surfaces` was made from.
    surface_list: Vec<SurfaceMaterial>,
    pub(crate) labels: Buffer,
    maps: MapBuffers,
    face_frames: Vec<FaceFrame>,
    regions: Vec<RegionFrame>,
    /// The object's curved patches (slots after the regions').
    curved: Vec<CurvedPatch>,
    pub table_albedo: f32,
    /// The table's square (`Stage::table`).
    pub table: [f32; 4],
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
        // The stage, not only its mesh: triplanar patches' smooth normals ride in the
        // shading triangles' w (`Stage::corner_w`).
        let level = LevelData::build(stage, tracer.backend, DEFAULT_BVH_QUALITY, profiler)?;
        Self::with_level(tracer, stage, &level, profiler)
    }

    /// As [`GpuScene::new`] from a [`PreparedScene`] (its stage and acceleration
    /// structure made beforehand, perhaps on another thread and for several devices):
    /// only the uploads here.
    pub fn from_prepared(
        tracer: &PathTracer,
        prepared: &PreparedScene,
        profiler: Option<&Profiler>,
    ) -> Result<GpuScene, RenderError> {
        if prepared.object.backend != tracer.backend {
            return Err(RenderError::Vk(crate::vk::VkError::Other(format!(
                "a scene prepared for the {} backend given to a {} path tracer",
                prepared.object.backend.name(),
                tracer.backend.name()
            ))));
        }
        Self::with_level(tracer, &prepared.stage, &prepared.object, profiler)
    }

    fn with_level(
        tracer: &PathTracer,
        stage: &Stage,
        level: &LevelData,
        profiler: Option<&Profiler>,
    ) -> Result<GpuScene, RenderError> {
        let ctx = &tracer.ctx;
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let geometry = Arc::new(TraceGeometry::upload(ctx, level, profiler)?);
        // Material in the low byte, the slope-map slot above it (region + 1; 0 for the
        // table), the top bit for triangles labelled A, B or C: the shader finds the
        // region's map without another buffer.
        let slots = stage.regions.len() + stage.curved.len() + 1;
        if slots as u64 > MAT_SLOT_MASK as u64 {
            return Err(RenderError::Slope(slope::SlopeError::Invalid {
                region: stage.regions.len() as u32,
                message: format!(
                    "more than {} planar regions and curved patches",
                    MAT_SLOT_MASK - 1
                ),
            }));
        }
        let mat_words = material_words(stage);
        let labels: Vec<u32> = stage.mesh.labels.iter().map(label_word).collect();
        let empty = MapKey {
            maps: Vec::new(),
            placement: None,
            filter: TextureFilter::None,
        };
        let maps = upload_maps(tracer, &[], &[], slots, empty)?;
        BUILT.fetch_add(1, Ordering::Relaxed);
        Ok(GpuScene {
            geometry,
            materials: Buffer::from_slice(ctx, "materials", &mat_words, storage)?,
            surfaces: Buffer::from_slice(
                ctx,
                "material table",
                &surface_blocks(&stage.surfaces),
                storage,
            )?,
            surface_list: stage.surfaces.clone(),
            labels: Buffer::from_slice(ctx, "triangle labels", &labels, storage)?,
            maps,
            face_frames: stage.face_frames.clone(),
            regions: stage.regions.clone(),
            curved: stage.curved.clone(),
            table_albedo: stage.table_albedo,
            table: stage.table,
            triangle_count: stage.mesh.triangles.len() as u32,
        })
    }

    /// Puts `maps` on the faces and spreads them over the object's regions as `placement`
    /// says (`scene::assemble::place_maps`), replacing any before; uploads only when they
    /// differ from the current ones (same map objects, same placement: nothing to do).
    pub fn set_face_maps(
        &mut self,
        tracer: &PathTracer,
        maps: &[FaceMap],
        placement: &Placement,
    ) -> Result<(), RenderError> {
        self.set_face_maps_filtered(tracer, maps, placement, TextureFilter::None)
    }

    /// [`set_face_maps`](Self::set_face_maps) for views rendered with `filter`: with
    /// `TextureFilter::Lean` each map's moment pyramid is built (on the CPU) and uploaded
    /// too (4 bytes per texel more, docs/rendering.md, "Filtered slope maps").
    pub fn set_face_maps_filtered(
        &mut self,
        tracer: &PathTracer,
        maps: &[FaceMap],
        placement: &Placement,
        filter: TextureFilter,
    ) -> Result<(), RenderError> {
        let key = map_key(maps, placement, filter);
        if key != self.maps.key {
            let placed = place_maps(maps, &self.face_frames, &self.regions, placement)?;
            let first = self.regions.len() as u32;
            let curved = place_curved_maps(maps, &self.curved, first, placement);
            let slots = self.regions.len() + self.curved.len() + 1;
            self.maps = upload_maps(tracer, &placed, &curved, slots, key)?;
        }
        Ok(())
    }

    /// Replaces the material table's values (`[[material.region]]` entry i stays entry
    /// i: which triangle takes which entry is the stage's); uploads only when they
    /// differ. A dataset job's entries take each instance's alpha. The number of entries
    /// must be the stage's (or zero when the stage had none).
    pub fn set_surfaces(
        &mut self,
        tracer: &PathTracer,
        surfaces: &[SurfaceMaterial],
    ) -> Result<(), RenderError> {
        if surfaces == self.surface_list.as_slice() {
            return Ok(());
        }
        if surfaces.len() != self.surface_list.len() {
            return Err(RenderError::Assemble(
                crate::scene::config::ConfigError::Invalid {
                    field: "material.region",
                    message: format!(
                        "{} entries for a scene built with {}",
                        surfaces.len(),
                        self.surface_list.len()
                    ),
                }
                .into(),
            ));
        }
        self.surfaces = Buffer::from_slice(
            &tracer.ctx,
            "material table",
            &surface_blocks(surfaces),
            vk::BufferUsageFlags::STORAGE_BUFFER,
        )?;
        self.surface_list = surfaces.to_vec();
        Ok(())
    }

    /// Whether views with `filter` can read these maps: "lean" needs the moment pyramids
    /// of every map (none needed when no slot has a map).
    pub fn maps_support(&self, filter: TextureFilter) -> bool {
        filter == TextureFilter::None || !self.maps.any || self.maps.key.filter == filter
    }

    /// The object's planar regions (where slope maps are projected).
    pub fn regions(&self) -> &[RegionFrame] {
        &self.regions
    }

    /// Frames of the stage's inspected faces (where views and slope maps are placed).
    pub fn face_frames(&self) -> &[FaceFrame] {
        &self.face_frames
    }

    pub(crate) fn map_buffers(&self) -> (&Buffer, [&Buffer; slope::MAP_BUFFERS]) {
        (
            &self.maps.headers,
            self.maps.texels.each_ref().map(|b| &**b),
        )
    }

    /// The buffer each of the maps' texel slots reads (tests: scenes on one device that
    /// show the same maps read the same buffers).
    pub fn slope_texel_buffers(&self) -> [vk::Buffer; slope::MAP_BUFFERS] {
        self.maps.texels.each_ref().map(|b| b.raw)
    }

    /// The curved patches' projection blocks (`CurvedMapBlock` per slot).
    pub(crate) fn curved_buffer(&self) -> &Buffer {
        &self.maps.curved
    }

    /// The maps' moment pyramids (unused words without "lean").
    pub(crate) fn moment_buffers(&self) -> [&Buffer; slope::MAP_BUFFERS] {
        self.maps.moments.each_ref().map(|b| &**b)
    }

    /// GPU scenes built by this process so far.
    pub fn built_count() -> usize {
        BUILT.load(Ordering::Relaxed)
    }
}

/// The shader's material table; one unused entry when there is none (a binding may not
/// be empty). The Fresnel average of a conductor is computed here, per entry (the
/// energy tables E, E_avg are for F = 1 and serve every IOR; see energy.rs).
pub fn surface_blocks(surfaces: &[SurfaceMaterial]) -> Vec<SurfaceBlock> {
    if surfaces.is_empty() {
        return vec![SurfaceBlock::default()];
    }
    surfaces
        .iter()
        .map(|s| SurfaceBlock {
            kind: match s.kind {
                SurfaceKind::Conductor => SURFACE_CONDUCTOR,
                SurfaceKind::Diffuse => SURFACE_DIFFUSE,
            },
            alpha: s.alpha,
            ior_n: s.ior_n,
            ior_k: s.ior_k,
            f_avg: super::bsdf::Fresnel::Conductor {
                n: s.ior_n,
                k: s.ior_k,
            }
            .average(),
            albedo: s.albedo,
            ..Default::default()
        })
        .collect()
}

fn map_key(maps: &[FaceMap], p: &Placement, filter: TextureFilter) -> MapKey {
    MapKey {
        maps: maps
            .iter()
            .map(|m| {
                (
                    Arc::as_ptr(&m.slopes) as usize,
                    m.rotation_deg.to_bits(),
                    m.offset_mm.map(f32::to_bits),
                    m.face,
                )
            })
            .collect(),
        placement: Some((p.cover, p.seed, p.rotation_range_deg.to_bits())),
        filter,
    }
}

/// The per-triangle material words the shader reads (src/gpu_interface.in): material
/// in the low byte, the slope-map slot above it (`MAT_MAP_SHIFT`: region + 1, curved
/// patch after the regions, 0 for the table and for `finish = "none"` entries),
/// `MAT_LABELLED` for triangles labelled A, B or C.
pub fn material_words(stage: &Stage) -> Vec<u32> {
    stage
        .materials
        .iter()
        .zip(&stage.mesh.labels)
        .enumerate()
        .map(|(t, (&m, l))| {
            // A material without the finish (`finish = "none"`) gets no slope map.
            let bare = m >= MAT_REGION_FIRST
                && stage
                    .surfaces
                    .get((m - MAT_REGION_FIRST) as usize)
                    .is_none_or(|s| s.finish == Finish::None);
            let slot = if bare { 0 } else { stage.map_slot(t) };
            let labelled = (FACE_A..=FACE_C).contains(&l.face) as u32 * MAT_LABELLED;
            m | (slot & MAT_SLOT_MASK) << MAT_MAP_SHIFT | labelled
        })
        .collect()
}

fn upload_maps(
    tracer: &PathTracer,
    placed: &[slope::PlacedMap],
    curved: &[PlacedCurved],
    slots: usize,
    key: MapKey,
) -> Result<MapBuffers, RenderError> {
    let ctx = &tracer.ctx;
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let max_bytes = ctx.info.max_storage_buffer_range as u64;
    let mut all = placed.to_vec();
    all.extend(curved.iter().map(|c| c.map.clone()));
    let (mut headers, distinct) = slope::pack_headers(&all, slots, max_bytes)?;
    let blocks = slope::curved_blocks(curved, &mut headers)?;
    // The headers are read as a texel buffer (path_trace.comp `map_header`, four texels
    // a slot): within the device's texel limit.
    ctx.info.fits_texel_buffer(
        "slope maps' headers",
        std::mem::size_of_val(&headers[..]),
        &format!("the scene has too many slope-map slots ({})", headers.len()),
    )?;
    // A binding may not be empty; a slot without a map never reads it.
    let unused = Arc::new(Buffer::from_slice(ctx, "no slope map", &[0u32], storage)?);
    let shared_error = |map: &Arc<slope::SlopeMap>, e: SharedMapError| -> RenderError {
        match e {
            SharedMapError::Vk(e) => e.into(),
            SharedMapError::Slope(e) => e.into(),
            SharedMapError::NotFinite => slope::not_finite(&all, map).into(),
        }
    };
    let mut texels = [unused.clone(), unused.clone(), unused.clone()];
    let mut moments = [unused.clone(), unused.clone(), unused];
    for (b, map) in distinct.iter().enumerate() {
        texels[b] =
            on_render_pool(|| device_maps::texels(ctx, map)).map_err(|e| shared_error(map, e))?;
        if key.filter == TextureFilter::Lean {
            // The first slot reading buffer b names the map in errors.
            let slot = headers
                .iter()
                .position(|h| (h.dims[3] & MAP_BUFFER_MASK) as usize == b + 1)
                .unwrap_or(0);
            let region = slot.saturating_sub(1) as u32;
            moments[b] = device_maps::moments(ctx, map, region, max_bytes)
                .map_err(|e| shared_error(map, e))?;
        }
    }
    Ok(MapBuffers {
        any: !placed.is_empty() || !curved.is_empty(),
        key,
        // Read as a uniform texel buffer (path_trace.comp `map_header`; checked above).
        headers: Buffer::from_slice(
            ctx,
            "slope map headers",
            &headers,
            storage | vk::BufferUsageFlags::UNIFORM_TEXEL_BUFFER,
        )?,
        texels,
        curved: Buffer::from_slice(ctx, "curved maps", &blocks, storage)?,
        moments,
    })
}
