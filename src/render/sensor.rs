//! The camera's sensor after EMVA 1288 (release 4.0, the linear camera model): image
//! plane irradiance from the path-traced radiance, photons, electrons with shot and dark
//! noise, optional dark current, dark signal and photo-response non-uniformity (DSNU,
//! PRNU), full-well clipping with vertical blooming,
//! system gain K and quantisation. A CPU step on the linear radiance, so exposure and noise
//! can be redone without rendering. Model, parameters and approximations:
//! docs/rendering.md ("Sensor").

use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal, Poisson};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::scene::Camera;
use crate::scene::config::{AutoStatistic, Blooming, ExposureSetting, SensorConfig};

/// Planck's constant, J s.
pub const PLANCK: f64 = 6.626_070_15e-34;
/// Speed of light, m / s.
pub const LIGHT_SPEED: f64 = 299_792_458.0;

/// What is wrong with a sensor input.
#[derive(Debug, thiserror::Error)]
pub enum SensorError {
    #[error("sensor: {0}")]
    Invalid(String),
}

/// Per pixel, the mean number of electrons per second for a radiance of 1 W sr^-1 m^-2
/// reaching the camera through that pixel (quantum efficiency included).
#[derive(Clone, Debug, PartialEq)]
pub struct Responsivity {
    pub width: u32,
    pub height: u32,
    pub electrons_per_s: Vec<f64>,
}

impl Responsivity {
    /// From the camera geometry: the power on a pixel is `L * A * cos(theta) * Omega`,
    /// aperture area `A = pi (f / 2N)^2`, `Omega` the pixel's solid angle seen from the
    /// pupil (its pinhole rays: `cos^3(theta)` times the area in undistorted normalised
    /// coordinates, the distortion's Jacobian included) and `theta` the chief ray's angle
    /// to the axis, which gives `pi L p^2 cos^4(theta) |J| / (4 N^2)` for pixel pitch p.
    /// Photons: power * lambda / (h c); electrons: times the quantum efficiency.
    /// `focal_mm`: the pinhole-to-sensor distance (`camera.focal_mm`), `f_number`: the
    /// working f-number.
    pub fn new(cam: &Camera, focal_mm: f64, f_number: f64, sensor: &SensorConfig) -> Self {
        let (w, h) = (cam.width, cam.height);
        let f = focal_mm * 1e-3;
        let aperture = std::f64::consts::PI * (f / (2.0 * f_number)).powi(2);
        // Pixel size in undistorted normalised coordinates (1/fx, 1/fy) before the
        // distortion's Jacobian.
        let dx = 2.0 * cam.tan_half_w as f64 / w as f64;
        let dy = 2.0 * cam.tan_half_h as f64 / h as f64;
        let photon_j = PLANCK * LIGHT_SPEED / (sensor.wavelength_nm * 1e-9);
        let k = aperture * dx * dy / photon_j * sensor.quantum_efficiency;
        let mut out = Vec::with_capacity(w as usize * h as usize);
        for py in 0..h {
            for px in 0..w {
                let d = cam.pixel_dir(px, py);
                let cos = d.dot(cam.forward).max(0.0) as f64;
                let jac = if cam.distortion.is_zero() {
                    1.0
                } else {
                    // Undistorted coordinates of the ray; the pixel's area there is its
                    // distorted area over the distortion's Jacobian determinant.
                    let z = d.dot(cam.forward);
                    let x = d.dot(cam.right) / z;
                    let y = -d.dot(cam.up) / z;
                    1.0 / cam.distortion.jacobian_det(x, y).abs().max(1e-9) as f64
                };
                out.push(k * cos.powi(4) * jac);
            }
        }
        Responsivity {
            width: w,
            height: h,
            electrons_per_s: out,
        }
    }

    /// A uniform responsivity (tests, flat-field targets).
    pub fn uniform(width: u32, height: u32, electrons_per_s: f64) -> Self {
        Responsivity {
            width,
            height,
            electrons_per_s: vec![electrons_per_s; width as usize * height as usize],
        }
    }

    /// Mean electrons per pixel (noise free, before clipping) for `radiance` and
    /// exposure time `t_s`; NaN and negative radiance count as 0.
    pub fn mean_electrons(&self, radiance: &[f32], t_s: f64) -> Vec<f64> {
        radiance
            .iter()
            .zip(&self.electrons_per_s)
            .map(|(&l, &r)| pixel_electrons(l, r, t_s))
            .collect()
    }
}

