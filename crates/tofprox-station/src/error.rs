//! The station's one error type: a bad station file names the file and the key (as
//! `tofprox_format::FormatError` does), a failed step names the step.

use std::path::PathBuf;

use tofprox_bridge::BridgeError;
use tofprox_format::{ExtractError, FormatError, ProcessError};

/// Why the station could not run (a module that fails its limits is not an error: the
/// [`crate::Report`] says which part failed).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StationError {
    /// The station file does not parse or a value is out of range.
    #[error("{}{}: {message}", path.display(), key.as_deref().map(|k| format!(": {k}")).unwrap_or_default())]
    File {
        /// The station file.
        path: PathBuf,
        /// The key the error is about, when there is one (`limits.fpn_sigma_lsb`).
        key: Option<String>,
        /// What is wrong.
        message: String,
    },
    /// The station file is for another line than the one asked for.
    #[error("{}: the station is for the {file} line, --line {asked} was asked", path.display())]
    LineMismatch {
        /// The station file.
        path: PathBuf,
        /// Its `line`.
        file: crate::Line,
        /// The line asked for.
        asked: crate::Line,
    },
    /// The device failed during a step.
    #[error("{step}: {source}")]
    Device {
        /// The station's step (`dark`, `wiggling`, …).
        step: String,
        /// The device's error.
        #[source]
        source: BridgeError,
    },
    /// Writing a step's recording or the set failed.
    #[error("{step}: {source}")]
    Format {
        /// The station's step.
        step: String,
        /// The file error.
        #[source]
        source: FormatError,
    },
    /// A part could not be extracted from its step's captures.
    #[error("{step}: {source}")]
    Extract {
        /// The station's step.
        step: String,
        /// The extraction's error.
        #[source]
        source: ExtractError,
    },
    /// The check target could not be processed with the new set.
    #[error("check: {source}")]
    Check {
        /// The processing error.
        #[source]
        source: ProcessError,
    },
    /// Writing the report failed.
    #[error("writing {}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
}

impl StationError {
    pub(crate) fn file(path: &std::path::Path, key: &str, message: impl Into<String>) -> Self {
        StationError::File {
            path: path.to_path_buf(),
            key: (!key.is_empty()).then(|| key.to_string()),
            message: message.into(),
        }
    }
}
