//! Errors of the scene crate. Every error names the file (or the in-memory source) and the field
//! it concerns, so a user can fix the input without reading code.

use std::path::{Path, PathBuf};

/// An invalid value, before it is attached to a file: `field` is the dotted name of the offending
/// field (`volume.phase.g`, `header.xres`, `voxel[3,0,1]`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("field `{field}`: {msg}")]
pub struct FieldError {
    pub field: String,
    pub msg: String,
}

impl FieldError {
    pub fn new(field: impl Into<String>, msg: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            msg: msg.into(),
        }
    }

    /// Attaches the file (or source label) the field was read from.
    pub fn at(self, path: impl AsRef<Path>) -> Error {
        Error::Invalid {
            path: path.as_ref().to_path_buf(),
            field: self.field,
            msg: self.msg,
        }
    }
}

/// Errors from reading scenes, volumes and images.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    // The I/O error is part of the message, not a `source`: an error chain (anyhow's `{:#}`)
    // would print it twice.
    #[error("{}: {err}", path.display())]
    Io { path: PathBuf, err: std::io::Error },
    #[error("{}: field `{field}`: {msg}", path.display())]
    Invalid {
        path: PathBuf,
        field: String,
        msg: String,
    },
    #[error("{}: {msg}", path.display())]
    Parse { path: PathBuf, msg: String },
}

impl Error {
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.as_ref().to_path_buf(),
            err: source,
        }
    }

    pub fn parse(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Error::Parse {
            path: path.as_ref().to_path_buf(),
            msg: msg.into(),
        }
    }

    pub fn invalid(
        path: impl AsRef<Path>,
        field: impl Into<String>,
        msg: impl Into<String>,
    ) -> Self {
        FieldError::new(field, msg).at(path)
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