/// One pixel's mean electrons ([`Responsivity::mean_electrons`]): radiance `l` at
/// `r` electrons per second and unit radiance, for `t_s` seconds; NaN and negative
/// radiance count as 0.
fn pixel_electrons(l: f32, r: f64, t_s: f64) -> f64 {
    if l > 0.0 { l as f64 * r * t_s } else { 0.0 }
}

/// The largest code of `bits` bits.
pub fn max_code(bits: u32) -> f64 {
    ((1u64 << bits) - 1) as f64
}

/// Saturation in electrons: the full well or the ADC's top code, whichever comes first.
pub fn saturation_electrons(s: &SensorConfig) -> f64 {
    let adc = (max_code(s.bit_depth) - s.black_level_dn) / s.gain_dn_per_electron;
    s.saturation_electrons.min(adc)
}

/// The exposure time for `sensor.exposure`: a fixed time, or "auto": the time at which
/// the `auto_percentile` percentile (or, with `auto_statistic = "mean"`, the mean) of
/// the noise-free signal of the pixels in `mask`
/// (all pixels when None or when the mask selects none) is `auto_fraction` of
/// saturation ([`saturation_electrons`]). Errors when those pixels are all dark.
pub fn exposure_time_s(
    resp: &Responsivity,
    radiance: &[f32],
    mask: Option<&[bool]>,
    sensor: &SensorConfig,
) -> Result<f64, SensorError> {
    match sensor.exposure {
        ExposureSetting::Fixed { ms } => Ok(ms * 1e-3),
        ExposureSetting::Auto(_) => {
            // The signal per second of the pixels in `m`, in pixel order (on all cores;
            // `Responsivity::mean_electrons` at 1 s of those pixels alone).
            let pick = |m: Option<&[bool]>| -> Vec<f64> {
                let pixels = radiance.par_iter().zip(&resp.electrons_per_s);
                let rate = |(&l, &r): (&f32, &f64)| pixel_electrons(l, r, 1.0);
                match m {
                    Some(m) => pixels
                        .zip(m)
                        .filter(|(_, in_mask)| **in_mask)
                        .map(|(p, _)| rate(p))
                        .collect(),
                    None => pixels.map(rate).collect(),
                }
            };
            let mut v = pick(mask);
            if v.is_empty() {
                v = pick(None);
            }
            let (p, what) = match sensor.auto_statistic {
                AutoStatistic::Percentile => (
                    percentile(&mut v, sensor.auto_percentile),
                    format!("the {} percentile", sensor.auto_percentile),
                ),
                AutoStatistic::Mean => (
                    v.iter().sum::<f64>() / v.len().max(1) as f64,
                    "the mean".to_string(),
                ),
            };
            if p.is_nan() || p <= 0.0 {
                return Err(SensorError::Invalid(format!(
                    "exposure = \"auto\": {what} of the object's pixels is dark (no light reaches them); give `exposure = {{ ms = ... }}`"
                )));
            }
            Ok(sensor.auto_fraction * saturation_electrons(sensor) / p)
        }
    }
}

/// The `pct` percentile (0..100) of `v` by the nearest-rank method (reorders `v`: a
/// selection, not a full sort; the same value a sort would give).
pub fn percentile(v: &mut [f64], pct: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let rank = ((pct / 100.0) * v.len() as f64).ceil() as usize;
    let k = rank.clamp(1, v.len()) - 1;
    *v.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1
}

/// One exposure: digital numbers per pixel (row-major, `bit_depth` bits) and the
/// exposure time used.
#[derive(Clone, Debug, PartialEq)]
pub struct Capture {
    pub width: u32,
    pub height: u32,
    pub exposure_s: f64,
    pub bit_depth: u32,
    pub codes: Vec<u16>,
}

impl Capture {
    /// 8-bit codes (bit depth 8 only).
    pub fn codes8(&self) -> Option<Vec<u8>> {
        (self.bit_depth == 8).then(|| self.codes.iter().map(|&c| c as u8).collect())
    }
}

/// What the PRNU pattern's seed is mixed with, so that it is not the DSNU pattern's
/// stream where the two seeds are equal.
const PRNU_STREAM: u64 = 0x9e37_79b9_7f4a_7c15;
/// The column and row DSNU offsets' streams of the DSNU seed.
const COLUMN_STREAM: u64 = 0xbf58_476d_1ce4_e5b9;
const ROW_STREAM: u64 = 0x94d0_49bb_1331_11eb;

