//! The one public error type of `tofprox-core`.

use thiserror::Error;

/// Everything that can go wrong in the processing core. Bad input never panics; it ends here.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum CoreError {
    /// An array does not have the shape the operation needs.
    #[error("shape mismatch for {what}: expected {expected}, got {got}")]
    ShapeMismatch {
        /// Which array (e.g. "raw frames", "offset calibration").
        what: &'static str,
        /// Expected shape, human readable.
        expected: String,
        /// Actual shape, human readable.
        got: String,
    },
    /// A parameter is out of its valid range (non-finite, negative frequency, …).
    #[error("invalid parameter {name}: {reason}")]
    InvalidParameter {
        /// Parameter name as in the API (e.g. "modulation_hz").
        name: &'static str,
        /// Why it is invalid.
        reason: String,
    },
    /// A set of phase shifts is not what the operation needs (not equally spaced, missing 0°/90°, …).
    #[error("invalid phase set {phases_deg:?}: {reason}")]
    InvalidPhases {
        /// The offending phase shifts in degrees.
        phases_deg: Vec<f64>,
        /// Why they are unusable.
        reason: String,
    },
    /// Input data is unusable (non-finite values, all pixels saturated, no signal, …).
    #[error("invalid input data: {0}")]
    InvalidData(String),
    /// A calibration could not be extracted or does not fit the pipeline.
    #[error("calibration error: {0}")]
    Calibration(String),
}

impl CoreError {
    pub(crate) fn shape(what: &'static str, expected: impl ToString, got: impl ToString) -> Self {
        CoreError::ShapeMismatch {
            what,
            expected: expected.to_string(),
            got: got.to_string(),
        }
    }

    pub(crate) fn param(name: &'static str, reason: impl Into<String>) -> Self {
        CoreError::InvalidParameter {
            name,
            reason: reason.into(),
        }
    }
}

/// An error and its causes as one line, `outer: cause: root`, each message
/// once: a cause whose text the line already holds (an error that prints its
/// source, e.g. `cannot read X: No such file (os error 2)` over the I/O error)
/// is not repeated. The one error printer of the
/// binaries and the Python package.
pub fn error_line(err: &(dyn std::error::Error + 'static)) -> String {
    let mut line = String::new();
    let mut cur: Option<&(dyn std::error::Error + 'static)> = Some(err);
    while let Some(e) = cur {
        let m = e.to_string();
        if !m.is_empty() && !line.contains(&m) {
            if !line.is_empty() {
                line.push_str(": ");
            }
            line.push_str(&m);
        }
        cur = e.source();
    }
    line
}
