//! Mean absolute error between two images, optionally restricted to pixel indices.

use super::gray::GrayImage;

/// Mean |a - b| over `indices` (all pixels if `None`); `NaN` when nothing is selected.
/// Sizes must already match.
pub fn mae(a: &GrayImage, b: &GrayImage, indices: Option<&[u32]>) -> f64 {
    let (sum, n) = match indices {
        Some(ix) => (
            ix.iter()
                .map(|&i| f64::from((a.data[i as usize] - b.data[i as usize]).abs()))
                .sum::<f64>(),
            ix.len(),
        ),
        None => (
            a.data
                .iter()
                .zip(&b.data)
                .map(|(x, y)| f64::from((x - y).abs()))
                .sum::<f64>(),
            a.data.len(),
        ),
    };
    if n == 0 { f64::NAN } else { sum / n as f64 }
}
