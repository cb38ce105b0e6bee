//! Host errors: every one names the file, channel or parameter concerned, so
//! the CLI can print it as one clear line.

use std::fmt;
use std::path::{Path, PathBuf};

/// What went wrong around the kernels.
#[derive(Debug)]
pub enum HostError {
    /// A file could not be read.
    Read {
        /// The file.
        path: PathBuf,
        /// What the OS or the decoder said.
        reason: String,
    },
    /// A file is not a frame we can use.
    BadInput {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A required channel is missing.
    MissingChannel {
        /// The file.
        path: PathBuf,
        /// The buffer (e.g. "albedo").
        buffer: &'static str,
        /// The channel names looked for.
        wanted: String,
        /// Who needs it.
        needed_by: String,
    },
    /// A file could not be written.
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// A command-line argument or parameter is wrong.
    Usage(String),
    /// A kernel refused its arguments (an internal inconsistency: the host
    /// checks shapes before calling).
    Kernel(String),
}

impl HostError {
    /// A read error for `path`.
    pub fn read(path: &Path, reason: impl fmt::Display) -> Self {
        HostError::Read { path: path.to_path_buf(), reason: reason.to_string() }
    }
    /// A bad-input error for `path`.
    pub fn bad(path: &Path, reason: impl fmt::Display) -> Self {
        HostError::BadInput { path: path.to_path_buf(), reason: reason.to_string() }
    }
    /// A write error for `path`.
    pub fn write(path: &Path, reason: impl fmt::Display) -> Self {
        HostError::Write { path: path.to_path_buf(), reason: reason.to_string() }
    }
}

impl fmt::Display for HostError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            HostError::Read { path, reason } => write!(f, "{}: cannot read: {reason}", path.display()),
            HostError::BadInput { path, reason } => write!(f, "{}: {reason}", path.display()),
            HostError::MissingChannel { path, buffer, wanted, needed_by } => {
                write!(f, "{}: missing {buffer} channels ({wanted}), which {needed_by} needs", path.display())
            }
            HostError::Write { path, reason } => write!(f, "{}: cannot write: {reason}", path.display()),
            HostError::Usage(s) => write!(f, "{s}"),
            HostError::Kernel(s) => write!(f, "internal error: {s}"),
        }
    }
}

impl std::error::Error for HostError {}

impl From<mcdenoise_core::Error> for HostError {
    fn from(e: mcdenoise_core::Error) -> Self {
        HostError::Kernel(e.to_string())
    }
}

/// Result with the host error.
pub type Result<T> = std::result::Result<T, HostError>;
