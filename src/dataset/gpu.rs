//! The production renderer behind [`ImageRenderer`]: the Vulkan path tracer with the
//! annotation pass in the same render graph. The path tracer (pipelines, energy tables)
//! is built once per process; the GPU scene (acceleration structure, materials, labels)
//! once per mesh key, and kept while the job renders that mesh's views; each request's
//! face textures are placed on it as slope maps (re-uploaded only when they change).

use std::sync::Arc;

use super::renderer::{ImageRenderer, ImageRequest, RenderedImage, TextureMap};
use crate::render::annotate::DEFAULT_COVERAGE_GRID;
use crate::render::energy::EnergyTables;
use crate::render::noise::NoiseEstimate;
use crate::render::slope::FaceMap;
use crate::render::{
    FrameOptions, GpuScene, PathTracer, PreparedScene, RenderSettings, render_frame,
};
use crate::scene::Mesh;
use crate::scene::assemble::{DefectSurface, Stage, ViewSetup};
use crate::scene::config::SceneConfig;
use crate::scene::materials::{GltfMaterials, RegionMaterial, RegionSelector};
use crate::scene::mesh::FACE_OTHER;
use crate::trace::{AccelChoice, Backend, resolve};
use crate::vk::{Context, ContextOptions, Profiler, timed};

/// Face id given to the object's non-inspected triangles for the annotation pass only,
/// so "object" and "table or nothing" (both face 0 in faces.png) can be told apart.
const FACE_OBJECT_OTHER: u8 = 4;

/// The GPU path tracer + annotation pass, with the scene defaults of `SceneConfig` (ring
/// light, table, aluminium IOR) and each request's camera.
pub struct GpuRenderer {
    ctx: Arc<Context>,
    tracer: PathTracer,
    /// The GPU scene of the last mesh key and region-material selectors.
    cached: Option<(SceneKey, GpuScene)>,
    base: SceneConfig,
    stages: Vec<(String, f64)>,
    /// The timeline of the last image (CPU phases, GPU passes).
    profile: Option<Profiler>,
    /// Samples and noise estimate of the last image.
    samples: Option<(u32, Vec<NoiseEstimate>)>,
    /// The rays the last render chose (`Frame::analytic_rays_chosen`).
    rays: Option<u32>,
}

impl GpuRenderer {
    /// Opens the Vulkan device (validation also by `SYNOSIS_VALIDATION=1`) and builds the
    /// path tracer.
    pub fn new(accel: AccelChoice, validation: bool) -> Result<GpuRenderer, String> {
        let ctx = Context::new(&ContextOptions {
            validation,
            ray_query: true,
        })
        .map_err(|e| format!("Vulkan: {e}"))?;
        let backend = resolve(accel, &ctx.info).map_err(|e| e.to_string())?;
        Self::on(ctx, backend)
    }

    /// A renderer on `ctx` with a path tracer of `backend` and no scene yet.
    fn on(ctx: Arc<Context>, backend: Backend) -> Result<GpuRenderer, String> {
        let tracer =
            PathTracer::new(&ctx, backend, &EnergyTables::compute()).map_err(|e| e.to_string())?;
        Ok(GpuRenderer {
            ctx,
            tracer,
            cached: None,
            base: SceneConfig::default(),
            stages: Vec::new(),
            profile: None,
            samples: None,
            rays: None,
        })
    }

    /// `n` more renderers on this one's Vulkan device, each with a context of its own
    /// ([`Context::beside`]: its own queue while the device has a free one), its own path
    /// tracer (the same backend) and GPU scenes, made in parallel. Against renderers on
    /// separate devices ([`GpuRenderer::new`] twice) they share one device's memory
    /// overhead (on an H100 6 renderers took 7.0 GB instead of 20.4 GB) at the same
    /// speed as measured (docs/benchmarks/dataset.md, "Renderers beside one another").
    pub fn beside(&self, n: usize) -> Result<Vec<GpuRenderer>, String> {
        let (ctx, backend) = (&self.ctx, self.tracer.backend);
        std::thread::scope(|s| {
            let made: Vec<_> = (0..n)
                .map(|_| {
                    s.spawn(move || {
                        let ctx = ctx.beside().map_err(|e| format!("Vulkan: {e}"))?;
                        Self::on(ctx, backend)
                    })
                })
                .collect();
            made.into_iter()
                .map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
                .collect()
        })
    }

    /// The size of the device's largest device-local memory heap (bytes).
    pub fn device_local_bytes(&self) -> u64 {
        let heaps = &self.ctx.info.memory_heaps;
        heaps
            .iter()
            .filter(|h| h.device_local)
            .map(|h| h.size_bytes)
            .max()
            .unwrap_or(0)
    }

    /// True when the Vulkan device is a CPU implementation (lavapipe): there the "GPU"
    /// work runs on the same cores as the run's CPU stages, so overlapping them gains
    /// nothing (`dataset run` then defaults to one image in flight).
    pub fn device_is_cpu(&self) -> bool {
        self.ctx.info.is_cpu
    }
}

