//! Documented limits on every input file, checked before anything is allocated for its
//! content (docs/reliability.md lists them). A file over a limit gives an error that names
//! the file and the limit, never an allocation failure.

use std::io::Read;
use std::path::Path;

/// Width and height of any image read (EXR, PNG): the largest documented render size.
pub const MAX_IMAGE_SIDE: usize = 16_384;
/// Text files: job, scene and defect-spec TOML, parameter TOML, LabelMe JSON.
pub const MAX_TEXT_BYTES: u64 = 16 << 20;
/// A glTF/GLB file and each buffer it names.
pub const MAX_MESH_BYTES: u64 = 2 << 30;
/// Pixels of one image `synosis metrics` / `compare` reads (about 31 bytes per pixel of
/// working memory: 64 Mpixel, e.g. 8192 x 8192, is about 2 GB).
pub const MAX_METRICS_PIXELS: u64 = 64 << 20;
/// Bytes the PNG decoder may allocate for one image (a 16384^2 16-bit gray image).
pub const MAX_PNG_ALLOC: u64 = 1 << 30;

fn too_big(what: &str, got: String, limit: String) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::InvalidData,
        format!("{got}: over the limit for {what} ({limit})"),
    )
}

/// Reads a text file of at most `MAX_TEXT_BYTES`.
pub fn read_text(path: &Path) -> std::io::Result<String> {
    read_text_limited(path, MAX_TEXT_BYTES, "a text file")
}

/// Reads a UTF-8 file of at most `limit` bytes (checked before reading, and while
/// reading, for files that grow or lie about their size).
pub fn read_text_limited(path: &Path, limit: u64, what: &str) -> std::io::Result<String> {
    let f = std::fs::File::open(path)?;
    let len = f.metadata()?.len();
    if len > limit {
        return Err(too_big(
            what,
            format!("{len} bytes"),
            format!("{limit} bytes"),
        ));
    }
    let mut s = String::new();
    f.take(limit + 1).read_to_string(&mut s)?;
    if s.len() as u64 > limit {
        return Err(too_big(what, "more bytes".into(), format!("{limit} bytes")));
    }
    Ok(s)
}

/// Checks an image's size against `MAX_IMAGE_SIDE`.
pub fn check_image_size(width: usize, height: usize) -> std::io::Result<()> {
    if width == 0 || height == 0 || width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        return Err(too_big(
            "images",
            format!("{width} x {height} pixels"),
            format!("1 to {MAX_IMAGE_SIDE} pixels a side"),
        ));
    }
    Ok(())
}

/// Reads an EXR file's header only and checks its first layer's size; returns
/// (width, height, channel names).
pub fn exr_header(path: &Path) -> std::io::Result<(usize, usize, Vec<String>)> {
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(std::io::Error::other)?;
    let h = meta
        .headers
        .first()
        .ok_or_else(|| std::io::Error::other("EXR has no layer"))?;
    let (w, hh) = (h.layer_size.width(), h.layer_size.height());
    check_image_size(w, hh)?;
    let names = h.channels.list.iter().map(|c| c.name.to_string()).collect();
    Ok((w, hh, names))
}

/// PNG decoder limits: `MAX_IMAGE_SIDE` a side, `MAX_PNG_ALLOC` bytes.
pub fn png_limits() -> image::Limits {
    let mut l = image::Limits::default();
    l.max_image_width = Some(MAX_IMAGE_SIDE as u32);
    l.max_image_height = Some(MAX_IMAGE_SIDE as u32);
    l.max_alloc = Some(MAX_PNG_ALLOC);
    l
}

/// Opens an image with [`png_limits`] (format from the content).
pub fn open_image(path: &Path) -> image::ImageResult<image::DynamicImage> {
    let mut r = image::ImageReader::open(path)?.with_guessed_format()?;
    r.limits(png_limits());
    r.decode()
}

/// The size of an image from its header only (nothing decoded).
pub fn image_dimensions(path: &Path) -> image::ImageResult<(u32, u32)> {
    image::ImageReader::open(path)?
        .with_guessed_format()?
        .into_dimensions()
}
