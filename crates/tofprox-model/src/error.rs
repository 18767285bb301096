//! The one public error type of the model crate.

use std::path::PathBuf;

/// What went wrong, for callers that branch on it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorKind {
    /// A model file or table is malformed (TOML syntax, wrong type).
    Parse,
    /// An effect id that is not in the catalogue.
    UnknownEffect,
    /// A parameter name the effect does not have.
    UnknownParam,
    /// A value outside its physical range.
    OutOfRange,
    /// Sensor geometry, capture request or scene is inconsistent.
    InvalidInput,
    /// Reading a model or waveform file failed.
    Io,
}

/// Error of the physical model: names the key (or file) and, for ranges, the allowed interval.
#[derive(Debug, thiserror::Error)]
#[error("{message}")]
pub struct ModelError {
    kind: ErrorKind,
    message: String,
    path: Option<PathBuf>,
    #[source]
    source: Option<Box<dyn std::error::Error + Send + Sync + 'static>>,
}

/// A model or waveform file the bounded reader refused (missing, not a regular file, above
/// its size limit; `tofprox_format::limits`), kept as the source.
impl From<tofprox_format::FormatError> for ModelError {
    fn from(e: tofprox_format::FormatError) -> Self {
        Self::new(ErrorKind::Io, format!("cannot read {e}")).with_source(e)
    }
}

/// An invalid sensor geometry (`tofprox-core`'s validation), kept as the source.
impl From<tofprox_core::CoreError> for ModelError {
    fn from(e: tofprox_core::CoreError) -> Self {
        Self::new(ErrorKind::InvalidInput, format!("sensor geometry: {e}")).with_source(e)
    }
}

impl ModelError {
    pub(crate) fn new(kind: ErrorKind, message: impl Into<String>) -> Self {
        Self {
            kind,
            message: message.into(),
            path: None,
            source: None,
        }
    }
    pub(crate) fn with_source(
        mut self,
        source: impl std::error::Error + Send + Sync + 'static,
    ) -> Self {
        self.source = Some(Box::new(source));
        self
    }
    pub(crate) fn invalid(message: impl Into<String>) -> Self {
        Self::new(ErrorKind::InvalidInput, message)
    }
    pub(crate) fn with_path(mut self, path: &std::path::Path) -> Self {
        self.message = format!("{}: {}", path.display(), self.message);
        self.path = Some(path.to_path_buf());
        self
    }
    /// The kind of failure.
    pub fn kind(&self) -> ErrorKind {
        self.kind
    }
    /// The file the error refers to, if any.
    pub fn path(&self) -> Option<&std::path::Path> {
        self.path.as_deref()
    }
}
