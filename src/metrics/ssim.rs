//! SSIM (Wang et al. 2004) with a Gaussian window, matching scikit-image's
//! `structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)`:
//! scipy's `gaussian_filter` (truncate 3.5, so 11 taps; mode "reflect") on the images,
//! their squares and their product, then the SSIM map.
//!
//! Everything is f32 for speed. Second moments are taken of the image minus a constant
//! offset: variance and covariance do not change, but E[x^2] - E[x]^2 stops cancelling
//! catastrophically (f32 has 24 bits; 255^2 already uses 16 of them).

use rayon::prelude::*;

use super::MetricsError;
use super::gray::{DATA_RANGE, GrayImage, check_same_size};
use super::masks::{Mask, Rect};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SsimParams {
    pub sigma: f64,
    pub k1: f64,
    pub k2: f64,
    pub data_range: f64,
}

impl Default for SsimParams {
    fn default() -> Self {
        Self {
            sigma: 1.5,
            k1: 0.01,
            k2: 0.03,
            data_range: DATA_RANGE,
        }
    }
}

/// Per-image data reused across many pairs: the local mean and variance on `rect`.
#[derive(Clone, Debug)]
pub struct SsimPrep {
    pub rect: Rect,
    offset: f32,
    /// Gaussian mean of (x - offset) on `rect`.
    mean_c: Vec<f32>,
    /// Gaussian variance on `rect`.
    var: Vec<f32>,
}

#[derive(Clone, Debug)]
pub struct Ssim {
    radius: usize,
    kernel: Vec<f32>,
    c1: f32,
    c2: f32,
}

impl Default for Ssim {
    fn default() -> Self {
        Self::new(SsimParams::default()).expect("default SSIM parameters are valid")
    }
}

impl Ssim {
    pub fn new(p: SsimParams) -> Result<Self, MetricsError> {
        if !(p.sigma > 0.0 && p.sigma < 100.0) {
            return Err(MetricsError::param(
                "sigma",
                format!("{} not in (0, 100)", p.sigma),
            ));
        }
        if !(p.data_range > 0.0 && p.data_range.is_finite()) {
            return Err(MetricsError::param(
                "data_range",
                format!("{} must be positive", p.data_range),
            ));
        }
        // Radius exactly as scipy.ndimage derives it from truncate = 3.5.
        let radius = (3.5 * p.sigma + 0.5) as usize;
        let w: Vec<f64> = (0..=2 * radius)
            .map(|i| {
                let x = i as f64 - radius as f64;
                (-0.5 * x * x / (p.sigma * p.sigma)).exp()
            })
            .collect();
        let sum: f64 = w.iter().sum();
        Ok(Self {
            radius,
            kernel: w.iter().map(|v| (v / sum) as f32).collect(),
            c1: ((p.k1 * p.data_range).powi(2)) as f32,
            c2: ((p.k2 * p.data_range).powi(2)) as f32,
        })
    }

    /// Window side length (11 for sigma 1.5).
    pub fn win_size(&self) -> usize {
        2 * self.radius + 1
    }

    /// Mean SSIM over the image minus a border of (win - 1) / 2, exactly as scikit-image.
    pub fn mean(&self, a: &GrayImage, b: &GrayImage) -> Result<f64, MetricsError> {
        check_same_size(a, "first image", b, "second image")?;
        let r = self.radius;
        if a.width < self.win_size() || a.height < self.win_size() {
            return Err(MetricsError::TooSmall {
                what: "image pair".into(),
                size: a.size(),
                min: self.win_size(),
            });
        }
        let rect = Rect {
            x0: r,
            y0: r,
            x1: a.width - r,
            y1: a.height - r,
        };
        let (pa, pb) = rayon::join(|| self.prepare(a, rect), || self.prepare(b, rect));
        Ok(self.mean_prepared(a, &pa, b, &pb, None))
    }

