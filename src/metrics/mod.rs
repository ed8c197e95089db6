//! Domain-similarity metrics between grayscale images (paper, "Pipeline Evaluation"):
//! Wasserstein distance between intensity histograms, mean absolute error and SSIM,
//! each also as a similarity in [0, 1], plus the dataset comparison (`compare`).
//! Pure CPU; see `docs/metrics.md` for the conventions.
//!
//! Intensities are in 8-bit units (0..=255) for 8- and 16-bit inputs alike.

mod align;
pub mod compare;
pub mod dataset;
mod error;
mod gray;
mod histogram;
pub mod labelme;
mod lpips;
mod mae;
mod masks;
mod ssim;

pub use align::{Alignment, Moments, paper_defaults};
pub use error::MetricsError;
pub use gray::{DATA_RANGE, GREY_CHANNEL_TOLERANCE, GrayImage};
pub use histogram::Histogram;
pub use lpips::{Lpips, LpipsFeatures, default_weights_path};
pub use mae::mae;
pub use masks::{Mask, Rect, face_mask};
pub use ssim::{Ssim, SsimParams, SsimPrep};

use serde::Serialize;

/// The distances for one pair, and their similarities (LPIPS only when asked for:
/// it needs the learned weights and a network's run per image).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PairMetrics {
    /// W1 between the masked intensity distributions, 8-bit units.
    pub hist_wd: f64,
    /// Mean absolute difference inside the mask, 8-bit units.
    pub mae: f64,
    /// Mean SSIM (inside the mask, or skimage's border-cropped mean without one).
    pub ssim: f64,
    pub hist_wd_similarity: f64,
    pub mae_similarity: f64,
    pub ssim_similarity: f64,
    /// Pixels the histogram and MAE were taken over.
    pub pixels: usize,
    /// LPIPS (AlexNet, v0.1) over the mask's positions (`lpips` module).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lpips: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lpips_similarity: Option<f64>,
}

impl PairMetrics {
    pub fn new(hist_wd: f64, mae: f64, ssim: f64, pixels: usize) -> Self {
        Self {
            hist_wd,
            mae,
            ssim,
            hist_wd_similarity: distance_similarity(hist_wd),
            mae_similarity: distance_similarity(mae),
            ssim_similarity: ssim_similarity(ssim),
            pixels,
            lpips: None,
            lpips_similarity: None,
        }
    }

    /// With the pair's LPIPS distance added.
    pub fn with_lpips(self, d: f64) -> Self {
        Self {
            lpips: Some(d),
            lpips_similarity: Some(lpips_similarity(d)),
            ..self
        }
    }
}

/// `1 - d / 255`, clamped: the paper's "1-HistWD" and "1-MAE" rows. Both distances are
/// at most the data range for values in 0..=255, so the clamp only guards rounding.
pub fn distance_similarity(d: f64) -> f64 {
    (1.0 - d / DATA_RANGE).clamp(0.0, 1.0)
}

/// SSIM lies in [-1, 1]; the paper reports it "bounded to [0, 1]", i.e. negative
/// (anti-correlated) structure counts as no similarity.
pub fn ssim_similarity(s: f64) -> f64 {
    s.clamp(0.0, 1.0)
}

/// `1 - LPIPS`, clamped: the paper's "1-LPIPS" row. AlexNet's LPIPS is 0 for equal
/// images and can exceed 1 for unlike textures (1.075 between a sandblasted and a
/// parallel-milled paper image of one view, docs/benchmarks/metrics.md): no similarity.
pub fn lpips_similarity(d: f64) -> f64 {
    (1.0 - d).clamp(0.0, 1.0)
}

/// All three metrics for one pair, over the mask if given. Without a mask, WD and MAE
/// use every pixel and SSIM is scikit-image's border-cropped mean.
pub fn pair_metrics(
    a: &GrayImage,
    b: &GrayImage,
    mask: Option<&Mask>,
) -> Result<PairMetrics, MetricsError> {
    gray::check_same_size(a, "first image", b, "second image")?;
    let ssim = Ssim::default();
    match mask {
        None => {
            let s = ssim.mean(a, b)?;
            let wd = Histogram::of(a, None).wasserstein(&Histogram::of(b, None));
            Ok(PairMetrics::new(wd, mae(a, b, None), s, a.data.len()))
        }
        Some(m) => {
            gray::check_mask_size(m, a.size())?;
            let ix = m.indices();
            if ix.is_empty() {
                return Err(MetricsError::EmptyMask {
                    what: "the pair mask".into(),
                });
            }
            let s = ssim.mean_masked(a, b, m)?;
            let wd = Histogram::of(a, Some(&ix)).wasserstein(&Histogram::of(b, Some(&ix)));
            Ok(PairMetrics::new(wd, mae(a, b, Some(&ix)), s, ix.len()))
        }
    }
}
