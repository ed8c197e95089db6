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

use std::f32::consts::PI;
use std::str::FromStr;

use rand::Rng;
use rand_distr::{Distribution, Poisson, StandardNormal, Uniform};
use rayon::prelude::*;
use rustfft::FftPlanner;
use rustfft::num_complex::Complex32;
use serde::{Deserialize, Serialize};

use super::error::{Result, check};
use super::maps::{HeightMap, Moments};
use super::progress::Progress;
use super::rng::stream;

/// Default height moments of a milled face when no measurement is given: mean 0,
/// Sq 0.8 um (typical face-milled aluminium, Ra 0.4 ... 0.8 um). A stand-in, not a
/// measured value of the paper's test bodies.
pub const MILLED_DEFAULT_MOMENTS: Moments = Moments {
    mean_um: 0.0,
    sq_um: 0.8,
};

const TILE: usize = 128;

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
    /// (the paper writes (Sigma_c)_ii = factor * delta / conf). Paper: 0.01.
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
    /// RMS of the ring noise N_k relative to a unit indentation depth, >= 0. The paper
    /// gives no amplitude; 0.05 keeps the noise visible but below the tilt variation.
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
            noise_amplitude: 0.05,
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

/// Normal distribution by mean and standard deviation; sd 0 gives the mean.
#[derive(Clone, Copy)]
struct Gauss(f64, f64);
impl Gauss {
    fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        let z: f64 = rng.sample(StandardNormal);
        self.0 + self.1 * z
    }
}

/// A nominal ring centre on the tool path with its movement direction.
#[derive(Clone, Copy, Debug)]
struct PathPoint {
    x: f64,
    y: f64,
    dir: [f64; 2],
}