    /// Mean of the SSIM map, computed over the whole image (neighbours outside the mask
    /// take part in each window), averaged over the mask pixels. With a mask that is all
    /// set except a (win - 1) / 2 border this equals [`Ssim::mean`].
    pub fn mean_masked(
        &self,
        a: &GrayImage,
        b: &GrayImage,
        mask: &Mask,
    ) -> Result<f64, MetricsError> {
        check_same_size(a, "first image", b, "second image")?;
        if mask.size() != a.size() {
            return Err(MetricsError::SizeMismatch {
                a: "image".into(),
                a_size: a.size(),
                b: "mask".into(),
                b_size: mask.size(),
            });
        }
        let rect = mask.bbox().ok_or_else(|| MetricsError::EmptyMask {
            what: "SSIM mask".into(),
        })?;
        let (pa, pb) = rayon::join(|| self.prepare(a, rect), || self.prepare(b, rect));
        Ok(self.mean_prepared(a, &pa, b, &pb, Some(mask)))
    }

    /// The full SSIM map (same size as the images), as scikit-image's `full=True`.
    pub fn map(&self, a: &GrayImage, b: &GrayImage) -> Result<Vec<f32>, MetricsError> {
        check_same_size(a, "first image", b, "second image")?;
        let rect = Rect::full(a.width, a.height);
        let (pa, pb) = rayon::join(|| self.prepare(a, rect), || self.prepare(b, rect));
        let cov = self.covariance(a, &pa, b, &pb);
        let mut out = vec![0.0; rect.width() * rect.height()];
        out.par_chunks_mut(rect.width())
            .enumerate()
            .for_each(|(y, row)| {
                for (x, o) in row.iter_mut().enumerate() {
                    *o = self.pixel(&pa, &pb, &cov, y * rect.width() + x) as f32;
                }
            });
        Ok(out)
    }

    /// Local mean and variance of `img` on `rect` (the rest of the image still feeds the
    /// windows). Compute once per image, then pair it with many others.
    pub fn prepare(&self, img: &GrayImage, rect: Rect) -> SsimPrep {
        let offset = offset_of(img, rect);
        let mean_c = self.blur(img.width, img.height, rect, |i| img.data[i] - offset);
        let mut var = self.blur(img.width, img.height, rect, |i| {
            let v = img.data[i] - offset;
            v * v
        });
        for (v, m) in var.iter_mut().zip(&mean_c) {
            *v -= m * m;
        }
        SsimPrep {
            rect,
            offset,
            mean_c,
            var,
        }
    }

    /// Mean SSIM on `pa.rect` (all of it, or the mask pixels in it). Both preps must
    /// share the rect and come from `a` and `b`.
    pub fn mean_prepared(
        &self,
        a: &GrayImage,
        pa: &SsimPrep,
        b: &GrayImage,
        pb: &SsimPrep,
        mask: Option<&Mask>,
    ) -> f64 {
        assert_eq!(pa.rect, pb.rect, "SSIM preps must share their rect");
        let cov = self.covariance(a, pa, b, pb);
        let rect = pa.rect;
        let (sum, n) = (0..rect.height())
            .into_par_iter()
            .map(|ry| {
                let mut s = 0.0f64;
                let mut n = 0usize;
                for rx in 0..rect.width() {
                    if let Some(m) = mask
                        && !m.data[(rect.y0 + ry) * m.width + rect.x0 + rx]
                    {
                        continue;
                    }
                    s += self.pixel(pa, pb, &cov, ry * rect.width() + rx);
                    n += 1;
                }
                (s, n)
            })
            .reduce(|| (0.0, 0), |x, y| (x.0 + y.0, x.1 + y.1));
        if n == 0 { f64::NAN } else { sum / n as f64 }
    }

    fn covariance(&self, a: &GrayImage, pa: &SsimPrep, b: &GrayImage, pb: &SsimPrep) -> Vec<f32> {
        let (oa, ob) = (pa.offset, pb.offset);
        let mut cov = self.blur(a.width, a.height, pa.rect, |i| {
            (a.data[i] - oa) * (b.data[i] - ob)
        });
        for ((c, ma), mb) in cov.iter_mut().zip(&pa.mean_c).zip(&pb.mean_c) {
            *c -= ma * mb;
        }
        cov
    }

