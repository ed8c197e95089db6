//! The render's own noise against the camera's: the criterion behind `[render]
//! noise_target` (docs/dataset.md, "Samples chosen from a noise target").
//!
//! Besides the radiance sum S the path tracer keeps per-pixel sums for the variance of
//! the pixel's mean after n samples (`PathParams::noise_sums`), by the estimator
//! (`[render] noise_estimate`, [`NoiseEstimator`]):
//!
//! - **"halves"** (default): the radiance of the last two *levels* of sample indices,
//!   level L >= 1 being [2^(L-1), 2^L). With P the largest power of two <= n and
//!   h = P / 2, the blocks [0, h) and [h, 2h) are the two halves of an aligned block of
//!   2h samples; with their means m1, m2 the variance of an h-sample mean is estimated as
//!   (m1 - m2)^2 / 2 (one degree of freedom a pixel; the criterion sums it over
//!   thousands), and that of the n-sample mean as that times h / n.
//!   *Approximation (independent halves, 1/n beyond them)*: with the Sobol sampler each
//!   aligned block of 2^m indices is a stratified set of its own (Burley's index
//!   shuffle maps aligned blocks to aligned blocks of the Owen-scrambled sequence), so
//!   the halves' spread includes the stratification within h samples; two halves of one
//!   block are negatively correlated (together they are a finer set) and n samples are
//!   stratified at least as well as h, so the estimate errs on the safe side, by the
//!   stratification between h and n at most. With independent samples it is unbiased.
//! - **"samples"** (the estimate before 2026-11-24): each sample's squared radiance Q;
//!   s^2 = (Q - S^2 / n) / (n - 1), the mean's variance s^2 / n. *Approximation
//!   (independent samples)*: conservative under Sobol by all of its stratification (on the
//!   paper job's crops 1.2 to 2.9x the measured error, issue 15).
//!
//! The render noise is brought into the sensor's codes exactly as the sensor step will
//! expose the image ([`exposure_time_s`] on the current mean image, times the caller's
//! factor), and compared with the camera's own temporal noise at each pixel's mean level
//! (EMVA 1288: shot noise + dark noise + quantisation, the model [`super::sensor::capture`]
//! samples from). The ratio of the two rms values over the object's pixels is what
//! `noise_target` bounds.

use super::cpu::Scratch;
use super::sensor::{Responsivity, SensorError, exposure_time_s, saturation_electrons};
pub use crate::scene::config::NoiseEstimator;
use crate::scene::config::SensorConfig;
use rayon::prelude::*;

/// The camera the noise is measured against: its responsivity, its sensor and the factor
/// the sensor step puts on the (auto or fixed) exposure time (a finish's exposure, the
/// image's random exposure 2^ev).
#[derive(Clone, Debug)]
pub struct CameraNoise {
    pub resp: Responsivity,
    pub sensor: SensorConfig,
    pub exposure_factor: f64,
}

/// When to stop adding samples: the render noise over the camera noise at most `target`
/// (`[render] noise_target`), not before `min_spp` samples (`[render] min_spp`), never
/// beyond the render's `spp`.
#[derive(Clone, Debug)]
pub struct NoiseStop {
    pub camera: CameraNoise,
    pub target: f64,
    pub min_spp: u32,
    /// How a pixel's variance is estimated (`[render] noise_estimate`).
    pub estimator: NoiseEstimator,
    /// `[render] adaptive_radius`: after each check the pixels whose share of the
    /// samples is reached stop ([`CameraNoise::pixel_samples_wanted`], each pixel's
    /// variance averaged over the (2 r + 1)^2 pixels around it); None: every pixel takes
    /// the same samples.
    pub adaptive_radius: Option<u32>,
    /// `[render] noise_target_growth`, g in [0, 1]: the target an image must meet grows
    /// with its mean samples m as `target` (m / `min_spp`)^g ([`NoiseStop::target_at`]).
    /// 0: every image to the same target. 0.5: the samples that minimise a set of
    /// images' pooled error (the mean of their squared noise) for the samples spent:
    /// with v_i an image's variance per sample, the fewest samples in all for a given
    /// sum of v_i / n_i are n_i proportional to sqrt(v_i) (Lagrange), i.e. each image
    /// stops where its noise ratio^2 = v_i / n_i falls to n_i / mu^2, ratio = const
    /// sqrt(n_i). An image whose samples are noisy takes fewer than a fixed target would
    /// give it and ends noisier; a quiet one stops at `min_spp` either way.
    /// docs/dataset.md, "Samples chosen from a noise target".
    pub growth: f64,
    /// `[render] analytic_rays_max`: at the first check, where it does not stop the
    /// image, the camera rays per sample of the analytic direct light's closed form are
    /// chosen for the rest of it ([`RayChoice`]); None: `analytic_rays` throughout.
    pub rays: Option<RayChoice>,
}

/// The choice of `[render] analytic_rays_max`: the camera rays m per sample whose closed
/// form the analytic direct light averages (the sample's own and m - 1 extra), for the
/// samples after the first noise check where that does not stop the image, from what
/// the samples before it measured.
///
/// A sample's variance is V_R + C m0 / m: C the variance from sample to sample of its
/// mean of the closed form A' over its m0 camera rays (the texture and glints under the
/// pixel, which more rays average further; its sums per pixel,
/// `View::read_sums`), V_R the rest (the paths, the light and BSDF samples: the
/// estimate's variance per sample less C); a sample's cost is a (1 + k m), k = `cost`
/// (one extra ray's time over the rest of a sample's). For each count m the
/// image's noise after n samples is predicted ((done V0 + (n - done) V(m)) / n^2, the
/// variances summed over the pixels the criterion counts, weighted as it weighs them),
/// and with it the first check that would meet the target ([`RayCheck`]: one a batch);
/// m is the count that gets there in the least time, (n - done) (1 + k m). The checks'
/// grid matters: more rays only pay where they make an image stop a check earlier,
/// fewer where it still stops at the same one.
///
/// **Approximations:** C falls as 1 / m, as for independent rays (the rays' points are
/// stratified, their own Sobol sequence: more rays may leave less than that); every pixel is taken to sample on
/// (with `adaptive_radius` the noisy ones sample longer than the rest); the prediction
/// must meet the target with the variance [`RAY_CHOICE_HEADROOM`] times higher (an
/// estimate made from few samples); k is one constant measured on one device
/// (`[render] analytic_ray_cost`; docs/benchmarks/dataset.md, "The extra rays chosen
/// per image"), not each image's own. m is the best of [`RAY_LADDER`] within [`min`,
/// `max`] (a pipeline each where the path tracer is specialized), taken only where it
/// beats m0's predicted time by [`RAY_CHOICE_MARGIN`]. Each sample stays unbiased
/// whatever its m.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayChoice {
    /// Fewest and most rays per sample the choice may take (the sample's own included).
    pub min: u32,
    pub max: u32,
    /// k: one extra ray's cost over the rest of a sample's (`[render] analytic_ray_cost`).
    pub cost: f64,
}

/// What [`RayChoice::choose`] knows at its check: the variances as sums over the pixels
/// the criterion counts (each weighted as [`CameraNoise::estimate`] weighs it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayCheck {
    /// Samples so far (every pixel's: the first check comes before any pixel stops).
    pub done: u32,
    /// A sample's variance (V0, at the rays so far).
    pub variance: f64,
    /// C, the part of it that is the variance of the sample's mean of its rays' closed
    /// forms (at the rays so far).
    pub rays: f64,
    /// The mean's variance the target allows (its ratio squared times the camera's).
    pub target: f64,
    /// The next noise check (the first the image may stop at after this one), the
    /// samples between the later ones (the batch), and the most samples (`spp`).
    pub first_stop: u32,
    pub step: u32,
    pub most: u32,
}

/// The ray counts [`RayChoice`] picks from.
pub const RAY_LADDER: [u32; 12] = [1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64];

/// [`RayChoice::cost`] when not given (`[render] analytic_ray_cost`): one extra ray's
/// time over the rest of a sample's on lavapipe, measured on the paper job's crops
/// (docs/benchmarks/dataset.md, "The extra rays chosen per image").
pub const DEFAULT_ANALYTIC_RAY_COST: f64 = 0.035;

/// [`RayChoice`] changes the rays only where the new count's predicted time to the
/// target is below this fraction of the current count's.
pub const RAY_CHOICE_MARGIN: f64 = 0.95;

/// [`RayChoice`] takes a check as met where its predicted variance times this is at most
/// the target's.
pub const RAY_CHOICE_HEADROOM: f64 = 1.25;

impl RayChoice {
    /// `[render] analytic_rays_max = max`'s choice, from 1 ray up, with `[render]
    /// analytic_ray_cost` (None: [`DEFAULT_ANALYTIC_RAY_COST`]); scene files and jobs alike.
    pub fn up_to(max: u32, cost: Option<f64>) -> RayChoice {
        RayChoice {
            min: 1,
            max,
            cost: cost.unwrap_or(DEFAULT_ANALYTIC_RAY_COST),
        }
    }

    /// The rays for the rest of an image made with `m0` rays so far; `m0` itself where
    /// the variances are unknown or no count is clearly faster.
    pub fn choose(&self, m0: u32, at: &RayCheck) -> u32 {
        let m0 = m0.max(1);
        let known = |v: f64| v.is_finite() && v >= 0.0;
        if !(known(at.variance) && known(at.rays) && known(at.target)) || at.variance <= 0.0 {
            return m0;
        }
        let done = at.done as f64;
        let rest = (at.variance - at.rays).max(0.0);
        // (whether the target is met by `most`, the time to the check that meets it, or
        // without one the time per unit of variance: V(m) (1 + k m)).
        let time = |m: u32| {
            let v = rest + at.rays * m0 as f64 / m as f64;
            let per_sample = 1.0 + self.cost * m as f64;
            let mut n = at.first_stop.max(at.done + 1).min(at.most.max(at.done + 1));
            loop {
                let nf = n as f64;
                let predicted = (done * at.variance + (nf - done) * v) / (nf * nf);
                if predicted * RAY_CHOICE_HEADROOM <= at.target {
                    return (true, (nf - done) * per_sample);
                }
                if n >= at.most {
                    return (false, v * per_sample);
                }
                n = n.saturating_add(at.step.max(1)).min(at.most);
            }
        };
        // Counts that meet the target before those that do not; then the least time.
        let key = |m: u32| {
            let (met, t) = time(m);
            (!met, t)
        };
        let best = RAY_LADDER
            .iter()
            .copied()
            .filter(|&m| m >= self.min && m <= self.max)
            .min_by(|&a, &b| {
                key(a)
                    .partial_cmp(&key(b))
                    .unwrap_or(std::cmp::Ordering::Equal)
            });
        match best {
            Some(m) => {
                let ((met, t), (met0, t0)) = (time(m), time(m0));
                if (met && !met0) || (met == met0 && t < RAY_CHOICE_MARGIN * t0) {
                    m
                } else {
                    m0
                }
            }
            None => m0,
        }
    }
}

