//! Sub-model 2: per-ring appearance draws (jitter, widths, tilt, weights, noise) and
//! the ring order flips.

use std::f32::consts::PI;

use rand::Rng;
use rand_distr::{Distribution, Poisson, StandardNormal, Uniform};
use rayon::prelude::*;
use rustfft::FftPlanner;
use rustfft::num_complex::Complex32;

use super::MilledParams;
use super::path::PathPoint;
use super::raster::annulus_hits_rect;
use crate::texture::rng::stream;

/// Normal distribution by mean and standard deviation; sd 0 gives the mean.
#[derive(Clone, Copy)]
struct Gauss(f64, f64);
impl Gauss {
    fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        let z: f64 = rng.sample(StandardNormal);
        self.0 + self.1 * z
    }
}

/// One sampled ring, compact for the raster loop.
pub(super) struct Ring {
    pub(super) c: [f32; 2],
    pub(super) dir: [f32; 2],
    pub(super) r_in: f32,
    pub(super) r_out: f32,
    pub(super) r0: f32,
    pub(super) wm: f32,
    pub(super) wi: f32,
    pub(super) wo: f32,
    /// 1 / w for the three components (0 where the width is 0).
    pub(super) inv_w: [f32; 3],
    pub(super) tilt: [[f32; 2]; 3],
    pub(super) ab: [f32; 2],
    pub(super) noise_amp: f32,
    pub(super) noise_off: usize,
    pub(super) noise_len: usize,
}

/// Samples every ring's appearance, applies the order flips, and drops rings whose band
/// misses the texture. Returns rings in composition order and the shared noise pool.
pub(super) fn sample_rings(
    p: &MilledParams,
    path: &[PathPoint],
    w: f64,
    h: f64,
    seed: u64,
) -> (Vec<Ring>, Vec<f32>) {
    let conf = p.conf;
    // (Sigma_c)_ii = factor * delta / conf follows the paper's 3-sigma rule ("standard
    // deviations were chosen ... such that the desired ranges are obtained. Hence
    // conf = 3"): factor * delta is the range, / conf the standard deviation in mm. A
    // variance would be (range / conf)^2. See docs/texture.md.
    let sd_c = p.center_noise * p.delta_mm / conf;
    let normal = |m: f64, s: f64| Gauss(m, s / conf);
    let d_wm = normal(p.w_minus_mean_mm, p.w_minus_sigma_mm);
    let d_wi = normal(p.w_inner_mean_mm, p.w_inner_sigma_mm);
    let d_wo = normal(p.w_outer_mean_mm, p.w_outer_sigma_mm);
    let d_t = [
        (
            normal(p.l_minus_mean, p.lh_minus_sigma),
            normal(p.h_minus_mean, p.lh_minus_sigma),
        ),
        (
            normal(p.l_inner_mean, p.lh_inner_sigma),
            normal(p.h_inner_mean, p.lh_inner_sigma),
        ),
        (
            normal(p.l_outer_mean, p.lh_outer_sigma),
            normal(p.h_outer_mean, p.lh_outer_sigma),
        ),
    ];
    let d_a = Uniform::new_inclusive(p.a_min, p.a_max).ok();
    let d_b = Uniform::new_inclusive(p.b_min, p.b_max).ok();
    let r0 = p.head_diameter_mm / 2.0;

    struct Draft {
        ring: Ring,
        noise: Vec<f32>,
        key: f64,
    }
    let reach = p
        .flip_reach_rings
        .unwrap_or((p.head_diameter_mm / p.delta_mm).ceil().max(1.0) as u32);
    let drafts: Vec<Option<Draft>> = path
        .par_iter()
        .enumerate()
        .map_init(FftPlanner::<f32>::new, |planner, (k, q)| {
            let mut rng = stream(seed, 1, k as u64);
            let jitter = |rng: &mut rand_pcg::Pcg64Mcg| Gauss(0.0, sd_c).sample(rng);
            let cx = q.x + jitter(&mut rng);
            let cy = q.y + jitter(&mut rng);
            // Negative draws of widths/scales (the paper's sigmas allow them) mean the
            // component is absent, not inverted.
            let wm = d_wm.sample(&mut rng).max(1e-6);
            let wi = d_wi.sample(&mut rng).max(0.0).min(r0 - wm / 2.0);
            let wo = d_wo.sample(&mut rng).max(0.0);
            let mut tilt = [[0.0f32; 2]; 3];
            for (t, (dl, dh)) in tilt.iter_mut().zip(&d_t) {
                *t = [
                    dl.sample(&mut rng).max(0.0) as f32,
                    dh.sample(&mut rng).max(0.0) as f32,
                ];
            }
            let a = d_a.map(|u| u.sample(&mut rng)).unwrap_or(p.a_min);
            let b = d_b.map(|u| u.sample(&mut rng)).unwrap_or(p.b_min);
            let flipped = rng.random::<f64>() < p.flip_fraction;
            let key = if flipped {
                k as f64 + rng.random_range(1..=reach) as f64 + 0.5
            } else {
                k as f64
            };
            let r_in = r0 - wm / 2.0 - wi;
            let r_out = r0 + wm / 2.0 + wo;
            if !annulus_hits_rect(cx, cy, r_in, r_out, 0.0, 0.0, w, h) {
                return None;
            }
            let (noise, noise_amp) = ring_noise(p, &mut rng, planner);
            Some(Draft {
                ring: Ring {
                    c: [cx as f32, cy as f32],
                    dir: [q.dir[0] as f32, q.dir[1] as f32],
                    r_in: r_in as f32,
                    r_out: r_out as f32,
                    r0: r0 as f32,
                    wm: wm as f32,
                    wi: wi as f32,
                    wo: wo as f32,
                    inv_w: [wm, wi, wo].map(|w| if w > 0.0 { (1.0 / w) as f32 } else { 0.0 }),
                    tilt,
                    ab: [a as f32, b as f32],
                    noise_amp,
                    noise_off: 0,
                    noise_len: 0,
                },
                noise,
                key,
            })
        })
        .collect();
    let mut drafts: Vec<Draft> = drafts.into_iter().flatten().collect();
    drafts.sort_by(|a, b| a.key.total_cmp(&b.key));
    let mut pool = Vec::with_capacity(drafts.iter().map(|d| d.noise.len()).sum());
    let rings = drafts
        .into_iter()
        .map(|mut d| {
            d.ring.noise_off = pool.len();
            d.ring.noise_len = d.noise.len();
            pool.extend_from_slice(&d.noise);
            d.ring
        })
        .collect();
    (rings, pool)
}

