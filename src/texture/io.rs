//! Files for people: EXR height (one f32 channel `Y`, micrometres), 16-bit PNG normal
//! map, 8-bit preview. The PNGs are encoded by `crate::image_io` (through a temporary
//! sibling name); callers that need all-or-nothing output of the whole set write temp
//! names and rename (see the CLI).

use std::path::Path;

use image::{ImageBuffer, Luma};
use rayon::prelude::*;

use super::error::{Result, TextureError};
use super::maps::{HeightMap, normal_from_slope};

/// The height map as channel `Y` (µm) with its texel spacing as attribute `spacing_um`,
/// through `image_io`'s EXR writer.
pub fn write_exr_height(map: &HeightMap, path: &Path) -> Result<()> {
    crate::image_io::write_exr_with(
        path,
        (map.width, map.height),
        "Y",
        &map.data,
        "height_um",
        &[("spacing_um", map.spacing_um as f32)],
    )
    .map_err(|e| TextureError::Exr {
        path: path.to_owned(),
        message: e.to_string(),
    })
}

fn png_err(path: &Path, e: impl ToString) -> TextureError {
    TextureError::Png {
        path: path.to_owned(),
        message: e.to_string(),
    }
}

/// 16-bit RGB normal map, n mapped from [-1, 1] to [0, 65535], image axes (x right,
/// y down, z out of the surface). Streamed in bands of rows so a 13107^2 map does not
/// need a second full-size buffer (the image crate would hold two: 2 GB).
pub fn write_normal_png16(map: &HeightMap, path: &Path) -> Result<()> {
    let w = map.width;
    crate::image_io::write_png_rgb16_streamed(path, w, map.height, 256, |y0, bytes| {
        bytes
            .par_chunks_mut(w * 6)
            .enumerate()
            .for_each(|(r, row)| {
                map.slope_row(y0 + r, |x, s| {
                    let n = normal_from_slope(s);
                    for c in 0..3 {
                        let v = ((n[c] * 0.5 + 0.5).clamp(0.0, 1.0) * 65535.0).round() as u16;
                        row[6 * x + 2 * c..6 * x + 2 * c + 2].copy_from_slice(&v.to_be_bytes());
                    }
                })
            })
    })
    .map_err(|e| png_err(path, e))
}

/// 8-bit grey preview, box-downsampled to at most `max_side`, mean +- 2.5 Sq mapped to
/// black..white. Previews go into docs: small files matter more than encode time here.
pub fn write_preview_png(map: &HeightMap, path: &Path, max_side: usize) -> Result<()> {
    let img = preview(map, max_side);
    crate::image_io::write_png_gray8_compact(path, img.width(), img.height(), img.as_raw())
        .map_err(|e| png_err(path, e))
}

pub fn preview(map: &HeightMap, max_side: usize) -> ImageBuffer<Luma<u8>, Vec<u8>> {
    let f = map.width.max(map.height).div_ceil(max_side.max(1)).max(1);
    let (w, h) = (map.width.div_ceil(f), map.height.div_ceil(f));
    let m = map.moments();
    let (lo, span) = (m.mean_um - 2.5 * m.sq_um, (5.0 * m.sq_um).max(1e-12));
    let mut out = vec![0u8; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let (mut s, mut n) = (0.0f64, 0usize);
            for yy in y * f..((y + 1) * f).min(map.height) {
                for xx in x * f..((x + 1) * f).min(map.width) {
                    s += map.get(xx, yy) as f64;
                    n += 1;
                }
            }
            let v = ((s / n.max(1) as f64 - lo) / span).clamp(0.0, 1.0);
            *o = (v * 255.0).round() as u8;
        }
    });
    ImageBuffer::from_raw(w as u32, h as u32, out).unwrap_or_default()
}