/// A fixed pattern of the camera (not of the image): `n` draws of Normal(0, `rms`), in
/// order, from the stream of `seed`. The PRNU gains and the pixel, column and row DSNU
/// offsets each take one, from their own seeds.
fn fixed_pattern(seed: u64, n: usize, rms: f64) -> impl Iterator<Item = f64> {
    let mut fixed = Pcg64Mcg::seed_from_u64(seed);
    (0..n).map(move |_| rms * fixed.sample::<f64, _>(rand_distr::StandardNormal))
}

/// Exposes the sensor: per pixel electrons = Poisson(mean * PRNU gain + dark current *
/// t) (shot noise of the signal and of the dark current) + DSNU offsets (per pixel, per
/// column, per row) + Normal(0, dark noise); full-well clipping with the excess spilled along the column
/// (`blooming = "vertical"`); code = round(K * electrons + black level), clipped to
/// [0, 2^bits - 1]. Noise is drawn from `seed` (the image's seed), the DSNU and PRNU
/// patterns from `sensor.dsnu_seed` and `sensor.prnu_seed` (fixed per camera). With no
/// PRNU and no dark current the electrons are those of the model without them, draw for
/// draw.
pub fn capture(
    resp: &Responsivity,
    radiance: &[f32],
    t_s: f64,
    sensor: &SensorConfig,
    seed: u64,
) -> Result<Capture, SensorError> {
    let (w, h) = (resp.width as usize, resp.height as usize);
    if radiance.len() != w * h {
        return Err(SensorError::Invalid(format!(
            "{} radiance values for a {w} x {h} sensor",
            radiance.len()
        )));
    }
    let mut mean = resp.mean_electrons(radiance, t_s);
    if sensor.prnu_percent > 0.0 {
        // A fixed gain per pixel, 1 + (prnu / 100) g with g ~ Normal(0, 1) from the
        // camera's PRNU seed (its own stream: equal DSNU and PRNU seeds give independent
        // patterns), not below 0.
        let rel = sensor.prnu_percent / 100.0;
        let gains = fixed_pattern(sensor.prnu_seed ^ PRNU_STREAM, mean.len(), rel);
        for (m, g) in mean.iter_mut().zip(gains) {
            *m *= (1.0 + g).max(0.0);
        }
    }
    if sensor.dark_current_electrons_per_s > 0.0 {
        // Thermal electrons: their mean joins the photo-electrons', and with them its shot
        // noise.
        let dark = sensor.dark_current_electrons_per_s * t_s;
        mean.iter_mut().for_each(|m| *m += dark);
    }
    let mut rng = Pcg64Mcg::seed_from_u64(seed ^ 0x5e45_0e12_88ee_1288);
    let dark = Normal::new(0.0, sensor.dark_noise_electrons)
        .map_err(|e| SensorError::Invalid(format!("dark_noise_electrons: {e}")))?;
    let mut e: Vec<f64> = mean
        .iter()
        .map(|&m| {
            let shot = if m <= 0.0 {
                0.0
            } else if m > 1e7 {
                // Poisson's normal limit (rand_distr's Poisson has an upper bound).
                (m + m.sqrt() * rng.sample::<f64, _>(rand_distr::StandardNormal)).max(0.0)
            } else {
                Poisson::new(m).map(|p| p.sample(&mut rng)).unwrap_or(m)
            };
            shot + dark.sample(&mut rng)
        })
        .collect();
    if sensor.dsnu_electrons > 0.0 {
        let offsets = fixed_pattern(sensor.dsnu_seed, e.len(), sensor.dsnu_electrons);
        for (v, o) in e.iter_mut().zip(offsets) {
            *v += o;
        }
    }
    if sensor.dsnu_column_electrons > 0.0 || sensor.dsnu_row_electrons > 0.0 {
        // An offset per column and one per row, each from the DSNU seed's own stream.
        let col: Vec<f64> = fixed_pattern(
            sensor.dsnu_seed ^ COLUMN_STREAM,
            w,
            sensor.dsnu_column_electrons,
        )
        .collect();
        let row: Vec<f64> =
            fixed_pattern(sensor.dsnu_seed ^ ROW_STREAM, h, sensor.dsnu_row_electrons).collect();
        for (i, v) in e.iter_mut().enumerate() {
            *v += col[i % w] + row[i / w];
        }
    }
    let full = sensor.saturation_electrons;
    match sensor.blooming {
        Blooming::Vertical => bloom_vertical(&mut e, w, h, full),
        Blooming::None => e.iter_mut().for_each(|v| *v = v.min(full)),
    }
    let top = max_code(sensor.bit_depth);
    let codes = e
        .iter()
        .map(|&v| {
            let c = (sensor.gain_dn_per_electron * v + sensor.black_level_dn).round();
            c.clamp(0.0, top) as u16
        })
        .collect();
    Ok(Capture {
        width: resp.width,
        height: resp.height,
        exposure_s: t_s,
        bit_depth: sensor.bit_depth,
        codes,
    })
}

