//! The lens's diffraction (`[sensor] diffraction = true`): the Airy pattern of a circular
//! aperture at the working f-number, applied to the linear radiance before the sensor
//! step. Model, parameters and approximations: docs/rendering.md ("Sensor",
//! *Diffraction*).

use std::borrow::Cow;

use rayon::prelude::*;

use crate::scene::config::SensorConfig;
use crate::vk::Profiler;

/// The kernel reaches out to this many times lambda N from its centre (the Airy
/// pattern's first dark ring is at 1.22 lambda N); the rings beyond, about 2 % of the
/// energy, are left out and the kernel renormalised ("truncated Airy kernel").
pub const AIRY_RADIUS_LAMBDA_N: f64 = 10.0;

/// Sub-samples per pixel side when the Airy pattern is integrated over a pixel's square.
const CELL_SAMPLES: usize = 8;

/// The Airy pattern's intensity at `x` = pi r / (lambda N), normalised to 1 at the
/// centre: (2 J1(x) / x)^2.
pub fn airy(x: f64) -> f64 {
    if x.abs() < 1e-6 {
        return 1.0;
    }
    let a = 2.0 * libm::j1(x) / x;
    a * a
}

/// The fraction of the Airy pattern's energy within `x` = pi r / (lambda N) of its centre
/// (Rayleigh): 1 - J0(x)^2 - J1(x)^2.
pub fn encircled_energy(x: f64) -> f64 {
    let (j0, j1) = (libm::j0(x), libm::j1(x));
    1.0 - j0 * j0 - j1 * j1
}

/// A square kernel of odd side, row-major, summing to 1.
#[derive(Clone, Debug, PartialEq)]
pub struct Kernel {
    pub radius: usize,
    pub weights: Vec<f32>,
}

impl Kernel {
    pub fn side(&self) -> usize {
        2 * self.radius + 1
    }
}

/// The Airy pattern of a circular aperture at working f-number `f_number` and
/// wavelength `wavelength_nm`, integrated over each pixel's square (pitch `pixel_um`),
/// out to [`AIRY_RADIUS_LAMBDA_N`] lambda N, renormalised to sum 1.
pub fn airy_kernel(pixel_um: f64, f_number: f64, wavelength_nm: f64) -> Kernel {
    let lambda_n_um = wavelength_nm * 1e-3 * f_number;
    let reach_um = AIRY_RADIUS_LAMBDA_N * lambda_n_um;
    let radius = (reach_um / pixel_um).ceil().max(1.0) as usize;
    let side = 2 * radius + 1;
    let mut weights = vec![0.0f64; side * side];
    for (i, w) in weights.iter_mut().enumerate() {
        let (cx, cy) = (
            (i % side) as f64 - radius as f64,
            (i / side) as f64 - radius as f64,
        );
        let mut sum = 0.0;
        for sy in 0..CELL_SAMPLES {
            for sx in 0..CELL_SAMPLES {
                let u = cx + (sx as f64 + 0.5) / CELL_SAMPLES as f64 - 0.5;
                let v = cy + (sy as f64 + 0.5) / CELL_SAMPLES as f64 - 0.5;
                let r_um = pixel_um * (u * u + v * v).sqrt();
                if r_um <= reach_um {
                    sum += airy(std::f64::consts::PI * r_um / lambda_n_um);
                }
            }
        }
        *w = sum;
    }
    let total: f64 = weights.iter().sum();
    Kernel {
        radius,
        weights: weights.iter().map(|&w| (w / total) as f32).collect(),
    }
}

/// How [`convolve`] reads the image outside its edges.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Border {
    /// The border pixels repeated outwards (a uniform image stays uniform).
    Replicate,
    /// Mirrored about the border pixel, which is not repeated: -1 -> 1, n -> n - 2
    /// (OpenCV's default border, BORDER_REFLECT_101).
    Reflect101,
}

impl Border {
    /// The pixel (0 .. n) that position `i` reads.
    pub fn source(self, i: i64, n: usize) -> usize {
        let n = n as i64;
        match self {
            Border::Replicate => i.clamp(0, n - 1) as usize,
            Border::Reflect101 if n == 1 => 0,
            Border::Reflect101 => {
                let period = 2 * (n - 1);
                let i = i.rem_euclid(period);
                (if i >= n { period - i } else { i }) as usize
            }
        }
    }
}

/// `image` (row-major, `width` x `height`) correlated with `kernel` (centred; for the
/// symmetric kernels here, a convolution), reading outside the image by `border`. Each
/// output pixel sums its taps in the kernel's row-major order, taps of weight 0 left out.
/// On all cores.
pub fn convolve(
    image: &[f32],
    width: usize,
    height: usize,
    kernel: &Kernel,
    border: Border,
) -> Vec<f32> {
    assert_eq!(image.len(), width * height, "image size");
    if image.is_empty() {
        return Vec::new();
    }
    let r = kernel.radius;
    let side = kernel.side();
    // The image with r pixels of border around it: every tap then reads inside.
    let pw = width + 2 * r;
    let columns: Vec<usize> = (0..pw)
        .map(|px| border.source(px as i64 - r as i64, width))
        .collect();
    let padded: Vec<f32> = (0..height + 2 * r)
        .flat_map(|py| {
            let y = border.source(py as i64 - r as i64, height);
            let row = &image[y * width..(y + 1) * width];
            columns.iter().map(move |&x| row[x])
        })
        .collect();
    let mut out = vec![0.0f32; image.len()];
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        for ky in 0..side {
            let src = &padded[(y + ky) * pw..(y + ky + 1) * pw];
            let k = &kernel.weights[ky * side..(ky + 1) * side];
            for (kx, &kw) in k.iter().enumerate() {
                if kw == 0.0 {
                    continue;
                }
                for (o, &v) in row.iter_mut().zip(&src[kx..kx + width]) {
                    *o += kw * v;
                }
            }
        }
    });
    out
}

