//! Tables for Kulla-Conty (2017) multiple-scattering compensation of the GGX conductor:
//! E(mu, alpha), the single-scattering albedo with F = 1, and its cosine-weighted average
//! E_avg(alpha) = 2 int E(mu) mu dmu. Computed on the CPU by deterministic quadrature
//! (VNDF importance sampling driven by a Hammersley point set, so the result is the same
//! on every run and machine) and uploaded to the shader, which interpolates bilinearly
//! exactly like [`EnergyTables::e`].

use glam::Vec3;

use super::bsdf::{ggx_g1, ggx_g2, hammersley, sample_vndf};

/// Table resolution in mu and in alpha.
pub const N: usize = 32;
/// Hammersley points per table entry.
pub const SAMPLES: u32 = 2048;

/// E (row-major, alpha rows of N mu entries) and E_avg (N alpha entries).
///
/// mu nodes: (i + 0.5) / N (clamped outside). alpha nodes: j / (N - 1); the node alpha = 0
/// holds the analytic limit E = 1 (a perfect mirror loses nothing).
#[derive(Clone, Debug, PartialEq)]
pub struct EnergyTables {
    pub e: Vec<f32>,
    pub e_avg: Vec<f32>,
}

/// Single-scattering directional albedo of GGX with F = 1, by VNDF sampling: the
/// estimator of f cos / pdf is G2 / G1(wo).
pub fn directional_albedo(alpha: f32, mu: f32, samples: u32) -> f32 {
    let mu = mu.clamp(1e-4, 1.0);
    let wo = Vec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let g1o = ggx_g1(alpha, wo);
    let mut sum = 0.0f64;
    for i in 0..samples {
        let (u1, u2) = hammersley(i, samples);
        let h = sample_vndf(alpha, wo, u1, u2);
        let wi = 2.0 * wo.dot(h) * h - wo;
        if wi.z > 0.0 {
            sum += (ggx_g2(alpha, wo, wi) / g1o) as f64;
        }
    }
    (sum / samples as f64) as f32
}

impl EnergyTables {
    pub fn compute() -> EnergyTables {
        let mut e = vec![0.0f32; N * N];
        let mut e_avg = vec![0.0f32; N];
        for j in 0..N {
            let alpha = j as f32 / (N - 1) as f32;
            let mut avg = 0.0f64;
            for i in 0..N {
                let mu = (i as f32 + 0.5) / N as f32;
                let v = if j == 0 {
                    1.0
                } else {
                    directional_albedo(alpha, mu, SAMPLES)
                };
                e[j * N + i] = v;
                avg += v as f64 * mu as f64;
            }
            e_avg[j] = (2.0 * avg / N as f64) as f32;
        }
        EnergyTables { e, e_avg }
    }

    fn alpha_coord(alpha: f32) -> (usize, usize, f32) {
        let x = (alpha.clamp(0.0, 1.0) * (N - 1) as f32).min((N - 1) as f32);
        let j0 = (x.floor() as usize).min(N - 2);
        (j0, j0 + 1, x - j0 as f32)
    }

    /// Bilinear lookup of E(mu, alpha).
    pub fn e(&self, mu: f32, alpha: f32) -> f32 {
        let x = (mu.clamp(0.0, 1.0) * N as f32 - 0.5).clamp(0.0, (N - 1) as f32);
        let i0 = (x.floor() as usize).min(N - 2);
        let fx = x - i0 as f32;
        let (j0, j1, fy) = Self::alpha_coord(alpha);
        let row = |j: usize| self.e[j * N + i0] * (1.0 - fx) + self.e[j * N + i0 + 1] * fx;
        row(j0) * (1.0 - fy) + row(j1) * fy
    }

    /// Linear lookup of E_avg(alpha).
    pub fn e_avg(&self, alpha: f32) -> f32 {
        let (j0, j1, f) = Self::alpha_coord(alpha);
        self.e_avg[j0] * (1.0 - f) + self.e_avg[j1] * f
    }

    /// The layout the shader reads: E (N*N) then E_avg (N).
    pub fn packed(&self) -> Vec<f32> {
        let mut v = self.e.clone();
        v.extend_from_slice(&self.e_avg);
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_incidence_alpha_one_is_one_minus_ln2() {
        let e = directional_albedo(1.0, 1.0, 1 << 16);
        assert!((e - (1.0 - std::f32::consts::LN_2)).abs() < 2e-3, "{e}");
    }
}