/// Vertical blooming of a CCD: a pixel above full well keeps `full` and its excess
/// charge spills along its column, half up and half down, filling the nearest pixels
/// below full well first; charge that reaches the top or bottom of the column with no room
/// left is lost (the column is full). Charge in a column is conserved otherwise.
pub fn bloom_vertical(e: &mut [f64], width: usize, height: usize, full: f64) {
    for x in 0..width {
        let idx = |y: usize| y * width + x;
        for y in 0..height {
            let excess = e[idx(y)] - full;
            if excess <= 0.0 {
                continue;
            }
            e[idx(y)] = full;
            let (mut up, mut down) = (excess * 0.5, excess * 0.5);
            // Down the column.
            let mut yy = y + 1;
            while down > 0.0 && yy < height {
                let room = (full - e[idx(yy)]).max(0.0);
                let put = room.min(down);
                e[idx(yy)] += put;
                down -= put;
                yy += 1;
            }
            // Up the column; what does not fit below goes up, and the other way round.
            up += down;
            let mut yy = y;
            while up > 0.0 && yy > 0 {
                yy -= 1;
                let room = (full - e[idx(yy)]).max(0.0);
                let put = room.min(up);
                e[idx(yy)] += put;
                up -= put;
            }
            if up > 0.0 {
                // Nothing above had room: try below again (the half that went up).
                let mut yy = y + 1;
                while up > 0.0 && yy < height {
                    let room = (full - e[idx(yy)]).max(0.0);
                    let put = room.min(up);
                    e[idx(yy)] += put;
                    up -= put;
                    yy += 1;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sensor() -> SensorConfig {
        SensorConfig {
            exposure: ExposureSetting::Fixed { ms: 1.0 },
            gain_dn_per_electron: 0.5,
            dark_noise_electrons: 7.0,
            saturation_electrons: 8000.0,
            bit_depth: 12,
            black_level_dn: 50.0,
            ..SensorConfig::default()
        }
    }

    /// EMVA 1288's non-uniformity measure on a uniformly lit target: of two images at one
    /// exposure, the variance of their mean over the pixels holds the fixed pattern plus
    /// half the temporal variance, and half their difference's variance the temporal
    /// variance alone; their gap is the PRNU's (prnu * signal)^2. 2 % on 6000 e-: 120 e-
    /// rms against 77 e- of shot noise. The pattern is the camera's: the same in every
    /// image, another with another `prnu_seed`; independent of the DSNU pattern with the
    /// same seed.
    #[test]
    fn prnu_is_a_fixed_gain_pattern_of_its_rms() {
        let s = SensorConfig {
            dark_noise_electrons: 0.0,
            gain_dn_per_electron: 0.5,
            bit_depth: 16,
            saturation_electrons: 1e6,
            prnu_percent: 2.0,
            prnu_seed: 7,
            ..sensor()
        };
        let (w, h) = (192u32, 192u32);
        let n = (w * h) as usize;
        let resp = Responsivity::uniform(w, h, 6.0e6);
        let radiance = vec![1.0f32; n];
        let shot = |s: &SensorConfig, seed: u64| -> Vec<f64> {
            capture(&resp, &radiance, 1e-3, s, seed)
                .unwrap()
                .codes
                .iter()
                .map(|&c| (c as f64 - s.black_level_dn) / s.gain_dn_per_electron)
                .collect()
        };
        let var = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() as f64 - 1.0)
        };
        let (a, b) = (shot(&s, 1), shot(&s, 2));
        let mean: Vec<f64> = a.iter().zip(&b).map(|(x, y)| 0.5 * (x + y)).collect();
        let diff: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
        let temporal = var(&diff) / 2.0;
        let fixed = var(&mean) - temporal / 2.0;
        let m = mean.iter().sum::<f64>() / n as f64;
        let prnu = fixed.max(0.0).sqrt() / m * 100.0;
        eprintln!("PRNU {prnu:.3} % (2), temporal {temporal:.0} e-^2 ({m:.0}), mean {m:.0}");
        assert!((m - 6000.0).abs() < 5.0, "mean {m}");
        assert!((prnu - 2.0).abs() < 0.1, "PRNU {prnu} %");
        // Shot noise unchanged by the pattern: the temporal variance is the signal.
        assert!((temporal / m - 1.0).abs() < 0.05, "temporal {temporal}");
        // The same pattern in every image: correlation of two images' deviations.
        let corr = |x: &[f64], y: &[f64]| {
            let (mx, my) = (
                x.iter().sum::<f64>() / n as f64,
                y.iter().sum::<f64>() / n as f64,
            );
            let c: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
            c / (var(x) * var(y)).sqrt() / (n as f64 - 1.0)
        };
        // 120^2 / (120^2 + 6000): about 0.71 between two images of one camera.
        assert!(corr(&a, &b) > 0.6, "same camera: {}", corr(&a, &b));
        let other = shot(
            &SensorConfig {
                prnu_seed: 8,
                ..s.clone()
            },
            2,
        );
        assert!(
            corr(&a, &other).abs() < 0.05,
            "another camera: {}",
            corr(&a, &other)
        );
        // DSNU with the same seed: an offset pattern uncorrelated with the gain pattern.
        let dsnu = SensorConfig {
            prnu_percent: 0.0,
            dsnu_electrons: 120.0,
            dsnu_seed: 7,
            ..s.clone()
        };
        let d = shot(&dsnu, 2);
        assert!(
            corr(&a, &d).abs() < 0.05,
            "DSNU and PRNU patterns: {}",
            corr(&a, &d)
        );
    }

    /// EMVA 1288 (release 4) splits the DSNU into row, column and pixel parts: in the
    /// dark, the variance over the columns of each column's mean is the column part plus
    /// the pixel and temporal variance over the rows' count (the row offsets are common to
    /// every column's mean), and the same for the rows; each part's own stream, so the
    /// pixel pattern of the same seed is unchanged.
    #[test]
    fn row_and_column_dsnu_are_offsets_shared_along_their_lines() {
        let (w, h) = (512usize, 384usize);
        let n = w * h;
        let s = SensorConfig {
            gain_dn_per_electron: 1.0,
            dsnu_electrons: 4.0,
            dsnu_column_electrons: 5.0,
            dsnu_row_electrons: 3.0,
            dsnu_seed: 11,
            black_level_dn: 200.0,
            ..sensor()
        };
        let resp = Responsivity::uniform(w as u32, h as u32, 1.0e6);
        let dark = vec![0.0f32; n];
        // A dark image's electrons (K = 1) above the black level.
        let electrons = |s: &SensorConfig| -> Vec<f64> {
            capture(&resp, &dark, 1e-3, s, 5)
                .unwrap()
                .codes
                .iter()
                .map(|&c| c as f64 - 200.0)
                .collect()
        };
        let e = electrons(&s);
        let var = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() as f64 - 1.0)
        };
        let col_means: Vec<f64> = (0..w)
            .map(|x| (0..h).map(|y| e[y * w + x]).sum::<f64>() / h as f64)
            .collect();
        let row_means: Vec<f64> = (0..h)
            .map(|y| e[y * w..(y + 1) * w].iter().sum::<f64>() / w as f64)
            .collect();
        // Pixel DSNU, dark noise and quantisation (1/12 DN^2 at K = 1).
        let pixel = 16.0 + 49.0 + 1.0 / 12.0;
        let col = (var(&col_means) - pixel / h as f64).sqrt();
        let row = (var(&row_means) - pixel / w as f64).sqrt();
        eprintln!("column DSNU {col:.2} e- (5), row DSNU {row:.2} e- (3)");
        // Standard errors of an rms from 512 and 384 lines: 3.1 % and 3.6 %.
        assert!((col / 5.0 - 1.0).abs() < 0.12, "column DSNU {col}");
        assert!((row / 3.0 - 1.0).abs() < 0.15, "row DSNU {row}");
        // Without the line parts, the pixel pattern of the seed is what it was with them.
        let plain = SensorConfig {
            dsnu_column_electrons: 0.0,
            dsnu_row_electrons: 0.0,
            ..s.clone()
        };
        let p = electrons(&plain);
        let lines: Vec<f64> = e.iter().zip(&p).map(|(a, b)| a - b).collect();
        // What the line parts added is constant along each column up to rounding to codes.
        let resid: Vec<f64> = (0..n)
            .map(|i| {
                lines[i] - col_means[i % w] + col_means.iter().sum::<f64>() / w as f64
                    - row_means[i / w]
                    + row_means.iter().sum::<f64>() / h as f64
            })
            .collect();
        assert!(
            var(&resid) < 1.0,
            "line offsets not shared: residual variance {}",
            var(&resid)
        );
    }

    /// Dark current in the dark: mean I_d t electrons above the black level, and its
    /// shot noise (variance I_d t) on top of the dark noise.
    #[test]
    fn dark_current_adds_its_signal_and_its_shot_noise() {
        let (w, h) = (128u32, 128u32);
        let n = (w * h) as usize;
        let resp = Responsivity::uniform(w, h, 1.0e6);
        let dark = vec![0.0f32; n];
        let s = SensorConfig {
            dark_current_electrons_per_s: 2000.0,
            ..sensor()
        };
        // 200 ms: 400 electrons.
        let codes = capture(&resp, &dark, 0.2, &s, 3).unwrap().codes;
        let e: Vec<f64> = codes.iter().map(|&c| (c as f64 - 50.0) / 0.5).collect();
        let m = e.iter().sum::<f64>() / n as f64;
        let v = e.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n as f64 - 1.0);
        // Variance in electrons: I_d t + sigma_d^2 + quantisation (1/12 DN^2 / K^2).
        let expect = 400.0 + 49.0 + (1.0 / 12.0) / 0.25;
        eprintln!("dark current: mean {m:.2} e- (400), variance {v:.1} ({expect:.1})");
        assert!((m - 400.0).abs() < 1.0, "mean {m}");
        assert!((v / expect - 1.0).abs() < 0.05, "variance {v} vs {expect}");
    }

    /// EMVA 1288's photon transfer method on a uniformly lit target: pairs of images at
    /// several exposure times, the mean and (from the pair's difference) the temporal
    /// variance of each; variance against mean minus dark mean is a line of slope K and
    /// intercept the dark variance K^2 sigma_d^2 + 1/12 (quantisation).
    #[test]
    fn photon_transfer_curve_gives_k_and_the_dark_variance() {
        let s = sensor();
        let (w, h) = (128u32, 128u32);
        let n = (w * h) as usize;
        // 1e6 e-/s at L = 1: t = 1 ms is 1000 electrons.
        let resp = Responsivity::uniform(w, h, 1.0e6);
        let radiance = vec![1.0f32; n];
        let stats = |t_ms: f64, seed: u64| {
            let a = capture(&resp, &radiance, t_ms * 1e-3, &s, seed)
                .unwrap()
                .codes;
            let b = capture(&resp, &radiance, t_ms * 1e-3, &s, seed + 1000)
                .unwrap()
                .codes;
            let mean = a.iter().chain(&b).map(|&c| c as f64).sum::<f64>() / (2 * n) as f64;
            let d: Vec<f64> = a
                .iter()
                .zip(&b)
                .map(|(&x, &y)| x as f64 - y as f64)
                .collect();
            let dm = d.iter().sum::<f64>() / n as f64;
            let var = d.iter().map(|v| (v - dm).powi(2)).sum::<f64>() / (n as f64 - 1.0) / 2.0;
            (mean, var)
        };
        let (dark_mean, dark_var) = stats(0.0, 1);
        let expect_dark = 0.25 * 49.0 + 1.0 / 12.0;
        // Relative standard error of a variance from n differences: sqrt(2 / n).
        let se = |v: f64| v * (2.0 / n as f64).sqrt();
        assert!(
            (dark_var - expect_dark).abs() < 4.0 * se(expect_dark),
            "dark variance {dark_var} vs {expect_dark}"
        );
        assert!((dark_mean - 50.0).abs() < 0.05, "dark mean {dark_mean}");
        // Up to 70 % of saturation (EMVA's fit range).
        let pts: Vec<(f64, f64)> = (1..=10)
            .map(|i| {
                let (m, v) = stats(i as f64 * 0.56, 10 + 2 * i as u64);
                (m - dark_mean, v)
            })
            .collect();
        // Least squares y = a + K x, weighted by 1 / var(y)^2 (var(y) grows with y).
        let wts: Vec<f64> = pts.iter().map(|p| 1.0 / se(p.1).powi(2)).collect();
        let sw: f64 = wts.iter().sum();
        let sx: f64 = pts.iter().zip(&wts).map(|(p, w)| w * p.0).sum();
        let sy: f64 = pts.iter().zip(&wts).map(|(p, w)| w * p.1).sum();
        let sxx: f64 = pts.iter().zip(&wts).map(|(p, w)| w * p.0 * p.0).sum();
        let sxy: f64 = pts.iter().zip(&wts).map(|(p, w)| w * p.0 * p.1).sum();
        let det = sw * sxx - sx * sx;
        let k = (sw * sxy - sx * sy) / det;
        let a = (sxx * sy - sx * sxy) / det;
        let (se_k, se_a) = ((sw / det).sqrt(), (sxx / det).sqrt());
        eprintln!(
            "PTC: K = {k:.4} +- {se_k:.4} (0.5), intercept {a:.2} +- {se_a:.2} ({expect_dark:.2}), dark variance {dark_var:.2}"
        );
        assert!((k - 0.5).abs() < 4.0 * se_k, "K = {k} +- {se_k}");
        assert!(
            (a - expect_dark).abs() < 4.0 * se_a,
            "intercept {a} +- {se_a}"
        );
        // The test can fail: the statistical errors are small against the quantities.
        assert!(se_k < 0.01 && se_a < 5.0, "{se_k} {se_a}");
    }

    #[test]
    fn blooming_conserves_the_excess_charge_in_its_column() {
        let (w, h) = (3usize, 10usize);
        let full = 100.0;
        let mut e = vec![10.0; w * h];
        e[4 * w] = 450.0; // column 0: 350 over full well, spills both ways
        e[w + 1] = 900.0; // column 1: more than fits above; the rest goes down
        for y in 0..h {
            e[y * w + 2] = 150.0; // column 2: every pixel full, the excess is lost
        }
        let before: Vec<f64> = (0..w).map(|x| (0..h).map(|y| e[y * w + x]).sum()).collect();
        bloom_vertical(&mut e, w, h, full);
        let after: Vec<f64> = (0..w).map(|x| (0..h).map(|y| e[y * w + x]).sum()).collect();
        assert!(e.iter().all(|&v| v <= full));
        assert!((after[0] - before[0]).abs() < 1e-9 && (after[1] - before[1]).abs() < 1e-9);
        assert_eq!(after[2], full * h as f64);
        // Column 0: 175 up, 175 down, into the nearest pixels (90 room each).
        let col0: Vec<f64> = (0..h).map(|y| e[y * w]).collect();
        assert_eq!(
            col0,
            [
                10.0, 10.0, 95.0, 100.0, 100.0, 100.0, 95.0, 10.0, 10.0, 10.0
            ]
        );
        // "none" clips and loses the excess.
        let s = SensorConfig {
            blooming: Blooming::None,
            dark_noise_electrons: 0.0,
            ..sensor()
        };
        let resp = Responsivity::uniform(1, 2, 1e9);
        let c = capture(&resp, &[1.0, 0.0], 1.0, &s, 0).unwrap();
        assert_eq!(c.codes, [(8000.0f64 * 0.5 + 50.0) as u16, 50]);
        let s = SensorConfig {
            blooming: Blooming::Vertical,
            ..s
        };
        let c = capture(&resp, &[1.0, 0.0], 1e-5, &s, 0).unwrap();
        // 10000 e- (shot noise: +-100): 8000 stay, the rest spills into the dark pixel
        // below (the edge above has no room).
        assert_eq!(c.codes[0], 4050);
        assert!((c.codes[1] as i32 - 1050).abs() < 250, "{:?}", c.codes);
    }

    #[test]
    fn auto_exposure_hits_its_target_within_one_code() {
        let s = SensorConfig {
            exposure: ExposureSetting::Auto(crate::scene::config::AutoExposure),
            auto_percentile: 99.5,
            auto_fraction: 0.9,
            gain_dn_per_electron: 0.03,
            black_level_dn: 2.0,
            bit_depth: 8,
            ..SensorConfig::default()
        };
        let (w, h) = (100u32, 80u32);
        let n = (w * h) as usize;
        // A bright "object" in the left half (graded), dark background, hot light pixels
        // outside the mask that auto exposure must ignore.
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        let radiance: Vec<f32> = (0..n)
            .map(|i| {
                if (i as u32 % w) < w / 2 {
                    rng.random_range(0.1..2.0)
                } else if i % 97 == 0 {
                    500.0
                } else {
                    0.01
                }
            })
            .collect();
        let mask: Vec<bool> = (0..n).map(|i| (i as u32 % w) < w / 2).collect();
        let resp = Responsivity::uniform(w, h, 2.0e6);
        let t = exposure_time_s(&resp, &radiance, Some(&mask), &s).unwrap();
        // Noise-free codes of the object's pixels; their 99.5th percentile.
        let mean = resp.mean_electrons(&radiance, t);
        let mut codes: Vec<f64> = mean
            .iter()
            .zip(&mask)
            .filter(|(_, m)| **m)
            .map(|(e, _)| (s.gain_dn_per_electron * e + s.black_level_dn).round())
            .collect();
        let got = percentile(&mut codes, 99.5);
        let target = 0.9 * saturation_electrons(&s) * s.gain_dn_per_electron + s.black_level_dn;
        eprintln!(
            "auto exposure {:.4} ms: percentile code {got}, target {target:.2}",
            t * 1e3
        );
        assert!((got - target).abs() <= 1.0, "{got} vs {target}");
        // Saturation is the ADC's here (255 codes), not the full well.
        assert!((saturation_electrons(&s) - 253.0 / 0.03).abs() < 1e-6);
        // All dark: a clear error.
        let e = exposure_time_s(&resp, &vec![0.0; n], Some(&mask), &s).unwrap_err();
        assert!(e.to_string().contains("ms ="), "{e}");
    }

    /// `auto_statistic = "mean"`: the object's mean noise-free signal reaches the target
    /// (its highlights may clip); outside the mask nothing counts.
    #[test]
    fn mean_auto_exposure_sets_the_objects_mean() {
        let s = SensorConfig {
            exposure: ExposureSetting::Auto(crate::scene::config::AutoExposure),
            auto_statistic: AutoStatistic::Mean,
            auto_fraction: 0.3,
            ..SensorConfig::default()
        };
        let (w, h) = (64u32, 32u32);
        let n = (w * h) as usize;
        // Object: dark surface with rare glints 100x brighter (a milled face); background
        // a hot light outside the mask.
        let radiance: Vec<f32> = (0..n)
            .map(|i| match (i as u32 % w < w / 2, i % 50 == 0) {
                (true, true) => 100.0,
                (true, false) => 1.0,
                (false, _) => 1000.0,
            })
            .collect();
        let mask: Vec<bool> = (0..n).map(|i| (i as u32 % w) < w / 2).collect();
        let resp = Responsivity::uniform(w, h, 1.0e6);
        let t = exposure_time_s(&resp, &radiance, Some(&mask), &s).unwrap();
        let e = resp.mean_electrons(&radiance, t);
        let inside: Vec<f64> = e
            .iter()
            .zip(&mask)
            .filter(|(_, m)| **m)
            .map(|(e, _)| *e)
            .collect();
        let mean = inside.iter().sum::<f64>() / inside.len() as f64;
        let target = 0.3 * saturation_electrons(&s);
        assert!(
            (mean / target - 1.0).abs() < 1e-9,
            "mean {mean} e- vs {target}"
        );
        // The percentile rule on the same image keeps the glints unclipped instead: a
        // much shorter exposure.
        let p = SensorConfig {
            auto_statistic: AutoStatistic::Percentile,
            auto_percentile: 99.5,
            auto_fraction: 0.9,
            ..s.clone()
        };
        let tp = exposure_time_s(&resp, &radiance, Some(&mask), &p).unwrap();
        assert!(t > 10.0 * tp, "mean rule {t} s vs percentile rule {tp} s");
        let dark = exposure_time_s(&resp, &vec![0.0; n], Some(&mask), &s).unwrap_err();
        assert!(dark.to_string().contains("the mean"), "{dark}");
    }

    #[test]
    fn responsivity_follows_the_thin_lens_irradiance_and_cos4() {
        let cam = Camera::look(
            glam::Vec3::ZERO,
            glam::Vec3::Z,
            -glam::Vec3::Y,
            60.0,
            41,
            41,
        );
        let s = SensorConfig::default();
        // focal such that the pitch is 5 µm: tan_half_h = 41 p / (2 f).
        let p = 5e-6;
        let f_mm = 41.0 * p / (2.0 * cam.tan_half_h as f64) * 1e3;
        let r = Responsivity::new(&cam, f_mm, 4.0, &s);
        let centre = r.electrons_per_s[20 * 41 + 20];
        let photon = PLANCK * LIGHT_SPEED / 550e-9;
        let expect = std::f64::consts::PI * p * p / (4.0 * 16.0) / photon * 0.6;
        assert!((centre / expect - 1.0).abs() < 1e-5, "{centre} vs {expect}");
        let corner = r.electrons_per_s[0];
        let cos = cam.pixel_dir(0, 0).dot(cam.forward) as f64;
        assert!((corner / centre - cos.powi(4)).abs() < 1e-5);
    }
}