/// Samples per pixel so far: the same for every pixel, or each pixel's own (`[render]
/// adaptive_radius`).
#[derive(Clone, Copy, Debug)]
pub enum PixelSamples<'a> {
    All(u32),
    Each(&'a [u32]),
}

impl<'a> PixelSamples<'a> {
    /// Each pixel's own `counts` where given, else `all` for every pixel.
    pub fn new(counts: Option<&'a [u32]>, all: u32) -> Self {
        counts.map_or(PixelSamples::All(all), PixelSamples::Each)
    }

    /// Pixel i's samples.
    pub fn of(&self, i: usize) -> u32 {
        match self {
            PixelSamples::All(n) => *n,
            PixelSamples::Each(counts) => counts[i],
        }
    }

    /// The most any pixel has.
    pub fn most(&self) -> u32 {
        match self {
            PixelSamples::All(n) => *n,
            PixelSamples::Each(counts) => counts.iter().copied().max().unwrap_or(0),
        }
    }

    /// The mean over the image's pixels.
    pub fn mean(&self) -> f64 {
        match self {
            PixelSamples::All(n) => *n as f64,
            PixelSamples::Each(counts) => {
                counts.iter().map(|&c| c as f64).sum::<f64>() / counts.len().max(1) as f64
            }
        }
    }
}

impl From<u32> for PixelSamples<'_> {
    fn from(n: u32) -> Self {
        PixelSamples::All(n)
    }
}

/// Samples before the first check when `min_spp` is not given (`[render] min_spp` of
/// scene and job files): few enough that a low-noise image stops early, many enough that
/// the per-pixel variance estimate has seen the radiance's spread.
pub const DEFAULT_MIN_SPP: u32 = 64;

/// The largest jump between two checks, as a factor on the samples done: the next check
/// is where the estimate predicts the target (noise falls as 1 / sqrt(spp)), but at most
/// this many times the samples done (an early estimate may be off).
pub const MAX_CHECK_GROWTH: u32 = 4;
/// The smallest step between two checks, as a fraction of the samples done (1 / this):
/// bounds the number of readbacks (logarithmic in spp) and the overshoot past the spp
/// the target needs (at most about 1 / 64 = 1.6 %, plus one batch). A check that lands
/// just above the target (ratio q < sqrt(1 + 1/64)) is followed by this step; with 1/16
/// five of ten measured images took 5 to 7 % more samples than they needed.
pub const MIN_CHECK_STEP_DIVISOR: u32 = 64;
/// Halvings of the bracket in which `adaptive_radius` looks for the target a growing
/// target meets at the shares' end ([`CameraNoise::pixel_samples_wanted`]): 16 take it
/// to 1.5e-5 of [target, ratio].
pub const GROWTH_BISECTIONS: u32 = 16;

/// The first power of two above `done` samples: where the "halves" estimate next learns
/// about the stratification of more samples (its checks come at most there, and a
/// render's batches do not run past it).
pub fn next_power_of_two_above(done: u32) -> u64 {
    (done as u64 + 1).next_power_of_two()
}

/// One evaluation of the criterion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseEstimate {
    /// Samples per pixel the estimate is of (the most any pixel had, with
    /// `[render] adaptive_radius`).
    pub spp: u32,
    /// Their mean over the image's pixels (`spp` unless adaptive).
    pub mean_spp: f64,
    /// rms render noise over rms camera noise, over the counted pixels.
    pub ratio: f64,
    /// rms render noise (standard error of the mean) in sensor codes (DN).
    pub render_rms_dn: f64,
    /// rms camera temporal noise in sensor codes (DN).
    pub camera_rms_dn: f64,
    /// Pixels counted: the object's, less those whose mean signal is at or above
    /// saturation (their code is clipped: no noise of either kind).
    pub pixels: usize,
    /// The exposure time the sensor step will use for this mean image, s.
    pub exposure_s: f64,
}

/// The mean image a noise check's [`CameraNoise::estimate`] was made from, at that
/// estimate's exposure: what [`CameraNoise::ray_variances`] and
/// [`CameraNoise::pixel_samples_wanted`] of the same check weigh each pixel by, so that
/// the three count the same pixels. (Before 2026-11-30 each made the mean image
/// itself: three times a check.)
pub struct CheckedImage {
    mean: Scratch<f32>,
    exposure_s: f64,
}

/// The camera's temporal noise variance in codes (DN^2) at a mean charge of
/// `mean_electrons` (photo-electrons and the dark current's, I_d t): K^2 (mu_e +
/// sigma_d^2) + 1/12 (shot noise of both, dark noise, uniform quantisation of a unit
/// step).
pub fn camera_variance_dn(sensor: &SensorConfig, mean_electrons: f64) -> f64 {
    let k = sensor.gain_dn_per_electron;
    let sd = sensor.dark_noise_electrons;
    k * k * (mean_electrons.max(0.0) + sd * sd) + 1.0 / 12.0
}

/// Variance of a pixel's mean radiance from the sums of `n` samples (`sum` of radiance,
/// `sum_sq` of squared radiance): s^2 / n with s^2 = (Q - S^2 / n) / (n - 1), clamped at 0
/// (rounding of the f32 sums). Infinite for n < 2 (no spread is known).
pub fn mean_variance(sum: f64, sum_sq: f64, n: u32) -> f64 {
    if n < 2 {
        return f64::INFINITY;
    }
    let n = n as f64;
    let s2 = ((sum_sq - sum * sum / n) / (n - 1.0)).max(0.0);
    s2 / n
}

/// Variance of a pixel's mean radiance after `n` samples from the "halves" sums: `sum`
/// of radiance and `levels` = the radiance of sample-index levels of even and odd L
/// (level L >= 1: indices [2^(L-1), 2^L); level 0: index 0), each holding its latest
/// level. P = the largest power of two <= n, h = P / 2: the halves [0, h) and [h, 2h)
/// (S(2h) = sum less the unfinished level [P, n)); (m1 - m2)^2 / 2 * h / n. Infinite for
/// n < 2.
pub fn halves_mean_variance(sum: f64, levels: [f64; 2], n: u32) -> f64 {
    if n < 2 {
        return f64::INFINITY;
    }
    let p = 1u32 << (31 - n.leading_zeros());
    let h = p / 2;
    // The level of indices [x, 2x) is log2(x) + 1.
    let level_sum = |x: u32| levels[((x.trailing_zeros() + 1) & 1) as usize];
    let first_2h = if p < n { sum - level_sum(p) } else { sum };
    let second = level_sum(h);
    let first = first_2h - second;
    let hf = h as f64;
    let d = (first - second) / hf;
    d * d / 2.0 * hf / n as f64
}

/// The variance of each pixel's mean after `n` samples from the path tracer's sums:
/// `sum` of radiance and `noise` as [`NoiseEstimator`] fills it (squares: one value a
/// pixel; halves: two).
#[inline]
fn pixel_variance(estimator: NoiseEstimator, sum: &[f32], noise: &[f32], n: u32, i: usize) -> f64 {
    match estimator {
        NoiseEstimator::Samples => mean_variance(sum[i] as f64, noise[i] as f64, n),
        NoiseEstimator::Halves => halves_mean_variance(
            sum[i] as f64,
            [noise[2 * i] as f64, noise[2 * i + 1] as f64],
            n,
        ),
    }
}

/// The mean image: each pixel's sum over its samples (none: 0).
pub fn mean_image(sum: &[f32], n: PixelSamples<'_>) -> Vec<f32> {
    mean_scratch(sum, n).into_vec()
}

/// A pixel's mean from its sum over `n` samples (none: 0), as [`mean_image`] has it.
#[inline]
fn pixel_mean(sum: f32, n: u32) -> f32 {
    sum * (1.0 / n.max(1) as f32)
}

/// [`mean_image`] into an array kept between checks.
fn mean_scratch(sum: &[f32], n: PixelSamples<'_>) -> Scratch<f32> {
    let mut mean = Scratch::stale(sum.len(), 0.0);
    mean.par_iter_mut()
        .zip(sum)
        .enumerate()
        .for_each(|(i, (m, &v))| *m = pixel_mean(v, n.of(i)));
    mean
}

/// Floats a pixel the path tracer keeps for `estimator` (its `NoiseSums` binding).
pub fn noise_floats_per_pixel(estimator: NoiseEstimator) -> usize {
    match estimator {
        NoiseEstimator::Samples => 1,
        NoiseEstimator::Halves => 2,
    }
}

