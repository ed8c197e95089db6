//! One image of a [`GpuScene`]: the camera, the light on it (a second trace level over
//! the scene's shared acceleration structure), the accumulation buffer and the
//! annotation targets. `record_batch` adds one batch of samples to a render graph.

use std::sync::Arc;

use ash::vk;
use glam::Vec3;

use super::RenderError;
use super::annotate::{Annotation, AnnotationTargets, record_annotate};
use super::cpu::{Scratch, on_render_pool};
use super::gpu_scene::GpuScene;
use super::noise::{NoiseEstimator, PixelSamples, mean_image, noise_floats_per_pixel};
use super::settings::{DirectLight, RenderSettings};
use super::tracer::PathTracer;
use crate::gpu_interface::{
    LIGHT_FACING, LIGHT_SPOT, LIGHT_UNIFORM, LightBlock, LightTri, NOISE_HALVES, NOISE_OFF,
    NOISE_SQUARES, PathParams, PathPush, PathTraceBinding as B, TILE, TileBlock,
};
use crate::graph::Graph;
use crate::scene::Camera;
use crate::scene::assemble::{EmitterSampling, LightGeometry, ViewSetup};
use crate::scene::light_cover::{LightCover, light_cover, ring_room, seen_box};
use crate::scene::lights::MM2_PER_M2;
use crate::trace::{TraceScene, TriangleSoup, scramble_multiplier};
use crate::vk::{Buffer, ComputePipeline, MemoryKind, Profiler, timed};

/// The image's tiles and how many dispatches cover them (a device allows only so many
/// workgroups per dispatch: 65,535 on lavapipe).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tiling {
    pub tiles_x: u32,
    pub tiles: u32,
    pub mult: u32,
    pub max_groups: u32,
}

impl Tiling {
    pub fn new(width: u32, height: u32, max_groups: u32) -> Tiling {
        let tiles_x = width.div_ceil(TILE);
        let tiles = tiles_x * height.div_ceil(TILE);
        Tiling {
            tiles_x,
            tiles,
            mult: scramble_multiplier(tiles),
            max_groups: max_groups.max(1),
        }
    }

    /// (tile block, workgroup count) of each dispatch, in order.
    pub fn dispatches(&self) -> impl Iterator<Item = (TileBlock, u32)> + '_ {
        group_chunks(self.tiles, self.max_groups).map(|(base, count)| {
            let block = TileBlock {
                tiles_x: self.tiles_x,
                mult: self.mult,
                group_base: base,
                tile_count: self.tiles,
            };
            (block, count)
        })
    }
}

/// `groups` workgroups cut into dispatches of at most `max_groups`: (first group,
/// count) of each, in order.
fn group_chunks(groups: u32, max_groups: u32) -> impl Iterator<Item = (u32, u32)> {
    let max = max_groups.max(1);
    (0..groups)
        .step_by(max as usize)
        .map(move |base| (base, max.min(groups - base)))
}

/// The path tracer's address table (`PathTraceBinding::Addresses`): per binding, in
/// binding order, the device address of the buffer given for it (a u64, the shader's
/// uvec2, as TraceScene's table), zero for the bindings not given (those the shader
/// reads as storage or texel buffers).
fn address_table(buffers: &[(B, &Buffer)]) -> Vec<vk::DeviceAddress> {
    let mut table = vec![0; B::COUNT];
    for &(binding, buffer) in buffers {
        table[binding as usize] = buffer.device_address();
    }
    table
}

/// The camera as the shaders take it.
pub fn camera_block(cam: &Camera) -> crate::gpu_interface::CameraBlock {
    crate::gpu_interface::CameraBlock {
        eye: cam.eye.extend(cam.lens_radius_mm).into(),
        right: (cam.right * cam.tan_half_w).extend(0.0).into(),
        up: (cam.up * cam.tan_half_h).extend(0.0).into(),
        forward: cam.forward.extend(cam.focus_distance_mm).into(),
        // w: the sampler kind of the thin-lens annotation, set by the caller.
        centre: [cam.principal.x, cam.principal.y, cam.distortion.k3, 0.0],
        dist: [
            cam.distortion.k1,
            cam.distortion.k2,
            cam.distortion.p1,
            cam.distortion.p2,
        ],
    }
}

/// What [`View::read_sums`] reads: the radiance sums, the noise estimate's, the rays'.
pub type ViewSums = (Scratch<f32>, Option<Scratch<f32>>, Option<Vec<f32>>);