/// What a GPU scene is built from besides the table: the mesh (by key) and which
/// triangles take which region material (the selectors; the materials' values are set
/// per request).
type SceneKey = (u64, Vec<Vec<RegionSelector>>);

/// What a run's preparing thread needs to make a [`GpuRenderer`]'s scenes
/// ([`ImageRenderer::scene_prep`]): its backend, scene defaults and device. The stage
/// (planar regions, region materials) and the object's acceleration structure are then
/// made once per object instance on that thread, while the renderers trace the instance
/// before, and every renderer only uploads them; an image's slope maps are put on the
/// device there too ([`ScenePrep::upload_maps`]).
#[derive(Clone)]
pub struct ScenePrep {
    backend: Backend,
    base: SceneConfig,
    device: Arc<Context>,
}

/// An image's slope maps put on the renderers' device ahead of its render
/// ([`ScenePrep::upload_maps`]); held until the image is rendered, so that its renderer
/// finds them there (`render::device_maps`).
pub struct MapsAhead {
    _buffers: Vec<Arc<crate::vk::Buffer>>,
}

impl ScenePrep {
    /// The preparation of `tracer`'s scenes (its backend and device) from `base`.
    fn of(tracer: &PathTracer, base: &SceneConfig) -> ScenePrep {
        ScenePrep {
            backend: tracer.backend,
            base: base.clone(),
            device: tracer.ctx.clone(),
        }
    }

    /// The backend the scenes are made for.
    pub fn backend(&self) -> Backend {
        self.backend
    }

    /// This preparation on a context of its own beside the renderer's
    /// ([`Context::beside`]: the device's next queue), so that the preparing thread's
    /// copies (`Buffer::resident`'s staging copy on a GPU whose memory the host cannot
    /// map) do not queue behind a renderer's batches; itself where none can be made.
    pub fn on_own_queue(&self) -> ScenePrep {
        match self.device.beside() {
            Ok(device) => ScenePrep {
                device,
                ..self.clone()
            },
            Err(_) => self.clone(),
        }
    }

