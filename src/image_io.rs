//! Writing images: single-channel f32 EXR and PNG, always through a temporary name.
//! Every PNG the crate writes is encoded here (8/16-bit grey, RGBA, the streamed 16-bit
//! RGB normal map, the compact 8-bit preview).

use std::path::Path;

use exr::prelude::*;

/// Writes a one-channel f32 EXR (channel `name`, e.g. "Y" or "Z"), row 0 at the top.
pub fn write_exr_f32(
    path: &Path,
    width: usize,
    height: usize,
    channel: &str,
    data: &[f32],
) -> std::io::Result<()> {
    write_exr_with(path, (width, height), channel, data, "", &[])
}

/// The crate's one EXR writer: one f32 channel, a layer name and f32 attributes (e.g.
/// a height map's `spacing_um`), through a temporary sibling name, removed on failure.
pub fn write_exr_with(
    path: &Path,
    (width, height): (usize, usize),
    channel: &str,
    data: &[f32],
    layer_name: &str,
    attributes: &[(&str, f32)],
) -> std::io::Result<()> {
    assert_eq!(data.len(), width * height, "image size mismatch");
    let tmp = crate::util::temp_sibling(path).with_extension("tmp.exr");
    let ch = AnyChannel::new(channel, FlatSamples::F32(data.to_vec()));
    let mut layer = Layer::new(
        (width, height),
        LayerAttributes::named(layer_name),
        // A fixed chunk order: the parallel compressor otherwise writes chunks in the
        // order they finish, and the same image gives different bytes (and hashes).
        Encoding {
            line_order: LineOrder::Increasing,
            ..Encoding::FAST_LOSSLESS
        },
        AnyChannels::sort(SmallVec::from_vec(vec![ch])),
    );
    for (k, v) in attributes {
        layer
            .attributes
            .other
            .insert(Text::from(*k), AttributeValue::F32(*v));
    }
    let result = Image::from_layer(layer)
        .write()
        .to_file(&tmp)
        .map_err(std::io::Error::other)
        .and_then(|_| std::fs::rename(&tmp, path));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Reads channel `Y` (or the only channel, e.g. `Z` of a depth map) of a one-layer
/// f32/f16 EXR: (width, height, data). Several channels without `Y` are refused. The
/// header is checked against `limits::MAX_IMAGE_SIDE` before any pixel is read.
pub fn read_exr_f32(path: &Path) -> std::io::Result<(usize, usize, Vec<f32>)> {
    read_exr_channel(path, None)
}

/// The crate's one EXR reader: channel `required` (an error naming the file's channels
/// when it is missing), or with `None` channel `Y` or the only channel. The header is
/// checked against `limits::MAX_IMAGE_SIDE` before any pixel is read.
pub fn read_exr_channel(
    path: &Path,
    required: Option<&str>,
) -> std::io::Result<(usize, usize, Vec<f32>)> {
    let (_, _, names) = crate::limits::exr_header(path)?;
    let want = match required {
        Some(c) if names.iter().any(|n| n == c) => c.to_string(),
        Some(c) => {
            return Err(std::io::Error::other(format!(
                "no channel named {c} (channels: {})",
                names.join(", ")
            )));
        }
        None if names.iter().any(|n| n == "Y") => "Y".to_string(),
        None if names.len() == 1 => names[0].clone(),
        None => {
            return Err(std::io::Error::other(format!(
                "no channel named Y among several (channels: {})",
                names.join(", ")
            )));
        }
    };
    let img = read_first_flat_layer_from_file(path).map_err(std::io::Error::other)?;
    let size = img.layer_data.size;
    let ch = img
        .layer_data
        .channel_data
        .list
        .iter()
        .find(|c| c.name.to_string() == want)
        .ok_or_else(|| std::io::Error::other(format!("EXR has no channel {want}")))?;
    let data: Vec<f32> = ch.sample_data.values_as_f32().collect();
    if data.len() != size.0 * size.1 {
        return Err(std::io::Error::other(format!(
            "{} samples for {} x {} pixels",
            data.len(),
            size.0,
            size.1
        )));
    }
    Ok((size.0, size.1, data))
}

/// PNG bytes of an image (the image crate's default PNG settings).
fn png_bytes(img: image::DynamicImage) -> std::io::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(std::io::Error::other)?;
    Ok(bytes)
}