/// One sampled ring, compact for the raster loop.
struct Ring {
    c: [f32; 2],
    dir: [f32; 2],
    r_in: f32,
    r_out: f32,
    r0: f32,
    wm: f32,
    wi: f32,
    wo: f32,
    /// 1 / w for the three components (0 where the width is 0).
    inv_w: [f32; 3],
    tilt: [[f32; 2]; 3],
    ab: [f32; 2],
    noise_amp: f32,
    noise_off: usize,
    noise_len: usize,
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

/// Nominal ring centres in chronological order. Both paths overshoot the texture by
/// d/2 + 0.5 mm so every ring touching the texture exists; the meander's turn-arounds
/// and the spiral's entry/exit moves therefore lie outside the texture and are not drawn.
fn tool_path(p: &MilledParams, w: f64, h: f64, seed: u64) -> Result<Vec<PathPoint>> {
    let d = p.head_diameter_mm;
    let rho = p.rho_mm();
    let delta = p.delta_mm;
    let margin = d / 2.0 + 0.5;
    let mut rng = stream(seed, 0, 0);
    let (ph_rho, ph_delta) = if p.random_path_phase {
        (rng.random::<f64>(), rng.random::<f64>())
    } else {
        (0.0, 0.0)
    };
    let mut pts = Vec::new();
    match p.path {
        ToolPath::Parallel => {
            let y0 = -margin + ph_rho * rho;
            let x0 = -margin + ph_delta * delta;
            let nx = ((w + 2.0 * margin - ph_delta * delta) / delta).ceil() as usize + 1;
            let mut j = 0usize;
            loop {
                let y = y0 + j as f64 * rho;
                if y > h + margin {
                    break;
                }
                for i in 0..nx {
                    let (x, dir) = if j.is_multiple_of(2) {
                        (x0 + i as f64 * delta, [1.0, 0.0])
                    } else {
                        (x0 + (nx - 1 - i) as f64 * delta, [-1.0, 0.0])
                    };
                    pts.push(PathPoint { x, y, dir });
                }
                j += 1;
            }
        }
        ToolPath::Spiral => {
            let [cx, cy] = p.spiral_center_mm.unwrap_or([w / 2.0, h / 2.0]);
            let far = [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)]
                .iter()
                .map(|&(x, y)| ((x - cx).powi(2) + (y - cy).powi(2)).sqrt())
                .fold(0.0f64, f64::max);
            let r_max = far + margin;
            // The spiral is walked from its centre even when that lies far outside.
            let steps = std::f64::consts::PI * r_max * r_max / (rho * delta);
            check(
                steps <= 2e8,
                "spiral_center_mm",
                cx.hypot(cy),
                "close enough to the texture that the spiral needs <= 2e8 steps",
            )?;
            let k = rho / (2.0 * std::f64::consts::PI);
            let mut theta = 0.0f64;
            let rot = ph_rho * 2.0 * std::f64::consts::PI;
            loop {
                let r = k * theta;
                if r > r_max {
                    break;
                }
                let (sn, cs) = (theta + rot).sin_cos();
                let tx = k * cs - r * sn;
                let ty = k * sn + r * cs;
                let norm = (tx * tx + ty * ty).sqrt();
                let (x, y) = (cx + r * cs, cy + r * sn);
                if x > -margin && x < w + margin && y > -margin && y < h + margin {
                    pts.push(PathPoint {
                        x,
                        y,
                        dir: [tx / norm, ty / norm],
                    });
                }
                theta += delta / norm;
            }
            if !p.spiral_outward {
                pts.reverse();
                for q in &mut pts {
                    q.dir = [-q.dir[0], -q.dir[1]];
                }
            }
            if p.spiral_exit_line {
                let (sn, cs) = p.spiral_exit_angle_deg.to_radians().sin_cos();
                let line = (0..=(r_max / delta).ceil() as usize).filter_map(|i| {
                    let r = i as f64 * delta;
                    let (x, y) = (cx + r * cs, cy + r * sn);
                    let inside = x > -margin && x < w + margin && y > -margin && y < h + margin;
                    inside.then_some(PathPoint {
                        x,
                        y,
                        dir: [cs, sn],
                    })
                });
                if p.spiral_outward {
                    // Entry: from outside to the centre, before the spiral.
                    let mut entry: Vec<PathPoint> = line
                        .map(|q| PathPoint {
                            dir: [-cs, -sn],
                            ..q
                        })
                        .collect();
                    entry.reverse();
                    entry.append(&mut pts);
                    pts = entry;
                } else {
                    pts.extend(line);
                }
            }
        }
    }
    Ok(pts)
}

/// Samples every ring's appearance, applies the order flips, and drops rings whose band
/// misses the texture. Returns rings in composition order and the shared noise pool.
fn sample_rings(
    p: &MilledParams,
    path: &[PathPoint],
    w: f64,
    h: f64,
    seed: u64,
) -> (Vec<Ring>, Vec<f32>) {
    let conf = p.conf;
    // (Sigma_c)_ii = factor * delta / conf is linear in a length, so it is read as a
    // standard deviation in mm (a variance would scale with delta^2); see docs/texture.md.
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
/// by one inverse FFT. Normalised by sqrt(lambda_k / 2) so its RMS is 1; the amplitude
/// is applied in the raster loop.
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
    let norm = 1.0 / (lambda as f32 / 2.0).sqrt();
    let table = spec.iter().map(|c| c.im * norm).collect();
    (table, p.noise_amplitude as f32)
}

#[allow(clippy::too_many_arguments)]
fn annulus_hits_rect(
    cx: f64,
    cy: f64,
    r_in: f64,
    r_out: f64,
    x0: f64,
    y0: f64,
    x1: f64,
    y1: f64,
) -> bool {
    let nx = cx.clamp(x0, x1) - cx;
    let ny = cy.clamp(y0, y1) - cy;
    let near = nx * nx + ny * ny;
    let fx = (cx - x0).abs().max((cx - x1).abs());
    let fy = (cy - y0).abs().max((cy - y1).abs());
    let far = fx * fx + fy * fy;
    near <= r_out * r_out && far >= r_in.max(0.0) * r_in.max(0.0)
}

