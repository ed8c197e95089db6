//! The one error type of the metrics module: every variant names the file or field at fault.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum MetricsError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot decode image {path}: {source}")]
    Decode {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    #[error(
        "{path}: expected a grayscale (8- or 16-bit) image (PNG, TIFF, BMP, JPEG), found {color}"
    )]
    NotGrayscale { path: PathBuf, color: String },
    #[error("size mismatch: {a} is {a_size:?} but {b} is {b_size:?} (width, height)")]
    SizeMismatch {
        a: String,
        a_size: (usize, usize),
        b: String,
        b_size: (usize, usize),
    },
    #[error("{what}: image is {size:?} (width, height), {metric} needs at least {min} x {min}")]
    TooSmall {
        what: String,
        metric: &'static str,
        size: (usize, usize),
        min: usize,
    },
    #[error("empty mask: {what} selects no pixel")]
    EmptyMask { what: String },
    #[error("{path}: invalid JSON: {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error("{path}: {field}: {msg}")]
    Field {
        path: PathBuf,
        field: String,
        msg: String,
    },
    #[error("{path} line {line}: {msg}")]
    Line {
        path: PathBuf,
        line: usize,
        msg: String,
    },
    #[error("invalid parameter {field}: {msg}")]
    Param { field: String, msg: String },
}

impl MetricsError {
    pub(crate) fn field(path: impl Into<PathBuf>, field: &str, msg: impl Into<String>) -> Self {
        Self::Field {
            path: path.into(),
            field: field.to_string(),
            msg: msg.into(),
        }
    }

    pub(crate) fn param(field: &str, msg: impl Into<String>) -> Self {
        Self::Param {
            field: field.to_string(),
            msg: msg.into(),
        }
    }
}