impl CameraNoise {
    /// The criterion after `n` samples (a pixel's own with [`PixelSamples::Each`]).
    /// `sum`, `noise`: the path tracer's per-pixel sums (radiance; `estimator`'s,
    /// [`noise_floats_per_pixel`] a pixel); `exposure_mask`: the pixels auto exposure
    /// looks at (the inspected faces, as the sensor step); `object_mask`: the pixels the
    /// rms is taken over (all when it selects none). The mean image is the one
    /// [`super::View::read`] would return at `n`; it comes back with the estimate, at
    /// the estimate's exposure, for [`CameraNoise::ray_variances`] and
    /// [`CameraNoise::pixel_samples_wanted`] of the same check.
    pub fn estimate<'a>(
        &self,
        estimator: NoiseEstimator,
        sum: &[f32],
        noise: &[f32],
        n: impl Into<PixelSamples<'a>>,
        exposure_mask: &[bool],
        object_mask: &[bool],
    ) -> Result<(NoiseEstimate, CheckedImage), SensorError> {
        let n = n.into();
        let px = self.resp.electrons_per_s.len();
        if sum.len() != px
            || noise.len() != px * noise_floats_per_pixel(estimator)
            || exposure_mask.len() != px
            || object_mask.len() != px
            || matches!(n, PixelSamples::Each(c) if c.len() != px)
        {
            return Err(SensorError::Invalid(format!(
                "noise estimate: {} / {} sums and {} / {} mask values for {px} pixels",
                sum.len(),
                noise.len(),
                exposure_mask.len(),
                object_mask.len()
            )));
        }
        let mean = mean_scratch(sum, n);
        let t = exposure_time_s(&self.resp, &mean, Some(exposure_mask), &self.sensor)?
            * self.exposure_factor;
        let image = CheckedImage {
            mean,
            exposure_s: t,
        };
        let all = !object_mask.iter().any(|&m| m);
        let full = saturation_electrons(&self.sensor);
        // Each pixel's terms on all cores (into arrays kept between checks), summed in
        // pixel order (the same sums as one loop over the pixels).
        let mut counted = Scratch::stale(px, false);
        let mut render_t = Scratch::stale(px, 0.0f64);
        let mut camera_t = Scratch::stale(px, 0.0f64);
        counted
            .par_iter_mut()
            .zip(render_t.par_iter_mut())
            .zip(camera_t.par_iter_mut())
            .enumerate()
            .for_each(|(i, ((c, r), cam))| {
                *c = false;
                if !(all || object_mask[i]) {
                    return;
                }
                let Some((w, mu)) = self.pixel_weight(i, &image, full) else {
                    return;
                };
                let var_l = pixel_variance(estimator, sum, noise, n.of(i), i);
                *c = true;
                *r = w * var_l;
                *cam = camera_variance_dn(&self.sensor, mu);
            });
        let (mut render, mut camera, mut pixels) = (0.0f64, 0.0f64, 0usize);
        for i in 0..px {
            if counted[i] {
                render += render_t[i];
                camera += camera_t[i];
                pixels += 1;
            }
        }
        let (render_rms_dn, camera_rms_dn, ratio) = if pixels == 0 {
            (0.0, 0.0, 0.0)
        } else {
            let (r, c) = (
                (render / pixels as f64).sqrt(),
                (camera / pixels as f64).sqrt(),
            );
            (r, c, r / c)
        };
        let est = NoiseEstimate {
            spp: n.most(),
            mean_spp: n.mean(),
            ratio,
            render_rms_dn,
            camera_rms_dn,
            pixels,
            exposure_s: t,
        };
        Ok((est, image))
    }

    /// The criterion's weight of pixel `i` of the check's mean image `image` (its mean
    /// radiance, at the image's exposure), (K e)^2 (K the gain in codes per electron, e
    /// the pixel's electrons per unit radiance), and its mean signal in electrons; None
    /// at or above saturation (`full` electrons), where the criterion does not count it.
    /// One rule for [`CameraNoise::estimate`], [`CameraNoise::ray_variances`] and
    /// [`CameraNoise::pixel_samples_wanted`].
    ///
    /// With `blooming = "vertical"` a pixel below saturation that its column's excess
    /// fills in the capture is still counted as one of its own: for one session on
    /// 2026-11-30 (the twenty-eighth) the criterion left such pixels out, which cut the paper job's
    /// samples (frame 4877: 19.5 -> 2.18 spp) but left the glints whose 2-sample means
    /// fell below full in their neighbours' bloom at 2 samples, and their spills'
    /// lengths raised the captured images' error 10 % above the 256-spp image's on the
    /// six reference crops (docs/benchmarks/dataset.md, "A blooming run's noise where it
    /// ends").
    fn pixel_weight(&self, i: usize, image: &CheckedImage, full: f64) -> Option<(f64, f64)> {
        let e_per_l = self.resp.electrons_per_s[i] * image.exposure_s;
        // The dark current's electrons join the photo-electrons (as in
        // `sensor::capture`): their shot noise is the camera's, and their charge fills
        // the well with the signal's.
        let dark = self.sensor.dark_current_electrons_per_s * image.exposure_s;
        let mu = (image.mean[i] as f64).max(0.0) * e_per_l + dark;
        (mu < full).then(|| ((self.sensor.gain_dn_per_electron * e_per_l).powi(2), mu))
    }

    /// [`RayChoice::choose`]'s two sums after `n` samples (each pixel's own): a
    /// sample's variance (the estimate's variance of the mean times the samples) and C,
    /// the variance from sample to sample of its mean of its rays' closed forms (from
    /// `ray_sums`: per pixel the sums of that mean and of its square, at 2 i and 2 i + 1),
    /// each pixel weighted as [`CameraNoise::estimate`] weighs its render variance, over
    /// the pixels it counts (the object's, below saturation; every pixel where
    /// `object_mask` selects none), `image` the mean image that estimate returned.
    #[allow(clippy::too_many_arguments)]
    pub fn ray_variances<'a>(
        &self,
        estimator: NoiseEstimator,
        sum: &[f32],
        noise: &[f32],
        ray_sums: &[f32],
        n: impl Into<PixelSamples<'a>>,
        image: &CheckedImage,
        object_mask: &[bool],
    ) -> (f64, f64) {
        let n = n.into();
        let all = !object_mask.iter().any(|&m| m);
        let full = saturation_electrons(&self.sensor);
        let (mut total, mut rays) = (0.0f64, 0.0f64);
        for i in 0..sum.len() {
            if !(all || object_mask[i]) {
                continue;
            }
            let ni = n.of(i);
            let var = pixel_variance(estimator, sum, noise, ni, i);
            let c = mean_variance(ray_sums[2 * i] as f64, ray_sums[2 * i + 1] as f64, ni);
            let Some((w, _)) = self.pixel_weight(i, image, full) else {
                continue;
            };
            if !var.is_finite() || !c.is_finite() {
                continue;
            }
            total += w * var * ni as f64;
            rays += w * c * ni as f64;
        }
        (total, rays)
    }

    /// `[render] adaptive_radius`: the samples each pixel should end with so that the
    /// criterion meets `target` at the fewest samples in all, from the sums after `n`
    /// (each pixel's own), `image` the mean image that check's estimate returned.
    ///
    /// With s_i a pixel's variance per sample in codes (its mean's variance times its
    /// samples, as the estimate weighs it; 0 where the mean is at or above saturation),
    /// the samples n_i that minimise sum n_i subject to sum over the counted pixels of
    /// s_i / n_i = target^2 sum c_i (c_i the camera's variance: the criterion met) are
    /// n_i = sqrt(s_i) S / (target^2 sum c_i), S = sum over the counted pixels of
    /// sqrt(s_i) (Lagrange; the pixels the criterion does not count get the same
    /// marginal rule). A pixel already has its samples (`n`, never taken back): where
    /// its share is below them it keeps them, its variance s_i / n_i spent from the
    /// budget, and the others share the rest (water filling).
    ///
    /// **Approximation (neighbours share a variance):** one pixel's estimate has one or
    /// few degrees of freedom, and a pixel whose few samples missed a rare bright path
    /// would stop with a low value; s_i is therefore the mean over the (2 `radius` + 1)^2
    /// pixels around it (clipped at the image's edges, `width` pixels a row) **of its own
    /// kind** (counted pixels over counted ones, the others over the others; a saturated
    /// pixel or one of unknown variance is in no mean, so neither the object's silhouette
    /// nor a clipped glint dilutes its neighbours' variance), which the stop depends on
    /// far more than on the pixel's own samples. The bias this leaves is measured, not
    /// zero (docs/dataset.md, "Samples per pixel").
    ///
    /// **Budget consistent with the estimate:** the means do not sum to the pixels' own
    /// variances (windows clipped at edges and at the other kind, uneven spread within a
    /// window), so the budget is scaled by P / A, A = sum over the counted pixels of their
    /// own s_i / n_i (the estimate's render variance now), P the same sum of the means:
    /// the shares meet the target exactly when the variance is spread as the means say.
    /// Hence a check above the target never stops every pixel (were all shares at most
    /// the samples had, P <= budget P / A, i.e. A <= budget: the target met); before
    /// 2026-11-27 a quarter of the paper job's frames stopped that way above the target.
    /// A pixel with fewer samples than the most has stopped for good (later batches
    /// sample only the others): its variance is spent from the start, so that the
    /// pixels that can still sample are the ones the argument above finds (its value
    /// here is still its share by the same rule, which the caller does not use).
    ///
    /// **A growing target** (`grown`: Some((target_at, ratio)), `[render]
    /// noise_target_growth`): the target the image must meet rises with its mean samples
    /// m (`target_at`, [`NoiseStop::target_at`]; `target` is its value now, `ratio` the
    /// estimate now). The shares are made for the T with T = target_at(m(T)), m(T) the
    /// mean samples the shares for T give (every pixel its share or the samples it has):
    /// the image then meets its grown target where the shares end, instead of stopping
    /// short of it and sampling a few pixels at every batch. T - target_at(m(T)) rises
    /// with T (m falls as T rises, target_at rises with m), is at most 0 at `target`
    /// and above 0 at `ratio`: [`GROWTH_BISECTIONS`] halvings of [target, ratio], the
    /// shares those of the lower end (T <= target_at(m(T)): met at the stop). The
    /// argument above holds with T: all shares reached would mean ratio <= T =
    /// target_at(m_now), the target met.
    #[allow(clippy::too_many_arguments)]
    pub fn pixel_samples_wanted<'a>(
        &self,
        estimator: NoiseEstimator,
        sum: &[f32],
        noise: &[f32],
        n: impl Into<PixelSamples<'a>>,
        image: &CheckedImage,
        object_mask: &[bool],
        width: usize,
        target: f64,
        grown: Option<(&(dyn Fn(f64) -> f64 + Sync), f64)>,
        radius: u32,
    ) -> Scratch<f64> {
        let n = n.into();
        let px = sum.len();
        let all = !object_mask.iter().any(|&m| m);
        let full = saturation_electrons(&self.sensor);
        // A pixel's variance per sample in codes and its mean signal in electrons; None
        // at or above saturation.
        let variance = |i: usize| -> Option<(f64, f64)> {
            let (w, mu) = self.pixel_weight(i, image, full)?;
            let v = w * pixel_variance(estimator, sum, noise, n.of(i), i) * n.of(i) as f64;
            Some((v, mu))
        };
        // One pass on all cores: the variance per sample (0 when unknown or saturated),
        // whether it is unknown, whether it is in its kind's means (known and below
        // saturation), and the camera's variance of a counted pixel (NaN: not counted);
        // then the camera's sum in pixel order (the same sum as one loop). Every array
        // is kept between checks (`Scratch`).
        let mut per_sample = Scratch::stale(px, 0.0f64);
        let mut unknown = Scratch::stale(px, false);
        let mut in_mean = Scratch::stale(px, false);
        let mut camera_of = Scratch::stale(px, f64::NAN);
        per_sample
            .par_iter_mut()
            .zip(unknown.par_iter_mut())
            .zip(in_mean.par_iter_mut())
            .zip(camera_of.par_iter_mut())
            .enumerate()
            .for_each(|(i, (((p, u), m), c))| {
                (*p, *u, *m, *c) = (0.0, false, false, f64::NAN);
                if let Some((v, mu)) = variance(i) {
                    match v.is_finite() {
                        true => (*p, *m) = (v, true),
                        false => *u = true,
                    }
                    if all || object_mask[i] {
                        *c = camera_variance_dn(&self.sensor, mu);
                    }
                }
            });
        let mut camera = 0.0f64;
        // The counted pixels with a known variance, in order: the budget's terms.
        let mut shared = Scratch::<u32>::empty();
        for (i, &c) in camera_of.iter().enumerate() {
            if !c.is_nan() {
                camera += c;
                if !unknown[i] {
                    shared.push(i as u32);
                }
            }
        }
        // A pixel's kind: counted or not.
        let counted = |i: usize| all || object_mask[i];
        drop(camera_of);
        let smooth = kind_mean(
            &per_sample,
            &in_mean,
            counted,
            width.max(1),
            radius as usize,
        );
        let mut roots = Scratch::stale(px, 0.0f64);
        roots
            .par_iter_mut()
            .zip(&smooth[..])
            .for_each(|(r, v)| *r = v.max(0.0).sqrt());
        // The estimate's render variance now (the pixels' own) and the means' (in pixel
        // order: the same sums on every run).
        let (mut own, mut means) = (0.0f64, 0.0f64);
        for &i in shared.iter() {
            let i = i as usize;
            let m = n.of(i).max(1) as f64;
            own += per_sample[i] / m;
            means += smooth[i] / m;
        }
        let consistent = if own > 0.0 && means > 0.0 {
            means / own
        } else {
            1.0
        };
        // Pixels whose share is at most the samples they have keep those (fixed): their
        // variance is spent, the rest of the budget is shared by the others; repeat
        // until no more become fixed (each round only adds fixed pixels). A pixel with
        // fewer than the most samples stopped at an earlier check and takes no more:
        // fixed from the start.
        let most = n.most();
        let mut stopped = Scratch::stale(px, false);
        stopped
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, s)| *s = n.of(i) < most);
        // A fixed pixel's variance (its share of the budget spent), once for every round.
        let mut spent_of = Scratch::stale(px, 0.0f64);
        spent_of
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, s)| *s = smooth[i] / n.of(i).max(1) as f64);
        // The scale on the roots that meets target t (the budget t^2 times the camera's
        // variance, made consistent).
        let water = |t: f64| -> f64 {
            // (In the order of before: the same budget to the bit without growth.)
            let budget = t * t * camera * consistent;
            let mut fixed = Scratch::stale(px, false);
            fixed.copy_from_slice(&stopped);
            loop {
                let (mut spent, mut free) = (0.0f64, 0.0f64);
                for &i in shared.iter() {
                    let i = i as usize;
                    if fixed[i] {
                        spent += spent_of[i];
                    } else {
                        free += roots[i];
                    }
                }
                let scale = if budget > spent {
                    free / (budget - spent)
                } else {
                    f64::INFINITY
                };
                let more = fixed
                    .par_iter_mut()
                    .enumerate()
                    .map(|(i, f)| {
                        let now = !*f && !unknown[i] && roots[i] * scale <= n.of(i) as f64;
                        *f |= now;
                        now
                    })
                    .reduce(|| false, |a, b| a || b);
                if !more {
                    break scale;
                }
            }
        };
        let scale = match grown {
            None => water(target),
            Some((target_at, ratio)) => {
                // The mean samples the shares of `scale` give, summed in fixed chunks in
                // order (the same sum whatever the thread count).
                let mean_wanted = |scale: f64| -> f64 {
                    let parts: Vec<f64> = (0..px.div_ceil(TERM_CHUNK))
                        .into_par_iter()
                        .map(|c| {
                            (c * TERM_CHUNK..((c + 1) * TERM_CHUNK).min(px))
                                .map(|i| {
                                    let have = n.of(i) as f64;
                                    match unknown[i] || stopped[i] {
                                        true => have,
                                        false => (roots[i] * scale).max(have),
                                    }
                                })
                                .sum::<f64>()
                        })
                        .collect();
                    parts.iter().sum::<f64>() / px.max(1) as f64
                };
                let (mut lo, mut hi) = (target, ratio.max(target));
                for _ in 0..GROWTH_BISECTIONS {
                    let mid = 0.5 * (lo + hi);
                    if mid <= target_at(mean_wanted(water(mid))) {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                water(lo)
            }
        };
        // Each pixel's samples, in the roots' place.
        roots.par_iter_mut().zip(&unknown[..]).for_each(|(r, &u)| {
            *r = if u {
                f64::INFINITY
            } else if *r > 0.0 {
                *r * scale
            } else {
                0.0
            }
        });
        roots
    }
}