/// Per-tile ring lists in composition order (rings are already sorted).
fn index_rings(rings: &[Ring], tiles_x: usize, tiles_y: usize, tile_mm: f64) -> Vec<Vec<u32>> {
    let mut buckets = vec![Vec::new(); tiles_x * tiles_y];
    for (k, r) in rings.iter().enumerate() {
        let (cx, cy, ro) = (r.c[0] as f64, r.c[1] as f64, r.r_out as f64);
        let tx0 = ((cx - ro) / tile_mm).floor().max(0.0) as usize;
        let ty0 = ((cy - ro) / tile_mm).floor().max(0.0) as usize;
        let tx1 = (((cx + ro) / tile_mm).floor().max(0.0) as usize).min(tiles_x - 1);
        let ty1 = (((cy + ro) / tile_mm).floor().max(0.0) as usize).min(tiles_y - 1);
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                let (x0, y0) = (tx as f64 * tile_mm, ty as f64 * tile_mm);
                if annulus_hits_rect(
                    cx,
                    cy,
                    r.r_in as f64,
                    ro,
                    x0,
                    y0,
                    x0 + tile_mm,
                    y0 + tile_mm,
                ) {
                    buckets[ty * tiles_x + tx].push(k as u32);
                }
            }
        }
    }
    buckets
}

struct TileCtx {
    x0: usize,
    y0: usize,
    cols: usize,
    rows: usize,
    s: f32,
}

/// Composes one ring into a tile: f = L_k R_k + (1 - L_k) f on the ring's band only.
fn raster_ring(r: &Ring, pool: &[f32], t: &TileCtx, tile: &mut [f32]) {
    let s = t.s;
    let (cx, cy) = (r.c[0], r.c[1]);
    let row_lo = (((cy - r.r_out) / s - 0.5).ceil().max(t.y0 as f32) as usize).max(t.y0);
    let row_hi = (((cy + r.r_out) / s - 0.5).floor()).min((t.y0 + t.rows) as f32 - 1.0);
    if row_hi < row_lo as f32 {
        return;
    }
    let noise = &pool[r.noise_off..r.noise_off + r.noise_len];
    let inv_band = 1.0 / (r.r_out - r.r_in);
    let inv_rout = 1.0 / r.r_out;
    for j in row_lo..=row_hi as usize {
        let dy = (j as f32 + 0.5) * s - cy;
        let ext_out = r.r_out * r.r_out - dy * dy;
        if ext_out < 0.0 {
            continue;
        }
        let xo = ext_out.sqrt();
        let ext_in = r.r_in * r.r_in - dy * dy;
        let row = &mut tile[(j - t.y0) * TILE..(j - t.y0) * TILE + t.cols];
        let mut seg = |xa: f32, xb: f32| {
            let ia = (((cx + xa) / s - 0.5).ceil()).max(t.x0 as f32) as usize;
            let ib = (((cx + xb) / s - 0.5).floor()).min((t.x0 + t.cols) as f32 - 1.0);
            if ib < ia as f32 {
                return;
            }
            for i in ia..=ib as usize {
                let dx = (i as f32 + 0.5) * s - cx;
                let rad = (dx * dx + dy * dy).sqrt();
                if rad < r.r_in || rad > r.r_out {
                    continue;
                }
                let front = 0.5 + 0.5 * (dx * r.dir[0] + dy * r.dir[1]) * inv_rout;
                let mut v = ring_profile(r, rad - r.r0, front);
                if r.noise_amp > 0.0 {
                    let env = cos_half_pi((rad - r.r_in) * inv_band - 0.5);
                    v += r.noise_amp * env * lookup(noise, fast_atan2(dy, dx));
                }
                let l = r.ab[0] + (r.ab[1] - r.ab[0]) * front;
                let f = &mut row[i - t.x0];
                *f = l * v + (1.0 - l) * *f;
            }
        };
        if ext_in > 0.0 {
            let xi = ext_in.sqrt();
            seg(-xo, -xi);
            seg(xi, xo);
        } else {
            seg(-xo, xo);
        }
    }
}

