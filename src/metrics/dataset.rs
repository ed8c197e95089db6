//! Reading the two dataset layouts compare understands (see `docs/metrics.md`):
//! synthetic (`manifest.jsonl` + face-id PNGs) and real (LabelMe JSON + `index.csv`).

use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::MetricsError;
use super::labelme::LabelMe;
use super::masks::{Mask, face_mask};

/// One image with what compare needs to know about it.
#[derive(Clone, Debug)]
pub struct Sample {
    pub id: String,
    pub image: PathBuf,
    pub viewpoint: String,
    pub finish: String,
    pub faces: FaceSource,
    /// The bit depth of a 16-bit image's codes when it is not 16 (a synthetic dataset of a
    /// 10- or 12-bit sensor records it as `bit_depth`; a real one's `index.csv` may give
    /// it): codes are scaled by 255 / (2^bit_depth - 1) instead of 1 / 257.
    pub bit_depth: Option<u32>,
}

#[derive(Clone, Debug)]
pub enum FaceSource {
    /// 8-bit face-id PNG: 0 background, 1 = first face label, 2 = second, ...
    FaceIds(PathBuf),
    LabelMe {
        json: PathBuf,
        labels: LabelMe,
    },
}

impl Sample {
    /// Texture type: the finish up to its first '-', lower case
    /// ("sandblasted-2.5bar" -> "sandblasted").
    pub fn texture(&self) -> String {
        texture_of(&self.finish)
    }

    /// The image in 8-bit units (see [`super::gray::GrayImage::load_codes`]).
    pub fn load_image(&self) -> Result<super::gray::GrayImage, MetricsError> {
        super::gray::GrayImage::load_codes(&self.image, self.bit_depth)
    }

    /// Masks of the given faces (`face_labels[i]` has id `i + 1`), in order.
    pub fn face_masks(
        &self,
        face_labels: &[String],
        faces: &[usize],
    ) -> Result<Vec<Mask>, MetricsError> {
        match &self.faces {
            FaceSource::FaceIds(path) => {
                let img = super::gray::open(path)?;
                faces
                    .iter()
                    .map(|&f| face_mask(&img, path, (f + 1) as u8))
                    .collect()
            }
            FaceSource::LabelMe { json, labels } => faces
                .iter()
                .map(|&f| labels.face_mask(json, &face_labels[f]))
                .collect(),
        }
    }
}

pub fn texture_of(finish: &str) -> String {
    finish
        .split('-')
        .next()
        .unwrap_or("")
        .trim()
        .to_ascii_lowercase()
}

/// Reads `dir` in whichever layout it holds: `manifest.jsonl` (synthetic) takes
/// precedence over `index.csv` (real, LabelMe).
pub fn load_dir(dir: &Path) -> Result<Vec<Sample>, MetricsError> {
    let manifest = dir.join("manifest.jsonl");
    let index = dir.join("index.csv");
    if manifest.is_file() {
        load_synthetic(dir, &manifest)
    } else if index.is_file() {
        load_real(dir, &index)
    } else {
        Err(MetricsError::field(
            dir,
            "layout",
            "neither manifest.jsonl (synthetic layout) nor index.csv (LabelMe layout) found",
        ))
    }
}

/// Unknown fields are ignored, so the generator may add more later.
#[derive(Deserialize)]
struct ManifestLine {
    #[serde(default)]
    id: Option<String>,
    image: String,
    faces: String,
    viewpoint: String,
    finish: String,
    #[serde(default)]
    bit_depth: Option<u32>,
}

