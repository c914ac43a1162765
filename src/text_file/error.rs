//! The one error type of every dataset reader and writer: it always names
//! the file, and the line or field when there is one.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
/// Why a dataset, calibration or settings file could not be read or written. Every variant names
/// the file.
pub enum DatasetError {
    #[error("{path}: {source}")]
    /// The file or folder could not be opened, read or written.
    Io {
        /// The file or folder.
        path: PathBuf,
        #[source]
        /// The I/O error.
        source: std::io::Error,
    },
    /// A row that does not parse: `line` is 1-based, as editors count.
    #[error("{path}:{line}: {message}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong with the row.
        message: String,
    },
    /// A YAML or config field missing or out of range.
    #[error("{path}: field `{field}`: {message}")]
    BadField {
        /// The file.
        path: PathBuf,
        /// The field's name (dotted when nested).
        field: String,
        /// What is wrong with it.
        message: String,
    },
    #[error("{path}: cannot decode image: {message}")]
    /// An image file that does not decode.
    Image {
        /// The image file.
        path: PathBuf,
        /// The decoder's error.
        message: String,
    },
    /// A folder that is not one of the layouts we read.
    #[error("{path}: {message}")]
    Layout {
        /// The folder.
        path: PathBuf,
        /// What it lacks (e.g. no `mav0/` or image folder).
        message: String,
    },
}

impl DatasetError {
    /// The file (or folder) the error is about.
    pub fn path(&self) -> &std::path::Path {
        match self {
            Self::Io { path, .. }
            | Self::Malformed { path, .. }
            | Self::BadField { path, .. }
            | Self::Image { path, .. }
            | Self::Layout { path, .. } => path,
        }
    }
    /// [`Self::Io`] for `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
    /// [`Self::Malformed`] for line `line` (1-based) of `path`.
    pub fn malformed(path: impl Into<PathBuf>, line: usize, message: impl Into<String>) -> Self {
        Self::Malformed {
            path: path.into(),
            line,
            message: message.into(),
        }
    }
    /// [`Self::BadField`] for `field` of `path`.
    pub fn bad_field(
        path: impl Into<PathBuf>,
        field: impl Into<String>,
        message: impl Into<String>,
    ) -> Self {
        Self::BadField {
            path: path.into(),
            field: field.into(),
            message: message.into(),
        }
    }
    /// [`Self::Layout`] for the folder `path`.
    pub fn layout(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Layout {
            path: path.into(),
            message: message.into(),
        }
    }
}
