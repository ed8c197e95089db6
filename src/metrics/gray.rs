//! Grayscale images as f32 in 8-bit units, so 8- and 16-bit inputs are comparable.

use std::path::Path;

use image::DynamicImage;

use super::MetricsError;
use super::masks::Mask;

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

    /// Decodes an 8- or 16-bit grayscale image (PNG, TIFF, BMP or JPEG; an alpha channel
    /// is ignored); a colour one is read only where it holds a grey image (its channels
    /// within [`GREY_CHANNEL_TOLERANCE`]).
    pub fn load(path: &Path) -> Result<Self, MetricsError> {
        Self::load_codes(path, None)
    }

    /// As [`Self::load`], but the codes of a 16-bit image have `bit_depth` bits (10, 12: a
    /// deep sensor's codes written unscaled) and are scaled by 255 / (2^bit_depth - 1), so
    /// the top code is 255. `None` or 16: 1 / 257. 8-bit images are read as they are. A
    /// code over 2^bit_depth - 1 is an error naming its pixel.
    pub fn load_codes(path: &Path, bit_depth: Option<u32>) -> Result<Self, MetricsError> {
        let img = open(path)?;
        let (width, height) = (img.width() as usize, img.height() as usize);
        let top = match bit_depth {
            Some(b @ 1..=15) => Some(((1u32 << b) - 1) as f64),
            _ => None,
        };
        if let Some(b) = bit_depth {
            check_codes(path, &img, b)?;
        }
        let from16 = |v: u16| match top {
            Some(t) => (f64::from(v) * 255.0 / t) as f32,
            None => from16(v),
        };
        let data = match img {
            DynamicImage::ImageLuma8(b) => b.into_raw().into_iter().map(f32::from).collect(),
            DynamicImage::ImageLumaA8(b) => b.pixels().map(|p| f32::from(p.0[0])).collect(),
            DynamicImage::ImageLuma16(b) => b.into_raw().into_iter().map(from16).collect(),
            DynamicImage::ImageLumaA16(b) => b.pixels().map(|p| from16(p.0[0])).collect(),
            // A grey image stored as colour (a mono camera's frames saved as RGB, or
            // JPEG's rounding of one): its channels' mean, where they agree.
            DynamicImage::ImageRgb8(b) => {
                grey_of_colour(path, "Rgb8", width, b.pixels().map(|p| p.0.map(f32::from)))?
            }
            DynamicImage::ImageRgba8(b) => grey_of_colour(
                path,
                "Rgba8",
                width,
                b.pixels().map(|p| [p.0[0], p.0[1], p.0[2]].map(f32::from)),
            )?,
            DynamicImage::ImageRgb16(b) => {
                grey_of_colour(path, "Rgb16", width, b.pixels().map(|p| p.0.map(from16)))?
            }
            DynamicImage::ImageRgba16(b) => grey_of_colour(
                path,
                "Rgba16",
                width,
                b.pixels().map(|p| [p.0[0], p.0[1], p.0[2]].map(from16)),
            )?,
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

/// With a stated bit depth b, a 16-bit image's codes must be at most 2^b - 1: a higher
/// one means the depth is wrong (a full-range 16-bit image read as 12-bit codes would
/// reach 16 times the data range). The error names the pixel. An 8-bit image cannot hold
/// codes of more than 8 bits.
fn check_codes(path: &Path, img: &DynamicImage, bits: u32) -> Result<(), MetricsError> {
    let codes: &[u16] = match img {
        DynamicImage::ImageLuma16(b) => b.as_raw(),
        DynamicImage::ImageLumaA16(b) => b.as_raw(),
        DynamicImage::ImageRgb16(b) => b.as_raw(),
        DynamicImage::ImageRgba16(b) => b.as_raw(),
        _ if bits > 8 => {
            return Err(MetricsError::field(
                path,
                "bit_depth",
                format!("{bits} bits given for an 8-bit image (its codes are read as 8-bit)"),
            ));
        }
        _ => return Ok(()),
    };
    let top = ((1u64 << bits.min(16)) - 1) as f64;
    let channels = img.color().channel_count() as usize;
    let alpha = img.color().has_alpha();
    let over = codes.iter().enumerate().find(|&(i, &c)| {
        let is_alpha = alpha && i % channels == channels - 1;
        !is_alpha && f64::from(c) > top
    });
    match over {
        None => Ok(()),
        Some((i, &c)) => {
            let px = i / channels;
            let w = img.width() as usize;
            Err(MetricsError::field(
                path,
                "bit_depth",
                format!(
                    "code {c} at pixel ({}, {}) is over {top} (2^{bits} - 1): the image's codes \
                     have more than {bits} significant bits; give its real bit depth (9 to 16)",
                    px % w,
                    px / w
                ),
            ))
        }
    }
}

/// How far (8-bit units) a colour image's channels may differ at a pixel for it to be
/// read as a grey image stored as colour ("grey stored as colour" in docs/metrics.md):
/// a mono camera's frames saved as RGB agree exactly, a JPEG of them within a code or
/// two; a colour image is refused, not converted by a weighting of its channels.
pub const GREY_CHANNEL_TOLERANCE: f32 = 2.0;

/// The grey values of a colour image's pixels (`rgb`, in 8-bit units, row-major, rows of
/// `width`): each pixel's mean of its three channels, or an error naming the first pixel
/// whose channels differ by more than [`GREY_CHANNEL_TOLERANCE`].
fn grey_of_colour(
    path: &Path,
    color: &str,
    width: usize,
    rgb: impl Iterator<Item = [f32; 3]>,
) -> Result<Vec<f32>, MetricsError> {
    rgb.enumerate()
        .map(|(i, [r, g, b])| {
            let spread = r.max(g).max(b) - r.min(g).min(b);
            if spread > GREY_CHANNEL_TOLERANCE {
                return Err(MetricsError::NotGrayscale {
                    path: path.to_path_buf(),
                    color: format!(
                        "{color} whose channels differ by {spread:.1} of 255 at pixel ({}, {}) \
                         (a grey image stored as colour is read where they differ by at most \
                         {GREY_CHANNEL_TOLERANCE}; convert a colour image to grey first)",
                        i % width.max(1),
                        i / width.max(1)
                    ),
                });
            }
            Ok((r + g + b) / 3.0)
        })
        .collect()
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

/// `mask` is the size of the images it selects from.
pub(crate) fn check_mask_size(mask: &Mask, size: (usize, usize)) -> Result<(), MetricsError> {
    if mask.size() != size {
        return Err(MetricsError::SizeMismatch {
            a: "images".into(),
            a_size: size,
            b: "mask".into(),
            b_size: mask.size(),
        });
    }
    Ok(())
}