    /// Converts and uploads `maps` (an image's face textures) to the renderers' device,
    /// unless a scene there holds them already, on the calling thread and rayon's global
    /// pool: the renderer of the image then takes them as they are instead of converting
    /// and uploading each map itself on its render thread. Renderers on other devices
    /// upload their own. Fails with the index of the map that could not be uploaded.
    pub fn upload_maps(&self, maps: &[&Arc<TextureMap>]) -> Result<MapsAhead, (usize, String)> {
        let buffers = maps
            .iter()
            .enumerate()
            .map(|(i, m)| {
                crate::render::device_maps::texels(&self.device, m).map_err(|e| (i, e.to_string()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(MapsAhead { _buffers: buffers })
    }

    /// The scene of `mesh` (an object instance's) with its region materials
    /// (`materials`, `gltf`: as in [`ImageRequest`]) and `defects`' surface.
    pub fn prepare(
        &self,
        mesh: &Mesh,
        materials: &[RegionMaterial],
        gltf: Option<&GltfMaterials>,
        defects: DefectSurface,
        profiler: Option<&Profiler>,
    ) -> Result<PreparedScene, String> {
        let mut object = mesh.clone();
        for l in &mut object.labels {
            if l.face == FACE_OTHER {
                l.face = FACE_OBJECT_OTHER;
            }
        }
        let mut stage = timed(profiler, "stage (planar regions)", || {
            Stage::new(object, self.base.object.position_mm, &self.base.table)
        });
        if !materials.is_empty() {
            // Which triangle takes which entry depends on the mesh only (one object per
            // mesh key); the entries' values (an instance's alpha) are set per request.
            stage
                .set_region_materials(materials, gltf)
                .map_err(|e| e.to_string())?;
        }
        if defects == DefectSurface::Burnished {
            stage.burnish_defects();
        }
        PreparedScene::new(stage, self.backend, profiler).map_err(|e| e.to_string())
    }
}

/// The GPU scene for `req`'s mesh: the cached one when the mesh key and the material
/// selectors are the same, else uploaded from the request's prepared scene (made on the
/// run's preparing thread) or, without one, made here.
fn scene_for<'c>(
    cached: &'c mut Option<(SceneKey, GpuScene)>,
    tracer: &PathTracer,
    base: &SceneConfig,
    req: &ImageRequest,
    profiler: &Profiler,
) -> Result<&'c mut GpuScene, String> {
    let key: SceneKey = (
        req.mesh_key,
        req.materials.iter().map(|m| m.selectors.clone()).collect(),
    );
    if cached.as_ref().map(|c| &c.0) != Some(&key) {
        *cached = None; // free the old scene before building the next
        let made;
        let prepared = match req.scene {
            Some(p) if p.backend() == tracer.backend => p,
            _ => {
                made = ScenePrep::of(tracer, base).prepare(
                    req.mesh,
                    req.materials,
                    req.gltf_materials,
                    req.placement.defects,
                    Some(profiler),
                )?;
                &made
            }
        };
        let scene =
            GpuScene::from_prepared(tracer, prepared, Some(profiler)).map_err(|e| e.to_string())?;
        *cached = Some((key, scene));
    }
    Ok(&mut cached.as_mut().expect("just filled").1)
}

/// Each inspected face's texture: planar projection in the face frame, rotated, shifted
/// by whole texture pixels along the face's (u, v) axes.
fn face_maps(req: &ImageRequest) -> Vec<FaceMap> {
    req.face_textures
        .iter()
        .map(|t| FaceMap {
            face: t.face,
            slopes: t.map.clone(),
            rotation_deg: t.rotation_rad.to_degrees(),
            offset_mm: t.offset_px.map(|p| p * (t.map.spacing_um * 1e-3) as f32),
        })
        .collect()
}

impl ImageRenderer for GpuRenderer {
    fn describe(&self) -> String {
        format!("gpu-path-tracer/{}", self.tracer.backend.name())
    }

    fn scene_prep(&self) -> Option<ScenePrep> {
        Some(ScenePrep::of(&self.tracer, &self.base))
    }

    fn last_stages(&self) -> Vec<(String, f64)> {
        self.stages.clone()
    }

    fn last_profile(&self) -> Option<&Profiler> {
        self.profile.as_ref()
    }

    fn last_samples(&self) -> Option<(u32, Vec<NoiseEstimate>)> {
        self.samples.clone()
    }

    fn last_rays(&self) -> Option<u32> {
        self.rays
    }
    fn device_memory(&self) -> Option<crate::vk::MemoryInUse> {
        Some(self.ctx.memory_in_use())
    }

    fn render(&mut self, req: &ImageRequest) -> Result<RenderedImage, String> {
        // The scene defaults with the job's camera (intrinsics and lens).
        let mut base = self.base.clone();
        base.camera = req.camera.clone();
        let cfg = super::renderer::render_config(
            &base,
            req.view,
            req.pose,
            req.width,
            req.height,
            req.spp,
            req.bounces,
            req.seed,
            req.alpha,
        )?;
        let mut cfg = cfg;
        cfg.render.labels = req.labels;
        cfg.render.direct_light = req.direct_light;
        cfg.render.analytic_rays = req.analytic_rays;
        cfg.render.light_samples = req.light_samples;
        cfg.render.bsdf_samples = req.bsdf_samples;
        cfg.render.split_paths = req.split_paths;
        cfg.render.batch_spp = req.batch_spp;
        if !req.lights.is_empty() {
            // The job's lights replace the default ring.
            cfg.light.list = Some(req.lights.to_vec());
        }
        let pose = cfg.camera.pose().map_err(|e| e.to_string())?;
        self.profile = None;
        self.samples = None;
        self.rays = None;
        let profiler = Profiler::new();
        let tracer = &self.tracer;
        let scene = scene_for(&mut self.cached, tracer, &self.base, req, &profiler)?;
        profiler
            .cpu("face maps (place, pack, upload)", || {
                scene.set_face_maps_filtered(
                    tracer,
                    &face_maps(req),
                    &req.placement,
                    cfg.render.texture_filter,
                )
            })
            .map_err(|e| e.to_string())?;
        let surfaces: Vec<_> = req.materials.iter().map(|m| m.material.clone()).collect();
        scene
            .set_surfaces(tracer, &surfaces)
            .map_err(|e| e.to_string())?;
        let (frames, first_light) = (scene.face_frames(), scene.triangle_count);
        let setup = ViewSetup::for_pose(frames, first_light, &pose, &cfg.camera, &cfg.light)
            .map_err(|e| e.to_string())?;
        let opts = FrameOptions {
            annotate_grid: Some(DEFAULT_COVERAGE_GRID),
            profiler: Some(&profiler),
            noise: req.noise,
        };
        let settings = RenderSettings::from(&cfg);
        let frame = render_frame(tracer, scene, &setup, &settings, opts, |_| {})
            .map_err(|e| e.to_string())?;
        // CPU phases of the stage and the acceleration structures (the object's only when
        // this request built its GPU scene; the view's light every time), GPU time of the
        // two passes.
        let secs = |names: &[&str]| names.iter().map(|n| profiler.total_ms(n)).sum::<f64>() / 1e3;
        self.stages = vec![
            (
                "render.acceleration".into(),
                secs(&[
                    "stage (planar regions)",
                    "upload geometry",
                    "BVH build (obvhs)",
                    "upload BVH",
                    "AS build (BLAS+TLAS)",
                ]),
            ),
            ("render.path_trace_gpu".into(), secs(&["path trace"])),
            ("render.annotate_gpu".into(), secs(&["annotate"])),
        ];
        if req.noise.is_some() {
            self.stages
                .push(("render.noise_estimate".into(), secs(&["noise estimate"])));
        }
        self.profile = Some(profiler);
        self.samples = Some((frame.spp, frame.noise_checks.clone()));
        self.rays = frame.analytic_rays_chosen;
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
            pixel_spp: frame.pixel_spp,
        })
    }
}
