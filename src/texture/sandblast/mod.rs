//! Sandblasted surfaces (paper, "Sandblasted surface"): an exemplar height map is
//! resampled to the target spacing (nearest neighbour), many ADSN patches are drawn from
//! it and joined by Efros-Freeman minimum-error cuts, and the result is moment matched.

pub mod adsn;
pub mod exemplar;
pub mod quilting;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::error::{Result, TextureError, check};
use super::maps::{HeightMap, Moments};
use super::milling::check_size;
use super::progress::Progress;
use super::rng::stream;
use adsn::AdsnKernel;

/// Patch layout and moment target for sandblasted synthesis.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SandblastParams {
    /// Patch side, pixels, >= 16. Paper: 512.
    pub patch_size: usize,
    /// Overlap of neighbouring patches, pixels, in [1, patch_size / 2]. Paper: 256.
    pub overlap: usize,
    /// Target moments (um); None keeps the (resampled) exemplar's mean and Sq.
    pub moments: Option<Moments>,
}

impl Default for SandblastParams {
    fn default() -> Self {
        Self {
            patch_size: 512,
            overlap: 256,
            moments: None,
        }
    }
}

impl SandblastParams {
    pub fn validate(&self) -> Result<()> {
        check(
            (16..=8192).contains(&self.patch_size),
            "patch_size",
            self.patch_size as f64,
            "[16, 8192] pixels",
        )?;
        check(
            self.overlap >= 1 && self.overlap <= self.patch_size / 2,
            "overlap",
            self.overlap as f64,
            "[1, patch_size / 2] pixels",
        )?;
        if let Some(m) = self.moments {
            check(m.sq_um >= 0.0, "moments.sq_um", m.sq_um, ">= 0 um")?;
            check(
                m.mean_um.is_finite(),
                "moments.mean_um",
                m.mean_um,
                "finite",
            )?;
        }
        Ok(())
    }
}

/// Nearest-neighbour resampling from the exemplar's spacing to a coarser one (the paper
/// only coarsens: nu_T >= nu_M).
pub fn resample_nearest(ex: &HeightMap, spacing_um: f64) -> Result<HeightMap> {
    check(spacing_um > 0.0, "spacing_um", spacing_um, "> 0 um")?;
    if spacing_um < ex.spacing_um * (1.0 - 1e-9) {
        return Err(TextureError::InvalidParameter {
            field: "spacing_um",
            value: spacing_um,
            allowed: ">= the exemplar's spacing (nearest-neighbour resampling only coarsens)",
        });
    }
    let ratio = spacing_um / ex.spacing_um;
    let w = ((ex.width as f64 / ratio).floor() as usize).max(1);
    let h = ((ex.height as f64 / ratio).floor() as usize).max(1);
    let src = |i: usize, n: usize| (((i as f64 + 0.5) * ratio) as usize).min(n - 1);
    let mut out = HeightMap::new(w, h, spacing_um);
    out.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let sy = src(y, ex.height);
        for (x, v) in row.iter_mut().enumerate() {
            *v = ex.get(src(x, ex.width), sy);
        }
    });
    Ok(out)
}

/// Synthesises a `width x height` sandblasted height map at `spacing_um` from an
/// exemplar (at its own spacing; it is resampled here).
pub fn generate_sandblasted(
    exemplar: &HeightMap,
    p: &SandblastParams,
    width: usize,
    height: usize,
    spacing_um: f64,
    seed: u64,
    progress: &dyn Progress,
) -> Result<HeightMap> {
    p.validate()?;
    check_size(width, height, spacing_um)?;
    let ex = resample_nearest(exemplar, spacing_um)?;
    let kernel = AdsnKernel::new(&ex, 2 * p.patch_size)?;
    let target = p.moments.unwrap_or_else(|| ex.moments());
    let mut map = quilt(&kernel, p, width, height, seed, progress);
    map.spacing_um = spacing_um;
    map.match_moments(target);
    Ok(map)
}

/// Patch layout: patches every `patch - overlap` pixels; the last ones are cropped.
fn quilt(
    kernel: &AdsnKernel,
    p: &SandblastParams,
    width: usize,
    height: usize,
    seed: u64,
    progress: &dyn Progress,
) -> HeightMap {
    let (ps, o) = (p.patch_size, p.overlap);
    let step = ps - o;
    let count = |n: usize| if n <= ps { 1 } else { (n - o).div_ceil(step) };
    let (nx, ny) = (count(width), count(height));
    let per_axis = kernel.size / ps;
    let per_pair = 2 * per_axis * per_axis;
    let mut map = HeightMap::new(width, height, 1.0);
    progress.start("sandblast patch rows", ny as u64);
    for j in 0..ny {
        let pairs = nx.div_ceil(per_pair);
        let patches: Vec<Vec<f32>> = (0..pairs)
            .into_par_iter()
            .flat_map_iter(|r| {
                let mut rng = stream(seed, 2 + j as u64, r as u64);
                let (a, b) = kernel.realize_pair(&mut rng);
                let mut crops = Vec::with_capacity(per_pair);
                for field in [&a, &b] {
                    for cy in 0..per_axis {
                        for cx in 0..per_axis {
                            let mut c = Vec::with_capacity(ps * ps);
                            for y in 0..ps {
                                let off = (cy * ps + y) * kernel.size + cx * ps;
                                c.extend_from_slice(&field[off..off + ps]);
                            }
                            crops.push(c);
                        }
                    }
                }
                crops
            })
            .collect();
        let y0 = j * step;
        for (i, patch) in patches.iter().take(nx).enumerate() {
            quilting::place_patch(
                &mut map.data,
                width,
                0,
                patch,
                ps,
                i * step,
                y0,
                o,
                i > 0,
                j > 0,
            );
        }
        progress.advance(1);
    }
    map
}
