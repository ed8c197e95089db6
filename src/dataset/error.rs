//! Everything that can go wrong between a job file and a finished dataset.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A value in the job file outside its allowed range; names the field.
    #[error("{file}: {field} = {value}: {allowed}")]
    Field {
        file: String,
        field: String,
        value: String,
        allowed: String,
    },
    #[error("{file}: {message}")]
    Parse { file: String, message: String },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}, line {line}: {message}")]
    Manifest {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("object {object}: {source}")]
    Defect {
        object: String,
        source: crate::defect::DefectError,
    },
    #[error("object {object}: {source}")]
    Mesh {
        object: String,
        source: crate::scene::MeshError,
    },
    #[error("texture of finish {finish}, instance {instance}: {message}")]
    Texture {
        finish: String,
        instance: u32,
        message: String,
    },
    #[error("image {index} ({id}): the renderer failed: {message}")]
    Render {
        index: usize,
        id: String,
        message: String,
    },
    #[error("{dir}: {message}")]
    Layout { dir: PathBuf, message: String },
    /// Another process writes into the folder (its OS file lock is held).
    #[error(
        "{dir}: in use by another synosis process ({holder}); wait for it to end, or use another folder"
    )]
    Locked { dir: PathBuf, holder: String },
    /// The run stopped on purpose (an injected failure for tests) after this many images.
    #[error("stopped after {done} image(s) (injected failure)")]
    Interrupted { done: usize },
}

impl DatasetError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        DatasetError::Io {
            path: path.into(),
            source,
        }
    }

    pub(crate) fn layout(dir: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        DatasetError::Layout {
            dir: dir.into(),
            message: message.into(),
        }
    }
}

pub type Result<T, E = DatasetError> = std::result::Result<T, E>;
