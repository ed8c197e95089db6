//! Milled surfaces: the ring model of the paper ("Milled surface").
//!
//! Three sub-models: the tool path places ring centres (parallel meander or Archimedean
//! spiral), each ring gets its own appearance (indentation, inner/outer accumulation,
//! tilt, sine noise), and rings are composed in chronological order by a convex
//! combination with linear weights. Geometry is in millimetres, ring heights are
//! unitless (indentation depth ~1) until moment matching turns them into micrometres.
//!
//! Rasterisation is tiled: a spatial index lists, per 128 x 128 tile, the rings whose
//! band crosses it, in composition order, so memory stays at the output plus the ring
//! list and the work is parallel across tile rows.

mod path;
mod raster;
mod rings;

use std::str::FromStr;

use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::error::{Result, check};
use super::maps::{HeightMap, Moments};
use super::progress::Progress;
use path::tool_path;
use raster::{TILE, TileCtx, index_rings, raster_ring};
use rings::sample_rings;

/// Default height moments of a milled face when no measurement is given: mean 0,
/// Sq 0.8 um (typical face-milled aluminium, Ra 0.4 ... 0.8 um). A stand-in, not a
/// measured value of the paper's test bodies.
pub const MILLED_DEFAULT_MOMENTS: Moments = Moments {
    mean_um: 0.0,
    sq_um: 0.8,
};

/// Tool path shape.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ToolPath {
    /// Parallel lines along +x, alternating direction (meander), stepped by rho in y.
    Parallel,
    /// Archimedean spiral r = rho * theta / (2 pi) around `spiral_center_mm`.
    Spiral,
}

impl FromStr for ToolPath {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "parallel" => Ok(Self::Parallel),
            "spiral" => Ok(Self::Spiral),
            _ => Err(format!("unknown path `{s}`: allowed parallel | spiral")),
        }
    }
}