/// Pixels a chunk of the growing target's mean samples holds (summed in order: the same
/// sum whatever the thread count).
const TERM_CHUNK: usize = 16384;

/// The mean of `v` over the (2 r + 1)^2 window around each value taken only over the
/// window's values of the same kind (`kind(i)`, two kinds) that are `in_mean`; 0 where
/// the window holds none. `v` is an image `width` values a row.
///
/// Each kind's mean is the window mean of v w over that of w (w: 1 for the kind's
/// values in the mean, else 0), each window mean a box mean (a running sum along each
/// row, then one down each column; the tests' `box_mean`), the same sums in the same
/// order, so the result equals that composition bit for bit (tested); made in one pass along the
/// rows for all four sums and one down the columns, the columns in chunks on all cores,
/// into planes kept between calls ([`Scratch`]). A noise check's largest part at the
/// paper's size: 128 -> 43 to 75 ms on 2 cores on synthetic sums
/// (`examples/bench_noise_check.rs`), `samples wanted` 0.91x in real renders
/// (docs/benchmarks/dataset.md, "A noise check's CPU time").
pub fn kind_mean(
    v: &[f64],
    in_mean: &[bool],
    kind: impl Fn(usize) -> bool + Sync,
    width: usize,
    r: usize,
) -> Scratch<f64> {
    let px = v.len();
    let height = px / width;
    assert_eq!(
        height * width,
        px,
        "kind_mean: {px} values are not rows of {width}"
    );
    let least = 0.5 / ((2 * r + 1) * (2 * r + 1)) as f64;
    // The sums, a plane each (v w and w of the first kind, then of the second), along
    // the rows: each row's running sums (rows on all cores), each value's window mean
    // along its row. A plane of 0 for a kind no value is of.
    let mut planes: [Scratch<f64>; 4] = std::array::from_fn(|_| Scratch::stale(px, 0.0));
    let [s0, w0, s1, w1] = &mut planes;
    s0.par_chunks_mut(width)
        .zip(w0.par_chunks_mut(width))
        .zip(s1.par_chunks_mut(width))
        .zip(w1.par_chunks_mut(width))
        .enumerate()
        .for_each_init(
            || std::array::from_fn::<_, 4, _>(|_| Scratch::filled(width + 1, 0.0f64)),
            |prefix, (y, (((s0, w0), s1), w1))| {
                let row = y * width..(y + 1) * width;
                for (j, i) in row.enumerate() {
                    let w = in_mean[i] as u8 as f64;
                    let (k, vw) = (kind(i), v[i] * w);
                    // The other kind's sums gain v 0 and 0 (as `box_mean` of its planes).
                    let (s_first, w_first) = if k { (vw, w) } else { (v[i] * 0.0, 0.0) };
                    let (s_second, w_second) = if k { (v[i] * 0.0, 0.0) } else { (vw, w) };
                    for (p, add) in prefix
                        .iter_mut()
                        .zip([s_first, w_first, s_second, w_second])
                    {
                        p[j + 1] = p[j] + add;
                    }
                }
                for (p, out) in prefix.iter().zip([s0, w0, s1, w1]) {
                    window_means(p, out, r);
                }
            },
        );
    // Down the columns, COLUMNS at a time on all cores: each column's running sums, then
    // each value's window mean and its own kind's quotient, a chunk's values column-chunk
    // major (chunk c's at c COLUMNS height); then gathered into rows.
    const COLUMNS: usize = 32;
    let mut chunks = Scratch::stale(px, 0.0f64);
    chunks
        .par_chunks_mut(COLUMNS * height.max(1))
        .enumerate()
        .for_each_init(Scratch::<f64>::empty, |prefix, (c, out)| {
            let (x0, x1) = (c * COLUMNS, ((c + 1) * COLUMNS).min(width));
            let cw = x1 - x0;
            // Plane k's running sums at row y (of rows 0..y) at prefix[(k (height + 1)
            // + y) cw ..][..cw].
            prefix.clear();
            prefix.resize(4 * (height + 1) * cw, 0.0f64);
            for (k, plane) in planes.iter().enumerate() {
                let p = &mut prefix[k * (height + 1) * cw..(k + 1) * (height + 1) * cw];
                for y in 0..height {
                    let (done, next) = p.split_at_mut((y + 1) * cw);
                    let (above, row) = (&done[y * cw..], &mut next[..cw]);
                    let src = &plane[y * width + x0..y * width + x1];
                    for ((p, a), s) in row.iter_mut().zip(above).zip(src) {
                        *p = a + s;
                    }
                }
            }
            let at = |k: usize, y: usize, x: usize| prefix[(k * (height + 1) + y) * cw + x];
            for y in 0..height {
                let (lo, hi) = window(y, height, r);
                let n = (hi - lo) as f64;
                for x in 0..cw {
                    let k = if kind(y * width + x0 + x) { 0 } else { 2 };
                    let s = (at(k, hi, x) - at(k, lo, x)) / n;
                    let w = (at(k + 1, hi, x) - at(k + 1, lo, x)) / n;
                    // A window's mean of 0/1 weights is 0 or at least 1 / (2 r + 1)^2;
                    // below half of that it is 0 up to the running sums' rounding.
                    out[y * cw + x] = if w > least { s / w } else { 0.0 };
                }
            }
        });
    drop(planes);
    let mut mean = Scratch::stale(px, 0.0f64);
    mean.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        for (c, chunk) in chunks.chunks(COLUMNS * height).enumerate() {
            let x0 = c * COLUMNS;
            let cw = chunk.len() / height;
            row[x0..x0 + cw].copy_from_slice(&chunk[y * cw..(y + 1) * cw]);
        }
    });
    mean
}

