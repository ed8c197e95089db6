//! Reading and writing one image's files: every file goes to a temporary name and is
//! renamed into place; each write returns the content hash the manifest records.

use std::path::Path;

use super::error::{DatasetError, Result};
use super::seed::fnv1a64;

/// "fnv1a64:<16 hex digits>" of a file's bytes.
pub fn content_hash(bytes: &[u8]) -> String {
    format!("fnv1a64:{:016x}", fnv1a64(bytes))
}

fn write(path: &Path, bytes: &[u8]) -> Result<String> {
    crate::util::write_atomic(path, bytes).map_err(|e| DatasetError::io(path, e))?;
    Ok(content_hash(bytes))
}

pub fn write_gray8(path: &Path, w: usize, h: usize, data: &[u8]) -> Result<String> {
    let bytes = crate::image_io::png_gray8(w as u32, h as u32, data)
        .map_err(|e| DatasetError::io(path, e))?;
    write(path, &bytes)
}

pub fn write_gray16(path: &Path, w: usize, h: usize, data: &[u16]) -> Result<String> {
    let bytes = crate::image_io::png_gray16(w as u32, h as u32, data)
        .map_err(|e| DatasetError::io(path, e))?;
    write(path, &bytes)
}

pub fn write_json(path: &Path, value: &serde_json::Value) -> Result<String> {
    let bytes = serde_json::to_vec_pretty(value)
        .map_err(|e| DatasetError::io(path, std::io::Error::other(e)))?;
    write(path, &bytes)
}

/// Linear radiance as a one-channel ("Y") f32 EXR; its hash is of the file as written.
pub fn write_exr(path: &Path, w: usize, h: usize, data: &[f32]) -> Result<String> {
    crate::image_io::write_exr_f32(path, w, h, "Y", data).map_err(|e| DatasetError::io(path, e))?;
    let bytes = std::fs::read(path).map_err(|e| DatasetError::io(path, e))?;
    Ok(content_hash(&bytes))
}

pub fn read_exr(path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    crate::image_io::read_exr_f32(path).map_err(|e| DatasetError::io(path, e))
}

fn open(path: &Path) -> Result<image::DynamicImage> {
    crate::limits::open_image(path).map_err(|e| DatasetError::io(path, std::io::Error::other(e)))
}

pub fn read_gray8(path: &Path) -> Result<(usize, usize, Vec<u8>)> {
    let img = open(path)?.into_luma8();
    Ok((img.width() as usize, img.height() as usize, img.into_raw()))
}

pub fn read_gray16(path: &Path) -> Result<(usize, usize, Vec<u16>)> {
    let img = open(path)?.into_luma16();
    Ok((img.width() as usize, img.height() as usize, img.into_raw()))
}

/// True for the names `util::temp_sibling` and `image_io` give temporary files.
pub fn is_temp_name(name: &str) -> bool {
    name.starts_with('.') && name.contains(".tmp")
}

/// Removes temporary files a killed run left in `dir` (not recursive).
pub fn remove_stray_temps(dir: &Path) -> Result<usize> {
    let mut n = 0;
    let Ok(rd) = std::fs::read_dir(dir) else {
        return Ok(0);
    };
    for e in rd.flatten() {
        if is_temp_name(&e.file_name().to_string_lossy()) && e.path().is_file() {
            std::fs::remove_file(e.path()).map_err(|err| DatasetError::io(e.path(), err))?;
            n += 1;
        }
    }
    Ok(n)
}
