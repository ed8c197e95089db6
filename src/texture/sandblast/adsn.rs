//! Asymptotic discrete spot noise (Galerne, Gousseau, Morel 2011) of an exemplar:
//! t = mu + (u - mu) / sqrt(|Omega|) (*) W, computed in the Fourier domain from the
//! exemplar's periodic component (Moisan 2011), so its borders leave no cross in the
//! spectrum.

use std::f32::consts::PI;

use rand::Rng;
use rand_distr::StandardNormal;
use rayon::prelude::*;
use rustfft::num_complex::Complex32;

use crate::texture::error::{Result, TextureError};
use crate::texture::fft2::fft2;
use crate::texture::maps::HeightMap;

/// Moisan's periodic component p = u - s, where the smooth component s solves
/// Laplacian(s) = boundary jumps of u (discrete Poisson, solved by FFT).
pub fn periodic_component(u: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut v = vec![Complex32::new(0.0, 0.0); w * h];
    for x in 0..w {
        let jump = u[(h - 1) * w + x] - u[x];
        v[x].re += jump;
        v[(h - 1) * w + x].re -= jump;
    }
    for y in 0..h {
        let jump = u[y * w + w - 1] - u[y * w];
        v[y * w].re += jump;
        v[y * w + w - 1].re -= jump;
    }
    fft2(&mut v, w, h, false);
    v.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
        let cy = (2.0 * PI * r as f32 / h as f32).cos();
        for (q, z) in row.iter_mut().enumerate() {
            let cx = (2.0 * PI * q as f32 / w as f32).cos();
            let den = 2.0 * cx + 2.0 * cy - 4.0;
            *z = if q == 0 && r == 0 {
                Complex32::new(0.0, 0.0)
            } else {
                *z / den
            };
        }
    });
    fft2(&mut v, w, h, true);
    let n = (w * h) as f32;
    u.iter().zip(&v).map(|(&a, s)| a - s.re / n).collect()
}

/// Fourier-domain ADSN kernel on a `size x size` periodic domain (the exemplar,
/// mean-padded when smaller, as the paper enlarges it).
pub struct AdsnKernel {
    pub size: usize,
    pub mean: f32,
    spec: Vec<Complex32>,
}

impl AdsnKernel {
    /// `exemplar` must already be at the target spacing. The domain is the next power of
    /// two >= max(exemplar side, `min_size`).
    pub fn new(exemplar: &HeightMap, min_size: usize) -> Result<Self> {
        let (w, h) = (exemplar.width, exemplar.height);
        if w < 2 || h < 2 {
            return Err(TextureError::BadExemplar {
                what: format!("{w} x {h} pixels"),
                reason: "needs at least 2 x 2 pixels at the target spacing".into(),
            });
        }
        let m = exemplar.moments();
        if m.sq_um.is_nan() || m.sq_um <= 1e-9 * m.mean_um.abs().max(1.0) {
            return Err(TextureError::BadExemplar {
                what: format!("{w} x {h} pixels"),
                reason: "height is constant (or not finite); it has no texture".into(),
            });
        }
        let p = periodic_component(&exemplar.data, w, h);
        let mean = (p.iter().map(|&v| v as f64).sum::<f64>() / p.len() as f64) as f32;
        let size = w.max(h).max(min_size).next_power_of_two();
        let norm = 1.0 / ((w * h) as f32).sqrt();
        let mut spec = vec![Complex32::new(0.0, 0.0); size * size];
        for y in 0..h {
            for x in 0..w {
                spec[y * size + x].re = (p[y * w + x] - mean) * norm;
            }
        }
        fft2(&mut spec, size, size, false);
        // Folds the inverse FFT's factor N and the noise spectrum's sqrt(N) into one.
        let k = 1.0 / (size as f32);
        spec.par_iter_mut().for_each(|z| *z *= k);
        Ok(Self { size, mean, spec })
    }

    /// Two independent ADSN realisations (real and imaginary part of one inverse FFT of
    /// the kernel times complex white noise), each `size x size`, row-major.
    pub fn realize_pair<R: Rng>(&self, rng: &mut R) -> (Vec<f32>, Vec<f32>) {
        let mut z: Vec<Complex32> = self
            .spec
            .iter()
            .map(|&k| {
                let g = Complex32::new(rng.sample(StandardNormal), rng.sample(StandardNormal));
                k * g
            })
            .collect();
        fft2(&mut z, self.size, self.size, true);
        let a = z.iter().map(|c| self.mean + c.re).collect();
        let b = z.iter().map(|c| self.mean + c.im).collect();
        (a, b)
    }
}
