//! Wasserstein-1 distance between intensity histograms. A histogram keeps one bin per
//! distinct value, so the distance equals scipy's `wasserstein_distance` on the raw
//! masked pixel values, while for 8-bit data it costs O(256) per pair instead of O(n).

use super::Alignment;
use super::gray::GrayImage;
use super::masks::Mask;

/// Distinct values, ascending, with their pixel counts.
#[derive(Clone, Debug, PartialEq)]
pub struct Histogram {
    bins: Vec<(f32, u32)>,
    total: u64,
}

impl Histogram {
    /// Histogram of the pixels selected by `indices` (all pixels if `None`).
    pub fn of(img: &GrayImage, indices: Option<&[u32]>) -> Self {
        let mut values: Vec<f32> = match indices {
            Some(ix) => ix.iter().map(|&i| img.data[i as usize]).collect(),
            None => img.data.clone(),
        };
        // Loaded images sit on the 16-bit code grid (8-bit v = 257 v / 257 too), so a
        // counting pass replaces the sort; anything off the grid falls back to sorting.
        let mut counts = vec![0u32; 65536];
        let on_grid = values.iter().all(|&v| {
            let c = f64::from(v) * 257.0;
            let r = c.round();
            if (c - r).abs() < 1e-2 && (0.0..=65535.0).contains(&r) {
                counts[r as usize] += 1;
                true
            } else {
                false
            }
        });
        let total = values.len() as u64;
        let mut bins = Vec::new();
        if on_grid {
            for (code, &n) in counts.iter().enumerate() {
                if n > 0 {
                    bins.push(((code as f64 / 257.0) as f32, n));
                }
            }
        } else {
            values.sort_by(f32::total_cmp);
            for v in values {
                match bins.last_mut() {
                    Some((last, n)) if *last == v => *n += 1,
                    _ => bins.push((v, 1)),
                }
            }
        }
        Self { bins, total }
    }

    pub fn of_mask(img: &GrayImage, mask: &Mask) -> Self {
        Self::of(img, Some(&mask.indices()))
    }

    pub fn total(&self) -> u64 {
        self.total
    }

    pub fn bins(&self) -> &[(f32, u32)] {
        &self.bins
    }

    /// The histogram of the aligned image; the same f32 arithmetic as
    /// [`GrayImage::aligned`], so both give identical values.
    pub fn aligned(&self, align: Alignment) -> Self {
        let mut bins: Vec<(f32, u32)> = self
            .bins
            .iter()
            .map(|&(v, n)| (align.apply(v), n))
            .collect();
        // A negative factor reverses the order; clamping merges equal values.
        bins.sort_by(|a, b| a.0.total_cmp(&b.0));
        bins.dedup_by(|next, kept| {
            if next.0 == kept.0 {
                kept.1 += next.1;
                true
            } else {
                false
            }
        });
        Self {
            bins,
            total: self.total,
        }
    }

    /// W1 = integral of |F_u - F_v| over the merged support. `NaN` if either is empty.
    pub fn wasserstein(&self, other: &Histogram) -> f64 {
        if self.total == 0 || other.total == 0 {
            return f64::NAN;
        }
        let (nu, nv) = (self.total as f64, other.total as f64);
        let (u, v) = (&self.bins, &other.bins);
        let (mut i, mut j) = (0, 0);
        let (mut cu, mut cv) = (0u64, 0u64);
        let mut prev = f64::from(u[0].0.min(v[0].0));
        let mut area = 0.0;
        while i < u.len() || j < v.len() {
            let x = match (u.get(i), v.get(j)) {
                (Some(a), Some(b)) => a.0.min(b.0),
                (Some(a), None) => a.0,
                (None, Some(b)) => b.0,
                (None, None) => unreachable!(),
            };
            let x64 = f64::from(x);
            area += (cu as f64 / nu - cv as f64 / nv).abs() * (x64 - prev);
            prev = x64;
            if i < u.len() && u[i].0 == x {
                cu += u64::from(u[i].1);
                i += 1;
            }
            if j < v.len() && v[j].0 == x {
                cv += u64::from(v[j].1);
                j += 1;
            }
        }
        area
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hist(v: &[f32]) -> Histogram {
        Histogram::of(&GrayImage::new(v.len(), 1, v.to_vec()).unwrap(), None)
    }

    #[test]
    fn unequal_sizes_match_the_cdf_integral() {
        // scipy.stats.wasserstein_distance([0, 1], [0, 0, 3]) = 1/6 + 2 * 1/3 = 5/6
        let d = hist(&[0.0, 1.0]).wasserstein(&hist(&[0.0, 0.0, 3.0]));
        assert!((d - 5.0 / 6.0).abs() < 1e-12, "{d}");
        // Off the 16-bit grid (sort path) gives the same as on it.
        let d = hist(&[0.25, 1.25]).wasserstein(&hist(&[0.25, 0.25, 3.25]));
        assert!((d - 5.0 / 6.0).abs() < 1e-12, "{d}");
    }

    #[test]
    fn aligned_histogram_merges_clamped_bins() {
        let h = hist(&[10.0, 100.0, 200.0, 200.0]).aligned(Alignment {
            factor: 2.0,
            bias: 0.0,
        });
        assert_eq!(h.bins(), &[(20.0, 1), (200.0, 1), (255.0, 2)]);
        assert_eq!(h.total(), 4);
    }
}
