//! Writing images: single-channel f32 EXR and PNG, always through a temporary name.

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
    assert_eq!(data.len(), width * height, "image size mismatch");
    let tmp = crate::util::temp_sibling(path).with_extension("tmp.exr");
    let ch = AnyChannel::new(channel, FlatSamples::F32(data.to_vec()));
    let layer = Layer::new(
        (width, height),
        LayerAttributes::named(""),
        // A fixed chunk order: the parallel compressor otherwise writes chunks in the
        // order they finish, and the same image gives different bytes (and hashes).
        Encoding {
            line_order: LineOrder::Increasing,
            ..Encoding::FAST_LOSSLESS
        },
        AnyChannels::sort(SmallVec::from_vec(vec![ch])),
    );
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
    let (_, _, names) = crate::limits::exr_header(path)?;
    let want = if names.iter().any(|n| n == "Y") {
        "Y".to_string()
    } else if names.len() == 1 {
        names[0].clone()
    } else {
        return Err(std::io::Error::other(format!(
            "no channel named Y among several (channels: {})",
            names.join(", ")
        )));
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
    Ok((size.0, size.1, data))
}

fn encode_png(img: image::DynamicImage, path: &Path) -> std::io::Result<()> {
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(std::io::Error::other)?;
    crate::util::write_atomic(path, &bytes)
}

/// 8-bit RGBA PNG from packed u32 pixels (R in the low byte).
pub fn write_png_rgba8(path: &Path, width: u32, height: u32, rgba: &[u32]) -> std::io::Result<()> {
    let bytes: Vec<u8> = rgba.iter().flat_map(|p| p.to_le_bytes()).collect();
    let img = image::RgbaImage::from_raw(width, height, bytes)
        .ok_or_else(|| std::io::Error::other("size mismatch"))?;
    encode_png(image::DynamicImage::ImageRgba8(img), path)
}

/// 8-bit grayscale PNG.
pub fn write_png_gray8(path: &Path, width: u32, height: u32, data: &[u8]) -> std::io::Result<()> {
    let img = image::GrayImage::from_raw(width, height, data.to_vec())
        .ok_or_else(|| std::io::Error::other("size mismatch"))?;
    encode_png(image::DynamicImage::ImageLuma8(img), path)
}

/// 16-bit grayscale PNG.
pub fn write_png_gray16(path: &Path, width: u32, height: u32, data: &[u16]) -> std::io::Result<()> {
    let img =
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(width, height, data.to_vec())
            .ok_or_else(|| std::io::Error::other("size mismatch"))?;
    encode_png(image::DynamicImage::ImageLuma16(img), path)
}
