//! Errors of the texture models. Every parameter error names the field and its allowed
//! range, so a user can fix a TOML file or a CLI flag without reading the source.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum TextureError {
    #[error("invalid parameter `{field}` = {value}: allowed {allowed}")]
    InvalidParameter {
        field: &'static str,
        value: f64,
        allowed: &'static str,
    },
    #[error("cannot read {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("exemplar {what} is unusable: {reason}")]
    BadExemplar { what: String, reason: String },
    #[error("EXR {path}: {message}")]
    Exr { path: PathBuf, message: String },
    #[error("PNG {path}: {message}")]
    Png { path: PathBuf, message: String },
}

pub type Result<T> = std::result::Result<T, TextureError>;

/// Checks `lo < value < hi` style ranges; `allowed` is the human-readable range.
pub(crate) fn check(
    ok: bool,
    field: &'static str,
    value: f64,
    allowed: &'static str,
) -> Result<()> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(TextureError::InvalidParameter {
            field,
            value,
            allowed,
        })
    }
}