/// Noise N_k over the ring angle: lambda_k ~ P(lambda) sines with integer frequencies
/// tau ~ P(tau) (cycles per turn, so the ring closes) and phases ~ U(-pi, pi), tabulated
/// by one inverse FFT. Each sine has unit amplitude (the paper's sum, not renormalised),
/// so the noise RMS is sqrt(lambda_k / 2) and grows with lambda; the per-sine amplitude
/// `noise_amplitude` is applied in the raster loop.
fn ring_noise(
    p: &MilledParams,
    rng: &mut rand_pcg::Pcg64Mcg,
    planner: &mut FftPlanner<f32>,
) -> (Vec<f32>, f32) {
    if p.noise_amplitude <= 0.0 || p.noise_lambda <= 0.0 {
        return (Vec::new(), 0.0);
    }
    let lambda = Poisson::new(p.noise_lambda)
        .map(|d| d.sample(rng) as usize)
        .unwrap_or(0);
    if lambda == 0 {
        return (Vec::new(), 0.0);
    }
    let taus: Vec<(usize, f32)> = (0..lambda)
        .map(|_| {
            let tau = if p.noise_tau > 0.0 {
                Poisson::new(p.noise_tau)
                    .map(|d| d.sample(rng) as usize)
                    .unwrap_or(0)
            } else {
                0
            };
            (tau, rng.random_range(-PI..PI))
        })
        .collect();
    let max_tau = taus.iter().map(|t| t.0).max().unwrap_or(0);
    // >= 8 samples per cycle keeps linear interpolation error below ~8 %.
    let n = (8 * (max_tau + 1)).next_power_of_two().max(64);
    let mut spec = vec![Complex32::new(0.0, 0.0); n];
    for &(tau, xi) in &taus {
        spec[tau % n] += Complex32::from_polar(1.0, xi);
    }
    planner.plan_fft_inverse(n).process(&mut spec);
    let table = spec.iter().map(|c| c.im).collect();
    (table, p.noise_amplitude as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// RMS of the ring noise (per unit sine amplitude) averaged over many rings.
    fn mean_rms(lambda: f64) -> f64 {
        let p = MilledParams {
            noise_lambda: lambda,
            ..Default::default()
        };
        let mut planner = FftPlanner::new();
        let mut sum = 0.0;
        let n = 200;
        for k in 0..n {
            let mut rng = stream(3, 7, k);
            let (table, amp) = ring_noise(&p, &mut rng, &mut planner);
            assert_eq!(amp, p.noise_amplitude as f32);
            let ms = table.iter().map(|&v| (v as f64).powi(2)).sum::<f64>() / table.len() as f64;
            sum += ms.sqrt();
        }
        sum / n as f64
    }

    /// The paper's lambda set {30, 50, 70} must change the noise: lambda_k unit sines
    /// have an RMS of sqrt(lambda_k / 2) (no renormalisation).
    #[test]
    fn ring_noise_grows_with_lambda() {
        for lambda in [30.0, 50.0, 70.0] {
            let rms = mean_rms(lambda);
            let want = (lambda / 2.0).sqrt();
            assert!(
                (rms / want - 1.0).abs() < 0.05,
                "lambda {lambda}: rms {rms}, want {want}"
            );
        }
    }
}
