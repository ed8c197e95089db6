//! LabelMe annotations of the real images (the paper's public real dataset): face
//! polygons named after the faces (`A`, `B`, `C` by default).

use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::MetricsError;
use super::masks::Mask;

#[derive(Clone, Debug, Deserialize)]
pub struct LabelMe {
    #[serde(rename = "imagePath")]
    pub image_path: String,
    #[serde(rename = "imageWidth")]
    pub image_width: usize,
    #[serde(rename = "imageHeight")]
    pub image_height: usize,
    pub shapes: Vec<Shape>,
}

#[derive(Clone, Debug, Deserialize)]
pub struct Shape {
    pub label: String,
    pub points: Vec<[f64; 2]>,
    /// Old LabelMe files omit it; they only had polygons.
    #[serde(default)]
    pub shape_type: Option<String>,
}

impl LabelMe {
    pub fn load(path: &Path) -> Result<Self, MetricsError> {
        let text = crate::limits::read_text(path).map_err(|source| MetricsError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let lm: LabelMe = serde_json::from_str(&text).map_err(|source| MetricsError::Json {
            path: path.to_path_buf(),
            source,
        })?;
        if lm.image_width == 0 || lm.image_height == 0 {
            return Err(MetricsError::field(
                path,
                "imageWidth/imageHeight",
                format!("{} x {} is empty", lm.image_width, lm.image_height),
            ));
        }
        Ok(lm)
    }

    /// The image file, relative to the JSON file's folder as LabelMe writes it.
    pub fn image_file(&self, json_path: &Path) -> PathBuf {
        json_path
            .parent()
            .unwrap_or(Path::new("."))
            .join(self.image_path.replace('\\', "/"))
    }

    /// Union of the shapes labelled `label` (trimmed, case-insensitive). Polygons and
    /// rectangles are accepted; any other shape type under a face label is an error.
    /// Errors if no shape carries the label: a real image must show its face.
    pub fn face_mask(&self, json_path: &Path, label: &str) -> Result<Mask, MetricsError> {
        let mut mask = Mask::filled(self.image_width, self.image_height, false);
        let mut found = false;
        for (i, s) in self.shapes.iter().enumerate() {
            if !s.label.trim().eq_ignore_ascii_case(label) {
                continue;
            }
            let field = || format!("shapes[{i}] (label {:?})", s.label);
            match s.shape_type.as_deref().unwrap_or("polygon") {
                "polygon" => {
                    if s.points.len() < 3 {
                        return Err(MetricsError::field(
                            json_path,
                            &field(),
                            format!("a polygon needs at least 3 points, has {}", s.points.len()),
                        ));
                    }
                    mask.fill_polygon(&s.points);
                }
                "rectangle" => {
                    let [[x0, y0], [x1, y1]] = s.points[..] else {
                        return Err(MetricsError::field(
                            json_path,
                            &field(),
                            "a rectangle needs exactly 2 points",
                        ));
                    };
                    mask.fill_polygon(&[[x0, y0], [x1, y0], [x1, y1], [x0, y1]]);
                }
                other => {
                    return Err(MetricsError::field(
                        json_path,
                        &field(),
                        format!("shape_type {other:?} for a face; use polygon or rectangle"),
                    ));
                }
            }
            found = true;
        }
        if !found {
            return Err(MetricsError::field(
                json_path,
                "shapes",
                format!("no shape labelled {label:?}"),
            ));
        }
        Ok(mask)
    }
}