/// The window of `r` on either side of `j` in `0..len`, clipped at the ends: `lo..hi`.
fn window(j: usize, len: usize, r: usize) -> (usize, usize) {
    (j.saturating_sub(r), (j + r + 1).min(len))
}

/// Each value's mean over the window of r on either side (clipped at the ends) from the
/// running sums `prefix` (prefix[j]: the sum of the first j values): (prefix[hi] -
/// prefix[lo]) / (hi - lo), as a box mean's pass along the rows; the interior, where
/// the window is whole, in one loop the compiler can vectorise (a division by the same
/// count: the same quotients).
fn window_means(prefix: &[f64], out: &mut [f64], r: usize) {
    let len = out.len();
    let whole = (2 * r + 1) as f64;
    for (j, o) in out.iter_mut().enumerate() {
        if j >= r && j + r < len {
            continue;
        }
        let (lo, hi) = window(j, len, r);
        *o = (prefix[hi] - prefix[lo]) / (hi - lo) as f64;
    }
    if len > 2 * r {
        let inner = &mut out[r..len - r];
        let (below, above) = (&prefix[..len - 2 * r], &prefix[2 * r + 1..]);
        for ((o, a), b) in inner.iter_mut().zip(above).zip(below) {
            *o = (a - b) / whole;
        }
    }
}

impl NoiseStop {
    /// Samples at the first check: `min_spp` (at least 2, at most `spp`).
    pub fn first_check(&self, spp: u32) -> u32 {
        self.min_spp.max(2).min(spp)
    }

    /// Samples at the next check after an estimate of `ratio` at `done` samples: where
    /// the noise is predicted to reach the target (done (ratio / target)^2), kept within
    /// [done + done / MIN_CHECK_STEP_DIVISOR, MAX_CHECK_GROWTH done] and at least one
    /// more sample. With "halves" also at most the next power of two above `done`: the
    /// estimate only learns about the stratification of more samples when a power of two
    /// completes (in between it falls as 1 / n, the prediction itself), and it often
    /// falls faster there than the prediction assumes. The render checks at the first
    /// batch end at or after it.
    ///
    /// With a growing target (`growth` g > 0) the prediction is where the falling noise
    /// meets the rising target: ratio sqrt(done / n) = target_at(done) (n / done)^g, n =
    /// done (ratio / target_at(done))^(2 / (1 + 2 g)).
    pub fn next_check(&self, done: u32, ratio: f64) -> u32 {
        let predicted = if self.growth == 0.0 {
            done as f64 * (ratio / self.target).powi(2)
        } else {
            done as f64
                * (ratio / self.target_at(done as f64)).powf(2.0 / (1.0 + 2.0 * self.growth))
        };
        self.next_check_at(done, predicted)
    }

    /// The target an image with `mean_spp` samples per pixel must meet: `target`
    /// (mean_spp / min_spp)^growth (never below `target`); `target` itself when
    /// `growth` is 0.
    pub fn target_at(&self, mean_spp: f64) -> f64 {
        if self.growth == 0.0 {
            return self.target;
        }
        let first = self.min_spp.max(2) as f64;
        self.target * (mean_spp / first).max(1.0).powf(self.growth)
    }

