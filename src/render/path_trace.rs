//! The path-traced inspection image (glsl/path_trace.comp): `render_frame` composes the
//! three lifetimes of the render layer, a [`PathTracer`] per device, a [`GpuScene`] per
//! mesh and a [`View`] per image, and runs the view's batches of samples.

use std::sync::Arc;

use super::annotate::Annotation;
use super::cpu::{Scratch, on_render_pool};
use super::energy::EnergyTables;
use super::gpu_scene::GpuScene;
use super::noise::{
    CheckedImage, NoiseEstimate, NoiseEstimator, NoiseStop, PixelSamples, RayCheck,
    next_power_of_two_above,
};
use super::settings::RenderSettings;
use super::tracer::PathTracer;
use super::view::{View, tile_order};
use crate::graph::Graph;
use crate::scene::assemble::ViewSetup;
use crate::scene::mesh::is_inspected;
use crate::trace::Backend;
use crate::vk::{Context, Profiler, VkError};

pub use crate::gpu_interface::{MAT_CONDUCTOR, MAT_LIGHT, MAT_TABLE};
pub use crate::scene::assemble::{RenderScene, load_object};

/// Why a render could not be set up or run.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(transparent)]
    Assemble(#[from] crate::scene::assemble::AssembleError),
    #[error(transparent)]
    Vk(#[from] VkError),
    #[error(transparent)]
    Slope(#[from] super::slope::SlopeError),
    #[error("noise target: {0}")]
    Noise(#[from] super::sensor::SensorError),
}

/// A finished render: mean radiance per pixel (row 0 at the top) and GPU time.
pub struct Radiance {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
    pub gpu_ms: f64,
}

/// What [`render_frame`] does besides path tracing.
#[derive(Clone, Copy, Default)]
pub struct FrameOptions<'a> {
    /// Run the annotation pass too, with this many coverage rays per pixel side.
    pub annotate_grid: Option<u32>,
    pub profiler: Option<&'a Profiler>,
    /// Stop adding samples once the render noise is below the camera's by this
    /// criterion (`[render] noise_target`); `RenderSettings::spp` is then the maximum.
    /// None: exactly `spp` samples, as before.
    pub noise: Option<&'a NoiseStop>,
}

/// A rendered image and, when asked for, its annotation from the same camera rays'
/// first hits (the annotation pass in the first batch's graph, or the first batch's own
/// samples: `[render] labels`).
pub struct Frame {
    pub radiance: Radiance,
    pub annotation: Option<Annotation>,
    /// Samples per pixel rendered (`spp`, or fewer when a noise target stopped it; with
    /// `[render] adaptive_radius` the most any pixel took).
    pub spp: u32,
    /// With `[render] adaptive_radius`, each pixel's own samples when not all took
    /// `spp` (row by row); None: every pixel took `spp`.
    pub pixel_spp: Option<Vec<u32>>,
    /// The noise criterion's last estimate, at `spp` (with a noise target only).
    pub noise: Option<NoiseEstimate>,
    /// Every estimate made, in order (the last is `noise`): the error per spp.
    pub noise_checks: Vec<NoiseEstimate>,
    /// The annotation came from the path tracer's own first n x n samples (`[render]
    /// labels`), not from the annotation pass; false without an annotation.
    pub labels_from_samples: bool,
    /// `[render] analytic_rays_max`: the camera rays per sample of the analytic direct
    /// light's closed form chosen at the first noise check for the samples after it (the
    /// same count where none was clearly faster); None where no choice was made (no such
    /// setting, no extra rays, or the image stopped there).
    pub analytic_rays_chosen: Option<u32>,
}

impl Frame {
    /// Mean samples per pixel (`spp` unless adaptive).
    pub fn mean_spp(&self) -> f64 {
        PixelSamples::new(self.pixel_spp.as_deref(), self.spp).mean()
    }
}

/// Each pixel's samples (`Frame::pixel_spp`) as the 16-bit values of an spp.png, the
/// samples map `synosis render` and a dataset image write (at most 65535 shown).
pub fn spp_map(counts: &[u32]) -> Vec<u16> {
    counts.iter().map(|&c| c.min(65535) as u16).collect()
}

/// Renders one view of `scene`; `progress(done_spp)` after each batch (one graph each).
///
/// With `opts.noise`, after the batch that reaches each check (the first at `min_spp`,
/// the next where the estimate predicts the target, [`NoiseStop::next_check`]) the two
/// per-pixel sums are read back and the criterion evaluated; the render stops when it is
/// at most the target, or at `spp`. The first check is at `min_spp` exactly, later ones
/// at the end of the batch that reaches them ([`batch_before_check`]). The shader adds
/// each sample to a pixel's sums in sample order, whatever the batches, so the image
/// equals a render of the chosen spp byte for byte. The decision depends on float sums:
/// another device may stop at another batch.
///
/// With `adaptive_radius` in the criterion, each check that does not stop the render
/// also stops the pixels that have the samples their share of the target wants
/// ([`super::noise::CameraNoise::pixel_samples_wanted`]); the next batches sample only
/// the others (`View::set_pixels`), each pixel's mean over its own samples.
pub fn render_frame(
    tracer: &PathTracer,
    scene: &GpuScene,
    setup: &ViewSetup,
    settings: &RenderSettings,
    opts: FrameOptions<'_>,
    mut progress: impl FnMut(u32),
) -> Result<Frame, RenderError> {
    let mut view = View::with_variance(
        tracer,
        scene,
        setup,
        settings,
        opts.annotate_grid,
        opts.noise.map(|n| n.estimator),
        opts.noise.is_some_and(|n| n.rays.is_some()),
        opts.profiler,
    )?;
    let mut rays_chosen = None;
    let (spp, batch) = (settings.spp, settings.batch_spp.max(1));
    let (width, height) = (setup.camera.width, setup.camera.height);
    let mut done = 0u32;
    let mut gpu_ms = 0.0;
    let first_check = opts.noise.map(|n| n.first_check(spp));
    let halves = opts.noise.map(|n| n.estimator) == Some(NoiseEstimator::Halves);
    let mut next_check = first_check;
    // (exposure mask, object mask) from the annotation of the first batch.
    let mut masks: Option<(Vec<bool>, Vec<bool>)> = None;
    let mut checks: Vec<NoiseEstimate> = Vec::new();
    // `[render] adaptive_radius`: the samples each pixel stopped at (0: still sampling),
    // and the pixels still sampling in tile order (None: all of them).
    let adaptive = opts.noise.and_then(|n| n.adaptive_radius);
    let tracked = if adaptive.is_some() {
        width * height
    } else {
        0
    };
    let mut stopped = vec![0u32; tracked as usize];
    let mut sampling: Option<Vec<u32>> = None;
    while done < spp {
        let count = batch_before_check(batch, done, first_check, halves).min(spp - done);
        let timings = {
            let mut g = Graph::new(tracer.context(), "path trace");
            view.record_batch(tracer, &mut g, done, count);
            g.execute(opts.profiler)?
        };
        gpu_ms += timings
            .iter()
            .map(|t| t.gpu_ms)
            .filter(|t| t.is_finite())
            .sum::<f64>();
        done += count;
        progress(done);
        if let (Some(stop), Some(at)) = (opts.noise, next_check)
            && (done >= at || done == spp)
        {
            let counts = pixel_counts(&stopped, done);
            let samples = PixelSamples::new(counts.as_deref().map(Vec::as_slice), done);
            let (est, image, sums, ray_sums) =
                crate::vk::timed(opts.profiler, "noise estimate", || {
                    on_render_pool(|| noise_estimate(&view, stop, samples, &mut masks))
                })?;
            checks.push(est);
            if est.ratio <= stop.target_at(est.mean_spp) {
                break;
            }
            next_check = Some(stop.next_check(done, est.ratio));
            if let Some(choice) = stop.rays
                && checks.len() == 1
                && let Some(ray_sums) = ray_sums
            {
                // `[render] analytic_rays_max`: the rays for the rest of the image.
                let at = crate::vk::timed(opts.profiler, "rays chosen", || {
                    ray_check(
                        stop, &est, &image, &sums, &ray_sums, samples, batch, spp, &masks,
                    )
                });
                let m = choice.choose(view.extra_rays() + 1, &at);
                view.set_extra_rays(tracer, m - 1)?;
                rays_chosen = Some(m);
            }
            if let Some(radius) = adaptive {
                let (sum, noise) = sums;
                let object = &masks.as_ref().expect("filled by the estimate").1;
                let grown = |m: f64| stop.target_at(m);
                let (keep, fewest) = crate::vk::timed(opts.profiler, "samples wanted", || {
                    let want = on_render_pool(|| {
                        stop.camera.pixel_samples_wanted(
                            stop.estimator,
                            &sum,
                            &noise,
                            samples,
                            &image,
                            object,
                            width as usize,
                            stop.target_at(est.mean_spp),
                            (stop.growth > 0.0).then_some((&grown, est.ratio)),
                            radius,
                        )
                    });
                    // The pixels still sampling, in their order, in the list's own memory.
                    let mut keep = sampling.take().unwrap_or_else(|| tile_order(width, height));
                    keep.retain(|&i| {
                        let go_on = want[i as usize] > done as f64;
                        if !go_on {
                            stopped[i as usize] = done;
                        }
                        go_on
                    });
                    let fewest = keep
                        .iter()
                        .map(|&i| want[i as usize])
                        .fold(f64::INFINITY, f64::min);
                    (keep, fewest)
                });
                if keep.is_empty() {
                    break;
                }
                next_check = Some(stop.next_check_at(done, fewest));
                view.set_pixels(tracer, Some(&keep))?;
                sampling = Some(keep);
            }
        }
    }
    let counts = pixel_counts(&stopped, done);
    let samples = PixelSamples::new(counts.as_deref().map(Vec::as_slice), done);
    let (data, annotation) = view.read(samples)?;
    let radiance = Radiance {
        width,
        height,
        data,
        gpu_ms,
    };
    Ok(Frame {
        radiance,
        annotation,
        spp: done,
        pixel_spp: counts.map(Scratch::into_vec),
        noise: checks.last().copied(),
        noise_checks: checks,
        labels_from_samples: view.labels_from_samples(),
        analytic_rays_chosen: rays_chosen,
    })
}

/// Samples of the next batch after `done`: `batch`, cut to end at the first check
/// (`first`, `min_spp`; None without a noise target) when that comes before it
/// (`min_spp = 2` with batches of 4: 2 samples, the check, then 4 at a time), and, with
/// the "halves" estimate (`halves`), never past the next power of two. Later checks
/// fall at the end of the batch that reaches them. "halves" learns about the
/// stratification of more samples only when a power of two completes (its checks are
/// kept at most at the next one, [`NoiseStop::next_check`]); batches of `batch_spp` from
/// 0 end on the powers of two from `batch_spp` up, so this changes nothing for a first
/// check at a multiple of the batch (the recommended paper setting: 4 and 4). The first
/// check is the one pending while `done < first`. Cutting every batch at its check was
/// tried: with `adaptive_radius` the next check is where the first pixel still sampling
/// reaches its share, often a sample away, and a test image took 34 checks of
/// one-sample batches where batch ends gave 9.
pub fn batch_before_check(batch: u32, done: u32, first: Option<u32>, halves: bool) -> u32 {
    match first {
        Some(first) if done < first => batch.min(first - done),
        _ if halves => batch.min((next_power_of_two_above(done) - done as u64) as u32),
        _ => batch,
    }
}

/// Each pixel's samples when some stopped before `done` (`stopped`: the samples a pixel
/// stopped at, 0 for one still sampling, empty when the render is not adaptive): None
/// when every pixel has `done`.
fn pixel_counts(stopped: &[u32], done: u32) -> Option<Scratch<u32>> {
    if stopped.iter().all(|&s| s == 0) {
        return None;
    }
    let mut counts = Scratch::stale(stopped.len(), 0);
    for (c, &s) in counts.iter_mut().zip(stopped) {
        *c = if s == 0 { done } else { s };
    }
    Some(counts)
}

/// Per-pixel sums as [`View::read_sums`] reads them: radiance, and the noise estimate's.
type Sums = (Scratch<f32>, Scratch<f32>);

/// What one noise check made: the estimate, its mean image, the sums it was made from,
/// and the rays' sums where the view keeps them ([`noise_estimate`]).
type Check = (NoiseEstimate, CheckedImage, Sums, Option<Vec<f32>>);

/// The noise criterion after `done` samples, its mean image, the sums it was made
/// from, and the rays' sums where the view keeps them ([`View::read_sums`]); `masks`
/// (auto exposure's pixels: the inspected faces 1..=3; the rms's: the object,
/// face != 0) from the view's annotation, read once (every pixel without an annotation).
fn noise_estimate(
    view: &View,
    stop: &NoiseStop,
    done: PixelSamples<'_>,
    masks: &mut Option<(Vec<bool>, Vec<bool>)>,
) -> Result<Check, RenderError> {
    let (sum, noise, ray_sums) = view.read_sums()?;
    let noise = noise.expect("a view with a noise target keeps noise sums");
    if masks.is_none() {
        *masks = Some(match view.read_annotation()? {
            Some(a) => (
                a.face.iter().map(|&f| is_inspected(f)).collect(),
                a.face.iter().map(|&f| f != 0).collect(),
            ),
            None => (vec![true; sum.len()], vec![true; sum.len()]),
        });
    }
    let (exposure, object) = masks.as_ref().expect("just filled");
    let (est, image) =
        stop.camera
            .estimate(stop.estimator, &sum, &noise, done, exposure, object)?;
    Ok((est, image, (sum, noise), ray_sums))
}

/// What `[render] analytic_rays_max`'s choice knows at the first noise check (`est` and
/// its mean image `image`, from `sums` after `done` samples, every pixel's; later checks
/// a `batch` apart, at most `spp`; `masks` as the estimate took them): [`RayCheck`].
#[allow(clippy::too_many_arguments)]
fn ray_check(
    stop: &NoiseStop,
    est: &NoiseEstimate,
    image: &CheckedImage,
    sums: &Sums,
    ray_sums: &[f32],
    done: PixelSamples<'_>,
    batch: u32,
    spp: u32,
    masks: &Option<(Vec<bool>, Vec<bool>)>,
) -> RayCheck {
    let object = &masks.as_ref().expect("filled by the estimate").1;
    let (variance, rays) = stop.camera.ray_variances(
        stop.estimator,
        &sums.0,
        &sums.1,
        ray_sums,
        done,
        image,
        object,
    );
    let allowed = stop.target_at(est.mean_spp) * est.camera_rms_dn;
    RayCheck {
        done: done.most(),
        variance,
        rays,
        target: allowed * allowed * est.pixels as f64,
        first_stop: done.most() + batch,
        step: batch,
        most: spp,
    }
}

/// Renders a whole assembled scene once: builds the path tracer and the GPU scene for
/// this one image (a job over many images keeps them; see `dataset::gpu`).
pub fn render_scene(
    ctx: &Arc<Context>,
    scene: &RenderScene,
    settings: impl Into<RenderSettings>,
    backend: Backend,
    tables: &EnergyTables,
    opts: FrameOptions<'_>,
    progress: impl FnMut(u32),
) -> Result<Frame, RenderError> {
    let settings: RenderSettings = settings.into();
    let tracer = PathTracer::beginning(ctx, backend, tables, !settings.specialize)?;
    render_scene_on(&tracer, scene, settings, opts, progress)
}

/// [`render_scene`] with a path tracer the caller keeps, so that its pipelines are made
/// once for many scenes (lavapipe spends seconds turning the path tracer's SPIR-V into
/// its own code at each pipeline's creation, whatever the pipeline cache holds); the GPU
/// scene is built for this one image.
pub fn render_scene_on(
    tracer: &PathTracer,
    scene: &RenderScene,
    settings: impl Into<RenderSettings>,
    opts: FrameOptions<'_>,
    progress: impl FnMut(u32),
) -> Result<Frame, RenderError> {
    let settings: RenderSettings = settings.into();
    let mut gpu = GpuScene::new(tracer, &scene.stage, opts.profiler)?;
    crate::vk::timed(opts.profiler, "place and upload maps", || {
        gpu.set_face_maps_filtered(
            tracer,
            &scene.face_maps,
            &scene.placement,
            settings.texture_filter,
        )
    })?;
    render_frame(tracer, &gpu, &scene.view, &settings, opts, progress)
}

/// The radiance of [`render_scene`] without annotation.
pub fn path_trace(
    ctx: &Arc<Context>,
    scene: &RenderScene,
    settings: impl Into<RenderSettings>,
    backend: Backend,
    tables: &EnergyTables,
    profiler: Option<&Profiler>,
    progress: impl FnMut(u32),
) -> Result<Radiance, RenderError> {
    let opts = FrameOptions {
        annotate_grid: None,
        profiler,
        noise: None,
    };
    render_scene(ctx, scene, settings, backend, tables, opts, progress).map(|f| f.radiance)
}

#[cfg(test)]
mod tests {
    use super::batch_before_check;

    #[test]
    fn the_first_check_cuts_its_batch_and_halves_stops_at_powers_of_two() {
        // The first check exactly, however near.
        assert_eq!(batch_before_check(4, 0, Some(2), false), 2);
        assert_eq!(batch_before_check(8, 8, Some(9), false), 1);
        assert_eq!(batch_before_check(4, 0, Some(4), false), 4);
        assert_eq!(batch_before_check(4, 0, Some(8), false), 4);
        // Later checks: a whole batch ...
        assert_eq!(batch_before_check(4, 2, Some(2), false), 4);
        assert_eq!(batch_before_check(4, 4, Some(4), false), 4);
        assert_eq!(batch_before_check(8, 63, Some(8), false), 8);
        // ... with "halves" up to the next power of two at most.
        assert_eq!(batch_before_check(4, 2, Some(2), true), 2);
        assert_eq!(batch_before_check(8, 63, Some(8), true), 1);
        assert_eq!(batch_before_check(8, 61, Some(8), true), 3);
        assert_eq!(batch_before_check(8, 33, Some(8), true), 8);
        // Multiples of the batch from 0 already end on the powers of two.
        for done in (4..256).step_by(4) {
            assert_eq!(batch_before_check(4, done, Some(4), true), 4);
        }
        // No noise target: a whole batch.
        assert_eq!(batch_before_check(4, 2, None, false), 4);
    }
}