/// Every parameter of the paper's table "Overview of all parameters needed for the milling
/// model", with the paper's defaults. Standard deviations are given as in the paper, as
/// numerators: the sampled standard deviation is `sigma / conf`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MilledParams {
    /// d: ring (milling head) diameter, mm, > 0. Paper: 4 or 8.
    pub head_diameter_mm: f64,
    /// a_e: radial depth of cut, in (0, 1); alpha = 1 - a_e. Paper: 0.2, 0.5, 0.8.
    pub radial_depth: f64,
    /// gamma: blade-to-tool-edge allowance, in [0, alpha). Paper: 0.04.
    pub gamma: f64,
    /// Tool path. Paper: parallel or spiral.
    pub path: ToolPath,
    /// delta: centre spacing along the path, mm, > 0. Paper: 0.09.
    pub delta_mm: f64,
    /// conf: divisor of all standard deviations (3-sigma rule). Paper: 3.
    pub conf: f64,
    /// Sigma_c factor: centre jitter standard deviation = factor * delta / conf, mm, >= 0
    /// (the paper writes (Sigma_c)_ii = factor * delta / conf; by its 3-sigma rule
    /// factor * delta is the jitter's range). Paper: 0.01 (0.3 um); its variation set
    /// reaches 0.8 (24 um, a quarter of delta), which blurs the feed marks.
    pub center_noise: f64,
    /// epsilon: fraction of rings whose order is changed, in [0, 1]. Paper: 0.01.
    pub flip_fraction: f64,
    /// A flipped ring moves later in the order by U{1..=reach} rings; default (None):
    /// reach = ceil(d / delta), the number of rings it overlaps along the path, so it
    /// lands on top of its neighbours. Not specified by the paper.
    pub flip_reach_rings: Option<u32>,
    /// mu_{w-}: indentation width mean, mm, in (0, d/2). Paper: 0.05.
    pub w_minus_mean_mm: f64,
    /// sigma_{w-} (numerator), mm, >= 0. Paper: 0.025.
    pub w_minus_sigma_mm: f64,
    /// mu_{w+i}: inner accumulation width mean, mm, in [0, d/2 - mu_{w-}). Paper: 0.025.
    pub w_inner_mean_mm: f64,
    /// sigma_{w+i} (numerator), mm, >= 0. Paper: 0.1.
    pub w_inner_sigma_mm: f64,
    /// mu_{w+o}: outer accumulation width mean, mm, >= 0. Paper: 0.025.
    pub w_outer_mean_mm: f64,
    /// sigma_{w+o} (numerator), mm, >= 0. Paper: 0.1.
    pub w_outer_sigma_mm: f64,
    /// mu_{l-}: indentation depth scale at the ring's back, >= 0. Paper: 0.7.
    pub l_minus_mean: f64,
    /// mu_{h-}: indentation depth scale at the ring's front, >= 0. Paper: 1.
    pub h_minus_mean: f64,
    /// sigma_{l-} = sigma_{h-} (numerator), >= 0. Paper: 0.8.
    pub lh_minus_sigma: f64,
    /// mu_{l+i}, mu_{h+i}: inner accumulation height scales, >= 0. Paper: 0, 0.2.
    pub l_inner_mean: f64,
    pub h_inner_mean: f64,
    /// sigma_{l+i} = sigma_{h+i} (numerator), >= 0. Paper: 0.5.
    pub lh_inner_sigma: f64,
    /// mu_{l+o}, mu_{h+o}: outer accumulation height scales, >= 0. Paper: 0.2, 0.5.
    pub l_outer_mean: f64,
    pub h_outer_mean: f64,
    /// sigma_{l+o} = sigma_{h+o} (numerator), >= 0. Paper: 0.5.
    pub lh_outer_sigma: f64,
    /// lambda: mean number of noise sines per ring (Poisson), >= 0. Paper: 50.
    pub noise_lambda: f64,
    /// tau: mean sine frequency in cycles per ring turn (Poisson), >= 0. Paper: 50.
    pub noise_tau: f64,
    /// Amplitude of each of the lambda_k noise sines of N_k, relative to a unit
    /// indentation depth, >= 0; the noise RMS is amplitude * sqrt(lambda_k / 2), so it
    /// grows with lambda. The paper gives no amplitude; 0.01 gives an RMS of 0.05 at the
    /// paper's lambda = 50 (visible, below the tilt variation).
    pub noise_amplitude: f64,
    /// a_min, a_max: interaction weight at the ring's back ~ U(a_min, a_max). Paper: 0, 0.3.
    pub a_min: f64,
    pub a_max: f64,
    /// b_min, b_max: interaction weight at the ring's front ~ U(b_min, b_max). Paper: 0.1, 0.4.
    pub b_min: f64,
    pub b_max: f64,
    /// Spiral runs from the centre outwards (true) or from outside in (false).
    pub spiral_outward: bool,
    /// Spiral centre in texture coordinates, mm (x right, y down); None: texture centre.
    pub spiral_center_mm: Option<[f64; 2]>,
    /// Mill the straight move between the spiral centre and the outside (the paper
    /// leaves it open): before an outward spiral (entry), after an inward one (exit, on
    /// top of everything). Off by default (plunge / retract at the centre).
    pub spiral_exit_line: bool,
    /// Direction of that line from the centre, degrees from +x (image axes, y down).
    pub spiral_exit_angle_deg: f64,
    /// Shift the path grid by a seeded random phase (less than rho across, delta along),
    /// so textures of different seeds do not share ring positions.
    pub random_path_phase: bool,
    /// Target height moments (um) for moment matching.
    pub moments: Moments,
}