/// A view being rendered.
pub struct View<'s> {
    scene: &'s GpuScene,
    trace: TraceScene,
    lights: Buffer,
    /// Per light triangle, what the facing sampler's weight takes ([`light_tri_blocks`]).
    light_weights: Buffer,
    emitters: Buffer,
    params: Buffer,
    /// What `params` holds ([`View::set_extra_rays`] changes it between batches).
    params_block: PathParams,
    /// The path-tracing pipeline for these parameters (`PathTracer::path_pipeline`:
    /// specialized for them where `[render] specialize`).
    path: Arc<ComputePipeline>,
    accum: Buffer,
    /// The per-pixel sums of the noise estimate when the view estimates its noise
    /// (`variance`), else one float the shader never writes.
    noise_sums: Buffer,
    /// The noise estimate's floats a pixel (None: the view keeps no noise sums); with
    /// `params_block.cv_ray_sums` the buffer holds two more a pixel after them.
    variance: Option<usize>,
    /// Whether `path` is specialized for `params_block` (`[render] specialize`).
    specialize: bool,
    /// Whether `path` is the variant with split paths (`[render] split_paths`).
    split_paths: bool,
    annotation: Option<(AnnotationTargets, u32)>,
    /// The path tracer's first batch labels the pixels from its own samples
    /// (`[render] labels`, [`LabelSource::from_samples`]) instead of the annotation pass.
    labels_from_samples: bool,
    /// One-word stand-ins for the path tracer's label targets when it does not label
    /// (a binding may not be empty; the shader never writes them).
    label_placeholders: (Buffer, Buffer),
    /// The pixels the next batches sample ([`View::set_pixels`], `[render]
    /// adaptive_radius`) and how many; (a one-word placeholder, 0): the whole image.
    pixel_list: (Buffer, u32),
    camera: Camera,
    tiling: Tiling,
    /// (sampler kind, seed) of the path tracer, which the thin-lens annotation follows.
    sampling: (u32, u32),
    /// The device addresses the path tracer reads the scene's buffers through
    /// (`PathTraceBinding::Addresses`, [`address_table`]).
    addresses: Buffer,
}