    /// f32 is enough here: the terms are sums of positives or already-centred moments,
    /// and per-pixel rounding averages out in the mean (tests: within 1e-7 of skimage).
    #[inline]
    fn pixel(&self, pa: &SsimPrep, pb: &SsimPrep, cov: &[f32], i: usize) -> f64 {
        let mx = pa.mean_c[i] + pa.offset;
        let my = pb.mean_c[i] + pb.offset;
        let a1 = 2.0 * mx * my + self.c1;
        let a2 = 2.0 * cov[i] + self.c2;
        let b1 = mx * mx + my * my + self.c1;
        let b2 = pa.var[i] + pb.var[i] + self.c2;
        f64::from((a1 * a2) / (b1 * b2))
    }

    /// Separable Gaussian filter of `value(linear index)` evaluated on `rect` only, with
    /// scipy's "reflect" boundary (d c b a | a b c d | d c b a) at the image edges.
    fn blur(
        &self,
        width: usize,
        height: usize,
        rect: Rect,
        value: impl Fn(usize) -> f32 + Sync,
    ) -> Vec<f32> {
        let r = self.radius;
        let k = &self.kernel;
        let rw = rect.width();
        // Rows of the horizontal pass that the vertical pass will read.
        let mut row_lo = usize::MAX;
        let mut row_hi = 0;
        for y in rect.y0..rect.y1 {
            for t in 0..=2 * r {
                let yy = reflect(y as isize + t as isize - r as isize, height);
                row_lo = row_lo.min(yy);
                row_hi = row_hi.max(yy + 1);
            }
        }
        let mut horiz = vec![0.0f32; (row_hi - row_lo) * rw];
        horiz
            .par_chunks_mut(rw)
            .enumerate()
            .for_each_init(Vec::new, |pad, (j, out)| {
                let base = (row_lo + j) * width;
                pad.clear();
                // Reflection (an integer division) only where the window leaves the image.
                let first = rect.x0 as isize - r as isize;
                pad.extend((0..rw + 2 * r).map(|c| {
                    let x = first + c as isize;
                    let x = if x >= 0 && (x as usize) < width {
                        x as usize
                    } else {
                        reflect(x, width)
                    };
                    value(base + x)
                }));
                for (t, &w) in k.iter().enumerate() {
                    for (o, &p) in out.iter_mut().zip(&pad[t..t + rw]) {
                        *o += w * p;
                    }
                }
            });
        let mut out = vec![0.0f32; rect.height() * rw];
        out.par_chunks_mut(rw).enumerate().for_each(|(j, o)| {
            let y = rect.y0 + j;
            for (t, &w) in k.iter().enumerate() {
                let yy = reflect(y as isize + t as isize - r as isize, height) - row_lo;
                for (o, &h) in o.iter_mut().zip(&horiz[yy * rw..(yy + 1) * rw]) {
                    *o += w * h;
                }
            }
        });
        out
    }
}

fn offset_of(img: &GrayImage, rect: Rect) -> f32 {
    let mut s = 0.0f64;
    for y in rect.y0..rect.y1 {
        s += img.data[y * img.width + rect.x0..y * img.width + rect.x1]
            .iter()
            .map(|&v| f64::from(v))
            .sum::<f64>();
    }
    (s / (rect.width() * rect.height()).max(1) as f64) as f32
}

/// scipy.ndimage "reflect" index, valid for any offset (repeats with period 2n).
fn reflect(i: isize, n: usize) -> usize {
    let n = n as isize;
    let m = i.rem_euclid(2 * n);
    (if m >= n { 2 * n - 1 - m } else { m }) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reflect_matches_scipy() {
        let got: Vec<usize> = (-4..8).map(|i| reflect(i, 4)).collect();
        assert_eq!(got, vec![3, 2, 1, 0, 0, 1, 2, 3, 3, 2, 1, 0]);
        assert_eq!(reflect(-3, 2), 1);
    }

    #[test]
    fn kernel_has_eleven_taps_summing_to_one() {
        let s = Ssim::default();
        assert_eq!(s.win_size(), 11);
        let sum: f32 = s.kernel.iter().sum();
        assert!((sum - 1.0).abs() < 1e-6);
        assert!(s.kernel[5] > s.kernel[4] && (s.kernel[0] - s.kernel[10]).abs() < 1e-9);
    }
}
