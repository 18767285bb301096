//! Calibration for the loop: a `tofprox-format` calibration set, keyed to the
//! processing mode (2-phase and 4-phase wiggling LUTs are separate; a LUT of the
//! other mode is refused) and checked against the source's sensor by the one validity check
//! of a calibration set (`CalibrationSet::check_compatible`, as `tofprox process` does).

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
    /// The configured directory holds no calibration set (a module not yet calibrated).
    #[error(
        "calibration {dir}: no calibration set there (no calibration.toml): this module has not \
         been calibrated. Calibrate it on the line (`tofprox calibrate station`, docs/calibration.md \
         \"Production line\") or part by part (`tofprox calibrate fpn|crosstalk|wiggling|fppn REC \
         --out {dir}`), or point processing.calibration at its set"
    )]
    NotCalibrated {
        /// The configured directory.
        dir: String,
    },
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
        // README, step 1: uncalibrated 2-phase depth is off by 16–21 cm (thesis fig. 3.7), more
        // than the near/far thresholds; say so at every start rather than run silently.
        tracing::warn!(
            "no calibration set (processing.calibration unset): depth is uncalibrated, 2-phase \
             readings can be off by ~20 cm (set processing.calibration and \
             require_calibration = true; docs/calibration.md)"
        );
        return Ok(ModeCalibrations::default());
    };
    if !dir.join("calibration.toml").exists() {
        return Err(CalibrationError::NotCalibrated {
            dir: dir.display().to_string(),
        });
    }
    let set = CalibrationSet::load(dir)?;
    let mismatch = |message: String| CalibrationError::Mismatch {
        dir: dir.display().to_string(),
        message,
    };
    // The one validity check `tofprox process` applies too: modulation frequency, ADC bits,
    // window and full array of the set against the source's sensor (the daemon reads the full
    // array and crops the set to its read-out window).
    set.check_compatible(&source.sensor())
        .map_err(|e| mismatch(format!("refused for {}: {e}", source.describe())))?;
    if let Some(Err(e)) = set.rays() {
        return Err(mismatch(format!("its lens does not fit its array: {e}")));
    }
    let needed = match cfg.processing.mode {
        Algorithm::TwoPhase => set.wiggling(Algorithm::TwoPhase).is_some(),
        Algorithm::FourPhase => set.wiggling(Algorithm::FourPhase).is_some(),
    };
    if cfg.processing.require_calibration && (!needed || set.offset().is_none()) {
        return Err(mismatch(format!(
            "has no offset + wiggling calibration for processing.mode = {} (required)",
            cfg.processing.mode.as_str()
        )));
    }
    if set.amplitude().is_none() {
        tracing::warn!(
            "calibration {} has no amplitude part (`tofprox calibrate wiggling` writes it): near readings are checked against the nominal amplitude scale proximity.nominal_amplitude_scale = {}",
            dir.display(),
            cfg.proximity.nominal_amplitude_scale
        );
    }
    Ok(ModeCalibrations {
        two_phase: set.to_pipeline_calibration(Algorithm::TwoPhase),
        four_phase: set.to_pipeline_calibration(Algorithm::FourPhase),
        amplitude: set.amplitude().cloned(),
    })
}