impl Default for MilledParams {
    fn default() -> Self {
        Self {
            head_diameter_mm: 4.0,
            radial_depth: 0.5,
            gamma: 0.04,
            path: ToolPath::Parallel,
            delta_mm: 0.09,
            conf: 3.0,
            center_noise: 0.01,
            flip_fraction: 0.01,
            flip_reach_rings: None,
            w_minus_mean_mm: 0.05,
            w_minus_sigma_mm: 0.025,
            w_inner_mean_mm: 0.025,
            w_inner_sigma_mm: 0.1,
            w_outer_mean_mm: 0.025,
            w_outer_sigma_mm: 0.1,
            l_minus_mean: 0.7,
            h_minus_mean: 1.0,
            lh_minus_sigma: 0.8,
            l_inner_mean: 0.0,
            h_inner_mean: 0.2,
            lh_inner_sigma: 0.5,
            l_outer_mean: 0.2,
            h_outer_mean: 0.5,
            lh_outer_sigma: 0.5,
            noise_lambda: 50.0,
            noise_tau: 50.0,
            noise_amplitude: 0.01,
            a_min: 0.0,
            a_max: 0.3,
            b_min: 0.1,
            b_max: 0.4,
            spiral_outward: true,
            spiral_center_mm: None,
            spiral_exit_line: false,
            spiral_exit_angle_deg: 0.0,
            random_path_phase: true,
            moments: MILLED_DEFAULT_MOMENTS,
        }
    }
}

impl MilledParams {
    /// alpha = 1 - a_e: overlap of neighbouring tool paths.
    pub fn alpha(&self) -> f64 {
        1.0 - self.radial_depth
    }

    /// rho = (1 - (alpha - gamma)) d: distance between neighbouring sub-paths, mm.
    pub fn rho_mm(&self) -> f64 {
        (1.0 - (self.alpha() - self.gamma)) * self.head_diameter_mm
    }

    pub fn validate(&self) -> Result<()> {
        let p = self;
        check(
            p.head_diameter_mm > 0.0,
            "head_diameter_mm",
            p.head_diameter_mm,
            "> 0 mm",
        )?;
        check(
            p.radial_depth > 0.0 && p.radial_depth < 1.0,
            "radial_depth",
            p.radial_depth,
            "(0, 1) (alpha = 1 - a_e must lie in (0, 1))",
        )?;
        check(
            p.gamma >= 0.0 && p.gamma < p.alpha(),
            "gamma",
            p.gamma,
            "[0, alpha) with alpha = 1 - radial_depth",
        )?;
        check(p.delta_mm > 0.0, "delta_mm", p.delta_mm, "> 0 mm")?;
        check(p.conf > 0.0, "conf", p.conf, "> 0")?;
        check(
            p.center_noise >= 0.0,
            "center_noise",
            p.center_noise,
            ">= 0",
        )?;
        check(
            (0.0..=1.0).contains(&p.flip_fraction),
            "flip_fraction",
            p.flip_fraction,
            "[0, 1]",
        )?;
        if let Some(r) = p.flip_reach_rings {
            check(r >= 1, "flip_reach_rings", r as f64, ">= 1")?;
        }
        check(
            p.w_minus_mean_mm > 0.0 && p.w_minus_mean_mm < p.head_diameter_mm / 2.0,
            "w_minus_mean_mm",
            p.w_minus_mean_mm,
            "(0, d/2) mm",
        )?;
        check(
            p.w_inner_mean_mm >= 0.0
                && p.w_inner_mean_mm < p.head_diameter_mm / 2.0 - p.w_minus_mean_mm,
            "w_inner_mean_mm",
            p.w_inner_mean_mm,
            "[0, d/2 - w_minus_mean_mm) mm",
        )?;
        check(
            p.w_outer_mean_mm >= 0.0,
            "w_outer_mean_mm",
            p.w_outer_mean_mm,
            ">= 0 mm",
        )?;
        let nonneg: [(&'static str, f64); 15] = [
            ("w_minus_sigma_mm", p.w_minus_sigma_mm),
            ("w_inner_sigma_mm", p.w_inner_sigma_mm),
            ("w_outer_sigma_mm", p.w_outer_sigma_mm),
            ("l_minus_mean", p.l_minus_mean),
            ("h_minus_mean", p.h_minus_mean),
            ("lh_minus_sigma", p.lh_minus_sigma),
            ("l_inner_mean", p.l_inner_mean),
            ("h_inner_mean", p.h_inner_mean),
            ("lh_inner_sigma", p.lh_inner_sigma),
            ("l_outer_mean", p.l_outer_mean),
            ("h_outer_mean", p.h_outer_mean),
            ("lh_outer_sigma", p.lh_outer_sigma),
            ("noise_lambda", p.noise_lambda),
            ("noise_tau", p.noise_tau),
            ("noise_amplitude", p.noise_amplitude),
        ];
        for (f, v) in nonneg {
            check(v >= 0.0, f, v, ">= 0")?;
        }
        check(
            p.noise_lambda <= 1e4,
            "noise_lambda",
            p.noise_lambda,
            "[0, 10000]",
        )?;
        check(p.noise_tau <= 1e4, "noise_tau", p.noise_tau, "[0, 10000]")?;
        check((0.0..=1.0).contains(&p.a_min), "a_min", p.a_min, "[0, 1]")?;
        check(
            p.a_max >= p.a_min && p.a_max <= 1.0,
            "a_max",
            p.a_max,
            "[a_min, 1]",
        )?;
        check((0.0..=1.0).contains(&p.b_min), "b_min", p.b_min, "[0, 1]")?;
        check(
            p.b_max >= p.b_min && p.b_max <= 1.0,
            "b_max",
            p.b_max,
            "[b_min, 1]",
        )?;
        check(
            p.moments.sq_um >= 0.0,
            "moments.sq_um",
            p.moments.sq_um,
            ">= 0 um",
        )?;
        check(
            p.moments.mean_um.is_finite(),
            "moments.mean_um",
            p.moments.mean_um,
            "finite",
        )?;
        check(
            p.spiral_exit_angle_deg.is_finite(),
            "spiral_exit_angle_deg",
            p.spiral_exit_angle_deg,
            "finite degrees",
        )?;
        if let Some(c) = p.spiral_center_mm {
            check(c[0].is_finite(), "spiral_center_mm[0]", c[0], "finite")?;
            check(c[1].is_finite(), "spiral_center_mm[1]", c[1], "finite")?;
        }
        Ok(())
    }

    /// One draw from the paper's variation sets ("Texture parameter ranges").
    pub fn sample_variation<R: Rng + ?Sized>(&self, rng: &mut R) -> Self {
        MilledVariation::default().sample(self, rng)
    }
}

/// Variation sets of the paper's table "Texture parameter ranges": each listed parameter
/// is drawn uniformly from its set, the rest keep the base value. The paper prints the
/// ring distance set as {0.7 ... 1.1}; with delta = 0.09 mm bold, the unit is 0.1 mm.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MilledVariation {
    pub center_noise: Vec<f64>,
    pub delta_mm: Vec<f64>,
    pub flip_fraction: Vec<f64>,
    pub w_minus_sigma_mm: Vec<f64>,
    pub lh_minus_sigma: Vec<f64>,
    pub noise_lambda: Vec<f64>,
}

