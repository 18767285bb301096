//! The lab's one public error type, with a kind.
use std::fmt;

/// What went wrong, coarsely, for callers that branch on it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorKind {
    /// The recording lacks what the lab needs or holds inconsistent data.
    InvalidData,
    /// The model file or spec cannot be used.
    InvalidModel,
    /// An effect id that the lab does not know.
    UnknownEffect,
    /// An effect cannot be fitted on this recording (e.g. temperature never varies).
    NotIdentifiable,
    /// A numerical failure (singular system, non-finite value).
    Numerical,
    /// Reading or writing a file.
    Io,
    /// A recording or model file does not read: the file-format (or model) crate's error, with
    /// its own kind, file and key, is the [`source`](std::error::Error::source).
    Format,
}

/// Error of the model lab.
#[derive(Debug, thiserror::Error)]
pub struct LabError {
    kind: ErrorKind,
    message: String,
    #[source]
    source: Option<Box<dyn std::error::Error + Send + Sync + 'static>>,
}

impl LabError {
    /// An error of `kind` with a message naming what failed.
    pub fn new(kind: ErrorKind, message: impl Into<String>) -> Self {
        Self {
            kind,
            message: message.into(),
            source: None,
        }
    }
    /// A recording that does not read: `message` says what the lab was doing, the format
    /// crate's error (kind, file, key) is kept as the source.
    pub fn format(message: impl Into<String>, source: tofprox_format::FormatError) -> Self {
        Self {
            kind: ErrorKind::Format,
            message: message.into(),
            source: Some(Box::new(source)),
        }
    }
    /// A model file that does not load: `message` says which, the model crate's error (kind,
    /// file) is kept as the source.
    pub fn model(message: impl Into<String>, source: tofprox_model::ModelError) -> Self {
        Self {
            kind: ErrorKind::InvalidModel,
            message: message.into(),
            source: Some(Box::new(source)),
        }
    }
    /// What went wrong, for callers that branch on it.
    pub fn kind(&self) -> ErrorKind {
        self.kind
    }
    pub(crate) fn data(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::InvalidData, message)
    }
    pub(crate) fn numerical(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::Numerical, message)
    }
}

impl fmt::Display for LabError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}