impl<'s> View<'s> {
    /// Sets up `setup` on `scene`; `annotate_grid`: also label the image, with this many
    /// coverage rays per pixel side.
    pub fn new(
        tracer: &PathTracer,
        scene: &'s GpuScene,
        setup: &ViewSetup,
        settings: &RenderSettings,
        annotate_grid: Option<u32>,
        profiler: Option<&Profiler>,
    ) -> Result<View<'s>, RenderError> {
        Self::with_variance(
            tracer,
            scene,
            setup,
            settings,
            annotate_grid,
            None,
            false,
            profiler,
        )
    }

    /// [`View::new`]; with `variance` the path tracer also keeps that estimator's
    /// per-pixel sums ([`View::read_sums`]), the noise estimate of `[render]
    /// noise_target` (src/render/noise.rs); with `extra_ray_stats` as well, and the
    /// analytic direct light with extra camera rays, also the spread of their closed
    /// forms' mean ([`View::read_sums`]' third part, `[render] analytic_rays_max`). Without them,
    /// nothing changes.
    #[allow(clippy::too_many_arguments)]
    pub fn with_variance(
        tracer: &PathTracer,
        scene: &'s GpuScene,
        setup: &ViewSetup,
        settings: &RenderSettings,
        annotate_grid: Option<u32>,
        variance: Option<NoiseEstimator>,
        extra_ray_stats: bool,
        profiler: Option<&Profiler>,
    ) -> Result<View<'s>, RenderError> {
        let ctx = &tracer.ctx;
        let cam = &setup.camera;
        let (width, height) = (cam.width, cam.height);
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let light = &setup.light;
        let trace = TraceScene::layered(ctx, scene.geometry.clone(), &light.tris, profiler)?;
        let light_words = light_words(light);
        let mut blocks = light_blocks(light);
        let emitting = light.selection().iter().any(|&p| p > 0.0);
        if blocks.is_empty() {
            blocks.push(LightBlock::default()); // a binding may not be empty; never read
        }
        if !scene.maps_support(settings.texture_filter) {
            return Err(RenderError::Slope(super::slope::SlopeError::Invalid {
                region: 0,
                message: "texture_filter = \"lean\" needs the maps' moment pyramids: upload them with GpuScene::set_face_maps_filtered".into(),
            }));
        }
        let cover = if settings.light_shortcuts {
            timed(profiler, "light cover", || {
                let grid = scene.geometry.bounds.and_then(|b| seen_box(cam, b));
                on_render_pool(|| light_cover(&light.tris, grid))
            })
        } else {
            LightCover::none(light.tris.triangles.len())
        };
        let mut params = path_params(scene, cam, light, settings);
        params.cover_lo = cover.lo.extend(0.0).into();
        params.cover_cell = cover.cell.extend(0.0).into();
        if !emitting {
            params.emitter_count = 0;
        }
        params.noise_sums = match variance {
            None => NOISE_OFF,
            Some(NoiseEstimator::Samples) => NOISE_SQUARES,
            Some(NoiseEstimator::Halves) => NOISE_HALVES,
        };
        let annotation = match annotate_grid {
            Some(grid) => Some((AnnotationTargets::new(ctx, width, height)?, grid)),
            None => None,
        };
        let labels_from_samples =
            annotate_grid.is_some_and(|_| settings.labels.from_samples(cam.lens_radius_mm > 0.0));
        let placeholder = |name| Buffer::new(ctx, name, 4, storage, MemoryKind::Device);
        let label_placeholders = (
            placeholder("label ids (unused)")?,
            placeholder("label coverage (unused)")?,
        );
        let usage = storage | vk::BufferUsageFlags::TRANSFER_DST;
        let n = width as u64 * height as u64;
        let lights = Buffer::from_slice(ctx, "lights", &light_words, storage)?;
        let emitters = Buffer::from_slice(ctx, "light list", &blocks, storage)?;
        let light_weights = Buffer::from_slice(
            ctx,
            "light triangle weights",
            &light_tri_words(&light_tri_blocks(&light.tris, &cover), &cover),
            storage,
        )?;
        let (_, texels) = scene.map_buffers();
        let moments = scene.moment_buffers();
        let table = address_table(&[
            (B::Geometry, trace.shade_tris()),
            (B::Materials, &scene.materials),
            (B::Lights, &lights),
            (B::Energy, &tracer.energy),
            (B::Slopes0, texels[0]),
            (B::Slopes1, texels[1]),
            (B::Slopes2, texels[2]),
            (B::LightGeometry, trace.second_shade_tris()),
            (B::Surfaces, &scene.surfaces),
            (B::CurvedMaps, scene.curved_buffer()),
            (B::Moments0, moments[0]),
            (B::Moments1, moments[1]),
            (B::Moments2, moments[2]),
            (B::LabelWords, &scene.labels),
            (B::LightWeights, &light_weights),
        ]);
        let addresses = Buffer::from_slice(ctx, "path tracer addresses", &table, storage)?;
        // `[render] analytic_rays_max`: the rays' mean's sums, in two more floats a pixel.
        let ray_sums = variance.is_some()
            && extra_ray_stats
            && params.direct_light == DirectLight::Analytic as u32
            && params.cv_extra_rays > 0;
        params.cv_ray_sums = ray_sums as u32;
        let split_paths = settings.split_paths && settings.bsdf_samples > 1;
        let path = tracer.path_pipeline(&params, settings.specialize, split_paths)?;
        Ok(View {
            scene,
            trace,
            lights,
            light_weights,
            emitters,
            addresses,
            params: Buffer::from_slice(ctx, "path params", &[params], storage)?,
            params_block: params,
            specialize: settings.specialize,
            split_paths,
            path,
            accum: Buffer::new(ctx, "radiance sum", n * 4, usage, MemoryKind::Readback)?,
            noise_sums: {
                // Without `variance` one float: a binding may not be empty, and the shader
                // never writes it (NOISE_OFF).
                let (name, bytes) = match variance {
                    Some(e) => (
                        "noise sums",
                        n * 4 * (noise_floats_per_pixel(e) + 2 * ray_sums as usize) as u64,
                    ),
                    None => ("noise sums (unused)", 4),
                };
                Buffer::new(ctx, name, bytes, usage, MemoryKind::Readback)?
            },
            variance: variance.map(noise_floats_per_pixel),
            annotation,
            labels_from_samples,
            label_placeholders,
            pixel_list: (placeholder("pixel list (unused)")?, 0),
            camera: *cam,
            tiling: Tiling::new(width, height, ctx.info.max_workgroup_count[0]),
            sampling: (settings.sampler as u32, settings.seed),
        })
    }

    /// Whether the annotation comes from the path tracer's own samples (`[render]
    /// labels`) rather than the annotation pass; false without an annotation.
    pub fn labels_from_samples(&self) -> bool {
        self.labels_from_samples
    }

    /// From the next batch on, sample only `pixels` (indices y * width + x, in the order
    /// given: TILE x TILE consecutive ones make a workgroup, so neighbours should follow
    /// each other); every pixel of the image again when `pixels` is None. A batch after
    /// the first must give every listed pixel the same samples so far (the list only
    /// shrinks: `[render] adaptive_radius`).
    pub fn set_pixels(
        &mut self,
        tracer: &PathTracer,
        pixels: Option<&[u32]>,
    ) -> Result<(), RenderError> {
        let (ctx, storage) = (&tracer.ctx, vk::BufferUsageFlags::STORAGE_BUFFER);
        self.pixel_list = match pixels {
            Some(list) if !list.is_empty() => (
                Buffer::from_slice(ctx, "pixel list", list, storage)?,
                list.len() as u32,
            ),
            // An empty list samples nothing: the caller stops instead.
            _ => (
                Buffer::new(ctx, "pixel list (unused)", 4, storage, MemoryKind::Device)?,
                0,
            ),
        };
        Ok(())
    }

    /// Adds samples `start .. start + count` to `g` (of the pixels of
    /// [`View::set_pixels`]; the first batch must be of the whole image); the first batch
    /// (start 0) clears the accumulation and labels the pixels: from its own first n x n
    /// samples when the view labels from samples (those past `count` traced for their
    /// labels alone), else by the annotation pass.
    pub fn record_batch<'a>(
        &'a self,
        tracer: &'a PathTracer,
        g: &mut Graph<'a>,
        start: u32,
        count: u32,
    ) {
        let off = tracer.backend_bindings();
        let refs = self.trace.import(g);
        let (headers, texels) = self.scene.map_buffers();
        let geo = g.import(self.trace.shade_tris());
        let ltris = g.import(self.trace.second_shade_tris());
        let mats = g.import(&self.scene.materials);
        let surf = g.import(&self.scene.surfaces);
        let curved = g.import(self.scene.curved_buffer());
        let lts = g.import(&self.lights);
        let ems = g.import(&self.emitters);
        let en = g.import(&tracer.energy);
        let pr = g.import(&self.params);
        let mut acc = g.import(&self.accum);
        let mut noise = g.import(&self.noise_sums);
        let mh = g.import(headers);
        let [ma, mb, mc] = texels.map(|b| g.import(b));
        let moments = self.scene.moment_buffers();
        let [m0, m1, m2] = moments.map(|b| g.import(b));
        let labels = g.import(&self.scene.labels);
        // n: the path tracer labels from its first n x n samples (0: it does not), into
        // `targets`.
        let mut label_grid = 0u32;
        let mut targets = None;
        if start == 0 {
            g.fill("clear radiance", &mut acc, 0);
            if self.variance.is_some() {
                g.fill("clear noise sums", &mut noise, 0);
            }
            if let Some((t, grid)) = &self.annotation {
                let n = (*grid).clamp(1, 16);
                let (mut ids, mut cov) = (g.import(&t.ids), g.import(&t.coverage));
                if self.labels_from_samples {
                    label_grid = n;
                    targets = Some((ids, cov));
                } else {
                    let size = (self.camera.width, self.camera.height);
                    let cam = camera_block(&self.camera);
                    let sampling = (self.sampling.0, self.sampling.1);
                    record_annotate(
                        g,
                        &tracer.annotate,
                        &refs,
                        off,
                        &labels,
                        (&mut ids, &mut cov),
                        &cam,
                        size,
                        *grid,
                        &self.tiling,
                        sampling,
                    );
                }
            }
        }
        let (mut ids, mut cov) = targets.unwrap_or_else(|| {
            (
                g.import(&self.label_placeholders.0),
                g.import(&self.label_placeholders.1),
            )
        });
        let list = g.import(&self.pixel_list.0);
        let addr = g.import(&self.addresses);
        let weights = g.import(&self.light_weights);
        let pixel_count = if start == 0 { 0 } else { self.pixel_list.1 };
        let dispatches: Vec<(TileBlock, u32)> = if pixel_count == 0 {
            self.tiling.dispatches().collect()
        } else {
            list_dispatches(pixel_count, self.tiling.max_groups)
        };
        for (tiles, groups) in dispatches {
            let push = PathPush {
                sample_start: start,
                sample_count: count,
                labels: label_grid,
                pixel_count,
                tiles,
            };
            refs.bind(g.dispatch("path trace", &self.path, [groups, 1, 1]))
                .read(B::Geometry.at(off), &geo)
                .read(B::Materials.at(off), &mats)
                .read(B::Lights.at(off), &lts)
                .read(B::Energy.at(off), &en)
                .read(B::Params.at(off), &pr)
                .read_write(B::Accum.at(off), &mut acc)
                .read(B::MapHeaders.at(off), &mh)
                .read(B::Slopes0.at(off), &ma)
                .read(B::Slopes1.at(off), &mb)
                .read(B::Slopes2.at(off), &mc)
                .read(B::LightGeometry.at(off), &ltris)
                .read(B::LightList.at(off), &ems)
                .read(B::Surfaces.at(off), &surf)
                .read(B::CurvedMaps.at(off), &curved)
                .read(B::Moments0.at(off), &m0)
                .read(B::Moments1.at(off), &m1)
                .read(B::Moments2.at(off), &m2)
                .read_write(B::NoiseSums.at(off), &mut noise)
                .read(B::LabelWords.at(off), &labels)
                .write(B::LabelIds.at(off), &mut ids)
                .write(B::LabelCoverage.at(off), &mut cov)
                .read(B::PixelList.at(off), &list)
                .read(B::LightWeights.at(off), &weights)
                .read(B::Addresses.at(off), &addr)
                .push(&push)
                .submit();
        }
    }

    /// The per-pixel sums so far: radiance; the noise estimate's when the view was made
    /// `with_variance` (else None); and, split off the same read, the rays' sums where
    /// the view keeps them (made `with_variance` and `extra_ray_stats`, the analytic
    /// direct light with extra rays, and no [`View::set_extra_rays`] since; else None):
    /// per pixel the sums over its samples of each sample's mean of its camera rays'
    /// closed forms and of its square, pixel i's at 2 i and 2 i + 1.
    pub fn read_sums(&self) -> Result<ViewSums, RenderError> {
        let mut sum = Scratch::empty();
        self.accum.read_into(&mut sum)?;
        let Some(floats) = self.variance else {
            return Ok((sum, None, None));
        };
        let mut sq = Scratch::empty();
        self.noise_sums.read_into(&mut sq)?;
        let n = sum.len();
        let rays =
            (self.params_block.cv_ray_sums != 0).then(|| sq[floats * n..(floats + 2) * n].to_vec());
        sq.truncate(floats * n);
        Ok((sum, Some(sq), rays))
    }

    /// The extra camera rays a sample takes for the control variate's closed form
    /// (`[render] analytic_rays` - 1; 0 without the analytic direct light).
    pub fn extra_rays(&self) -> u32 {
        if self.params_block.direct_light == DirectLight::Analytic as u32 {
            self.params_block.cv_extra_rays
        } else {
            0
        }
    }

    /// From the next batch on, each sample takes `extra` extra camera rays (`[render]
    /// analytic_rays_max`'s choice), from a sequence of their own (another seed: the
    /// points the rays before took are not taken again), and the rays' sums are no
    /// longer kept. Samples stay unbiased whatever their count; with `[render]
    /// specialize` the pipeline is the one made for the new count. The count the view
    /// has keeps its rays' sequence (the samples those rays would take anyway) and only
    /// stops keeping the sums.
    pub fn set_extra_rays(&mut self, tracer: &PathTracer, extra: u32) -> Result<(), RenderError> {
        let mut p = self.params_block;
        if p.cv_extra_rays == extra && p.cv_ray_sums == 0 {
            return Ok(());
        }
        if p.cv_extra_rays != extra {
            p.cv_extra_rays = extra;
            p.cv_seed = extra_ray_seed(p.seed, Some(extra));
        }
        p.cv_ray_sums = 0;
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
        self.params = Buffer::from_slice(&tracer.ctx, "path params", &[p], storage)?;
        if self.specialize {
            self.path = tracer.path_pipeline(&p, true, self.split_paths)?;
        }
        self.params_block = p;
        Ok(())
    }

    /// The annotation so far (complete after the first batch); None if not asked for.
    pub fn read_annotation(&self) -> Result<Option<Annotation>, RenderError> {
        match &self.annotation {
            Some((targets, _)) => Ok(Some(targets.read()?)),
            None => Ok(None),
        }
    }

    /// Mean radiance per pixel after `spp` samples (each pixel's own with
    /// [`PixelSamples::Each`]), and the annotation if asked for.
    pub fn read<'a>(
        &self,
        spp: impl Into<PixelSamples<'a>>,
    ) -> Result<(Vec<f32>, Option<Annotation>), RenderError> {
        let sum: Vec<f32> = self.accum.read()?;
        let spp = spp.into();
        let mean = on_render_pool(|| mean_image(&sum, spp));
        Ok((mean, self.read_annotation()?))
    }
}