impl Default for MilledVariation {
    fn default() -> Self {
        Self {
            center_noise: vec![0.01, 0.05, 0.1, 0.2, 0.4, 0.6, 0.8],
            delta_mm: vec![0.07, 0.075, 0.08, 0.085, 0.09, 0.095, 0.1, 0.105, 0.11],
            flip_fraction: vec![0.01, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5],
            w_minus_sigma_mm: vec![0.015, 0.02, 0.025, 0.03, 0.035],
            lh_minus_sigma: vec![0.4, 0.6, 0.8, 1.0, 1.2],
            noise_lambda: vec![30.0, 50.0, 70.0],
        }
    }
}

impl MilledVariation {
    pub fn sample<R: Rng + ?Sized>(&self, base: &MilledParams, rng: &mut R) -> MilledParams {
        fn pick<R: Rng + ?Sized>(set: &[f64], keep: f64, rng: &mut R) -> f64 {
            if set.is_empty() {
                keep
            } else {
                set[rng.random_range(0..set.len())]
            }
        }
        let mut p = base.clone();
        p.center_noise = pick(&self.center_noise, p.center_noise, rng);
        p.delta_mm = pick(&self.delta_mm, p.delta_mm, rng);
        p.flip_fraction = pick(&self.flip_fraction, p.flip_fraction, rng);
        p.w_minus_sigma_mm = pick(&self.w_minus_sigma_mm, p.w_minus_sigma_mm, rng);
        p.lh_minus_sigma = pick(&self.lh_minus_sigma, p.lh_minus_sigma, rng);
        p.noise_lambda = pick(&self.noise_lambda, p.noise_lambda, rng);
        p
    }
}
/// Synthesises a milled height map of `width` x `height` pixels at `spacing_um`.
pub fn generate_milled(
    p: &MilledParams,
    width: usize,
    height: usize,
    spacing_um: f64,
    seed: u64,
    progress: &dyn Progress,
) -> Result<HeightMap> {
    p.validate()?;
    check_size(width, height, spacing_um)?;
    let s_mm = spacing_um * 1e-3;
    let (w_mm, h_mm) = (width as f64 * s_mm, height as f64 * s_mm);
    // Guards memory: rings ~ covered area / (rho * delta).
    let margin = p.head_diameter_mm + 1.0;
    let span = (w_mm + margin).max(h_mm + margin);
    let rings_est = span * span / (p.rho_mm() * p.delta_mm);
    check(
        rings_est <= 2e7,
        "delta_mm",
        p.delta_mm,
        "large enough that the texture needs at most 20 million rings (~ area / (rho * delta))",
    )?;
    let path = tool_path(p, w_mm, h_mm, seed)?;
    let (rings, pool) = sample_rings(p, &path, w_mm, h_mm, seed);

    let tiles_x = width.div_ceil(TILE);
    let tiles_y = height.div_ceil(TILE);
    let buckets = index_rings(&rings, tiles_x, tiles_y, TILE as f64 * s_mm);

    progress.start("milled rings", tiles_y as u64);
    let mut map = HeightMap::new(width, height, spacing_um);
    map.data
        .par_chunks_mut(TILE * width)
        .enumerate()
        .for_each(|(ty, band)| {
            let rows = band.len() / width;
            let mut tile = vec![0.0f32; TILE * TILE];
            for tx in 0..tiles_x {
                let cols = TILE.min(width - tx * TILE);
                tile.fill(0.0);
                let ctx = TileCtx {
                    x0: tx * TILE,
                    y0: ty * TILE,
                    cols,
                    rows,
                    s: s_mm as f32,
                };
                for &k in &buckets[ty * tiles_x + tx] {
                    raster_ring(&rings[k as usize], &pool, &ctx, &mut tile);
                }
                for r in 0..rows {
                    band[r * width + tx * TILE..r * width + tx * TILE + cols]
                        .copy_from_slice(&tile[r * TILE..r * TILE + cols]);
                }
            }
            progress.advance(1);
        });
    map.match_moments(p.moments);
    Ok(map)
}

