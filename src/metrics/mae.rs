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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_of_selected_and_all_pixels() {
        let a = GrayImage::new(3, 3, (0..9).map(|v| v as f32).collect()).unwrap();
        let b = GrayImage::new(3, 3, vec![4.0; 9]).unwrap();
        // |0-4| .. |8-4| = 4 3 2 1 0 1 2 3 4: sum 20.
        assert_eq!(mae(&a, &b, None), 20.0 / 9.0);
        assert_eq!(
            mae(&a, &b, Some(&[0, 4, 8, 2, 7])),
            (4.0 + 0.0 + 4.0 + 2.0 + 3.0) / 5.0
        );
        assert!(mae(&a, &b, Some(&[])).is_nan());
    }

    #[test]
    fn small_terms_after_a_large_one_count() {
        // One large difference then many small ones: an f32 accumulator would lose them;
        // the f64 sum keeps every one.
        let n = 1 << 20;
        let mut av = vec![0.0f32; n];
        av[0] = 1.0e7;
        let a = GrayImage::new(n, 1, av).unwrap();
        let mut bv = vec![0.25f32; n];
        bv[0] = 0.0;
        let b = GrayImage::new(n, 1, bv).unwrap();
        let want = (1.0e7 + 0.25 * (n - 1) as f64) / n as f64;
        assert_eq!(mae(&a, &b, None), want);
    }
}