/// The pixels of a `width` x `height` image tile by tile (TILE x TILE, rows of tiles),
/// row by row within a tile, as y * width + x: the order of a pixel list
/// ([`View::set_pixels`]) that keeps a workgroup's pixels together.
pub fn tile_order(width: u32, height: u32) -> Vec<u32> {
    let mut order = Vec::with_capacity((width * height) as usize);
    for ty in (0..height).step_by(TILE as usize) {
        for tx in (0..width).step_by(TILE as usize) {
            for y in ty..(ty + TILE).min(height) {
                for x in tx..(tx + TILE).min(width) {
                    order.push(y * width + x);
                }
            }
        }
    }
    order
}

/// (block, workgroup count) of each dispatch over a pixel list of `pixels` entries,
/// TILE x TILE a workgroup, at most `max_groups` workgroups a dispatch.
fn list_dispatches(pixels: u32, max_groups: u32) -> Vec<(TileBlock, u32)> {
    group_chunks(pixels.div_ceil(TILE * TILE), max_groups)
        .map(|(base, count)| {
            let block = TileBlock {
                group_base: base,
                ..Default::default()
            };
            (block, count)
        })
        .collect()
}

/// The path tracer's parameter block for one view.
fn path_params(
    scene: &GpuScene,
    cam: &Camera,
    light: &LightGeometry,
    s: &RenderSettings,
) -> PathParams {
    let m = &s.material;
    let fresnel = super::bsdf::Fresnel::Conductor {
        n: m.ior_n,
        k: m.ior_k,
    };
    let (lights_lo, lights_hi) = lights_box(light);
    PathParams {
        cam: camera_block(cam),
        width: cam.width,
        height: cam.height,
        max_bounces: s.max_bounces,
        seed: s.seed,
        alpha: m.alpha,
        ior_n: m.ior_n,
        ior_k: m.ior_k,
        f_avg: fresnel.average(),
        comp: m.energy_compensation as u32,
        light_count: light.lights.len() as u32,
        sample_gen: s.sampler as u32,
        emitter_count: light.emitters.len() as u32,
        table_albedo: scene.table_albedo,
        light_first: scene.triangle_count,
        texture_filter: s.texture_filter as u32,
        pixel_angle: pixel_angle(cam),
        filter_scale: s.texture_filter_scale,
        direct_light: s.direct_light as u32,
        cv_extra_rays: s.analytic_rays.max(1) - 1,
        light_samples: s.light_samples.max(1),
        bsdf_samples: s.bsdf_samples.max(1),
        shortcuts: s.light_shortcuts as u32,
        lights_lo,
        lights_hi,
        table: scene.table,
        cv_seed: extra_ray_seed(s.seed, None),
        ..Default::default()
    }
}