pub(crate) fn check_size(width: usize, height: usize, spacing_um: f64) -> Result<()> {
    check(width > 0, "size (width)", width as f64, ">= 1 pixel")?;
    check(height > 0, "size (height)", height as f64, ">= 1 pixel")?;
    check(
        width <= 65_536,
        "size (width)",
        width as f64,
        "<= 65536 pixels",
    )?;
    check(
        height <= 65_536,
        "size (height)",
        height as f64,
        "<= 65536 pixels",
    )?;
    check(spacing_um > 0.0, "spacing_um", spacing_um, "> 0 um")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::texture::rng::stream;

    #[test]
    fn rho_follows_paper() {
        let p = MilledParams {
            head_diameter_mm: 4.0,
            radial_depth: 0.5,
            ..Default::default()
        };
        assert!((p.rho_mm() - 0.54 * 4.0).abs() < 1e-12);
    }

    #[test]
    fn variation_stays_in_sets() {
        let base = MilledParams::default();
        let v = MilledVariation::default();
        let mut rng = stream(7, 0, 0);
        for _ in 0..50 {
            let p = base.sample_variation(&mut rng);
            assert!(v.delta_mm.contains(&p.delta_mm));
            assert!(v.noise_lambda.contains(&p.noise_lambda));
            assert!(v.center_noise.contains(&p.center_noise));
            assert_eq!(p.head_diameter_mm, base.head_diameter_mm);
            p.validate().expect("variation must be valid");
        }
    }
}
