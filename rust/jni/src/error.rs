//! The one error type of the boundary. Every variant's message says what was wrong and, where there
//! is one, the fix; at the JNI edge each becomes an `org.noisecal.jni.NoisecalException` carrying
//! exactly this message.

use std::path::PathBuf;

use noisecal_core::error::{CodecError, FrameError, SessionError};
use thiserror::Error;

/// Anything a call across the boundary can fail with.
#[derive(Debug, Error)]
pub enum BoundaryError {
    #[error(
        "buffer is not a direct ByteBuffer: pass Image.planes[0].buffer (a heap buffer from ByteBuffer.wrap/allocate has no native address; use ByteBuffer.allocateDirect)"
    )]
    NotDirect,
    #[error("frame buffer is null: pass Image.planes[0].buffer")]
    NullBuffer,
    #[error("session handle {0} is closed or was never opened: the NoisecalSession was used after close()")]
    ClosedHandle(i64),
    #[error(
        "session {0} is unusable: an earlier call on it failed inside the native core (panic); close it and restore from the last checkpoint"
    )]
    Poisoned(i64),
    #[error("{name} is {value}: {expected}")]
    Argument { name: &'static str, value: String, expected: String },
    #[error(transparent)]
    Frame(#[from] FrameError),
    #[error(transparent)]
    Session(#[from] SessionError),
    #[error(transparent)]
    Codec(#[from] CodecError),
    #[error("{what} {path}: {source}; check the path exists and is writable", path = .path.display())]
    Io {
        what: &'static str,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("bad path {0:?}: pass a non-empty path to a file in an existing directory")]
    BadPath(String),
    #[error("{0}")]
    Recording(String),
    #[error("JNI call failed: {0}")]
    Jni(#[from] jni::errors::Error),
}

impl BoundaryError {
    pub(crate) fn io(what: &'static str, path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io { what, path: path.into(), source }
    }

    pub(crate) fn arg(name: &'static str, value: impl ToString, expected: impl Into<String>) -> Self {
        Self::Argument { name, value: value.to_string(), expected: expected.into() }
    }
}

pub type Result<T, E = BoundaryError> = std::result::Result<T, E>;