    /// [`NoiseStop::next_check`] for a check predicted at `predicted` samples (with
    /// `adaptive_radius`: the fewest any still-sampling pixel wants), within the same
    /// bounds.
    pub fn next_check_at(&self, done: u32, predicted: f64) -> u32 {
        let predicted = predicted.ceil();
        let lo = done as f64 + (done.div_ceil(MIN_CHECK_STEP_DIVISOR)).max(1) as f64;
        let mut hi = done as f64 * MAX_CHECK_GROWTH as f64;
        if self.estimator == NoiseEstimator::Halves {
            hi = hi.min(next_power_of_two_above(done) as f64);
        }
        let next = if predicted.is_finite() {
            predicted.clamp(lo, hi.max(lo))
        } else {
            hi.max(lo)
        };
        next.min(u32::MAX as f64) as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::sensor::capture;
    use crate::scene::config::Blooming;

    /// The mean of `v` (an image `width` values a row) over the (2 r + 1)^2 window around
    /// each value, clipped at the image's edges (two passes of running sums): the reference
    /// [`kind_mean`]'s sums are checked against, and its code before they were fused.
    fn box_mean(v: &[f64], width: usize, r: usize) -> Vec<f64> {
        let height = v.len() / width;
        // Along the rows: each row's running sum on its own (rows on all cores).
        let mut rows = vec![0.0; v.len()];
        rows.par_chunks_mut(width)
            .zip(v.par_chunks(width))
            .for_each(|(out, src)| {
                let mut prefix = vec![0.0f64; width + 1];
                for j in 0..width {
                    prefix[j + 1] = prefix[j] + src[j];
                }
                for (j, o) in out.iter_mut().enumerate() {
                    let (lo, hi) = window(j, width, r);
                    *o = (prefix[hi] - prefix[lo]) / (hi - lo) as f64;
                }
            });
        // Along the columns: every column's running sum, a row at a time (the same sums in
        // the same order per column), then each output row from two of them (written over
        // the rows' pass, which the sums hold by then).
        let mut prefix = vec![0.0f64; (height + 1) * width];
        for y in 0..height {
            let (done, next) = prefix.split_at_mut((y + 1) * width);
            let (above, row) = (&done[y * width..], &mut next[..width]);
            for x in 0..width {
                row[x] = above[x] + rows[y * width + x];
            }
        }
        rows.par_chunks_mut(width)
            .take(height)
            .enumerate()
            .for_each(|(y, o)| {
                let (lo, hi) = window(y, height, r);
                let (a, b) = (&prefix[lo * width..], &prefix[hi * width..]);
                for ((o, b), a) in o.iter_mut().zip(b).zip(a) {
                    *o = (b - a) / (hi - lo) as f64;
                }
            });
        rows
    }

    fn sensor() -> SensorConfig {
        SensorConfig {
            exposure: crate::scene::config::ExposureSetting::Fixed { ms: 2.0 },
            gain_dn_per_electron: 0.5,
            dark_noise_electrons: 3.0,
            saturation_electrons: 1000.0,
            bit_depth: 12,
            ..SensorConfig::default()
        }
    }

    fn stop_of(target: f64, min_spp: u32, growth: f64) -> NoiseStop {
        NoiseStop {
            camera: CameraNoise {
                resp: Responsivity::uniform(1, 1, 1.0),
                sensor: sensor(),
                exposure_factor: 1.0,
            },
            target,
            min_spp,
            // "samples": no power-of-two bound on the next check.
            estimator: NoiseEstimator::Samples,
            adaptive_radius: None,
            growth,
            rays: None,
        }
    }

    #[test]
    fn a_growing_target_and_its_prediction() {
        // growth 0: the target itself and the 1 / sqrt(spp) prediction, as before.
        let fixed = stop_of(2.0, 4, 0.0);
        assert_eq!(fixed.target_at(100.0), 2.0);
        assert_eq!(fixed.next_check(4, 4.0), 16);
        // growth 0.5 from a first check at 4: target 2 sqrt(m / 4), never below 2.
        let g = stop_of(2.0, 4, 0.5);
        assert!((g.target_at(16.0) - 4.0).abs() < 1e-12);
        assert_eq!(g.target_at(2.0), 2.0);
        // Ratio 8 at 4 spp: the noise 8 sqrt(4 / n) meets 2 sqrt(n / 4) at n = 16, where
        // the target is 4.
        assert_eq!(g.next_check(4, 8.0), 16);
        // The prediction checks out: at 16 spp the ratio is 8 sqrt(4 / 16) = 4, met.
        assert!(8.0 * (4.0f64 / 16.0).sqrt() <= g.target_at(16.0) + 1e-12);
    }

    #[test]
    fn the_camera_noise_checked_against_is_the_captures_with_dark_current() {
        // A flat image on 128 x 128 pixels: the capture's spread over the pixels (no
        // fixed patterns) is its temporal noise, which the check's camera noise must
        // be: with a dark current twice the signal's charge, its shot noise is most of it.
        let (w, h) = (128u32, 128u32);
        let px = (w * h) as usize;
        let radiance = vec![1.0f32; px];
        let resp = Responsivity::uniform(w, h, 100_000.0); // 200 e- at 2 ms
        for dark_current in [0.0, 200_000.0] {
            let sensor = SensorConfig {
                saturation_electrons: 20_000.0,
                dark_current_electrons_per_s: dark_current, // 0 or 400 e- at 2 ms
                ..sensor()
            };
            let cam = CameraNoise {
                resp: resp.clone(),
                sensor: sensor.clone(),
                exposure_factor: 1.0,
            };
            let (sum, sq) = (vec![2.0f32; px], vec![2.0f32; px]);
            let all = vec![true; px];
            let (est, _) = cam
                .estimate(NoiseEstimator::Samples, &sum, &sq, 2, &all, &all)
                .unwrap();
            assert_eq!(est.pixels, px);
            let shot = if dark_current > 0.0 { 600.0 } else { 200.0 };
            let want = 0.25 * (shot + 9.0) + 1.0 / 12.0;
            assert!(
                (est.camera_rms_dn.powi(2) - want).abs() < 1e-9 * want,
                "{est:?}"
            );
            let c = capture(&resp, &radiance, est.exposure_s, &sensor, 7).unwrap();
            let codes: Vec<f64> = c.codes.iter().map(|&c| c as f64).collect();
            let mean = codes.iter().sum::<f64>() / px as f64;
            let var = codes.iter().map(|c| (c - mean).powi(2)).sum::<f64>() / (px - 1) as f64;
            // The variance of a variance from n normal draws: 2 sigma^4 / (n - 1), so
            // sqrt(2 / 16383) = 1.1 % relative: 5 % is over four of its deviations.
            let rel = var / want - 1.0;
            assert!(
                rel.abs() < 0.05,
                "dark current {dark_current}: capture {var} DN^2, check {want} ({rel:+.3})"
            );
        }
    }

    #[test]
    fn camera_variance_is_shot_dark_and_quantisation() {
        let s = sensor();
        // K^2 (mu + sd^2) + 1/12 = 0.25 (400 + 9) + 1/12.
        let v = camera_variance_dn(&s, 400.0);
        assert!((v - (102.25 + 1.0 / 12.0)).abs() < 1e-12, "{v}");
        // Dark: only the dark noise and quantisation.
        assert!((camera_variance_dn(&s, 0.0) - (2.25 + 1.0 / 12.0)).abs() < 1e-12);
    }

    #[test]
    fn mean_variance_of_known_samples() {
        // Samples 1, 2, 3, 6: mean 3, s^2 = (4 + 1 + 0 + 9) / 3 = 14/3, of the mean 14/12.
        let x = [1.0f64, 2.0, 3.0, 6.0];
        let (s, q) = (x.iter().sum::<f64>(), x.iter().map(|v| v * v).sum::<f64>());
        assert!((mean_variance(s, q, 4) - 14.0 / 12.0).abs() < 1e-12);
        assert_eq!(mean_variance(1.0, 1.0, 1), f64::INFINITY);
        // Rounding below zero is clamped.
        assert_eq!(mean_variance(3.0, 2.999_999, 3), 0.0);
    }

    #[test]
    fn estimate_by_hand_with_fixed_and_auto_exposure() {
        let s = sensor();
        // Two object pixels and a background pixel (not counted), 1e5 e-/s per unit
        // radiance; fixed 2 ms times a factor 1.5: 300 e- per unit radiance.
        let resp = Responsivity::uniform(3, 1, 1.0e5);
        let cam = CameraNoise {
            resp,
            sensor: s.clone(),
            exposure_factor: 1.5,
        };
        let n = 4u32;
        // Pixel 0: samples 1, 2, 3, 6 (mean 3, var of mean 14/12); pixel 1: all 0.5;
        // pixel 2 (background): anything.
        let sum = [12.0f32, 2.0, 100.0];
        let sum_sq = [50.0f32, 1.0, 1.0e4];
        let object = [true, true, false];
        let est = cam
            .estimate(NoiseEstimator::Samples, &sum, &sum_sq, n, &object, &object)
            .unwrap()
            .0;
        assert!((est.exposure_s - 3e-3).abs() < 1e-15);
        // Render: (K * 300)^2 * [14/12, 0]; camera: K^2 (900 + 9) + 1/12 and
        // K^2 (150 + 9) + 1/12 (pixel 0's 900 e- is below the 1000 e- full well).
        let render = (0.5f64 * 300.0).powi(2) * 14.0 / 12.0 / 2.0;
        let camera: f64 = (0.25 * 909.0 + 0.25 * 159.0 + 2.0 / 12.0) / 2.0;
        assert_eq!(est.pixels, 2);
        assert!((est.render_rms_dn - render.sqrt()).abs() < 1e-9, "{est:?}");
        assert!((est.camera_rms_dn - camera.sqrt()).abs() < 1e-9, "{est:?}");
        assert!((est.ratio - (render / camera).sqrt()).abs() < 1e-12);

        // Auto exposure: the 99.5th percentile of the exposure mask's rate (pixel 0:
        // 3 * 1e5 e-/s) at 0.9 of saturation (the ADC's 4095 / 0.5 = 8190 e- is above
        // the full well: 1000 e-), times the factor.
        let auto = CameraNoise {
            sensor: SensorConfig {
                exposure: crate::scene::config::ExposureSetting::Auto(
                    crate::scene::config::AutoExposure,
                ),
                ..s
            },
            ..cam.clone()
        };
        let est = auto
            .estimate(NoiseEstimator::Samples, &sum, &sum_sq, n, &object, &object)
            .unwrap()
            .0;
        let t = 0.9 * 1000.0 / 3.0e5 * 1.5;
        assert!((est.exposure_s / t - 1.0).abs() < 1e-12, "{est:?}");
        // Pixel 0 is now at 1.5 x 900 e- (above the full well): only pixel 1 counts,
        // which has no render noise.
        assert_eq!(est.pixels, 1);
        assert_eq!(est.ratio, 0.0);
        // An empty object mask counts every pixel; wrong lengths are an error.
        let est = cam
            .estimate(
                NoiseEstimator::Samples,
                &sum,
                &sum_sq,
                n,
                &object,
                &[false; 3],
            )
            .unwrap()
            .0;
        assert_eq!(est.pixels, 2, "the background pixel's mean is saturated");
        assert!(
            cam.estimate(NoiseEstimator::Samples, &sum, &sum_sq, n, &object, &[true])
                .is_err()
        );
        // Halves: pixel 0's samples 1, 2, 3, 6 hold levels 0 {1}, 1 {2}, 2 {3, 6}: the
        // two floats are level 2 (even) = 9 and level 1 (odd) = 2. P = 4, h = 2: halves
        // (1, 2) and (3, 6), means 1.5 and 4.5: (3^2) / 2 * 2 / 4 = 2.25.
        let levels = [9.0f32, 2.0, 1.0, 1.0, 0.0, 0.0];
        let est = cam
            .estimate(NoiseEstimator::Halves, &sum, &levels, n, &object, &object)
            .unwrap()
            .0;
        let render = (0.5f64 * 300.0).powi(2) * 2.25 / 2.0;
        assert!((est.render_rms_dn - render.sqrt()).abs() < 1e-9, "{est:?}");
        assert!(
            cam.estimate(NoiseEstimator::Halves, &sum, &sum_sq, n, &object, &object)
                .is_err(),
            "halves need two floats a pixel"
        );
    }

    /// The shader's level sums (glsl/path_trace.comp) for samples `x`: level L >= 1 holds
    /// indices [2^(L-1), 2^L), level 0 index 0, into float L & 1, cleared at its first.
    fn level_sums(x: &[f64]) -> [f64; 2] {
        let mut h = [0.0f64; 2];
        for (j, &r) in x.iter().enumerate() {
            let j = j as u32;
            let level = if j == 0 { 0 } else { 32 - j.leading_zeros() };
            let k = (level & 1) as usize;
            if j & j.wrapping_sub(1) == 0 {
                h[k] = 0.0;
            }
            h[k] += r;
        }
        h
    }

    #[test]
    fn halves_compare_the_two_halves_of_the_last_whole_block() {
        // n = 8: halves [0, 4) and [4, 8); n = 11: the same halves (P = 8, h = 4), scaled by
        // 4 / 11; n = 2: samples 0 and 1.
        let x: Vec<f64> = (0..11)
            .map(|k| ((k * 7) % 5) as f64 + 0.5 * k as f64)
            .collect();
        for n in [2usize, 3, 4, 5, 8, 11] {
            let p = 1usize << (usize::BITS - 1 - n.leading_zeros());
            let h = p / 2;
            let m1 = x[..h].iter().sum::<f64>() / h as f64;
            let m2 = x[h..2 * h].iter().sum::<f64>() / h as f64;
            let want = (m1 - m2).powi(2) / 2.0 * h as f64 / n as f64;
            let got = halves_mean_variance(x[..n].iter().sum(), level_sums(&x[..n]), n as u32);
            assert!(
                (got - want).abs() < 1e-9 * want.max(1.0),
                "n {n}: {got} vs {want}"
            );
        }
        assert_eq!(halves_mean_variance(1.0, [1.0, 0.0], 1), f64::INFINITY);
    }

    #[test]
    fn halves_are_unbiased_for_independent_samples() {
        // Uniform samples on [0, 1) (variance 1/12) from a fixed LCG: the mean of the
        // estimate over many pixels is 1 / (12 n) within its statistical error.
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for n in [2u32, 7, 16, 40] {
            let pixels = 20_000;
            let mut total = 0.0;
            for _ in 0..pixels {
                let x: Vec<f64> = (0..n).map(|_| uniform()).collect();
                total += halves_mean_variance(x.iter().sum(), level_sums(&x), n);
            }
            let got = total / pixels as f64 * 12.0 * n as f64;
            // One degree of freedom a pixel: relative error sqrt(2 / pixels) = 1 %.
            assert!((got - 1.0).abs() < 0.05, "n {n}: {got}");
        }
    }

    #[test]
    fn box_mean_averages_the_window_clipped_at_the_edges() {
        // A 3 x 2 image.
        let v = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        assert_eq!(box_mean(&v, 3, 0), v.to_vec());
        let m = box_mean(&v, 3, 1);
        assert_eq!(m[0], 3.0, "1 2 4 5");
        assert_eq!(m[1], 3.5, "all six");
        assert_eq!(m[5], 4.0, "2 3 5 6");
        assert_eq!(box_mean(&v, 3, 5), vec![3.5; 6]);
    }

    #[test]
    fn box_mean_equals_the_window_means_on_a_larger_image() {
        // 37 x 23 values, radius 4: each output against the plain mean of its clipped
        // window (the running sums round differently: within 1e-12).
        let (w, h, r) = (37usize, 23usize, 4usize);
        let v: Vec<f64> = (0..w * h)
            .map(|i| ((i * 7919) % 101) as f64 * 0.37 + 1.0)
            .collect();
        let m = box_mean(&v, w, r);
        for y in 0..h {
            for x in 0..w {
                let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
                let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
                let mut s = 0.0;
                for yy in y0..y1 {
                    for xx in x0..x1 {
                        s += v[yy * w + xx];
                    }
                }
                let want = s / ((y1 - y0) * (x1 - x0)) as f64;
                let got = m[y * w + x];
                assert!(
                    (got - want).abs() <= 1e-12 * want,
                    "({x}, {y}): {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn kind_mean_takes_each_pixels_own_kind_in_its_window() {
        // 29 x 17 values, radius 3; kind: a disc, in_mean: all but every 7th value.
        let (w, h, r) = (29usize, 17usize, 3usize);
        let v: Vec<f64> = (0..w * h)
            .map(|i| ((i * 7919) % 97) as f64 * 0.41 + 0.5)
            .collect();
        let kind = |i: usize| {
            let (x, y) = ((i % w) as f64 - 14.0, (i / w) as f64 - 8.0);
            x * x + y * y < 49.0
        };
        let in_mean: Vec<bool> = (0..w * h).map(|i| i % 7 != 3).collect();
        let m = kind_mean(&v, &in_mean, kind, w, r);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let (mut s, mut c) = (0.0, 0usize);
                for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                        let j = yy * w + xx;
                        if in_mean[j] && kind(j) == kind(i) {
                            s += v[j];
                            c += 1;
                        }
                    }
                }
                let want = if c == 0 { 0.0 } else { s / c as f64 };
                assert!(
                    (m[i] - want).abs() <= 1e-9 * want.max(1.0),
                    "({x}, {y}): {} vs {want}",
                    m[i]
                );
            }
        }
        // One kind everywhere: the plain window mean.
        let all = vec![true; w * h];
        let plain = kind_mean(&v, &all, |_| true, w, r);
        let b = box_mean(&v, w, r);
        assert!(plain.iter().zip(&b).all(|(p, b)| (p - b).abs() <= 1e-9 * b));
    }

