//! Stand-in exemplar: no real sandblasting measurement ships with the project, so this
//! generator makes a plausible one, a field of overlapping impact craters. It is NOT
//! calibrated against measurements; pass a real Alicona export for faithful textures.
//!
//! Each grain impact leaves a paraboloid bowl with a raised rim (material pushed aside).
//! Crater diameter scales with grain size and weakly with pressure (impact energy grows
//! with pressure, the crater with its cube root in the plastic regime; we use p^(1/4)),
//! the depth-to-diameter ratio grows with impact speed (~ sqrt(p)). Craters add up; with
//! several layers of coverage the field is close to Gaussian, as the paper observes.

use rand::Rng;
use rand_distr::{Distribution, LogNormal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::texture::error::{Result, check};
use crate::texture::maps::{HeightMap, Moments};
use crate::texture::rng::stream;

/// Default height moments of a sandblasted face for a blasting pressure: mean 0,
/// Sq = 1.2 um * sqrt(p / 1 bar) (1.9 um at 2.5 bar, 2.9 um at 6 bar). A stand-in in the
/// range reported for corundum-blasted aluminium, not the paper's measurement.
pub fn sandblast_default_moments(pressure_bar: f64) -> Moments {
    Moments {
        mean_um: 0.0,
        sq_um: 1.2 * pressure_bar.max(0.0).sqrt(),
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StandInExemplar {
    /// Blasting pressure, bar, in (0, 20]. Paper: 2.5 or 6.
    pub pressure_bar: f64,
    /// Mean grain size, um, > 0 (F100 corundum ~ 150 um).
    pub grain_size_um: f64,
    /// Exemplar spacing, um, > 0 (the paper's measurements: 1.75).
    pub spacing_um: f64,
    /// Exemplar side, pixels, in [16, 16384].
    pub size_px: usize,
    /// Mean number of craters covering each point, > 0.
    pub coverage: f64,
}

impl Default for StandInExemplar {
    fn default() -> Self {
        Self {
            pressure_bar: 2.5,
            grain_size_um: 150.0,
            spacing_um: 1.75,
            size_px: 2048,
            coverage: 4.0,
        }
    }
}

struct Crater {
    x: f32,
    y: f32,
    r: f32,
    depth: f32,
}

impl StandInExemplar {
    pub fn validate(&self) -> Result<()> {
        check(
            self.pressure_bar > 0.0 && self.pressure_bar <= 20.0,
            "pressure_bar",
            self.pressure_bar,
            "(0, 20] bar",
        )?;
        check(
            self.grain_size_um > 0.0,
            "grain_size_um",
            self.grain_size_um,
            "> 0 um",
        )?;
        check(
            self.spacing_um > 0.0,
            "spacing_um",
            self.spacing_um,
            "> 0 um",
        )?;
        check(
            (16..=16384).contains(&self.size_px),
            "size_px",
            self.size_px as f64,
            "[16, 16384] pixels",
        )?;
        check(
            self.coverage > 0.0 && self.coverage <= 100.0,
            "coverage",
            self.coverage,
            "(0, 100]",
        )
    }

    /// Median crater radius, um.
    pub fn crater_radius_um(&self) -> f64 {
        0.15 * self.grain_size_um * (self.pressure_bar / 2.5).powf(0.25)
    }

    /// Height map in micrometres at `spacing_um`, moment matched to
    /// [`sandblast_default_moments`].
    pub fn generate(&self, seed: u64) -> Result<HeightMap> {
        self.validate()?;
        let n = self.size_px;
        let s = self.spacing_um as f32;
        let side = n as f32 * s;
        let r_med = self.crater_radius_um();
        let count = (self.coverage * (side as f64).powi(2)
            / (std::f64::consts::PI * (1.5 * r_med).powi(2)))
        .ceil() as usize;
        check(
            count <= 50_000_000,
            "grain_size_um",
            self.grain_size_um,
            "large enough for at most 50 million craters (coverage * area / crater area)",
        )?;
        let ratio = 0.12 * (self.pressure_bar / 2.5).sqrt();
        let mut rng = stream(seed, 3, 0);
        let radius = LogNormal::new(r_med.ln(), 0.35).map_err(|_| {
            crate::texture::error::TextureError::InvalidParameter {
                field: "grain_size_um",
                value: self.grain_size_um,
                allowed: "> 0 um",
            }
        })?;
        let mut craters: Vec<Crater> = (0..count)
            .map(|_| {
                let r = radius.sample(&mut rng) as f32;
                Crater {
                    x: rng.random::<f32>() * side,
                    y: rng.random::<f32>() * side,
                    r,
                    depth: r * 2.0 * ratio as f32,
                }
            })
            .collect();
        craters.sort_by(|a, b| a.y.total_cmp(&b.y));
        let max_r = craters.iter().map(|c| c.r).fold(0.0f32, f32::max) * 1.5;
        let mut map = HeightMap::new(n, n, self.spacing_um);
        map.data.par_chunks_mut(n).enumerate().for_each(|(j, row)| {
            let py = (j as f32 + 0.5) * s;
            let lo = craters.partition_point(|c| c.y < py - max_r);
            for c in craters[lo..].iter().take_while(|c| c.y <= py + max_r) {
                let reach = 1.5 * c.r;
                let dy = py - c.y;
                if dy.abs() > reach {
                    continue;
                }
                let xo = (reach * reach - dy * dy).sqrt();
                let i0 = ((c.x - xo) / s - 0.5).ceil().max(0.0) as usize;
                let i1 = ((c.x + xo) / s - 0.5).floor().min(n as f32 - 1.0);
                if i1 < i0 as f32 {
                    continue;
                }
                for (i, v) in row.iter_mut().enumerate().take(i1 as usize + 1).skip(i0) {
                    let dx = (i as f32 + 0.5) * s - c.x;
                    let q = (dx * dx + dy * dy).sqrt() / c.r;
                    *v += crater_profile(q) * c.depth;
                }
            }
        });
        map.match_moments(sandblast_default_moments(self.pressure_bar));
        Ok(map)
    }
}

/// Crater height at normalised radius q = r / R, in units of the crater depth: a
/// paraboloid bowl inside, a rim of about a third of the depth outside, zero beyond 1.5.
fn crater_profile(q: f32) -> f32 {
    if q < 1.0 {
        q * q - 1.0
    } else if q < 1.5 {
        let t = (q - 1.0) / 0.5;
        0.35 * (std::f32::consts::PI * t).sin()
    } else {
        0.0
    }
}