fn encode_png(img: image::DynamicImage, path: &Path) -> std::io::Result<()> {
    crate::util::write_atomic(path, &png_bytes(img)?)
}

/// The bytes of an 8-bit grayscale PNG (for callers that hash what they write).
pub fn png_gray8(width: u32, height: u32, data: &[u8]) -> std::io::Result<Vec<u8>> {
    let img = image::GrayImage::from_raw(width, height, data.to_vec())
        .ok_or_else(|| std::io::Error::other("image size mismatch"))?;
    png_bytes(image::DynamicImage::ImageLuma8(img))
}

/// The bytes of a 16-bit grayscale PNG (for callers that hash what they write).
pub fn png_gray16(width: u32, height: u32, data: &[u16]) -> std::io::Result<Vec<u8>> {
    let img =
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(width, height, data.to_vec())
            .ok_or_else(|| std::io::Error::other("image size mismatch"))?;
    png_bytes(image::DynamicImage::ImageLuma16(img))
}

/// 8-bit RGBA PNG from packed u32 pixels (R in the low byte).
pub fn write_png_rgba8(path: &Path, width: u32, height: u32, rgba: &[u32]) -> std::io::Result<()> {
    let bytes: Vec<u8> = rgba.iter().flat_map(|p| p.to_le_bytes()).collect();
    let img = image::RgbaImage::from_raw(width, height, bytes)
        .ok_or_else(|| std::io::Error::other("size mismatch"))?;
    encode_png(image::DynamicImage::ImageRgba8(img), path)
}

/// 8-bit RGB PNG from interleaved R, G, B bytes.
pub fn write_png_rgb8(path: &Path, width: u32, height: u32, rgb: &[u8]) -> std::io::Result<()> {
    let img = image::RgbImage::from_raw(width, height, rgb.to_vec())
        .ok_or_else(|| std::io::Error::other("size mismatch"))?;
    encode_png(image::DynamicImage::ImageRgb8(img), path)
}

/// 8-bit grayscale PNG.
pub fn write_png_gray8(path: &Path, width: u32, height: u32, data: &[u8]) -> std::io::Result<()> {
    crate::util::write_atomic(path, &png_gray8(width, height, data)?)
}

/// 16-bit grayscale PNG.
pub fn write_png_gray16(path: &Path, width: u32, height: u32, data: &[u16]) -> std::io::Result<()> {
    crate::util::write_atomic(path, &png_gray16(width, height, data)?)
}

/// 8-bit grayscale PNG made small rather than fast (best compression, adaptive row
/// filters): for previews that go into docs.
pub fn write_png_gray8_compact(
    path: &Path,
    width: u32,
    height: u32,
    data: &[u8],
) -> std::io::Result<()> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    crate::util::write_atomic_with(path, |f| {
        PngEncoder::new_with_quality(
            std::io::BufWriter::new(f),
            CompressionType::Best,
            FilterType::Adaptive,
        )
        .write_image(data, width, height, image::ExtendedColorType::L8)
        .map_err(std::io::Error::other)
    })
}

/// 16-bit RGB PNG (fast compression) streamed in bands of `band` rows, so an image
/// larger than memory allows twice is never held whole: `fill(first_row, bytes)` fills
/// the big-endian samples of the rows from `first_row` (6 bytes per pixel,
/// `bytes.len() / (6 * width)` rows).
pub fn write_png_rgb16_streamed(
    path: &Path,
    width: usize,
    height: usize,
    band: usize,
    mut fill: impl FnMut(usize, &mut [u8]),
) -> std::io::Result<()> {
    let band = band.max(1);
    crate::util::write_atomic_with(path, |f| {
        let mut out = std::io::BufWriter::new(f);
        let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Sixteen);
        enc.set_compression(png::Compression::Fast);
        let mut writer = enc.write_header().map_err(std::io::Error::other)?;
        let mut stream = writer.stream_writer().map_err(std::io::Error::other)?;
        let mut bytes = vec![0u8; band * width * 6];
        for y0 in (0..height).step_by(band) {
            let n = band.min(height - y0) * width * 6;
            fill(y0, &mut bytes[..n]);
            std::io::Write::write_all(&mut stream, &bytes[..n])?;
        }
        stream.finish().map_err(std::io::Error::other)?;
        writer.finish().map_err(std::io::Error::other)?;
        std::io::Write::flush(&mut out)
    })
}
