//! Grayscale images as f32 in 8-bit units, so 8- and 16-bit inputs are comparable.

use std::path::Path;

use image::DynamicImage;

use super::MetricsError;

/// Full-scale value of every image after loading: intensities live in 8-bit units
/// (0..=255) whatever the file's bit depth, 16-bit codes being divided by 257
/// (65535 / 257 = 255 exactly).
pub const DATA_RANGE: f64 = 255.0;

/// A grayscale image, row-major, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct GrayImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl GrayImage {
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Result<Self, MetricsError> {
        if data.len() != width * height {
            return Err(MetricsError::param(
                "data",
                format!(
                    "{} values for a {width} x {height} image (expected {})",
                    data.len(),
                    width * height
                ),
            ));
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Decodes an 8- or 16-bit grayscale PNG (an alpha channel is ignored).
    pub fn load(path: &Path) -> Result<Self, MetricsError> {
        Self::load_codes(path, None)
    }

    /// As [`Self::load`], but the codes of a 16-bit PNG have `bit_depth` bits (10, 12: a
    /// deep sensor's codes written unscaled) and are scaled by 255 / (2^bit_depth - 1), so
    /// the top code is 255. `None` or 16: 1 / 257. 8-bit PNGs are read as they are.
    pub fn load_codes(path: &Path, bit_depth: Option<u32>) -> Result<Self, MetricsError> {
        let img = open(path)?;
        let (width, height) = (img.width() as usize, img.height() as usize);
        let top = match bit_depth {
            Some(b @ 1..=15) => Some(((1u32 << b) - 1) as f64),
            _ => None,
        };
        let from16 = |v: u16| match top {
            Some(t) => (f64::from(v) * 255.0 / t) as f32,
            None => from16(v),
        };
        let data = match img {
            DynamicImage::ImageLuma8(b) => b.into_raw().into_iter().map(f32::from).collect(),
            DynamicImage::ImageLumaA8(b) => b.pixels().map(|p| f32::from(p.0[0])).collect(),
            DynamicImage::ImageLuma16(b) => b.into_raw().into_iter().map(from16).collect(),
            DynamicImage::ImageLumaA16(b) => b.pixels().map(|p| from16(p.0[0])).collect(),
            other => {
                return Err(MetricsError::NotGrayscale {
                    path: path.to_path_buf(),
                    color: format!("{:?}", other.color()),
                });
            }
        };
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Applies `factor * v + bias`, clamped to the 8-bit range as a saved image would be.
    pub fn aligned(&self, align: super::Alignment) -> Self {
        Self {
            width: self.width,
            height: self.height,
            data: self.data.iter().map(|&v| align.apply(v)).collect(),
        }
    }
}

fn from16(v: u16) -> f32 {
    (f64::from(v) / 257.0) as f32
}

pub(crate) fn open(path: &Path) -> Result<DynamicImage, MetricsError> {
    // image::open reports a missing file as an ImageError too; keep the io kind visible.
    if let Err(source) = std::fs::metadata(path) {
        return Err(MetricsError::Io {
            path: path.to_path_buf(),
            source,
        });
    }
    let decode = |source| MetricsError::Decode {
        path: path.to_path_buf(),
        source,
    };
    let (w, h) = crate::limits::image_dimensions(path).map_err(decode)?;
    let px = w as u64 * h as u64;
    if px > crate::limits::MAX_METRICS_PIXELS {
        return Err(MetricsError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!(
                    "{w} x {h} pixels: over the limit for metrics ({} Mpixel, e.g. 8192 x 8192); crop or scale the image first",
                    crate::limits::MAX_METRICS_PIXELS >> 20
                ),
            ),
        });
    }
    crate::limits::open_image(path).map_err(|source| MetricsError::Decode {
        path: path.to_path_buf(),
        source,
    })
}

pub(crate) fn check_same_size(
    a: &GrayImage,
    a_name: &str,
    b: &GrayImage,
    b_name: &str,
) -> Result<(), MetricsError> {
    if a.size() != b.size() {
        return Err(MetricsError::SizeMismatch {
            a: a_name.to_string(),
            a_size: a.size(),
            b: b_name.to_string(),
            b_size: b.size(),
        });
    }
    Ok(())
}