/// S_k * T_k at signed radial offset `s` from the indentation centre; `front` in [0, 1]
/// runs linearly from the ring's back (l) to its front (h).
#[inline]
fn ring_profile(r: &Ring, s: f32, front: f32) -> f32 {
    let half = 0.5 * r.wm;
    let lerp = |t: [f32; 2]| t[0] + (t[1] - t[0]) * front;
    if s.abs() <= half {
        -cos_half_pi(s * r.inv_w[0]) * lerp(r.tilt[0])
    } else if s < 0.0 {
        let u = s + half + 0.5 * r.wi;
        if r.wi > 0.0 && u.abs() <= 0.5 * r.wi {
            cos_half_pi(u * r.inv_w[1]) * lerp(r.tilt[1])
        } else {
            0.0
        }
    } else {
        let u = s - half - 0.5 * r.wo;
        if r.wo > 0.0 && u.abs() <= 0.5 * r.wo {
            cos_half_pi(u * r.inv_w[2]) * lerp(r.tilt[2])
        } else {
            0.0
        }
    }
}

/// cos(pi x) for |x| <= 1/2 by its Taylor polynomial (error < 3e-5): the shapes are
/// evaluated for every band pixel of every ring, where libm's cos dominated the time.
#[inline]
fn cos_half_pi(x: f32) -> f32 {
    let t = PI * PI * x * x;
    1.0 + t * (-0.5 + t * (1.0 / 24.0 + t * (-1.0 / 720.0 + t * (1.0 / 40320.0))))
}

/// Linear interpolation in a power-of-two periodic table at `angle` in [-pi, pi];
/// masks instead of `rem_euclid` / `%`, which cost as much as the rest of the pixel.
#[inline]
fn lookup(table: &[f32], angle: f32) -> f32 {
    let n = table.len();
    if n == 0 {
        return 0.0;
    }
    let x = angle * (n as f32 * (0.5 / PI)) + 2.0 * n as f32;
    let i = x as usize;
    let f = x - i as f32;
    let mask = n - 1;
    table[i & mask] * (1.0 - f) + table[(i + 1) & mask] * f
}

/// atan2 with ~1e-5 rad error (minimax polynomial on [0, 1]); the noise table does not need more.
#[inline]
fn fast_atan2(y: f32, x: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    let mx = ax.max(ay);
    if mx == 0.0 {
        return 0.0;
    }
    let a = ax.min(ay) / mx;
    let s = a * a;
    let mut r =
        a * (0.999_866 + s * (-0.330_299_5 + s * (0.180_141 + s * (-0.085_133 + s * 0.020_835_1))));
    if ay > ax {
        r = PI / 2.0 - r;
    }
    if x < 0.0 {
        r = PI - r;
    }
    if y < 0.0 { -r } else { r }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_atan2_matches_std() {
        for k in 0..1000 {
            let a = k as f32 * 0.00628 - PI;
            let (y, x) = a.sin_cos();
            let e = (fast_atan2(y * 3.0, x * 3.0) - y.atan2(x)).abs();
            assert!(
                e < 3e-5 || (e - 2.0 * PI).abs() < 3e-5,
                "angle {a}: err {e}"
            );
        }
    }

    #[test]
    fn cos_half_pi_is_accurate() {
        for k in 0..=1000 {
            let x = k as f32 / 1000.0 - 0.5;
            assert!((cos_half_pi(x) - (PI * x).cos()).abs() < 3e-5, "x = {x}");
        }
    }

    #[test]
    fn lookup_interpolates_periodically() {
        let table: Vec<f32> = (0..64).map(|i| i as f32).collect();
        let step = 2.0 * PI / 64.0;
        assert!((lookup(&table, 3.0 * step) - 3.0).abs() < 1e-3);
        assert!((lookup(&table, 3.5 * step) - 3.5).abs() < 1e-3);
        assert!((lookup(&table, -PI) - 32.0).abs() < 1e-3);
        assert!((lookup(&table, -0.5 * step) - 31.5).abs() < 1e-2);
    }

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
