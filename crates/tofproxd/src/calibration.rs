//! Calibration for the loop: a `tofprox-format` calibration set, keyed to the
//! processing mode (2-phase and 4-phase wiggling LUTs are separate; a LUT of the
//! other mode is refused) and checked against the sensor's full array.

use tofprox_core::Algorithm;
use tofprox_format::CalibrationSet;

use crate::config::Config;
use crate::controller::ModeCalibrations;
use crate::source::FrameSource;

/// Errors loading the calibration.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// The set could not be loaded.
    #[error("{0}")]
    Format(#[from] tofprox_format::FormatError),
    /// The set does not fit the sensor or the mode.
    #[error("calibration {dir}: {message}")]
    Mismatch {
        /// Its directory.
        dir: String,
        /// Why.
        message: String,
    },
}

/// Load the configured calibration (empty when none is configured).
pub fn load_for(
    cfg: &Config,
    source: &dyn FrameSource,
) -> Result<ModeCalibrations, CalibrationError> {
    let Some(dir) = &cfg.processing.calibration else {
        return Ok(ModeCalibrations::default());
    };
    let set = CalibrationSet::load(dir)?;
    let mismatch = |message: String| CalibrationError::Mismatch {
        dir: dir.display().to_string(),
        message,
    };
    let v = &set.validity;
    let (full_rows, full_cols) = source.full_size();
    if (v.full_rows, v.full_cols) != (full_rows, full_cols)
        || (v.rows, v.cols) != (full_rows, full_cols)
    {
        return Err(mismatch(format!(
            "is for a {}x{} window of a {}x{} array; the daemon needs a full-array calibration of {}x{}",
            v.rows, v.cols, v.full_rows, v.full_cols, full_rows, full_cols
        )));
    }
    let needed = match cfg.processing.mode {
        Algorithm::TwoPhase => set.wiggling_2phase.is_some(),
        Algorithm::FourPhase => set.wiggling_4phase.is_some(),
    };
    if cfg.processing.require_calibration && (!needed || set.offset.is_none()) {
        return Err(mismatch(format!(
            "has no offset + wiggling calibration for processing.mode = {} (required)",
            cfg.processing.mode.as_str()
        )));
    }
    Ok(ModeCalibrations {
        two_phase: set.to_pipeline_calibration(Algorithm::TwoPhase),
        four_phase: set.to_pipeline_calibration(Algorithm::FourPhase),
    })
}