/// The seed of the extra camera rays' sequence (`PathParams::cv_seed`): the render's
/// seed with a fixed pattern, and after [`View::set_extra_rays`] (`changed`: the new
/// count) another one for each count.
fn extra_ray_seed(seed: u32, changed: Option<u32>) -> u32 {
    let base = seed ^ 0x5ca1_ab1e;
    match changed {
        None => base,
        Some(extra) => base ^ (extra + 1).wrapping_mul(0x9e37_79b9),
    }
}

/// The shadow bundle's light box (`PathParams::lights_lo`, `lights_hi`): the bounds of
/// every light triangle's corners and spot position, widened by 1e-4 of the largest
/// coordinate plus 1e-3 mm (a shadow ray's end is computed as o + t d, a few ulps off
/// the light); w 1. All zero (no bundle) without lights.
fn lights_box(light: &LightGeometry) -> ([f32; 4], [f32; 4]) {
    let spots = light.emitters.iter().filter_map(|e| match e.sampling {
        EmitterSampling::Spot { position, .. } => Some(position),
        _ => None,
    });
    let corners = light
        .tris
        .triangles
        .iter()
        .flatten()
        .map(|&i| light.tris.positions[i as usize]);
    let (lo, hi) = corners.chain(spots).fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(p), hi.max(p)),
    );
    if lo.x > hi.x {
        return ([0.0; 4], [0.0; 4]);
    }
    let m = 1e-4 * lo.abs().max(hi.abs()).max_element() + 1e-3;
    ((lo - m).extend(1.0).into(), (hi + m).extend(1.0).into())
}

