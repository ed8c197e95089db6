//! Height and slope maps: the data the renderer uploads.
//!
//! Axis convention (all maps): row-major, row 0 at the top of the image, `x` grows to the
//! right (column index), `y` grows downwards (row index). Pixel `(i, j)` samples the point
//! `((i + 0.5) * spacing, (j + 0.5) * spacing)`. Heights are in micrometres, spacing in
//! micrometres, so slopes `dh/dx`, `dh/dy` are unitless. A renderer whose face frame has
//! `+v` pointing up in the image must negate `dh/dy`.

use rayon::prelude::*;

/// Height field in micrometres.
#[derive(Clone, Debug, PartialEq)]
pub struct HeightMap {
    pub width: usize,
    pub height: usize,
    pub spacing_um: f64,
    /// Row-major, `data[y * width + x]`, micrometres.
    pub data: Vec<f32>,
}

/// Per-pixel slopes `[dh/dx, dh/dy]` (unitless, image axes: x right, y down).
#[derive(Clone, Debug, PartialEq)]
pub struct SlopeMap {
    pub width: usize,
    pub height: usize,
    pub spacing_um: f64,
    pub data: Vec<[f32; 2]>,
}

/// First two moments of a height distribution (micrometres).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Moments {
    pub mean_um: f64,
    /// Standard deviation = Sq (root mean square roughness about the mean).
    pub sq_um: f64,
}

impl HeightMap {
    pub fn new(width: usize, height: usize, spacing_um: f64) -> Self {
        Self {
            width,
            height,
            spacing_um,
            data: vec![0.0; width * height],
        }
    }

    #[inline]
    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Mean and standard deviation, accumulated in f64 per row (stable for 13107^2).
    pub fn moments(&self) -> Moments {
        moments_of(&self.data, self.width.max(1))
    }

    /// Moment matching: `T = (sigma_M / sigma_pre) (T_pre - mu_pre) + mu_M`.
    /// A constant map cannot be scaled; it is shifted to the target mean only.
    pub fn match_moments(&mut self, target: Moments) {
        let m = self.moments();
        let scale = if m.sq_um > 0.0 {
            target.sq_um / m.sq_um
        } else {
            0.0
        };
        let (mu, tmu) = (m.mean_um, target.mean_um);
        self.data.par_chunks_mut(self.width.max(1)).for_each(|row| {
            for v in row {
                *v = (scale * (*v as f64 - mu) + tmu) as f32;
            }
        });
    }

    /// Slopes by central differences at the spacing (one-sided at the borders).
    pub fn slopes(&self) -> SlopeMap {
        let (w, h) = (self.width, self.height);
        let mut data = vec![[0.0f32; 2]; w * h];
        data.par_chunks_mut(w.max(1))
            .enumerate()
            .for_each(|(y, row)| self.slope_row(y, |x, s| row[x] = s));
        SlopeMap {
            width: w,
            height: h,
            spacing_um: self.spacing_um,
            data,
        }
    }

    /// Slopes of one row, handed to `put(x, [dh/dx, dh/dy])`; lets writers stream
    /// normals without holding a full slope map.
    pub fn slope_row(&self, y: usize, mut put: impl FnMut(usize, [f32; 2])) {
        let (w, h) = (self.width, self.height);
        let s = self.spacing_um as f32;
        let (ya, yb) = (y.saturating_sub(1), (y + 1).min(h - 1));
        let dy = (yb - ya).max(1) as f32 * s;
        for x in 0..w {
            let (xa, xb) = (x.saturating_sub(1), (x + 1).min(w - 1));
            let dx = (xb - xa).max(1) as f32 * s;
            let hx = if xb > xa {
                (self.get(xb, y) - self.get(xa, y)) / dx
            } else {
                0.0
            };
            let hy = if yb > ya {
                (self.get(x, yb) - self.get(x, ya)) / dy
            } else {
                0.0
            };
            put(x, [hx, hy]);
        }
    }
}

/// Unit normal `normalize(-dh/dx, -dh/dy, 1)` in image axes (x right, y down, z out).
#[inline]
pub fn normal_from_slope(s: [f32; 2]) -> [f32; 3] {
    let inv = 1.0 / (s[0] * s[0] + s[1] * s[1] + 1.0).sqrt();
    [-s[0] * inv, -s[1] * inv, inv]
}

impl SlopeMap {
    pub fn normal(&self, x: usize, y: usize) -> [f32; 3] {
        normal_from_slope(self.data[y * self.width + x])
    }
}

pub(crate) fn moments_of(data: &[f32], chunk: usize) -> Moments {
    let n = data.len().max(1) as f64;
    let (s, _) = data
        .par_chunks(chunk)
        .map(|c| (c.iter().map(|&v| v as f64).sum::<f64>(), 0))
        .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, 0));
    let mean = s / n;
    let ss: f64 = data
        .par_chunks(chunk)
        .map(|c| {
            c.iter()
                .map(|&v| {
                    let d = v as f64 - mean;
                    d * d
                })
                .sum::<f64>()
        })
        .sum();
    Moments {
        mean_um: mean,
        sq_um: (ss / n).sqrt(),
    }
}

impl SlopeMap {
    /// All slopes zero: renders exactly as no map (tested).
    pub fn flat(width: usize, height: usize, spacing_um: f64) -> SlopeMap {
        SlopeMap {
            width,
            height,
            spacing_um,
            data: vec![[0.0; 2]; width * height],
        }
    }

    /// Parallel sinusoidal grooves running along the map's y axis:
    /// h(x) = A sin(2 pi x / period), with A chosen so the steepest slope is
    /// `max_slope_deg` and x measured from the **map centre** (so the pattern at the
    /// centre does not depend on the map's size, and a map moved by an offset moves its
    /// grooves by exactly that offset). Covers `extent_mm` x `extent_mm`. A test pattern,
    /// not a finish.
    pub fn test_grooves(
        extent_mm: f32,
        spacing_um: f64,
        period_mm: f32,
        max_slope_deg: f32,
    ) -> SlopeMap {
        // An even texel count puts texel corners on the map centre for every extent, so a
        // bigger map (a farther offset elsewhere) samples the grooves at the same points.
        let n = ((extent_mm as f64 * 1000.0 / spacing_um / 2.0).ceil() as usize).max(1) * 2;
        let smax = max_slope_deg.to_radians().tan();
        let k = std::f64::consts::TAU / (period_mm as f64 * 1000.0);
        let mut data = vec![[0.0f32; 2]; n * n];
        for y in 0..n {
            for x in 0..n {
                let xu = (x as f64 + 0.5 - 0.5 * n as f64) * spacing_um;
                // dh/dx = A k cos(k x) with A k = tan(max slope).
                data[y * n + x] = [(smax as f64 * (k * xu).cos()) as f32, 0.0];
            }
        }
        SlopeMap {
            width: n,
            height: n,
            spacing_um,
            data,
        }
    }
}
