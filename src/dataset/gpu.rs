//! The production renderer behind [`ImageRenderer`]: the Vulkan path tracer with the
//! annotation pass in the same render graph (`render::path_trace::render_frame`).
//!
//! Limitation (documented in docs/dataset.md): the path tracer has no slope-map input
//! yet, so the requests' face textures are made (and recorded in the manifest) but not
//! applied; faces render as the smooth GGX conductor at the instance's roughness.

use std::sync::Arc;

use super::renderer::{ImageRenderer, ImageRequest, RenderedImage};
use crate::render::annotate::DEFAULT_COVERAGE_GRID;
use crate::render::energy::EnergyTables;
use crate::render::path_trace::{FrameOptions, RenderScene, render_frame};
use crate::render::slope::FaceMap;
use crate::scene::config::SceneConfig;
use crate::scene::mesh::FACE_OTHER;
use crate::trace::{AccelChoice, Backend, resolve};
use crate::vk::{Context, ContextOptions, Profiler};

/// Face id given to the object's non-inspected triangles for the annotation pass only,
/// so "object" and "table or nothing" (both face 0 in faces.png) can be told apart.
const FACE_OBJECT_OTHER: u8 = 4;

/// The GPU path tracer + annotation pass, with the scene defaults of `SceneConfig`
/// (camera, ring light, table, aluminium IOR).
pub struct GpuRenderer {
    ctx: Arc<Context>,
    backend: Backend,
    tables: EnergyTables,
    base: SceneConfig,
    stages: Vec<(String, f64)>,
}

impl GpuRenderer {
    /// Opens the Vulkan device (validation also by `SYNOSIS_VALIDATION=1`).
    pub fn new(accel: AccelChoice, validation: bool) -> Result<GpuRenderer, String> {
        let ctx = Context::new(&ContextOptions {
            validation,
            ray_query: true,
        })
        .map_err(|e| format!("Vulkan: {e}"))?;
        let backend = resolve(accel, &ctx.info).map_err(|e| e.to_string())?;
        Ok(GpuRenderer {
            ctx,
            backend,
            tables: EnergyTables::compute(),
            base: SceneConfig::default(),
            stages: Vec::new(),
        })
    }
}

impl ImageRenderer for GpuRenderer {
    fn describe(&self) -> String {
        format!("gpu-path-tracer/{}", self.backend.name())
    }

    fn last_stages(&self) -> Vec<(String, f64)> {
        self.stages.clone()
    }

    fn render(&mut self, req: &ImageRequest) -> Result<RenderedImage, String> {
        let mut cfg = self.base.clone();
        cfg.camera.view = req.view.to_string();
        cfg.set_resolution(req.width, req.height)
            .map_err(|e| e.to_string())?;
        cfg.render.spp = req.spp;
        cfg.render.max_bounces = req.bounces;
        // The shader takes a 32-bit seed: fold the 64-bit one.
        cfg.render.seed = (req.seed ^ (req.seed >> 32)) as u32;
        cfg.material.alpha = req.alpha;
        cfg.validate().map_err(|e| e.to_string())?;
        let mut object = req.mesh.clone();
        for l in &mut object.labels {
            if l.face == FACE_OTHER {
                l.face = FACE_OBJECT_OTHER;
            }
        }
        let mut scene = RenderScene::assemble(&object, &cfg).map_err(|e| e.to_string())?;
        // Each inspected face's texture: planar projection in the face frame, rotated,
        // shifted by whole texture pixels along the face's (u, v) axes.
        scene.face_maps = req
            .face_textures
            .iter()
            .map(|t| FaceMap {
                face: t.face,
                slopes: t.map.clone(),
                rotation_deg: t.rotation_rad.to_degrees(),
                offset_mm: t.offset_px.map(|p| p * (t.map.spacing_um * 1e-3) as f32),
            })
            .collect();
        let profiler = Profiler::new();
        let opts = FrameOptions {
            annotate_grid: Some(DEFAULT_COVERAGE_GRID),
            profiler: Some(&profiler),
        };
        let frame = render_frame(
            &self.ctx,
            &scene,
            &cfg,
            self.backend,
            &self.tables,
            opts,
            |_| {},
        )
        .map_err(|e| e.to_string())?;
        // CPU phases of the acceleration structure, GPU time of the two passes.
        let secs = |names: &[&str]| names.iter().map(|n| profiler.total_ms(n)).sum::<f64>() / 1e3;
        self.stages = vec![
            (
                "render.acceleration".into(),
                secs(&[
                    "upload geometry",
                    "BVH build (obvhs)",
                    "upload BVH",
                    "AS build (BLAS+TLAS)",
                ]),
            ),
            ("render.path_trace_gpu".into(), secs(&["path trace"])),
            ("render.annotate_gpu".into(), secs(&["annotate"])),
        ];
        self.ctx.check_validation().map_err(|e| e.to_string())?;
        let ann = frame
            .annotation
            .ok_or("the annotation pass returned nothing")?;
        let object_mask: Vec<u8> = ann.face.iter().map(|&f| (f != 0) as u8).collect();
        let face = ann
            .face
            .iter()
            .map(|&f| if f == FACE_OBJECT_OTHER { 0 } else { f })
            .collect();
        Ok(RenderedImage {
            width: frame.radiance.width,
            height: frame.radiance.height,
            radiance: frame.radiance.data,
            class: ann.class,
            instance: ann.instance,
            face,
            coverage: ann.coverage,
            object: object_mask,
        })
    }
}