/// The pixel cone's angle (rad): the square root of the centre pixel's solid angle,
/// sqrt((2 tan(fov_w / 2) / width) (2 tan(fov_h / 2) / height)).
pub fn pixel_angle(cam: &Camera) -> f32 {
    (4.0 * cam.tan_half_w * cam.tan_half_h / (cam.width as f32 * cam.height as f32)).sqrt()
}

/// Per light triangle (`LightGeometry::tris`, in the order the shader numbers them from
/// `first`): its centroid, twice its area and its unit normal (`LightTri`), what
/// glsl/common/lights.glsl `light_weight` takes, and its cover: the mask, and where its
/// hider list starts (in 32-bit words from the blocks' start: after all the blocks, in
/// the order of the triangles, as `light_tri_words` lays them out) and how long it is;
/// one zero block when there is none (a binding may not be empty; never read).
fn light_tri_blocks(tris: &TriangleSoup, cover: &LightCover) -> Vec<LightTri> {
    let p = &tris.positions;
    let words = tris.triangles.len() * (std::mem::size_of::<LightTri>() / 4);
    let mut next = words as u32;
    let mut blocks: Vec<LightTri> = tris
        .triangles
        .iter()
        .zip(&cover.masks)
        .zip(&cover.hiders)
        .map(|((t, &mask), hiders)| {
            let count = hiders.len() as u32;
            let at = next;
            next += count;
            let [a, b, c] = t.map(|i| p[i as usize]);
            let n = (b - a).cross(c - a);
            let area2 = n.length();
            let unit = if area2 > 0.0 { n / area2 } else { n * 0.0 };
            LightTri {
                center: ((a + b + c) * (1.0 / 3.0)).extend(area2).into(),
                normal: unit.extend(0.0).into(),
                cover: [mask, at, count, 0],
            }
        })
        .collect();
    if blocks.is_empty() {
        blocks.push(LightTri::default());
    }
    blocks
}

/// The light triangles' buffer: `blocks` as 32-bit words, then each triangle's hider
/// list (`LightCover::hiders`, indices in the light's list) in order.
fn light_tri_words(blocks: &[LightTri], cover: &LightCover) -> Vec<u32> {
    let mut words: Vec<u32> = bytemuck::cast_slice(blocks).to_vec();
    words.extend(cover.hiders.iter().flatten());
    words
}

/// Per light triangle (`LightGeometry::lights`' order) what glsl/common/lights.glsl
/// reads as `LIGHT_TRI_WORDS`: its emitter, the float bits of its inclusive area CDF
/// within the emitter, and the guide entry of the emitter's bucket of that index
/// ([`area_guide`]: where `pick_area_tri` searches); one zero entry when there is no
/// light triangle (a binding may not be empty; never read).
fn light_words(light: &LightGeometry) -> Vec<[u32; 4]> {
    let mut words: Vec<[u32; 4]> = light
        .lights
        .iter()
        .zip(&light.owner)
        .map(|(&(_, c), &e)| [e, c.to_bits(), 0, 0])
        .collect();
    for e in &light.emitters {
        let range = e.tri_range();
        let cdf: Vec<f32> = light.lights[range.clone()]
            .iter()
            .map(|&(_, c)| c)
            .collect();
        for (w, g) in words[range].iter_mut().zip(area_guide(&cdf)) {
            w[2] = g[0];
            w[3] = g[1];
        }
    }
    if words.is_empty() {
        words.push([0; 4]);
    }
    words
}

