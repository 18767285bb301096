//! The configuration's errors and the range checks every table's validation is made of.

use std::path::PathBuf;

/// Errors while loading or validating the configuration. The message always
/// names the file and/or the key.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read (missing, not a regular file, above the size limit).
    #[error("cannot read config {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The bounded reader's error (names the file).
        source: tofprox_format::FormatError,
    },
    /// The TOML is malformed or has unknown keys / wrong types.
    #[error("invalid config {path}: {message}")]
    Parse {
        /// The file (or `<string>`).
        path: PathBuf,
        /// toml's message (names the key and line).
        message: String,
    },
    /// A value is out of range.
    #[error("invalid config value `{key}`: {message}")]
    Range {
        /// Dotted key, e.g. `loop.fast_rate_hz`.
        key: String,
        /// What is wrong.
        message: String,
    },
}

pub(super) fn range(key: &str, ok: bool, message: impl Into<String>) -> Result<(), ConfigError> {
    if ok {
        Ok(())
    } else {
        Err(ConfigError::Range {
            key: key.to_string(),
            message: message.into(),
        })
    }
}

pub(super) fn finite_pos(key: &str, v: f64) -> Result<(), ConfigError> {
    range(
        key,
        v.is_finite() && v > 0.0,
        format!("must be a positive number, got {v}"),
    )
}

pub(super) fn fraction(key: &str, v: f32) -> Result<(), ConfigError> {
    range(
        key,
        v.is_finite() && (0.0..=1.0).contains(&v),
        format!("must be within 0..=1, got {v}"),
    )
}

pub(super) fn non_neg(key: &str, v: f64) -> Result<(), ConfigError> {
    range(
        key,
        v.is_finite() && v >= 0.0,
        format!("must be >= 0, got {v}"),
    )
}