/// The radiance the sensor sees through a diffraction-limited lens: `radiance` convolved
/// with the Airy kernel of `f_number` at `wavelength_nm` for pixels of `pixel_um`. NaN
/// and negative radiance count as 0 (as the sensor counts them).
pub fn diffract(
    radiance: &[f32],
    width: usize,
    height: usize,
    pixel_um: f64,
    f_number: f64,
    wavelength_nm: f64,
) -> Vec<f32> {
    let clean: Vec<f32> = radiance
        .iter()
        .map(|&l| if l > 0.0 { l } else { 0.0 })
        .collect();
    convolve(
        &clean,
        width,
        height,
        &airy_kernel(pixel_um, f_number, wavelength_nm),
        Border::Replicate,
    )
}

/// The radiance `sensor` sees: with `sensor.diffraction`, `radiance` through the lens
/// ([`diffract`] at `sensor.wavelength_nm`, timed as "lens diffraction" on `profiler`);
/// without, `radiance` itself. The one place `synosis render` and a dataset job's sensor
/// step decide it.
pub fn seen_by_sensor<'a>(
    radiance: &'a [f32],
    width: usize,
    height: usize,
    pixel_um: f64,
    f_number: f64,
    sensor: &SensorConfig,
    profiler: Option<&Profiler>,
) -> Cow<'a, [f32]> {
    if !sensor.diffraction {
        return Cow::Borrowed(radiance);
    }
    let run = || {
        diffract(
            radiance,
            width,
            height,
            pixel_um,
            f_number,
            sensor.wavelength_nm,
        )
    };
    Cow::Owned(match profiler {
        Some(p) => p.cpu("lens diffraction", run),
        None => run(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pattern's known values: the first dark ring at x = 3.8317 (1.22 pi), 83.8 %
    /// of the energy inside it, 91.0 % inside the second ring (x = 7.0156).
    #[test]
    fn airy_pattern_and_encircled_energy_match_their_known_values() {
        assert!((airy(0.0) - 1.0).abs() < 1e-12);
        assert!(airy(3.8317) < 1e-8, "{}", airy(3.8317));
        assert!((encircled_energy(3.8317) - 0.838).abs() < 1e-3);
        assert!((encircled_energy(7.0156) - 0.910).abs() < 1e-3);
        // Outside 10 lambda N (x = 10 pi): about 2 % of the energy.
        let outside = 1.0 - encircled_energy(10.0 * std::f64::consts::PI);
        assert!(outside > 0.01 && outside < 0.03, "{outside}");
    }

    /// Finely sampled (pixels of lambda N / 4), the kernel holds within the first dark
    /// ring the energy the pattern does there, over what the truncation keeps; it sums to
    /// 1 and is symmetric.
    #[test]
    fn the_kernel_holds_the_patterns_encircled_energy() {
        let (pixel, n, lambda) = (0.55 * 8.0 / 4.0, 8.0, 550.0);
        let k = airy_kernel(pixel, n, lambda);
        let side = k.side();
        let sum: f64 = k.weights.iter().map(|&w| w as f64).sum();
        assert!((sum - 1.0).abs() < 1e-5, "{sum}");
        for y in 0..side {
            for x in 0..side {
                let w = k.weights[y * side + x];
                assert!((w - k.weights[x * side + (side - 1 - y)]).abs() < 1e-7);
            }
        }
        let ring_px = 1.22 * 0.55 * n / pixel;
        let inside: f64 = (0..side * side)
            .filter(|&i| {
                let (dx, dy) = (
                    (i % side) as f64 - k.radius as f64,
                    (i / side) as f64 - k.radius as f64,
                );
                (dx * dx + dy * dy).sqrt() <= ring_px
            })
            .map(|i| k.weights[i] as f64)
            .sum();
        let want = encircled_energy(3.8317)
            / encircled_energy(AIRY_RADIUS_LAMBDA_N * std::f64::consts::PI);
        // Pixels straddle the ring: a few per cent of its energy either way.
        assert!((inside - want).abs() < 0.03, "{inside} vs {want}");
    }

    /// At the paper camera (6.9 µm pixels, f/11 working, 550 nm) the Airy disc's radius
    /// (7.4 µm) is about a pixel: a bright pixel keeps about half its energy, the rest
    /// goes to its neighbours; a uniform image stays uniform and the energy of an
    /// interior spot is conserved.
    #[test]
    fn a_point_spreads_as_the_paper_cameras_lens_spreads_it() {
        let (w, h) = (64usize, 48usize);
        let mut img = vec![0.0f32; w * h];
        img[24 * w + 32] = 1.0;
        let out = diffract(&img, w, h, 6.9, 11.0, 550.0);
        let total: f32 = out.iter().sum();
        assert!((total - 1.0).abs() < 1e-5, "{total}");
        let centre = out[24 * w + 32];
        assert!(centre > 0.3 && centre < 0.7, "centre keeps {centre}");
        assert!((out[24 * w + 33] - out[23 * w + 32]).abs() < 1e-6);
        let flat = diffract(&vec![0.25f32; w * h], w, h, 6.9, 11.0, 550.0);
        assert!(flat.iter().all(|&v| (v - 0.25).abs() < 1e-6));
        // A lens of f/1 at 6.9 µm pixels: almost no spread.
        let sharp = diffract(&img, w, h, 6.9, 1.0, 550.0);
        assert!(sharp[24 * w + 32] > 0.9);
    }
}