fn load_synthetic(dir: &Path, manifest: &Path) -> Result<Vec<Sample>, MetricsError> {
    let text = read(manifest)?;
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line_no = n + 1;
        if line.trim().is_empty() {
            continue;
        }
        let err = |msg: String| MetricsError::Line {
            path: manifest.to_path_buf(),
            line: line_no,
            msg,
        };
        let m: ManifestLine = serde_json::from_str(line).map_err(|e| err(e.to_string()))?;
        if m.viewpoint.trim().is_empty() || m.finish.trim().is_empty() {
            return Err(err("viewpoint and finish must not be empty".into()));
        }
        let id = m.id.unwrap_or_else(|| default_id(&m.image));
        out.push(Sample {
            id,
            image: dir.join(&m.image),
            viewpoint: m.viewpoint.trim().to_string(),
            finish: m.finish.trim().to_string(),
            faces: FaceSource::FaceIds(dir.join(&m.faces)),
            bit_depth: m.bit_depth,
        });
    }
    if out.is_empty() {
        return Err(MetricsError::field(manifest, "lines", "no image listed"));
    }
    Ok(out)
}

/// The image path without extension, or its folder for the folder-per-image layout
/// (`000123/image.png` -> `000123`).
fn default_id(image: &str) -> String {
    let p = Path::new(image);
    match (p.file_stem(), p.parent()) {
        (Some(stem), Some(parent)) if stem == "image" && !parent.as_os_str().is_empty() => {
            parent.to_string_lossy().into_owned()
        }
        _ => p.with_extension("").to_string_lossy().into_owned(),
    }
}

fn load_real(dir: &Path, index: &Path) -> Result<Vec<Sample>, MetricsError> {
    let text = read(index)?;
    let mut out = Vec::new();
    let mut header_seen = false;
    let mut with_depth = false;
    for (n, line) in text.lines().enumerate() {
        let line_no = n + 1;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let err = |msg: String| MetricsError::Line {
            path: index.to_path_buf(),
            line: line_no,
            msg,
        };
        let cols: Vec<&str> = line.split(',').map(str::trim).collect();
        if !header_seen {
            with_depth = match cols[..] {
                ["file", "viewpoint", "finish"] => false,
                ["file", "viewpoint", "finish", "bit_depth"] => true,
                _ => {
                    return Err(err(format!(
                        "header must be `file,viewpoint,finish` or `file,viewpoint,finish,bit_depth`, found `{line}`"
                    )));
                }
            };
            header_seen = true;
            continue;
        }
        let (file, viewpoint, finish, depth) = match (with_depth, &cols[..]) {
            (false, &[f, v, fi]) => (f, v, fi, ""),
            (true, &[f, v, fi]) => (f, v, fi, ""),
            (true, &[f, v, fi, d]) => (f, v, fi, d),
            _ => {
                return Err(err(format!(
                    "expected {} columns, found {}",
                    if with_depth { "3 or 4" } else { "3" },
                    cols.len()
                )));
            }
        };
        if file.is_empty() || viewpoint.is_empty() || finish.is_empty() {
            return Err(err("file, viewpoint and finish must not be empty".into()));
        }
        let bit_depth = match depth {
            "" => None,
            d => match d.parse::<u32>() {
                Ok(b @ 8..=16) => Some(b),
                _ => {
                    return Err(err(format!(
                        "bit_depth must be an integer from 8 to 16 (the significant bits of a 16-bit image's codes; empty: 16), found `{d}`"
                    )));
                }
            },
        };
        let json = if file.ends_with(".json") {
            dir.join(file)
        } else {
            dir.join(format!("{file}.json"))
        };
        let labels = LabelMe::load(&json)?;
        out.push(Sample {
            id: Path::new(file)
                .with_extension("")
                .to_string_lossy()
                .into_owned(),
            image: labels.image_file(&json),
            viewpoint: viewpoint.to_string(),
            finish: finish.to_string(),
            faces: FaceSource::LabelMe { json, labels },
            bit_depth,
        });
    }
    if out.is_empty() {
        return Err(MetricsError::field(index, "rows", "no image listed"));
    }
    Ok(out)
}

fn read(path: &Path) -> Result<String, MetricsError> {
    crate::limits::read_text_limited(path, 1 << 30, "a manifest or table").map_err(|source| {
        MetricsError::Io {
            path: path.to_path_buf(),
            source,
        }
    })
}
