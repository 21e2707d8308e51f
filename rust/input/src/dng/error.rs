//! Errors of DNG reading and writing, by category. Every message names the file and the fix.

use std::path::{Path, PathBuf};

/// What went wrong with one DNG file (or folder).
#[derive(Debug, thiserror::Error)]
pub enum DngError {
    /// The file or folder could not be opened, read, written or renamed.
    #[error("{}: {source} (check that the path exists and is readable/writable)", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// The file is not a readable TIFF/DNG: truncated, corrupt, or a layout the decoder rejects.
    #[error("{}: cannot decode DNG: {detail} (the file may be truncated or corrupt; copy it from the phone again)", path.display())]
    Decode { path: PathBuf, detail: String },

    /// A tag the calibration needs is absent.
    #[error("{}: missing DNG tag {tag}: {fix}", path.display())]
    MissingTag { path: PathBuf, tag: &'static str, fix: &'static str },

    /// A valid DNG that noisecal cannot use (non-Bayer CFA, demosaiced data, float samples, …).
    #[error("{}: unsupported DNG: {what}", path.display())]
    Unsupported { path: PathBuf, what: String },

    /// The caller's data does not fit what it asked for (writing only).
    #[error("{}: cannot write DNG: {what}", path.display())]
    InvalidInput { path: PathBuf, what: String },
}

impl DngError {
    /// An I/O error on the file at `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), source }
    }

    pub(crate) fn decode(path: &Path, detail: impl Into<String>) -> Self {
        Self::Decode { path: path.to_path_buf(), detail: detail.into() }
    }

    pub(crate) fn unsupported(path: &Path, what: impl Into<String>) -> Self {
        Self::Unsupported { path: path.to_path_buf(), what: what.into() }
    }

    pub(crate) fn invalid(path: &Path, what: impl Into<String>) -> Self {
        Self::InvalidInput { path: path.to_path_buf(), what: what.into() }
    }

    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            Self::Io { path, .. }
            | Self::Decode { path, .. }
            | Self::MissingTag { path, .. }
            | Self::Unsupported { path, .. }
            | Self::InvalidInput { path, .. } => path,
        }
    }
}