/// The triangle an area light's CDF gives u (glsl/common/lights.glsl `pick_area_tri`):
/// the first whose inclusive CDF exceeds u, else the last (the CDF does not decrease).
fn pick_by_cdf(cdf: &[f32], u: f32) -> u32 {
    cdf.partition_point(|&c| c <= u).min(cdf.len() - 1) as u32
}

/// The bucket of u among n equal parts of [0, 1), as the shader computes it in f32:
/// `min(uint(u * float(n)), n - 1)`.
fn guide_bucket(u: f32, n: u32) -> u32 {
    ((u * n as f32) as u32).min(n - 1)
}

/// A guide table for choosing a triangle by an area light's CDF (the cutpoint method,
/// Chen and Asau 1974): for each of n = cdf.len() buckets of u, the first and last
/// triangle [`pick_by_cdf`] gives for a u in it. Both are exact: the bucket's u values
/// are a run of consecutive floats (u * n rounds monotonically), found by bisecting the
/// float bits, and the triangle chosen does not decrease with u, so searching that range
/// gives the triangle a search of all of them gives, for every u in [0, 1).
fn area_guide(cdf: &[f32]) -> Vec<[u32; 2]> {
    if cdf.is_empty() {
        return Vec::new(); // a spot: no triangles, no buckets
    }
    let n = cdf.len() as u32;
    let one = 1.0f32.to_bits();
    // The bits of the least u in [0, 1) whose bucket is at least j (`one` if none).
    let first_of = |j: u32| {
        let (mut lo, mut hi) = (0u32, one);
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            if guide_bucket(f32::from_bits(mid), n) >= j {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        lo
    };
    let mut start = 0; // u = 0 is in bucket 0
    (0..n)
        .map(|j| {
            let next = first_of(j + 1);
            let guide = if start < next {
                let lo = pick_by_cdf(cdf, f32::from_bits(start));
                let hi = pick_by_cdf(cdf, f32::from_bits(next - 1));
                [lo, hi]
            } else {
                [0, n - 1] // no u falls in this bucket: never read, the whole range
            };
            start = next;
            guide
        })
        .collect()
}

/// The lights as the shader takes them (glsl/common/lights.glsl). When no light emits,
/// `View::new` turns next-event estimation off (as it always was for zero radiance).
fn light_blocks(light: &LightGeometry) -> Vec<LightBlock> {
    let sel = light.selection();
    // Inclusive CDF; from the last light that can be chosen on, exactly 1.
    let last = sel.iter().rposition(|&p| p > 0.0).unwrap_or(0);
    let mut acc = 0.0f64;
    light
        .emitters
        .iter()
        .zip(&sel)
        .enumerate()
        .map(|(i, (e, &p))| {
            acc += p;
            let cdf = if i >= last { 1.0 } else { acc as f32 };
            let (kind, segments) = match e.sampling {
                EmitterSampling::Uniform => (LIGHT_UNIFORM, 0),
                EmitterSampling::Facing([segments, per]) if segments * per == e.tri_count => {
                    (LIGHT_FACING, segments)
                }
                // Not one ring of equal segments: uniform by area.
                EmitterSampling::Facing(_) => (LIGHT_UNIFORM, 0),
                EmitterSampling::Spot { .. } => (LIGHT_SPOT, 0),
            };
            let (pos, dir, emit_x) = match e.sampling {
                EmitterSampling::Spot {
                    position,
                    axis,
                    intensity_w_sr,
                    cos_edge,
                    cos_inner,
                } => (
                    position.extend(cos_edge).into(),
                    axis.extend(cos_inner).into(),
                    (intensity_w_sr as f64 * MM2_PER_M2) as f32,
                ),
                _ => match (e.torus, e.reach) {
                    // A ring: its torus (analytic_light.glsl).
                    (Some(t), _) => (
                        t.centre.extend(t.major_mm).into(),
                        t.axis.extend(t.minor_mm).into(),
                        e.radiance,
                    ),
                    (None, Some(r)) => (r.centre.extend(0.0).into(), [0.0; 4], e.radiance),
                    (None, None) => ([0.0; 4], [0.0; 4], e.radiance),
                },
            };
            // A ring's segments around the ring (0: not a ring).
            let ring = e.torus.map_or(0.0, |t| t.segments_major as f32);
            let room = e.torus.map_or([0.0, 0.0], |t| {
                let tris: Vec<[Vec3; 3]> = light.tris.triangles[e.tri_range()]
                    .iter()
                    .map(|t| t.map(|i| light.tris.positions[i as usize]))
                    .collect();
                ring_room(&tris, t.centre, t.axis)
            });
            let reach = e.reach.map_or([0.0, -1.0, 0.0, 0.0], |r| {
                [r.inner, r.outer, room[0], room[1]]
            });
            LightBlock {
                pos,
                dir,
                emit: [emit_x, e.area, ring, cdf],
                shape: [e.first_tri, e.tri_count, kind, segments],
                reach,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// The guide table's range for u's bucket always holds the triangle a search of the
    /// whole CDF gives: checked at every bucket's edges (the floats on both sides of
    /// each j / n) and at random u, for areas from equal to wildly unequal, with runs of
    /// zero-area triangles (a flat CDF) and a single triangle.
    #[test]
    fn the_area_guide_brackets_the_full_search() {
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        let lights: Vec<Vec<f32>> = vec![
            vec![1.0],
            vec![1.0; 7],
            (0..3072).map(|i| 1.0 + (i % 48) as f32 / 10.0).collect(),
            (0..500)
                .map(|i| if i % 5 == 0 { 0.0 } else { (i * i) as f32 })
                .collect(),
            (0..257).map(|_| ((next() % 1000) as f32).powi(3)).collect(),
        ];
        for areas in lights {
            let total: f64 = areas.iter().map(|&a| a as f64).sum();
            let mut acc = 0.0f64;
            let cdf: Vec<f32> = areas
                .iter()
                .enumerate()
                .map(|(i, &a)| {
                    acc += a as f64;
                    if i + 1 == areas.len() {
                        1.0
                    } else {
                        (acc / total) as f32
                    }
                })
                .collect();
            let n = cdf.len() as u32;
            let guide = area_guide(&cdf);
            assert_eq!(guide.len(), cdf.len());
            let check = |u: f32| {
                let want = pick_by_cdf(&cdf, u);
                let [lo, hi] = guide[guide_bucket(u, n) as usize];
                assert!(
                    lo <= want && want <= hi,
                    "u {u}: {want} outside [{lo}, {hi}] ({n} triangles)"
                );
                // The shader's search within the range.
                let (mut a, mut b) = (lo, hi);
                while a < b {
                    let mid = (a + b) / 2;
                    if u < cdf[mid as usize] {
                        b = mid
                    } else {
                        a = mid + 1
                    }
                }
                assert_eq!(a, want, "u {u}");
            };
            for j in 0..=n {
                let edge = j as f32 / n as f32;
                let mut u = edge;
                for _ in 0..3 {
                    u = f32::from_bits(u.to_bits().saturating_sub(1));
                }
                for _ in 0..7 {
                    if (0.0..1.0).contains(&u) {
                        check(u);
                    }
                    u = f32::from_bits(u.to_bits() + 1);
                }
            }
            for &c in &cdf {
                for u in [c, f32::from_bits(c.to_bits().saturating_sub(1))] {
                    if (0.0..1.0).contains(&u) {
                        check(u);
                    }
                }
            }
            for _ in 0..20_000 {
                check((next() >> 40) as f32 / (1u64 << 24) as f32);
            }
            check(0.0);
            check(f32::from_bits(1.0f32.to_bits() - 1));
        }
        assert!(area_guide(&[]).is_empty());
    }

    /// The facing sampler's per-triangle data: the corners' mean, twice the area and the
    /// unit normal of cross(b - a, c - a); a degenerate triangle weighs nothing (zero
    /// area, zero normal), and no triangle still gives the one block a binding needs.
    #[test]
    fn light_tri_blocks_hold_centroid_area_and_normal() {
        let tris = TriangleSoup {
            positions: vec![
                Vec3::new(0.0, 0.0, 1.0),
                Vec3::new(2.0, 0.0, 1.0),
                Vec3::new(0.0, 3.0, 1.0),
                Vec3::new(4.0, 0.0, 1.0),
            ],
            triangles: vec![[0, 1, 2], [0, 1, 3]],
        };
        let cover = LightCover {
            masks: vec![5, 0],
            hiders: vec![vec![1, 7], vec![3]],
            ..LightCover::none(2)
        };
        let b = light_tri_blocks(&tris, &cover);
        // The hider lists after both 12-word blocks: words 24 and 25, then 26.
        assert_eq!(b[1].cover, [0, 26, 1, 0]);
        let w = light_tri_words(&b, &cover);
        assert_eq!(w.len(), 27);
        assert_eq!(&w[24..], &[1, 7, 3]);
        assert_eq!(b.len(), 2);
        let want = [2.0 / 3.0, 1.0, 1.0, 6.0];
        for (got, want) in b[0].center.iter().zip(want) {
            assert!((got - want).abs() < 1e-6, "{:?}", b[0].center);
        }
        assert_eq!(b[0].normal, [0.0, 0.0, 1.0, 0.0]);
        assert_eq!(b[1].center[3], 0.0);
        assert_eq!(b[1].normal, [0.0; 4]);
        let none = TriangleSoup {
            positions: vec![],
            triangles: vec![],
        };
        assert_eq!(b[0].cover, [5, 24, 2, 0]);
        assert_eq!(
            light_tri_blocks(&none, &LightCover::none(0)),
            vec![LightTri::default()]
        );
    }
}