    /// [`kind_mean`] as four [`box_mean`]s and their quotients (its definition, and its
    /// code before the sums were fused and the columns split over cores).
    fn kind_mean_by_box_means(
        v: &[f64],
        in_mean: &[bool],
        kind: impl Fn(usize) -> bool,
        width: usize,
        r: usize,
    ) -> Vec<f64> {
        let of_kind = |k: bool| {
            let w: Vec<f64> = (0..v.len())
                .map(|i| (in_mean[i] && kind(i) == k) as u8 as f64)
                .collect();
            let vw: Vec<f64> = v.iter().zip(&w).map(|(v, w)| v * w).collect();
            (box_mean(&vw, width, r), box_mean(&w, width, r))
        };
        let least = 0.5 / ((2 * r + 1) * (2 * r + 1)) as f64;
        let (a, b) = (of_kind(true), of_kind(false));
        (0..v.len())
            .map(|i| {
                let (s, w) = if kind(i) {
                    (a.0[i], a.1[i])
                } else {
                    (b.0[i], b.1[i])
                };
                if w > least { s / w } else { 0.0 }
            })
            .collect()
    }

    #[test]
    fn kind_mean_equals_its_box_means_bit_for_bit() {
        // Sizes below, at and across the column chunks, radii from 0 to past the image,
        // one kind or two, values spanning decades (rounding shows), some left out.
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(7);
        for (w, h, r) in [
            (1, 1, 0),
            (5, 3, 2),
            (31, 9, 1),
            (32, 32, 4),
            (33, 7, 9),
            (97, 41, 4),
            (300, 20, 3),
        ] {
            for kinds in [1, 2] {
                let v: Vec<f64> = (0..w * h)
                    .map(|_| 10f64.powf(rng.random_range(-6.0..3.0)) * rng.random_range(-0.2..1.0))
                    .collect();
                let in_mean: Vec<bool> = (0..w * h).map(|_| rng.random::<f64>() < 0.8).collect();
                let kind_of: Vec<bool> = (0..w * h)
                    .map(|i| kinds == 1 || (i * 7 + i / w * 3) % 5 < 3)
                    .collect();
                let kind = |i: usize| kind_of[i];
                let fused = kind_mean(&v, &in_mean, kind, w, r);
                let want = kind_mean_by_box_means(&v, &in_mean, kind, w, r);
                for (i, (a, b)) in fused.iter().zip(&want).enumerate() {
                    assert_eq!(
                        a.to_bits(),
                        b.to_bits(),
                        "{w} x {h}, r {r}, {kinds} kinds, value {i}: {a} vs {b}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_check_above_the_target_never_stops_every_pixel() {
        // Random images (an object disc on a background, some pixels saturated, the
        // variance in rare bright pixels as glints leave it, pixels with their own
        // samples, some stopped at an earlier check): for every target below the
        // estimate some pixel still sampling wants more samples than it has, and for
        // every target above it none does.
        use rand::{Rng, SeedableRng};
        let sensor = sensor();
        let (w, h) = (40usize, 30usize);
        let px = w * h;
        let cam = CameraNoise {
            resp: Responsivity::uniform(w as u32, h as u32, 100.0),
            sensor: sensor.clone(),
            exposure_factor: 1.0,
        };
        let samples = NoiseEstimator::Samples;
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        for trial in 0..40 {
            let object: Vec<bool> = (0..px)
                .map(|i| {
                    let (x, y) = ((i % w) as f64 - 20.0, (i / w) as f64 - 15.0);
                    x * x + y * y < 100.0
                })
                .collect();
            // Most pixels still sampling (6 samples), a third stopped earlier (2 to 5).
            let counts: Vec<u32> = (0..px)
                .map(|_| match rng.random_bool(0.3) {
                    true => rng.random_range(2..6),
                    false => 6,
                })
                .collect();
            let (mut sum, mut sq) = (vec![0f32; px], vec![0f32; px]);
            for i in 0..px {
                let n = counts[i] as f32;
                let x = if rng.random_bool(0.03) {
                    1e6
                } else {
                    rng.random_range(1.0..5.0)
                };
                let d = if rng.random_bool(0.1) {
                    rng.random_range(0.0..3.0)
                } else {
                    0.05
                };
                sum[i] = n * x;
                sq[i] = n * (x * x + d * d);
            }
            let each = PixelSamples::Each(&counts);
            let (est, image) = cam
                .estimate(samples, &sum, &sq, each, &object, &object)
                .unwrap();
            // The shares for a target t (and a growing one, `grown`).
            let wanted = |t: f64, grown: Option<(&(dyn Fn(f64) -> f64 + Sync), f64)>| {
                cam.pixel_samples_wanted(
                    samples,
                    &sum,
                    &sq,
                    each,
                    &image,
                    &object,
                    w,
                    t,
                    grown,
                    (trial % 4) as u32,
                )
            };
            for f in [0.3, 0.7, 0.95, 0.999, 1.001, 1.5] {
                let want = wanted(est.ratio * f, None);
                let more = (0..px).any(|i| counts[i] == 6 && want[i] > 6.0);
                assert_eq!(more, f < 1.0, "trial {trial}, target {f} x the estimate");
                // A growing target (from `est.ratio * f` at the mean now, as sqrt(m)):
                // the same, and the shares are those of the fixed target the grown one
                // reaches at the mean they give.
                let now = est.mean_spp;
                let base = est.ratio * f;
                let target_at = |m: f64| base * (m / now).max(1.0).sqrt();
                let grown = wanted(base, Some((&target_at, est.ratio)));
                let more = (0..px).any(|i| counts[i] == 6 && grown[i] > 6.0);
                assert_eq!(
                    more,
                    f < 1.0,
                    "trial {trial}, grown from {f} x the estimate"
                );
                // Stopped pixels (fewer than 6) keep their samples; a target out of reach
                // (the stopped pixels' variance above it) makes every share infinite.
                let mean_of = |want: &[f64]| {
                    (0..px)
                        .map(|i| match counts[i] < 6 {
                            true => counts[i] as f64,
                            false => want[i].max(6.0),
                        })
                        .sum::<f64>()
                        / px as f64
                };
                let m = mean_of(&grown);
                let at_m = wanted(target_at(m), None);
                // The grown shares aim at T <= target_at(m), met at their end: the fixed
                // target's shares at target_at(m) ask for no more; and at most the fixed
                // base target's (the grown one is at least that).
                let m2 = mean_of(&at_m);
                assert!(
                    m2 <= m * (1.0 + 1e-12) && m <= mean_of(&want) * (1.0 + 1e-12),
                    "trial {trial}, {f}: the grown shares' mean {m}, the fixed target's at it {m2}, at the base {}",
                    mean_of(&want)
                );
            }
        }
    }

    /// The "samples" sums of pixels of 2 samples x - d and x + d each: their sum and
    /// their sum of squares (the mean x, the mean's variance d^2).
    fn two_samples(x: &[f32], d: &[f32]) -> (Vec<f32>, Vec<f32>) {
        let sum = x.iter().map(|x| 2.0 * x).collect();
        let sq = x
            .iter()
            .zip(d)
            .map(|(x, d)| 2.0 * (x * x + d * d))
            .collect();
        (sum, sq)
    }

    #[test]
    fn pixels_that_blooming_fills_are_counted_as_their_own() {
        // One column of five pixels, 0.2 e- per unit radiance at the fixed 2 ms, full
        // well 1000 e-: pixel 0 at 2000 e- spills 1000 e- down its column in the
        // capture, filling pixels 1 and 2. The criterion counts those two by their own
        // means, as without blooming: the same estimate, rays' sums and samples.
        let x = [10_000.0f32, 2500.0, 2500.0, 2500.0, 2500.0];
        let d = [5.0f32, 40.0, 30.0, 20.0, 10.0];
        let (sum, sq) = two_samples(&x, &d);
        let rays: Vec<f32> = x
            .iter()
            .zip(&d)
            .flat_map(|(x, d)| [2.0 * x, 2.0 * (x * x + d * d / 4.0)])
            .collect();
        let cam = |blooming: Blooming| CameraNoise {
            resp: Responsivity::uniform(1, 5, 100.0),
            sensor: SensorConfig {
                blooming,
                ..sensor()
            },
            exposure_factor: 1.0,
        };
        let all = [true; 5];
        let samples = NoiseEstimator::Samples;
        let (bloom, plain) = (cam(Blooming::Vertical), cam(Blooming::None));
        let (est, image) = bloom.estimate(samples, &sum, &sq, 2, &all, &all).unwrap();
        let (own, plain_image) = plain.estimate(samples, &sum, &sq, 2, &all, &all).unwrap();
        assert_eq!(est.pixels, 4, "only pixel 0 is saturated in its own right");
        assert_eq!(est, own);
        assert_eq!(
            bloom.ray_variances(samples, &sum, &sq, &rays, 2, &image, &all),
            plain.ray_variances(samples, &sum, &sq, &rays, 2, &plain_image, &all)
        );
        let want =
            bloom.pixel_samples_wanted(samples, &sum, &sq, 2, &image, &all, 1, 0.01, None, 0);
        assert!(want[1] > 2.0 && want[2] > 2.0, "{want:?}");
        assert_eq!(want[0], 0.0, "{want:?}");
    }

    #[test]
    fn wanted_samples_follow_the_root_of_the_variance_and_meet_the_target() {
        // Five pixels of 2 samples x - d, x + d: the mean's variance d^2, a sample's 2 d^2;
        // the last one saturated (its code clips: no noise of either kind).
        let sensor = sensor();
        let cam = CameraNoise {
            resp: Responsivity::uniform(5, 1, 100.0),
            sensor: sensor.clone(),
            exposure_factor: 1.0,
        };
        let x = [3.0f32, 3.0, 3.0, 3.0, 1e5];
        let d = [0.0f32, 1.0, 2.0, 4.0, 1.0];
        let (sum, sq) = two_samples(&x, &d);
        let all = [true; 5];
        let samples = NoiseEstimator::Samples;
        let (est, image) = cam.estimate(samples, &sum, &sq, 2, &all, &all).unwrap();
        assert_eq!(est.pixels, 4, "the saturated pixel is not counted");
        let k_e = sensor.gain_dn_per_electron * 100.0 * est.exposure_s;
        let camera: f64 = (0..4)
            .map(|i| camera_variance_dn(&sensor, x[i] as f64 * 100.0 * est.exposure_s))
            .sum();
        let per_sample = |i: usize| k_e * k_e * 2.0 * (d[i] as f64).powi(2);
        let wanted = |target: f64, radius: u32| {
            cam.pixel_samples_wanted(samples, &sum, &sq, 2, &image, &all, 5, target, None, radius)
        };
        // The render variance with those samples (a pixel keeps the 2 it has).
        let render = |want: &[f64]| {
            (1..4)
                .map(|i| per_sample(i) / want[i].max(2.0))
                .sum::<f64>()
        };
        let target = (render(&[2.0; 5]) / camera).sqrt() / 8.0; // 64 x fewer variance
        let want = wanted(target, 0);
        assert_eq!((want[0], want[4]), (0.0, 0.0), "no spread, saturated");
        assert!(want[1] > 2.0, "{want:?}");
        assert!((want[2] / want[1] - 2.0).abs() < 1e-9, "{want:?}");
        assert!((want[3] / want[1] - 4.0).abs() < 1e-9, "{want:?}");
        // With those samples the render noise is the target times the camera's.
        assert!((render(&want) / camera - target * target).abs() < 1e-9 * target * target);
        // A target pixel 1 meets with its 2 samples: it keeps them, pixels 2 and 3
        // share the rest (still 1 : 2), the target met.
        let target = (render(&[2.0; 5]) / camera).sqrt() * 0.7;
        let want = wanted(target, 0);
        assert!(want[1] <= 2.0 && want[2] > 2.0, "{want:?}");
        assert!((want[3] / want[2] - 2.0).abs() < 1e-9, "{want:?}");
        assert!((render(&want) / camera - target * target).abs() < 1e-9 * target * target);
        // Met already: nobody wants more.
        let met = wanted((render(&[2.0; 5]) / camera).sqrt() * 1.01, 0);
        assert!(met.iter().all(|&w| w <= 2.0), "{met:?}");
        let target = (render(&[2.0; 5]) / camera).sqrt() / 8.0;
        // Averaged over the neighbours (radius 1), pixel 0 takes its neighbours' share.
        let smooth = wanted(target, 1);
        assert!(smooth[0] > 0.0 && smooth[4] > 0.0, "{smooth:?}");
        // Per-pixel counts: pixel 1 with 8 samples, four x - d and four x + d: a sample's
        // variance 8 d^2 / 7 (pixel 2's: 2 (2 d)^2, d = 1).
        let mut sum8 = sum.clone();
        let mut sq8 = sq.clone();
        sum8[1] *= 4.0;
        sq8[1] *= 4.0;
        let counts = [2, 8, 2, 2, 2];
        let each = PixelSamples::Each(&counts);
        let (est8, image8) = cam
            .estimate(samples, &sum8, &sq8, each, &all, &all)
            .unwrap();
        assert_eq!((est8.spp, est8.mean_spp), (8, 16.0 / 5.0));
        // (Pixels 0 and 2 to 4 have fewer samples than the most: stopped for good, their
        // variance spent, 20 of the 21 units (k_e^2) of `render` at 2 samples each;
        // pixel 1 holds 1 / 7 at its 8. A budget of 20.05 units is then left to pixel 1
        // alone, which wants more than its 8.)
        let target8 = (render(&[2.0; 5]) * (20.05 / 21.0) / camera).sqrt();
        let want8 = cam.pixel_samples_wanted(
            samples, &sum8, &sq8, each, &image8, &all, 5, target8, None, 0,
        );
        assert!(want8[1] > 8.0 && want8[1].is_finite(), "{want8:?}");
        let ratio = (8.0f64 / 7.0).sqrt() / (2.0 * 2.0f64.sqrt());
        assert!((want8[1] / want8[2] - ratio).abs() < 1e-6, "{want8:?}");
    }

    #[test]
    fn checks_follow_the_prediction_within_bounds() {
        let stop = NoiseStop {
            camera: CameraNoise {
                resp: Responsivity::uniform(1, 1, 1.0),
                sensor: sensor(),
                exposure_factor: 1.0,
            },
            target: 1.0,
            min_spp: 16,
            estimator: NoiseEstimator::Samples,
            adaptive_radius: None,
            growth: 0.0,
            rays: None,
        };
        assert_eq!(stop.first_check(1000), 16);
        assert_eq!(stop.first_check(8), 8);
        // Ratio 1.5 at 64 spp: predicted 64 * 2.25 = 144.
        assert_eq!(stop.next_check(64, 1.5), 144);
        // Far off: at most 4x; barely above: at least done / 64 more (the overshoot
        // past the samples the target needs, 1024 * 1.001^2 = 1026.05, stays under 1.6 %).
        assert_eq!(stop.next_check(64, 10.0), 256);
        assert_eq!(stop.next_check(1024, 1.001), 1040);
        assert_eq!(stop.next_check(12000, 1.003), 12188);
        assert_eq!(stop.next_check(3, 1.001), 4);
        // Halves: never past the next power of two (where the estimate learns more).
        let halves = NoiseStop {
            estimator: NoiseEstimator::Halves,
            ..stop.clone()
        };
        assert_eq!(halves.next_check(64, 1.2), 93, "within: as predicted");
        assert_eq!(
            halves.next_check(32, 3.0),
            64,
            "predicted 288, capped at 64"
        );
        assert_eq!(halves.next_check(64, 10.0), 128);
        assert_eq!(halves.next_check(48, 3.0), 64);
        assert_eq!(
            halves.next_check(1024, 1.001),
            1040,
            "the smallest step stays"
        );
    }

    #[test]
    fn the_rays_chosen_reach_the_target_in_the_least_time() {
        let c = RayChoice {
            min: 1,
            max: 64,
            cost: 0.035,
        };
        // V_A: the closed form's variance over a pixel's rays, C = V_A / m0.
        let at = |m0: u32, variance: f64, v_a: f64, target: f64| RayCheck {
            done: 2,
            variance,
            rays: v_a / m0 as f64,
            target,
            first_stop: 4,
            step: 4,
            most: 256,
        };
        // No spread, the target met at the first check whatever the count: one ray.
        assert_eq!(c.choose(16, &at(16, 1.0, 0.0, 0.4)), 1);
        // A spread that keeps 16 rays from the first check: the fewest rays that reach
        // it. m = 24: V = 0.1 + 16 / 24, (2 x 1.1 + 2 V) / 16 x 1.25 = 0.29 <= 0.3; 16
        // rays: 0.34 (the check at 8 instead).
        assert_eq!(c.choose(16, &at(16, 1.1, 16.0, 0.3)), 24);
        // Within the bounds given: at most 16, the check at 8 is the earliest; 8 rays
        // get there (0.289 with the headroom) and 4 only at 16 (15.96 against 7.68).
        let narrow = RayChoice {
            min: 4,
            max: 16,
            ..c
        };
        assert_eq!(narrow.choose(16, &at(16, 1.1, 16.0, 0.3)), 8);
        assert_eq!(narrow.choose(16, &at(16, 1.0, 0.0, 0.4)), 4);
        // A target no count reaches within `most`: the least variance per unit of time,
        // V(m) (1 + k m), least at sqrt(V_A / (k V_R)) = 48 here.
        let spread = 48.0 * 48.0 * 0.035;
        assert_eq!(c.choose(16, &at(16, 1.0 + spread / 16.0, spread, 1e-9)), 48);
        // The spread alone: the most.
        assert_eq!(c.choose(16, &at(16, 10.0 / 16.0, 10.0, 1e-9)), 64);
        // Nothing known: kept.
        assert_eq!(c.choose(16, &at(16, 0.0, 0.0, 1.0)), 16);
        assert_eq!(c.choose(16, &at(16, f64::NAN, 1.0, 1.0)), 16);
        assert_eq!(c.choose(16, &at(16, f64::INFINITY, 1.0, 1.0)), 16);
        // Near the current count's time (within the margin): kept.
        let spread = 18.0 * 18.0 * 0.035;
        assert_eq!(c.choose(16, &at(16, 1.0 + spread / 16.0, spread, 1e-9)), 16);
    }
}
