//! The crate's one public error type, with a [`ErrorKind`] callers match on
//! (in the style of nusb's `Error`): the kind says what failed and whether the
//! next cycle can recover, the context says where (request, register, state).

use std::fmt;

/// What went wrong, coarsely: enough for the daemon to pick a recovery and a
/// `State` to publish.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum ErrorKind {
    /// The device went away (unplug, reset by the host, hub power loss).
    /// Recovery: [`crate::UsbTransport::reopen`] (the driver does this itself
    /// at the start of the next cycle).
    Disconnected,
    /// No matching device on the bus.
    NotFound,
    /// A transfer did not complete in its timeout, or the sensor did not
    /// reach a state in its bounded wait.
    Timeout,
    /// An endpoint answered with STALL (halt). Recovery: clear halt.
    Stall,
    /// An I2C transaction was not acknowledged by the sensor.
    Nak,
    /// A frame failed validation (short, torn, bad header, wrong size,
    /// checksum): it was dropped and never delivered.
    CorruptFrame,
    /// The SPI flash holds no configuration image (erased).
    FlashEmpty,
    /// The SPI flash image is corrupt (bad magic, length or checksum), or a
    /// written image did not verify.
    FlashCorrupt,
    /// The sensor did not come out of reset (no chip id after start-up).
    ResetStuck,
    /// Invalid configuration (files, register map, request parameters).
    Config,
    /// The device answered with something the protocol does not allow.
    Protocol,
    /// Access denied by the OS (udev rule missing) or the device is busy.
    Access,
    /// Any other I/O failure (file, libusb internal).
    Io,
}

impl ErrorKind {
    /// Short stable name (used in logs, JSON and the daemon's `LastError`).
    pub fn as_str(self) -> &'static str {
        match self {
            ErrorKind::Disconnected => "disconnected",
            ErrorKind::NotFound => "not-found",
            ErrorKind::Timeout => "timeout",
            ErrorKind::Stall => "stall",
            ErrorKind::Nak => "i2c-nak",
            ErrorKind::CorruptFrame => "corrupt-frame",
            ErrorKind::FlashEmpty => "flash-empty",
            ErrorKind::FlashCorrupt => "flash-corrupt",
            ErrorKind::ResetStuck => "reset-stuck",
            ErrorKind::Config => "config",
            ErrorKind::Protocol => "protocol",
            ErrorKind::Access => "access",
            ErrorKind::Io => "io",
        }
    }

    /// True when a later cycle may succeed without changing configuration
    /// (everything but `Config`).
    pub fn is_transient(self) -> bool {
        !matches!(self, ErrorKind::Config)
    }
}

impl fmt::Display for ErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The bridge's error: a kind, a human-readable context chain and an optional
/// source.
#[derive(Debug, thiserror::Error)]
#[error("{context}")]
pub struct BridgeError {
    kind: ErrorKind,
    context: String,
    #[source]
    source: Option<Box<dyn std::error::Error + Send + Sync + 'static>>,
}

impl BridgeError {
    /// A new error of `kind` with a context message.
    pub fn new(kind: ErrorKind, context: impl Into<String>) -> Self {
        BridgeError {
            kind,
            context: context.into(),
            source: None,
        }
    }

    /// A new error with an underlying cause.
    pub fn with_source(
        kind: ErrorKind,
        context: impl Into<String>,
        source: impl std::error::Error + Send + Sync + 'static,
    ) -> Self {
        BridgeError {
            kind,
            context: context.into(),
            source: Some(Box::new(source)),
        }
    }

    /// Shorthand for a configuration error.
    pub fn config(context: impl Into<String>) -> Self {
        Self::new(ErrorKind::Config, context)
    }

    /// What went wrong.
    pub fn kind(&self) -> ErrorKind {
        self.kind
    }

    /// The context message (without the source chain).
    pub fn context(&self) -> &str {
        &self.context
    }

    /// Prefix more context (`"outer: old context"`), keeping kind and source.
    pub fn context_prefix(mut self, outer: impl fmt::Display) -> Self {
        self.context = format!("{outer}: {}", self.context);
        self
    }
}

/// Adds context to `Result<_, BridgeError>`.
pub trait ResultExt<T> {
    /// Prefix the error's context with `outer()`.
    fn ctx<D: fmt::Display>(self, outer: impl FnOnce() -> D) -> Result<T, BridgeError>;
}

impl<T> ResultExt<T> for Result<T, BridgeError> {
    fn ctx<D: fmt::Display>(self, outer: impl FnOnce() -> D) -> Result<T, BridgeError> {
        self.map_err(|e| e.context_prefix(outer()))
    }
}

/// Read a configuration file (driver config, register map, emulated device) through the
/// format crate's one bounded reader: regular files only, at most
/// `tofprox_format::limits::MAX_TOML_BYTES`, UTF-8.
pub(crate) fn read_config_text(path: &std::path::Path) -> Result<String, BridgeError> {
    tofprox_format::limits::read_text_bounded(path, tofprox_format::limits::MAX_TOML_BYTES)
        .map_err(|e| BridgeError::with_source(ErrorKind::Config, format!("cannot read {e}"), e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn context_chains_and_kind_survives() {
        let e =
            BridgeError::new(ErrorKind::Nak, "register 0x9400").context_prefix("start measurement");
        assert_eq!(e.kind(), ErrorKind::Nak);
        assert_eq!(e.to_string(), "start measurement: register 0x9400");
        assert!(!ErrorKind::Config.is_transient());
        assert!(ErrorKind::Stall.is_transient());
    }
}
