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
}

/// Error of the model lab.
#[derive(Debug, thiserror::Error)]
pub struct LabError {
    kind: ErrorKind,
    message: String,
}

impl LabError {
    /// An error of `kind` with a message naming what failed.
    pub fn new(kind: ErrorKind, message: impl Into<String>) -> Self {
        Self {
            kind,
            message: message.into(),
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
